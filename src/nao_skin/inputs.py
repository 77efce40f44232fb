"""Load touches from what users have: rosbag2 recordings or the thesis' legacy text files."""
from __future__ import annotations

from pathlib import Path

from .datasets import LoadReport
from .errors import DataError
from .skin import SkinCalibration, SkinModel
from .touches import TouchSet

TRUTH_FILE = "truth_calibration.yaml"      # written by `nao-skin simulate` next to its bag


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
    raise DataError(f"{path}: neither a rosbag2 recording nor a legacy .txt data set")


def load_touches(paths, skin: SkinModel, log=print) -> tuple:
    """Touches of every input, concatenated; the load report; ground truth if a simulator wrote one.

    Each input's skip summary goes to ``log``; nothing already read is lost
    because of a bad touch elsewhere.
    """
    from .bagio import read_touches
    from .legacy import read_legacy

    sets, truth = [], None
    report = LoadReport(source=", ".join(str(p) for p in paths))
    for raw in paths:
        path = Path(raw)
        if not path.exists():
            raise DataError(f"{path}: no such file or directory")
        if path.is_file() and path.suffix == ".txt":
            touches, rep = read_legacy(path, skin)
        else:
            bag = find_bag(path)
            touches, rep = read_touches(bag, skin)
            for candidate in (path / TRUTH_FILE, bag.parent / TRUTH_FILE):
                if candidate.exists() and truth is None:
                    truth = SkinCalibration.load(candidate, skin)
        for line in rep.lines(limit=5):
            log(line)
        report.n_read += rep.n_read
        report.n_loaded += rep.n_loaded
        report.merge(rep)
        if touches.n_touches:
            sets.append(touches)
    if not sets:
        raise DataError(f"{report.source}: no usable touch in the input")
    return (sets[0] if len(sets) == 1 else TouchSet.concatenate(sets)), report, truth
