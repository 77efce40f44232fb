"""Load touches from what users have: rosbag2 recordings, simulator output directories, the thesis' text files."""
from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from nao_skin.errors import DataError, NaoSkinError
from nao_skin.model.robot import JOINT_LIMIT_TOLERANCE
from nao_skin.model.skin import SkinCalibration, SkinModel, taxels_said
from nao_skin.paths import read_text
from nao_skin.touch.datasets import LoadReport
from nao_skin.touch.touches import TouchSet

TRUTH_FILE = "truth_calibration.yaml"      # written by `nao-skin simulate` next to its bag
WHAT = "a rosbag2 recording, a simulator output directory or a legacy .txt data set"


@dataclass(frozen=True)
class Inputs:
    """The recordings a calibration reads, as given (a sequence of paths), and the fingertip that pressed each text
    input whose touches a fingertip made (:func:`parse_fingertips`; a bag says so of its touches itself)."""

    paths: tuple
    fingertips: dict = field(default_factory=dict)

    @classmethod
    def of(cls, inputs) -> "Inputs":
        return inputs if isinstance(inputs, Inputs) else cls(tuple(inputs))

    def __iter__(self):
        return iter(self.paths)

    def __len__(self) -> int:
        return len(self.paths)

    def __getitem__(self, i):
        return self.paths[i]


def is_text_input(path: str | Path) -> bool:
    """A data set in the thesis' text format (a legacy .txt file)."""
    path = Path(path)
    return path.is_file() and path.suffix == ".txt"


def is_bag(path: Path) -> bool:
    return (path.is_dir() and (path / "metadata.yaml").exists()) or path.suffix in (".mcap", ".db3")


def find_bag(path: Path) -> Path:
    """A bag directory, a bag file, or a simulator output directory holding one bag."""
    if is_bag(path):
        return path
    if path.is_dir():
        bags = sorted(p for p in path.iterdir() if is_bag(p))
        if len(bags) == 1:
            return bags[0]
        if len(bags) > 1:
            raise DataError(f"{path}: holds {len(bags)} bags ({', '.join(b.name for b in bags)}); name one")
    raise DataError(f"{path}: neither {WHAT}")


def check_inputs(paths) -> None:
    """Fail fast, with the same line in every command, on an input that cannot be read at all."""
    if not paths:
        raise DataError(f"no input given ({WHAT})")
    seen: dict = {}             # recording -> the input that named it first
    for raw in paths:
        path = Path(raw)
        try:
            path.stat()
        except FileNotFoundError:
            raise DataError(f"{path}: no such file or directory") from None
        except OSError as exc:                  # a name too long, a loop of symlinks, no permission on a folder
            raise DataError(f"{path}: cannot read ({exc.strerror})") from None
        if path.is_dir() and not any(path.iterdir()):
            raise DataError(f"{path}: empty directory; expected {WHAT}")
        if path.is_file() and path.suffix != ".txt" and not is_bag(path):
            raise DataError(f"{path}: neither {WHAT}")
        recording = recording_of(path)
        if recording in seen:
            raise DataError(f"{raw}: the same recording as the input {seen[recording]}; give each input once"
                            f" (its touches would count twice)")
        seen[recording] = raw      # as typed: './x/' and 'x' differ only there


def recording_of(path: Path) -> Path:
    """The recording an input names, one path however it is named: a bag's directory, its storage file, the
    simulator output directory holding it, through symlinks."""
    if is_text_input(path):
        return path.resolve()
    bag = find_bag(path).resolve()
    if bag.is_file() and (bag.parent / "metadata.yaml").exists():
        return bag.parent
    return bag


class ReadOnce:
    """An input that no longer grows (an earlier sitting's recording a record session continues), for
    :func:`load_touches`: read on the first load only, then held in memory (moved away or removed meanwhile, it is
    still what was read, and still the recording it was: ``recording``). Each :meth:`read` returns its touches
    and a fresh copy of its load report (the loader adds its notes to the report it gets). It carries no ground
    truth: it is calibrated with a recording the recorder is writing, which never has one."""

    def __init__(self, path: str | Path, skin: SkinModel):
        self.path, self.skin = Path(path), skin
        self.recording: Path | None = None         # :func:`recording_of` the path, as it was read
        self._read: tuple | None = None

    @property
    def held(self) -> bool:
        return self._read is not None

    def read(self) -> tuple:
        import copy

        from nao_skin.formats.bag import read_touches
        from nao_skin.formats.legacy import read_legacy

        if self._read is None:
            self.recording = recording_of(self.path)
            self._read = (read_legacy(self.path, self.skin) if is_text_input(self.path)
                          else read_touches(find_bag(self.path), self.skin))
        touches, report = self._read
        return touches, copy.deepcopy(report)


def read_sitting(path: str | Path, skin: SkinModel) -> ReadOnce:
    """An earlier sitting's recording a record session continues, read (and held) and checked: a
    :class:`~nao_skin.errors.DataError` naming it when it holds no touch, or when its touches do not fit the skin
    the session reads (taxels its layouts lack, contact points far from the taxels they name: a sitting recorded
    with other taxel files, or another robot's recording): its touches would pull every live update apart."""
    sitting = ReadOnce(path, skin)
    touches, report = sitting.read()
    if touches.n_touches == 0:
        raise DataError(f"{path}: holds no touch ({report.summary()})")
    misfit = [*layout_hints(touches, report, skin), *cop_layout_notes(touches, skin, str(path))]
    if misfit:
        raise DataError(f"{misfit[0]} (a session continues only sittings recorded with the taxel files it reads:"
                        f" give that sitting's, {taxels_said()})")
    return sitting


def load_touches(paths, skin: SkinModel, log=print, summary=None, followed=None) -> tuple:
    """Touches of every input, concatenated; the load report; ground truth if a simulator wrote one.

    ``log`` gets each input's summary, what it is (:attr:`LoadReport.info <nao_skin.touch.datasets.LoadReport>`:
    a recording of the simulated robot, one still open) and first skip reasons; ``summary`` (default
    ``log``) gets the one-line summary of every input that skipped something and
    the hints, so a quiet caller still says what was left out. Nothing already
    read is lost because of a bad touch elsewhere. ``followed``: bags read again
    and again while they are recorded, by input path, each a
    :class:`~nao_skin.formats.bag.GrowingBag` that decodes only what is new (or a :class:`ReadOnce`).
    ``paths`` may be :class:`Inputs`: its text inputs a fingertip pressed are read as that fingertip's touches
    (:func:`as_fingertip_touches`).
    """
    from nao_skin.formats.bag import read_touches
    from nao_skin.formats.legacy import read_legacy

    followed = followed or {}
    fingertips = Inputs.of(paths).fingertips
    held = {raw for raw in paths if getattr(followed.get(raw), "held", False)}     # read before, in memory
    if len(held) < len(paths) or not paths:
        check_inputs([raw for raw in paths if raw not in held])
    summary = summary or log
    sets, truths = [], {}     # input -> the simulator's ground truth beside it (None: a real recording)
    report = LoadReport(source=", ".join(str(p) for p in paths))
    for raw in paths:
        path = Path(raw)
        follower = followed.get(raw)
        if isinstance(follower, ReadOnce):
            touches, rep = follower.read()
            truths[raw] = None
        elif is_text_input(path):
            touches, rep = read_legacy(path, skin)
            if str(raw) in fingertips:
                touches = as_fingertip_touches(touches, rep, skin, fingertips[str(raw)], str(path))
            truths[raw] = None
        else:
            bag = find_bag(path)
            touches, rep = follower.read() if follower is not None else read_touches(bag, skin)
            truths[raw] = next((c for c in (path / TRUTH_FILE, bag.parent / TRUTH_FILE) if c.exists()), None)
        for note in (joint_limit_note(touches, skin.robot, str(path)), *cop_layout_notes(touches, skin, str(path))):
            if note:
                rep.notes.append(note)
        lines = rep.lines(limit=5)
        # an input alone that gave no touch: the error below carries its summary line
        said_by_error = len(paths) == 1 and touches.n_touches == 0
        if not said_by_error:
            log(lines[0])
        summarised = rep.notes if summary is not log else []
        if summary is not log:
            for line in ([lines[0]] if rep.n_skipped and not said_by_error else []) + rep.notes:
                summary(line)
        for line in lines[1:]:
            if line not in summarised:      # said once, on the summary's stream
                log(line)
        for hint in layout_hints(touches, rep, skin):
            summary(hint)
        report.n_read += rep.n_read
        report.n_loaded += rep.n_loaded
        report.unit = rep.unit if raw == paths[0] or rep.unit == report.unit else "touches or messages"
        report.merge(rep)
        if touches.n_touches:
            sets.append(touches)
    for note in continuation_notes(paths, followed):
        report.notes.append(note)
        summary(note)
    if not sets:
        why = f"; {report.notes[0]}" if report.notes else ""    # e.g. why no moment was a touch
        raise DataError(f"{report.source}: no usable touch in the input ({report.summary()}){why}")
    truth, note = _ground_truth(truths, skin)
    if note:
        report.notes.append(note)
        summary(note)
    return (sets[0] if len(sets) == 1 else TouchSet.concatenate(sets)), report, truth


def continuation_notes(paths, followed=None) -> list:
    """A line per input recorded as the continuation of earlier sittings (``nao-skin record --continue-from``)
    some of which are not among the inputs: its calibration would leave their touches out. ``followed``:
    :func:`load_touches`'; an input held in memory is the recording it was read from, wherever that is now."""
    from nao_skin.formats.bag import continued_bags

    named = set()
    for raw in paths:
        held = (followed or {}).get(raw)
        try:
            named.add(held.recording if isinstance(held, ReadOnce) and held.held else recording_of(Path(raw)))
        except (NaoSkinError, OSError):
            pass
    out = []
    for raw in paths:
        path = Path(raw)
        try:
            bag = find_bag(path)
        except (NaoSkinError, OSError):      # a text file; an earlier sitting's bag moved away, read before
            continue
        missing = []
        for earlier in continued_bags(bag):
            try:
                recording = recording_of(Path(earlier))
            except (NaoSkinError, OSError):     # not there now: an input held in memory may have been read there
                recording = Path(os.path.realpath(earlier))
            if recording not in named:
                missing.append(earlier)
        if missing:
            out.append(f"{raw}: continues the capture of {', '.join(missing)} (record.launch.py continue_from:=,"
                       f" nao-skin record --continue-from),"
                       f" not among the inputs: name {'it' if len(missing) == 1 else 'them'} too to calibrate the"
                       f" whole capture")
    return out


def _ground_truth(truths: dict, skin: SkinModel) -> tuple:
    """``(truth or None, note or None)``: the simulator's ground truth the inputs carry, when they all carry
    the same one and it is of this skin. Found beside a recording, never asked for: one that does not fit
    (another robot or skin config given) or inputs of different simulations (or a real one among them),
    whose touches no one truth describes, mean no true error, said in a note, never a refused input."""
    files = {str(f.resolve()) if f is not None else None for f in truths.values()}
    if files <= {None}:
        return None, None
    try:    # read as every text input is: a FIFO named like it would wait, /dev/zero never end
        texts = {read_text(f, "as the simulator's ground truth") for f in {f for f in truths.values() if f}}
    except DataError as exc:
        return None, f"{exc}: no true taxel error is reported"
    if None in files or len(texts) > 1:
        each = ", ".join(f"{raw}: {f or 'none'}" for raw, f in truths.items())
        return None, f"the inputs carry different ground truths ({each}): no true taxel error is reported"
    try:
        return SkinCalibration.load(next(iter(truths.values())), skin), None
    except NaoSkinError as exc:
        return None, f"the simulator's ground truth does not fit this skin ({exc}): no true taxel error is reported"


def layout_hints(touches: TouchSet, report: LoadReport, skin: SkinModel) -> list:
    """A line per part whose data mostly names slots its layout does not have: the wrong layout file."""
    out = []
    for part, n_bad in sorted(report.unknown_slots.items()):
        kept = int(np.sum(touches.parts_of_touch()[:, touches.part_index(part)])) if part in touches.part_names else 0
        if n_bad > kept:
            source = skin.parts[part].layout_file if part in skin.parts else "?"
            out.append(f"{report.source}: {n_bad} {report.unit} of part '{part}' name taxels that its layout"
                       f" ({source}) does not have, {kept} touches of it were kept: pass the recording's own"
                       f" layout with {taxels_said(part)}")
    return out


COP_LAYOUT_MM = 20.0    # median recorded COP to its taxels' centre: a few mm with the file skinManager used


def cop_layout_notes(touches: TouchSet, skin, source: str) -> list:
    """One line per part whose recorded contact COPs lie far from the taxels they name in its layout.

    skinManager computes a contact's COP from its own taxel file: with the same layout the COP lies
    among the contact's taxels (the shared real recording: median 2.9 / 3.6 mm, at most 11 mm from
    their centre). Centimetres mean a taxel file of another part or robot, or one in other units:
    the calibration would fit taxels that are not where the skin reported its touches.
    """
    out = []
    known = np.all(np.isfinite(touches.contact_cop), axis=1)
    for index, name in enumerate(touches.part_names):
        part = skin.parts.get(name)
        if part is None:
            continue
        acts = np.flatnonzero(known[touches.act_contact] & (touches.contact_part[touches.act_contact] == index))
        if not len(acts):
            continue
        contact, inverse, count = np.unique(touches.act_contact[acts], return_inverse=True, return_counts=True)
        centre = np.stack([np.bincount(inverse, weights=part.positions[touches.act_slot[acts], d])
                           for d in range(3)], axis=1) / count[:, None]
        median = 1000.0 * float(np.median(np.linalg.norm(centre - touches.contact_cop[contact], axis=1)))
        if median > COP_LAYOUT_MM:
            out.append(f"{source}: part '{name}': the recorded contact COPs lie a median {median:.0f} mm from"
                       f" the taxels they name in {part.layout_file} (a few mm with the layout skinManager used):"
                       f" is that this robot's taxel file of this part?")
    return out


def parse_fingertips(items, inputs, said=lambda item: f"--fingertip {item!r}") -> dict:
    """``--fingertip [INPUT=]NAME`` items as ``{input: fingertip}``: an ``INPUT=NAME`` item names the fingertip that
    pressed one text input's touches, a bare ``NAME`` every text input no item names (the thesis' text format
    does not say which fingertip pressed; a bag does). ``said(item)``: an item as its lines name it (a node's
    parameter, a launch argument)."""
    named, default = {}, None
    texts = [str(p) for p in inputs if is_text_input(p)]
    for item in items:
        path, sep, name = str(item).rpartition("=")
        if not name:
            raise DataError(f"{said(item)}: expected NAME or INPUT=NAME, e.g. r_finger")
        if not sep:
            if default is not None:
                raise DataError(f"{said(item)}: a fingertip for every text input is given twice ({default},"
                                f" {name}); name each input's with INPUT=NAME")
            default = name
            continue
        if path not in [str(p) for p in inputs]:
            raise DataError(f"{said(item)}: {path} is not among the inputs ({', '.join(map(str, inputs))})")
        if path not in texts:
            raise DataError(f"{said(item)}: {path} is a bag; a bag says which fingertip pressed each of its"
                            f" touches, it names a text input's")
        if path in named:
            raise DataError(f"{said(item)}: {path} is given a fingertip twice")
        named[path] = name
    if default is not None:
        if not texts:
            raise DataError(f"{said(default)}: no text input to name it for (a bag says which fingertip pressed"
                            f" each of its touches)")
        named.update({p: default for p in texts if p not in named})
    return named


def as_fingertip_touches(touches: TouchSet, report: LoadReport, skin: SkinModel, fingertip: str,
                         source: str) -> TouchSet:
    """A text input's touches as touches of ``fingertip`` (a fingertip of the robot config): each fires one skin
    part that the skin config's ``fingertip_touch`` has it press. One line, naming the input, where they do not
    fit: a self-touch recording (two parts fire), or a part that fingertip does not press. A touch whose
    fingertip chain's joint angles are missing is skipped (counted in ``report``)."""
    from nao_skin.errors import ConfigError

    try:
        tip = skin.robot.fingertip(fingertip)
    except ConfigError as exc:
        raise DataError(f"{source}: --fingertip {fingertip}: {exc}") from None
    fired = touches.parts_of_touch()
    two = np.flatnonzero(fired.sum(axis=1) >= 2)
    if len(two):
        first = touches.keys[two[0]]
        names = [n for n, f in zip(touches.part_names, fired[two[0]]) if f]
        raise DataError(f"{source}: {len(two)} of {touches.n_touches} touches fire two skin parts (touch {first!r}:"
                        f" {', '.join(names)}): a self-touch recording, not touches of fingertip {fingertip}; name"
                        f" no fingertip for it")
    pressed = {touches.part_names[i] for i in np.flatnonzero(fired.any(axis=0))}
    allowed = {p for f, p in skin.fingertip_touch.pairs() if f == fingertip}
    if pressed - allowed:
        raise DataError(f"{source}: its touches fire {', '.join(sorted(pressed - allowed))}, which fingertip"
                        f" {fingertip} does not press ({skin.source}, fingertip_touch: it presses"
                        f" {', '.join(sorted(allowed)) or 'nothing'}; its chain is {tip.chain})")
    cols = [touches.joint_names.index(j) for j in skin.robot.chain_joint_names(tip.chain) if j in touches.joint_names]
    missing = ~np.all(np.isfinite(touches.joints[:, cols]), axis=1) if cols else np.zeros(touches.n_touches, bool)
    if len(cols) < len(skin.robot.chain_joint_names(tip.chain)):
        missing[:] = True
    if missing.any():
        report.skip("missing joint", f"{source}: {int(missing.sum())} touches lack a joint angle of chain {tip.chain}"
                                     f" (fingertip {fingertip}), e.g. touch {touches.keys[np.flatnonzero(missing)[0]]!r}",
                    count=int(missing.sum()))
        report.n_loaded -= int(missing.sum())
        touches = touches.subset(~missing)
    return touches.with_fingertip(fingertip)


def joint_limit_note(touches: TouchSet, robot, source: str) -> str | None:
    """One line on touches whose angles lie outside the robot config's joint limits, or None.

    They are kept: the angles are what the robot measured, and a limit in the
    config can be tighter than the joint's travel; many of them point at a
    wrong robot config or joint name mapping instead. An angle within
    :data:`~nao_skin.model.robot.JOINT_LIMIT_TOLERANCE` of a limit is at it (an
    encoder count past it at a hard stop): a third of a real recording's touches
    were said to be outside for 0.00007 rad.
    """
    cols = [i for i, n in enumerate(touches.joint_names) if n in robot.joint_index]
    if not cols or touches.n_touches == 0:
        return None
    q = touches.joints[:, cols]
    limits = robot.limits[[robot.joint_index[touches.joint_names[i]] for i in cols]]
    with np.errstate(invalid="ignore"):
        past = np.fmax(limits[:, 0] - q, q - limits[:, 1])        # > 0 outside; NaN (unused joint) ignored
    outside = np.nan_to_num(past, nan=0.0) > JOINT_LIMIT_TOLERANCE
    n = int(outside.any(axis=1).sum())
    if n == 0:
        return None
    t, j = np.unravel_index(np.argmax(np.where(outside, past, -np.inf)), past.shape)
    name = touches.joint_names[cols[j]]
    return (f"{source}: {n} of {touches.n_touches} touches have joint angles outside the robot config's limits"
            f" by over {JOINT_LIMIT_TOLERANCE:g} rad,"
            f" kept (measured angles; the config's limits may be tighter than the joint); the farthest:"
            f" {name} = {q[t, j]:.4g} rad in touch {touches.keys[t]!r}, {past[t, j]:.4g} rad past"
            f" [{limits[j, 0]:.4f}, {limits[j, 1]:.4f}]; check the robot config if many are")
