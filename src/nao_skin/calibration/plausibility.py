"""What makes a finished calibration implausible, in words.

The fit is still written (a user may want to look at what went wrong), but it is never reported as a
success without a word: a wrong robot config, a prior half a turn off, a taxel file of another part or a
stuck joint stream all end in a fit that minimises its cost somewhere no skin can be. Each rule is a
bound no calibration of a glued skin comes near (the shared real recording, 5 splits: hand mount 88 mm,
patches at most 5.2 mm / 12 deg, triangles 5.9 mm / 28.5 deg; 31 of 549 training touches set aside).
"""
from __future__ import annotations

import numpy as np

from nao_skin.calibration.pairing import robot_joints
from nao_skin.model.skin import SkinCalibration, SkinModel
from nao_skin.touch.touches import TouchSet

MOUNT_LIMIT_M = 0.25                     # half a Nao: a mount farther off sits on another body
PATCH_LIMIT = (0.03, np.radians(60.0))   # m, rad: a patch is glued by hand, not a hand's width off
TRIANGLE_LIMIT = (0.02, np.radians(60.0))
SET_ASIDE_SHARE = 0.5                    # most touches unexplained: the model, not the touches, is wrong
STILL_RAD = 1e-3                         # a joint moving less than this over every touch did not move


def implausible(train: TouchSet, skin: SkinModel, calib: SkinCalibration, parts, n_set_aside: int,
                kept: tuple, gate_mm: float) -> list:
    """One sentence per reason the calibration of ``parts`` from ``train`` cannot be the skin's pose.
    ``kept``: ``(label, mean mm)`` of the training touches the gate kept (:func:`~.evaluation.contact_figure`:
    the closest COP pairs, or for fingertip touches alone the fingertips' distance) (those set aside are far apart under any calibration: with them, a recording with a
    fifth of experimenter's touches looked unexplained by a calibration that was right)."""
    out = []
    if train.n_touches and n_set_aside > SET_ASIDE_SHARE * train.n_touches:
        out.append(f"{n_set_aside} of {train.n_touches} training touches were set aside as farther apart than"
                   f" the gate ({gate_mm:g} mm) after the mount fit: the recording does not fit the robot config,"
                   f" the taxel files or the starting calibration")
    label, kept_mm = kept
    if gate_mm > 0 and kept_mm > gate_mm:
        aside = f" (besides the {n_set_aside} set aside)" if n_set_aside else ""
        what = (f"closest COP pairs end {kept_mm:.1f} mm apart{aside}," if label == "closest COP"
                else f"fingertips end {kept_mm:.1f} mm from their contacts{aside},")
        out.append(f"the kept touches' {what} more than the gate"
                   f" ({gate_mm:g} mm): the calibration does not explain the recording")
    q = robot_joints(train, skin)
    fired = train.parts_of_touch()
    for name in parts:
        part = skin.parts[name]
        corr = calib.parts[name]
        far = 1000.0 * float(np.linalg.norm(corr.mount[:3]))
        if far > 1000.0 * MOUNT_LIMIT_M:
            out.append(f"part '{name}': its mount moved {far:.0f} mm from the skin config's (more than"
                       f" {1000 * MOUNT_LIMIT_M:.0f} mm, off the body): check the robot config and the taxel files")
        for kind, ids, values, (metres, radians) in (("patch", part.patch_ids, corr.patches, PATCH_LIMIT),
                                                     ("triangle", part.triangle_ids, corr.triangles, TRIANGLE_LIMIT)):
            if not len(values):
                continue
            moved = np.linalg.norm(values[:, :3], axis=1)
            turned = np.linalg.norm(values[:, 3:], axis=1)
            bad = np.flatnonzero((moved > metres) | (turned > radians))
            if len(bad):
                worst = bad[np.argmax(moved[bad] / metres + turned[bad] / radians)]
                out.append(f"part '{name}': {kind} frames moved beyond glue error (more than {1000 * metres:.0f} mm"
                           f" or {np.degrees(radians):.0f} deg): {len(bad)} of {len(values)}, {kind}"
                           f" {int(ids[worst])} by {1000 * moved[worst]:.1f} mm / {np.degrees(turned[worst]):.0f} deg:"
                           f" the touches pull the skin where no glued skin is")
        if part.chain is None:
            continue
        joints = [skin.robot.joint_index[j] for j in skin.robot.chain_joint_names(part.chain)]
        active = np.flatnonzero(fired[:, train.part_index(name)]) if name in train.part_names else np.zeros(0, int)
        angles = q[np.ix_(active, joints)]
        if len(active) > 1 and joints and np.all(np.isfinite(angles)) \
                and np.all(angles.max(axis=0) - angles.min(axis=0) < STILL_RAD):
            out.append(f"part '{name}': the joints of its chain ({part.chain}) did not move over its"
                       f" {len(active)} training touches (every touch one pose: a stuck joint stream?): the"
                       f" touches pin the skin at one spot only")
    return out

