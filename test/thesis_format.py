"""Touches written in the thesis' text format (a dict literal per file), as its recorder wrote them."""
from pathlib import Path

import numpy as np


def write_thesis_file(path: Path, touches, skin) -> None:
    """The touches in the thesis' text format, as its recorder wrote them: timestamp keys, skinManager
    contacts with the nominal taxel positions and their mean as the COP (no pressure known)."""
    nominal = {name: skin.parts[name].taxel_positions(None) for name in touches.part_names}
    entries = {}
    for t in range(touches.n_touches):
        contacts = {}
        for c in np.flatnonzero(touches.contact_touch == t):
            part = touches.part_names[touches.contact_part[c]]
            slots = touches.act_slot[touches.act_contact == c]
            pos, nor = nominal[part]
            cop = [float(v) for v in pos[slots].mean(axis=0)]
            contacts[len(contacts)] = {
                "cop": cop, "geoCenter": cop, "normal": [float(v) for v in nor[slots].mean(axis=0)],
                "skinPart": part, "bodyPartId": 0, "linkNumber": 0, "force": None, "moment": None,
                "averagePressure": None,
                "taxelInfo": {str(int(s)): [float(v) for v in np.r_[pos[s], nor[s]]] for s in slots}}
        joints = {name: float(touches.joints[t, k]) for k, name in enumerate(touches.joint_names)}
        entries[f"{touches.stamps[t]:.6f}"] = [contacts, joints]
    path.write_text(repr(entries))
