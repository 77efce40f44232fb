"""Results as plain JSON values: the one conversion every report, benchmark and topic uses."""
from __future__ import annotations

import numpy as np


def jsonable(obj, skip_keys: tuple = ()):
    """``obj`` with numpy scalars and arrays as Python values, tuples as lists, keys as strings and
    non-finite floats as None (JSON has no NaN); mapping entries named in ``skip_keys`` are left out."""
    if isinstance(obj, dict):
        return {str(k): jsonable(v, skip_keys) for k, v in obj.items() if k not in skip_keys}
    if isinstance(obj, (list, tuple)):
        return [jsonable(v, skip_keys) for v in obj]
    if isinstance(obj, np.ndarray):
        return jsonable(obj.tolist(), skip_keys)
    if isinstance(obj, np.generic):
        obj = obj.item()
    if isinstance(obj, float) and not np.isfinite(obj):
        return None
    return obj
