"""skinManager taxel position files: read and write.

Two forms are in use:

* plain: one row ``x y z nx ny nz`` per taxel slot (metres, local frame of the
  skin part), all-zero rows for thermal pads, missing triangles and unknown taxels;
* with a header, as iCub's ``skinGui``/``skinManager`` position files::

      name            left_hand
      spatial_sampling taxel
      taxel2Repr      ( 0 1 2 ... -2 ... -1 )
      [calibration]
      x y z nx ny nz
      ...

  ``taxel2Repr`` maps each slot to its representative taxel; the convention of
  the Nao skin files is -1 for a slot of an unused triangle and -2 for a thermal pad.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from nao_skin.errors import DataError
from nao_skin.paths import read_text

SLOTS_PER_TRIANGLE = 12
THERMAL_SLOTS = (6, 10)
DEFAULT_SLOTS = 384
# A Nao is about half a metre tall: a coordinate beyond this is another unit (mm) or a broken file,
# and squared distances of values near 1e300 overflow to inf in every later step.
MAX_COORDINATE = 10.0
NORMAL_TOLERANCE = 0.01     # of a taxel normal's length: files give them to 3 decimals or better
MAX_TAXEL_FILE_BYTES = 16 << 20   # 384 rows are some 30 kB; a skinManager file with its other sections, a little more


@dataclass
class TaxelFile:
    positions: np.ndarray            # (S, 3) metres
    normals: np.ndarray              # (S, 3) unit or zero
    name: str = ""
    header: dict = field(default_factory=dict)

    @property
    def present(self) -> np.ndarray:
        """Slots that hold a taxel: a non-zero row that is not a thermal pad."""
        nonzero = np.any(self.positions != 0.0, axis=1) | np.any(self.normals != 0.0, axis=1)
        k = np.arange(len(self.positions)) % SLOTS_PER_TRIANGLE
        return nonzero & ~np.isin(k, THERMAL_SLOTS)


def read_taxel_file(path: str | Path, n_slots: int = DEFAULT_SLOTS) -> TaxelFile:
    """Read either form; rows beyond the file are zero (no taxel)."""
    path = Path(path)
    text = read_text(path, "taxel file", limit=MAX_TAXEL_FILE_BYTES)
    lines = text.splitlines()
    header: dict = {}
    start = 0
    if any(line.strip().lower() == "[calibration]" for line in lines):
        for i, line in enumerate(lines):
            stripped = line.strip()
            if stripped.lower() == "[calibration]":
                start = i + 1
                break
            if stripped and not stripped.startswith(("#", "//")):
                key, _, value = stripped.partition(" ")
                header[key] = value.strip()
    rows = []
    for lineno, line in enumerate(lines[start:], start=start + 1):
        stripped = line.split("#", 1)[0].split("//", 1)[0].strip()
        if not stripped:
            continue
        if stripped.startswith("["):
            if stripped.lower() == "[calibration]":    # its rows would be read as none at all
                raise DataError(f"{path}:{lineno}: a second [calibration] section")
            break  # next section of a skinManager file
        parts = stripped.split()
        if len(parts) != 6:
            raise DataError(f"{path}:{lineno}: expected 6 numbers 'x y z nx ny nz', got {len(parts)}")
        try:
            if "_" in stripped:           # Python's float() reads 0.073_54 as 0.07354: no number of this format
                raise ValueError(stripped)
            values = [float(v) for v in parts]
        except ValueError:
            raise DataError(f"{path}:{lineno}: not a number in {stripped!r}") from None
        if not np.all(np.isfinite(values)):
            raise DataError(f"{path}:{lineno}: non-finite value in {stripped!r}")
        if max(abs(v) for v in values) > MAX_COORDINATE:
            raise DataError(f"{path}:{lineno}: a value beyond {MAX_COORDINATE:g} in {stripped!r}; positions are"
                            f" metres in the part's frame and normals unit vectors")
        length = float(np.linalg.norm(values[3:]))
        if any(values) and len(rows) % SLOTS_PER_TRIANGLE not in THERMAL_SLOTS and abs(length - 1.0) > NORMAL_TOLERANCE:
            # a taxel's normal places its fabric surface and orients its triangle: (5, 5, 5) moved a
            # calibration by a millimetre without a word
            raise DataError(f"{path}:{lineno}: the normal of slot {len(rows)} has length {length:.4g} in"
                            f" {stripped!r}; normals are unit vectors")
        rows.append(values)
        if len(rows) > n_slots:
            raise DataError(f"{path}:{lineno}: taxel row {len(rows)}, more than the {n_slots} slots of a skin part")
    if not rows:
        raise DataError(f"{path}: no taxel rows found")
    if len(rows) % SLOTS_PER_TRIANGLE:
        # rows beyond a file's end are slots without a taxel, but a triangle is written whole or not at all
        raise DataError(f"{path}: {len(rows)} taxel rows, which ends inside triangle {len(rows) // SLOTS_PER_TRIANGLE}"
                        f" ({SLOTS_PER_TRIANGLE} rows per triangle): is the file cut short?")
    data = np.zeros((n_slots, 6))
    data[: len(rows)] = rows
    return TaxelFile(data[:, :3].copy(), data[:, 3:].copy(), name=header.get("name", path.stem), header=header)


def write_taxel_file(path: str | Path, positions: np.ndarray, normals: np.ndarray, present: np.ndarray,
                     name: str, with_header: bool = True) -> None:
    """Write positions/normals of present slots (others as zero rows), 8 decimals."""
    positions = np.where(present[:, None], positions, 0.0)
    normals = np.where(present[:, None], normals, 0.0)
    out = []
    if with_header:
        k = np.arange(len(present)) % SLOTS_PER_TRIANGLE
        repr_ids = np.where(present, np.arange(len(present)), np.where(np.isin(k, THERMAL_SLOTS), -2, -1))
        out.append(f"name {name}")
        out.append("spatial_sampling taxel")
        out.append("taxel2Repr ( " + " ".join(str(int(v)) for v in repr_ids) + " )")
        out.append("[calibration]")
    for p, n in zip(positions, normals):
        out.append(" ".join(f"{v:.8f}" for v in (*p, *n)))
    Path(path).write_text("\n".join(out) + "\n")
