"""Touches written into a bag the way the pairing recorder writes them (tests of live recordings).

Also imported by the writer process of ``test_recording_survives.py``: one definition for both.
"""
from __future__ import annotations

import numpy as np


def write_recorded(bag, skin, touches, rows) -> None:
    """The touches ``rows`` into the open ``BagWriter``: per touch a JointState, then each touching part's taxels."""
    names = np.array(touches.part_names)
    for t in rows:
        stamp = int(round(touches.stamps[t] * 1e9))
        bag.write_joint_state(stamp, touches.joint_names, touches.joints[t])
        a = np.flatnonzero(touches.act_touch == t)
        for p in np.unique(touches.act_part[a]):
            sel = a[touches.act_part[a] == p]
            part = skin.part(names[p])
            slots = touches.act_slot[sel]
            bag.write_taxels(stamp, names[p], part.parent_frame, part.positions[slots], slots,
                             touches.act_pressure[sel], touches.contact_id[touches.act_contact[sel]])
