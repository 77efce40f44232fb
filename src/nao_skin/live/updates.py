"""Live calibration's bookkeeping, pure: when an update is due, how far the taxels moved, which parts settled.

The calibrate node recalibrates in the background while touches arrive; these
decide when (every ``every_touches`` new touches, or ``period`` seconds after
the last update if any touch came since), whether an update is sane enough to
publish, and say, per part, whether more touches still move it:
``collecting`` (not calibrated yet), ``converging``, or ``done`` (its taxels
moved less than ``settle_mm`` in each of the last ``updates`` updates, and
the held-out figure stayed flat over them: within ``flat_percent`` of its
mean, so a part is not called done while the fit still improves elsewhere).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np

from nao_skin.errors import DataError, NaoSkinError
from nao_skin.model.skin import SkinCalibration, SkinModel


@dataclass
class UpdateSchedule:
    every_touches: int = 25
    period: float = 10.0                  # s
    last_touches: int = 0                 # touches the last update started from
    last_time: float = -np.inf

    def due(self, touches: int, now: float) -> bool:
        new = touches - self.last_touches
        return new > 0 and (new >= self.every_touches or now - self.last_time >= self.period)

    def started(self, touches: int, now: float) -> None:
        self.last_touches, self.last_time = touches, now

    def again(self) -> None:
        """The update just started found no new touch to read (the recorder counts one before it flushes it):
        due again at the next check."""
        self.last_touches -= 1
        self.last_time = -np.inf


@dataclass
class WarmStart:
    """What the next live update starts from: mostly the last accepted calibration, now and then the whole plan.

    A warm update (``calibrate(..., prior=last, warm=parts, anchor=start, resume=state)``)
    runs only the joint refinement from the last accepted calibration and the
    prior widths its fit learnt, its patch and triangle prior centred where the
    session started. Warm updates
    cannot undo everything an early estimate from a few touches got wrong, so
    whenever the touches have grown ``refresh`` times since the last update
    from scratch, the next one is from scratch again (the whole plan from the
    session's start): with 2, at about 30, 60, 120, ... 1000, 2000 touches,
    a handful in a session, and the warm ones in between. :meth:`update` runs
    the warm update beside it and keeps the one whose held-out touches pair
    closer: over simulated sessions the warm chain was the closer one at every
    refresh after the first (seed 0 at 800 touches: test closest taxel 3.13
    against 3.40 mm, true worst part median 0.57 against 0.77 mm).
    """

    start: SkinCalibration                  # where the session started (nominal, or the calibration given)
    refresh: float = 2.0
    last: SkinCalibration | None = None     # the last accepted update's
    parts: tuple = ()                       # the parts it calibrated
    scratch_touches: int = 0                # touches of the last update from scratch
    state: object = None                    # the last accepted update's CalibrationResult.state
    refreshed: bool = False                 # the last update ran from scratch and warm, and kept the closer

    def arguments(self, n_touches: int, warm_only: bool = False) -> dict:
        """``prior``, ``warm``, ``anchor`` and ``resume`` of :func:`~nao_skin.calibration.engine.calibrate`
        for the next update; ``warm_only``: no refresh now (a session's final update: it goes on from the last
        accepted one, in a fraction of a refresh's time)."""
        if self.last is None or not self.parts or (n_touches >= self.refresh * self.scratch_touches
                                                   and not warm_only):
            return {"prior": self.start, "warm": (), "anchor": None, "resume": None}
        return self._warm_arguments()

    def _warm_arguments(self) -> dict:
        return {"prior": self.last, "warm": self.parts, "anchor": self.start, "resume": self.state}

    def update(self, n_touches: int, run: Callable[[dict], Any], warm_only: bool = False) -> tuple:
        """The next update, ``(result, arguments)``: ``run(arguments)`` calibrates with :meth:`arguments`'
        keywords and returns its :class:`~nao_skin.calibration.engine.CalibrationResult`. At a refresh that
        follows an accepted update the warm update runs too, and the result whose test split's closest
        taxel pairs are closer (mean, mm) is returned; either way the refresh is done for ``refresh`` times
        more touches. Hand both to :meth:`accepted` when the result is published."""
        arguments = self.arguments(n_touches, warm_only)
        self.refreshed = False
        result = run(arguments)
        if arguments["warm"] or self.last is None or not self.parts:
            return result, arguments
        self.scratch_touches = n_touches
        self.refreshed = True
        warm = self._warm_arguments()
        try:
            other = run(warm)
        except NaoSkinError:      # the update from scratch stands on its own
            return result, arguments
        if _test_taxel_mm(other) < _test_taxel_mm(result):
            return other, warm
        return result, arguments

    def accepted(self, result, n_touches: int, arguments: dict) -> None:
        """An update's result was published: the next warm update goes on from its calibration, the parts
        calibrated so far (this update's, and any an earlier one calibrated: its frames are held in this
        one's, :meth:`LiveUpdates.update`) and its fit's
        :attr:`~nao_skin.calibration.engine.CalibrationResult.state`."""
        if not arguments["warm"]:
            self.scratch_touches = n_touches
        self.last, self.state = result.calibration, result.state
        self.parts = tuple(dict.fromkeys([*self.parts, *result.report.parts]))


def _test_taxel_mm(result) -> float:
    """The test split's mean closest taxel pair of a calibration result (inf when it has none)."""
    value = result.report.final.get("test", {}).get("taxel_mean_mm", float("nan"))
    return float(value) if np.isfinite(value) else float("inf")


def taxel_displacement_mm(skin: SkinModel, before: SkinCalibration, after: SkinCalibration, parts) -> dict:
    """``{part: largest distance one of its taxels moved, mm}`` between two calibrations (chain-end frame)."""
    out = {}
    for name in parts:
        part = skin.parts[name]
        a, _ = part.taxel_positions(before.parts.get(name))
        b, _ = part.taxel_positions(after.parts.get(name))
        d = np.linalg.norm((a - b)[part.present], axis=1)
        out[name] = 1000.0 * float(d.max()) if len(d) else 0.0
    return out


def rejection(skin: SkinModel, calib: SkinCalibration, displacement_mm: dict, calibrated_before,
              max_move_mm: float) -> str | None:
    """Why an update must not be published (it diverged), or None.

    Non-finite frames, or a part the last accepted update had calibrated
    moving more than ``max_move_mm``: a few more touches refine a part, they
    do not relocate it (its first calibration may: a hand mount ~160 deg off).
    """
    for name, corr in calib.parts.items():
        if name in skin.parts and not all(np.all(np.isfinite(x)) for x in (corr.mount, corr.patches, corr.triangles)):
            return f"part '{name}': the update has non-finite frames"
    jumps = {p: mm for p, mm in displacement_mm.items() if p in calibrated_before and mm > max_move_mm}
    if jumps:
        part, mm = max(jumps.items(), key=lambda kv: kv[1])
        return (f"part '{part}': its taxels would move {mm:.1f} mm since the last accepted update"
                f" (more than {max_move_mm:g} mm: diverged)")
    return None


RELEASE = 2.0     # a done part is converging again once an update moves it this many times settle_mm


@dataclass
class Settling:
    """Per part: the displacement of each update it was calibrated in; its state from the last few.

    ``settle_mm`` is measured, not a wish: an update re-pairs the touches, so even at 1500 touches a part's
    largest taxel moves 0.15–0.3 mm from one update of 25 new touches to the next. At 0.1 mm every part was
    done in none of 20 simulated sessions by 1500 touches (random capture, ``nao-skin bench-capture
    --until-done --settle-mm 0.1 --strategies random --seeds 20``). At 0.3 mm, with the margin of
    :meth:`add`, it was in 19 of them, at about 1060 touches, the worst part's true taxel error median then
    0.51 mm (highest 0.65): the same without ``--settle-mm``. Fewer new touches per update (a slow
    operator, every ``period`` seconds) move the taxels less, so "done" comes sooner there."""

    settle_mm: float = 0.3
    updates: int = 3
    flat_percent: float = 5.0
    release: float = RELEASE
    history: dict = field(default_factory=dict)     # part -> [mm per update]
    figures: list = field(default_factory=list)     # held-out closest taxel mean (mm) per update
    done: set = field(default_factory=set)          # the parts done now

    def add(self, displacement_mm: dict, test_figure_mm: float = float("nan")) -> None:
        """One accepted update: how far each part it calibrated moved (mm), and its held-out figure.

        A part becomes done as the class says; once done it stays done until an update moves it ``release``
        times ``settle_mm`` or more. Without that margin the state of a part whose moves hover about
        ``settle_mm`` (0.19–3.7 mm, median 0.35, over 60 updates at 1200–2400 touches of a simulated
        session) went back and forth 20 times, every part at once whenever the held-out figure wavered: no
        signal an operator can stop on."""
        for part, mm in displacement_mm.items():
            self.history.setdefault(part, []).append(float(mm))
        self.figures.append(float(test_figure_mm))
        flat = self.figure_flat()
        for part, mm in displacement_mm.items():
            moved = self.history[part]
            if part in self.done:
                if mm >= self.release * self.settle_mm:
                    self.done.discard(part)
            elif flat and len(moved) >= self.updates and max(moved[-self.updates:]) < self.settle_mm:
                self.done.add(part)

    def figure_flat(self) -> bool:
        last = np.array(self.figures[-self.updates:])
        if len(last) < self.updates or not np.all(np.isfinite(last)):
            return False
        return bool(np.max(np.abs(last - last.mean())) <= self.flat_percent / 100.0 * last.mean())

    def states(self, parts) -> dict:
        return {part: "done" if part in self.done else "converging" if self.history.get(part) else "collecting"
                for part in parts}


class LiveUpdates:
    """One live update after another: what the calibrate node does with each and what the capture benchmark
    replays, so both see the same calibrations and the same part states.

    Each update starts where :class:`WarmStart` says; a result that diverged (:func:`rejection`) is
    refused and the last accepted one stays; an accepted one adds its displacement and held-out figure
    to :class:`Settling`. ``max_move_mm``: an update moving a part it had calibrated farther than this
    diverged.
    """

    MAX_MOVE_MM = 20.0      # a few more touches refine a part by tenths of a millimetre, never by centimetres

    def __init__(self, skin: SkinModel, start: SkinCalibration, refresh: float = WarmStart.refresh,
                 settling: Settling | None = None, max_move_mm: float = MAX_MOVE_MM):
        self.skin = skin
        self.warm_start = WarmStart(start, refresh)
        self.settling = Settling() if settling is None else settling
        self.max_move_mm = float(max_move_mm)

    def states(self, parts) -> dict:
        """``{part: collecting | converging | done}``."""
        return self.settling.states(parts)

    def update(self, n_touches: int, run: Callable[[dict], Any], warm_only: bool = False) -> tuple:
        """The next update over ``n_touches`` touches, ``(result, displacement_mm, arguments)``: ``run`` and
        ``warm_only`` as :meth:`WarmStart.update`'s. Raises :class:`~nao_skin.errors.DataError` when the result
        diverged (the last accepted calibration stays), and whatever ``run`` raises."""
        result, arguments = self.warm_start.update(n_touches, run, warm_only)
        before = self.warm_start.last or self.warm_start.start
        held = self._hold_parts_left_out(result, before)
        moved = taxel_displacement_mm(self.skin, before, result.calibration, result.report.parts)
        why = rejection(self.skin, result.calibration, moved, self.warm_start.parts, self.max_move_mm)
        if why is not None:
            raise DataError(f"update over {n_touches} touches not published: {why}")
        # the calibration holds them (written with their taxel files), as the update's warning says
        result.report.parts = [*result.report.parts, *held]
        self.settling.add(moved, result.report.final.get("test", {}).get("taxel_mean_mm", float("nan")))
        self.warm_start.accepted(result, n_touches, arguments)
        return result, moved, arguments

    @property
    def calibrated_parts(self) -> tuple:
        """The parts an accepted update has calibrated so far (each held since at its last value when an update
        left it out)."""
        return self.warm_start.parts

    def _hold_parts_left_out(self, result, before: SkinCalibration) -> list:
        """A part an earlier update calibrated and this one left out (its pairs' training touches fell below the
        minimum, as a new split may make them) keeps its last accepted frames: an update from scratch would
        otherwise publish it back at the session's start, and the next one would calibrate it anew unchecked."""
        left_out = [p for p in self.warm_start.parts if p not in result.report.parts and p in before.parts]
        for part in left_out:
            result.calibration.parts[part] = before.parts[part].copy()
            result.report.warnings.append(f"part '{part}': not calibrated by this update (too few touches in its"
                                          f" training split); its frames stay at the last accepted update's")
        return left_out
