"""A record session's live calibration, pure: one update over every touch recorded so far.

The calibrate node runs :meth:`LiveCalibration.update` in the background
whenever :class:`~nao_skin.live.updates.UpdateSchedule` says one is due, and
only publishes what it returns. An update reads what the recorder wrote since
the last one (a :class:`~nao_skin.formats.bag.GrowingBag`) and hands the
calibration to :class:`~nao_skin.live.updates.LiveUpdates`, as the capture
benchmark does: warm from the last accepted update, refused when it diverged,
and per part whether more touches still move it. A failed update changes
nothing: the last accepted calibration stays the one to publish and write.
When the session ends, a final update (``final=True``, once the recorder has
closed the bag: :meth:`LiveCalibration.wait_until_closed`) calibrates the
touches recorded since the last one, so that what is written covers them all.
An update can be stopped between two stages of its calibration (``stop``): a
session's end does not wait for an update it no longer needs, nor for a
final one past its time (the last accepted calibration stays the one written).
A session that continues earlier sittings (``earlier``: their bags, read once
at its start) calibrates their touches with the recording's, from the first
update on, which needs no new touch.
"""
from __future__ import annotations

import os
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Sequence

from nao_skin.calibration.engine import CalibrationResult
from nao_skin.calibration.options import CalibrationOptions
from nao_skin.calibration.pipeline import calibrate_loaded, load_inputs
from nao_skin.calibration.plan import pair_counts
from nao_skin.errors import DataError, NaoSkinError, TooFewTouches, one_line
from nao_skin.formats.bag import GrowingBag
from nao_skin.formats.inputs import ReadOnce, check_inputs, find_bag, read_sitting, recording_of
from nao_skin.formats.outdir import is_free, output_stamp
from nao_skin.formats.salvage import recording_lock
from nao_skin.live.updates import LiveUpdates, PartStates, WarmStart
from nao_skin.model.skin import SkinCalibration, SkinModel, pair_label
from nao_skin.paths import free_sibling
from nao_skin.touch.datasets import repeats_of
from nao_skin.touch.touches import TouchSet


class UpdateStopped(BaseException):
    """Raised between two stages of an update's calibration when its ``stop`` says so (a BaseException: no
    ``except Exception`` on the way takes it for a failure)."""


def stoppable(log: Callable[[str], None], stop: Callable[[], bool] | None) -> Callable[[str], None]:
    """``log``, that raises :class:`UpdateStopped` once ``stop()`` is true (the engine says each stage's end)."""
    if stop is None:
        return log

    def said(msg: str) -> None:
        if stop():
            raise UpdateStopped
        log(msg)

    return said


@dataclass
class LiveOutcome:
    """What one update did: the status to latch (the node adds the generation it publishes; empty when the
    bag held no touch since the last accepted update, so nothing ran), the result to publish if it was
    accepted, and every touch read (for the guidance; None when reading failed)."""

    status: dict
    accepted: CalibrationResult | None = None
    touches: TouchSet | None = None


class LiveCalibration:
    """The live calibration of one recording, update after update.

    ``start``: where the session started (nominal, or the calibration given);
    ``refresh``, ``scratch_below``: :class:`~nao_skin.live.updates.WarmStart`'s; ``max_move_mm``:
    an update moving a part it had calibrated farther than this diverged.
    """

    def __init__(self, skin: SkinModel, options: CalibrationOptions, recording: str | Path,
                 start: SkinCalibration, refresh: float, part_states: PartStates, max_move_mm: float,
                 earlier: Sequence = (), scratch_below: int = WarmStart.scratch_below):
        self.skin, self.options, self.recording = skin, options, str(recording)
        self.earlier = [str(p) for p in earlier]        # bags of earlier sittings: the session continues them
        self.earlier_count = 0                          # their touches (exact duplicates left out)
        self.updates = LiveUpdates(skin, start, refresh, part_states, max_move_mm, scratch_below)
        self.last: CalibrationResult | None = None     # the last accepted update's result
        self.last_count = 0                             # how many touches it calibrated
        self.read_count = 0                             # how many touches the recording held at the last read
        self.duplicates = 0                             # ... after leaving out this many exact duplicates
        self.recorded = 0                               # touches the recording held at the last read (all)
        self.repeated = 0                               # ... of them exact repeats of the earlier sittings' touches
        self._earlier_touches: TouchSet | None = None   # the earlier sittings' touches (duplicates left out)
        self._last_touches = -1                         # touches the last update calibrated (-1: it failed)
        # input -> its reader: each earlier sitting held once read (ReadOnce), the recording read as it grows
        self._followed: dict = {p: ReadOnce(p, skin) for p in self.earlier}
        self._bag_dir: Path | None = None

    def read_earlier(self, log: Callable[[str], None] | None = None,
                     summary: Callable[[str], None] | None = None) -> int:
        """Read the earlier sittings' bags once (they no longer grow: held in memory from now on), so that a bad
        one (:func:`~nao_skin.formats.inputs.read_sitting`) is said at the session's start, in one line
        (:class:`~nao_skin.errors.NaoSkinError`), not at its first update; their touches, exact duplicates left
        out. ``summary``: what is worth a look (e.g. a sitting they continue that is not among them)."""
        if self.earlier:
            log = log or (lambda msg: None)
            check_inputs(self.earlier)          # none named twice (a node started without nao-skin record's checks)
            if os.path.lexists(self.recording) and recording_of(Path(self.recording)) in \
                    {recording_of(Path(path)) for path in self.earlier}:
                raise DataError(f"{self.recording}: the recording is among the earlier sittings it continues;"
                                f" name only the earlier ones")
            self._followed.update({path: read_sitting(path, self.skin) for path in self.earlier})
            self._earlier_touches = load_inputs(self.earlier, self.skin, log=log, summary=summary or log,
                                                followed=self._followed).touches
            self.earlier_count = self._earlier_touches.n_touches
        return self.earlier_count

    def parts_state(self) -> dict:
        """``{part: collecting | converging | done}``."""
        return self.updates.states(self.skin.parts)

    def update(self, log: Callable[[str], None] | None = None, final: bool = False,
               stop: Callable[[], bool] | None = None) -> LiveOutcome:
        """Recalibrate on every touch recorded so far; never raises (a failure is a ``failed`` status).

        ``final``: the session's end; an update only when the recording holds a touch the last accepted
        update did not calibrate (empty status otherwise), so the calibration written covers every touch.
        ``stop``: checked between the calibration's stages (never while the recording is read); once true the
        update ends with a ``stopped`` status and changes nothing, the last accepted calibration stays.
        """
        log = log or (lambda msg: None)
        t0 = time.perf_counter()
        touches = None
        try:
            if self.recording not in self._followed and (not self.earlier or self.recording_exists()):
                bag = find_bag(Path(self.recording))     # the recorder has created the bag by its first touch
                self._bag_dir = bag if bag.is_dir() else bag.parent
                self._followed[self.recording] = _Kept(GrowingBag(bag, self.skin))
            # a session continuing earlier sittings calibrates their touches before its own first one
            inputs = [*self.earlier, *([self.recording] if self.recording in self._followed else [])]
            loaded = load_inputs(inputs, self.skin, log=log, summary=log, followed=self._followed)
            touches = loaded.touches
            self.read_count, self.duplicates = touches.n_touches, loaded.n_duplicates
            recorded = getattr(self._followed.get(self.recording), "touches", None)
            if recorded is not None:
                self.recorded = recorded.n_touches
                if self._earlier_touches is not None:
                    self.repeated = repeats_of(recorded, self._earlier_touches)
            if touches.n_touches == self._last_touches and (final or self._being_recorded()):
                # the recorder counts a touch before its next flush puts it in the bag: an update now would
                # repeat the last one (a closed bag, e.g. bench-live's --update-input, is calibrated again each
                # time: that is what is asked)
                return LiveOutcome({}, None, None)
            calibration_log = stoppable(log, stop)
            # the final update goes on from the last accepted one (warm), never a refresh from scratch: it adds the
            # touches since, at a session's end that must not keep the user waiting (below live_scratch_below
            # touches it is from scratch, as every update there: under a second)
            result, moved, start = self.updates.update(
                touches.n_touches,
                lambda args: calibrate_loaded(loaded, self.skin, self.options, log=calibration_log, **args),
                warm_only=final)
            report = result.report
            self.last, self._last_touches, self.last_count = result, touches.n_touches, touches.n_touches
            return LiveOutcome({"state": "updated", "touches": touches.n_touches,
                                "pairs": {pair_label(p): n for p, n in pair_counts(touches).items()},
                                "final": {k: report.final.get(k) for k in ("train", "test")},
                                "displacement_mm": moved, "held": report.held, "left_out": report.left_out,
                                "predicted_taxel_error_mm": report.final.get("predicted_taxel_error_mm", {}),
                                "parts": self.parts_state(), "seconds": time.perf_counter() - t0,
                                "from_scratch": not start["warm"],
                                # a refresh runs both (its seconds are theirs) and keeps the closer
                                "refresh": self.updates.warm_start.refreshed,
                                "warnings": report.warnings,
                                **({"earlier": self.earlier_count} if self.earlier else {})}, result, touches)
        except UpdateStopped:             # the session ends: nothing accepted, the next update runs again
            self._last_touches = -1
            return LiveOutcome({"state": "stopped", "touches": touches.n_touches, "seconds": time.perf_counter() - t0,
                                "parts": self.parts_state()}, None, touches)
        except TooFewTouches as exc:      # no pair has touches enough yet: wait for more
            self._last_touches = -1
            return LiveOutcome({"state": "waiting", "reason": str(exc), "parts": self.parts_state()}, None, touches)
        except NaoSkinError as exc:       # unreadable recording, diverged update: the last good frames stay
            self._last_touches = -1         # the next update runs, to say the recording is good again
            return LiveOutcome({"state": "failed", "error": str(exc), "parts": self.parts_state()}, None, touches)
        except Exception as exc:  # noqa: BLE001 - a failed update keeps the last good calibration published
            self._last_touches = -1
            return LiveOutcome({"state": "failed", "error": one_line(exc), "parts": self.parts_state()}, None,
                               touches)


    def _being_recorded(self) -> bool:
        """The recording is open in its recorder (its lock names a running process)."""
        lock = recording_lock(self._bag_dir) if self._bag_dir is not None else None
        return lock is not None and lock.state == "open"

    def recording_exists(self) -> bool:
        """The recorder has made the recording (it does with its first touch)."""
        if self._bag_dir is None:
            try:
                bag = find_bag(Path(self.recording))
            except (NaoSkinError, OSError):
                return False
            self._bag_dir = bag if bag.is_dir() else bag.parent
        return True

    def wait_until_closed(self, timeout: float, poll: float = 0.05) -> bool:
        """Wait up to ``timeout`` s for the recorder to close the recording (at the session's end it writes the
        touches it still holds, then closes): True when it is closed."""
        deadline = time.monotonic() + timeout
        while self._being_recorded():
            if time.monotonic() >= deadline:
                return False
            time.sleep(poll)
        return True


class _Kept:
    """The recording's reader (a :class:`~nao_skin.formats.bag.GrowingBag`), keeping the touches it read last,
    before the calibration leaves out their duplicates: how many of them repeat the earlier sittings' is said."""

    def __init__(self, reader):
        self.reader, self.touches = reader, None

    def read(self) -> tuple:
        touches, report = self.reader.read()
        self.touches = touches
        return touches, report


def request_out_dir(out_dir: str | Path, own: tuple | None) -> tuple:
    """``(directory, replacing, note or None)``: where the calibrate node writes a requested calibration, and what
    it may replace there (``replacing`` of :func:`~nao_skin.formats.outdir.replace_dir`). ``own``: ``(path,
    output_stamp)`` of the node's last output, which it may replace; else ``out_dir`` when it is free, or, when it
    holds a calibration the node did not write (an earlier run's, another command's), the first free
    ``<out_dir>.new``: the node never replaces what it was not asked to."""
    if own is not None and output_stamp(own[0]) == own[1]:
        return own[0], own[1], None
    if is_free(os.path.realpath(out_dir)):       # a link to an empty directory is free too
        return out_dir, (), None
    beside = free_sibling(out_dir, ".new")
    return beside, (), (f"out_dir {out_dir} holds a calibration this node did not write (an earlier run's, or"
                        f" another command's) and is left as it is; this one goes to {beside}")


def session_end_out_dir(out_dir: str | Path, at_start, requested) -> tuple:
    """``(directory, replacing, warning or None)``: where the session's last live calibration is written when it
    ends, and what it may replace there (``replacing`` of :func:`~nao_skin.formats.outdir.replace_dir`).

    ``out_dir`` when it is free, or when it holds the calibration requested of the node during the session
    (``requested``: its :func:`output_stamp`), which it replaces: both are the node's, and the session's last is
    the one to apply (its user finds it where the README says, ``<bag>_calibration/``). Else it holds a
    calibration that stays: an earlier one it held when the session started (``at_start``: its stamp then), or
    another command's (e.g. a calibrate --out of the bag so far); the live calibration goes beside it, and the
    warning says why.
    """
    if is_free(os.path.realpath(out_dir)):
        return out_dir, (), None
    now = output_stamp(out_dir)
    if requested is not None and now == requested:
        return out_dir, requested, None
    beside = free_sibling(out_dir, ".live")
    what = ("held an earlier calibration when the session started" if now == at_start
            else "was written by another command during the session")
    return beside, (), (f"out_dir {out_dir} {what} and is left as it is; the session's last live calibration goes to"
                        f" {beside}")
