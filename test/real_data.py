"""Where the shared real recording is: ``$NAO_SKIN_REAL_DATA``, ``../shared`` beside this
checkout (as CI lays it out), or the workplace's /work/shared. Read in place, never copied."""
import os
from pathlib import Path


def _find() -> Path:
    env = os.environ.get("NAO_SKIN_REAL_DATA")
    candidates = [Path(env)] if env else []
    candidates += [Path(__file__).resolve().parents[2] / "shared" / "data" / "real_selftouch",
                   Path("/work/shared/data/real_selftouch")]
    for c in candidates:
        if (c / "l_hand_torso.legacy.txt").exists():
            return c
    return candidates[0]


REAL_DIR = _find()
