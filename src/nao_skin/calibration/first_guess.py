"""Closed-form first guess of a mount: a rigid fit of per-touch contact points, refined ICP-style.

Real hand mounts sit ~160 degrees off nominal: a local solver started there
does not find them; this puts it in the right basin without anyone rotating
a frame by hand.
"""
from __future__ import annotations

import numpy as np

from nao_skin import se3
from nao_skin.calibration.fingertip import fingertip_centres
from nao_skin.calibration.pairing import KIND_COP, KIND_FINGERTIP, Pairing, chain_end_poses
from nao_skin.calibration.plan import Step
from nao_skin.calibration.rows import pair_step, select_rows
from nao_skin.errors import DataError
from nao_skin.model.skin import SelfTouch, SkinCalibration, SkinModel
from nao_skin.touch.contacts import segment_mean
from nao_skin.touch.touches import TouchSet


def guess_targets(step: Step, roles: SelfTouch) -> list:
    """(target, references, fingertips) for the closed-form mount fit: a fixed step's targets, or in a
    simultaneous step each touching part (``roles``) against the touched parts; and every part a fingertip of the
    step presses, against that fingertip (with the references, if any)."""
    tips = {t: tuple(f for f, p in step.fingertips if p == t) for t in step.targets}
    if step.references:
        return [(t, step.references, tips[t]) for t in step.targets]
    bodies = tuple(p for p in step.targets if p in roles.touched)
    guessed = [(h, bodies, tips[h]) for h in step.targets if h in roles.touching and bodies]
    return guessed + [(t, (), tips[t]) for t in step.targets if tips[t] and t not in {g[0] for g in guessed}]

# Surface normals enter the rigid fit with this weight (m^2 per touch, i.e. like points spread
# over ~10 mm): negligible against contacts spread over a part, decisive about the axis that
# points alone leave free when every contact lies on one band of the skin.
NORMAL_WEIGHT = 0.01 ** 2


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), 1e-12)


def _touch_centroids(touches: TouchSet, skin: SkinModel, calib: SkinCalibration, part: str, frame: str):
    """Per-touch mean of the part's activated taxels and their mean normal: in its
    chain-end frame ('local') or the base; and which touches have any."""
    pidx = touches.part_index(part)
    sel = touches.act_part == pidx
    touch = touches.act_touch[sel]
    local, normals = skin.parts[part].taxel_positions(calib.parts[part])
    pts, nor = local[touches.act_slot[sel]], normals[touches.act_slot[sel]]
    if frame == "base":
        fk = chain_end_poses(touches, skin, part)[touch]
        pts, nor = se3.transform_points(fk, pts), se3.rotate_vectors(fk, nor)
    counts = np.bincount(touch, minlength=touches.n_touches)
    return (segment_mean(pts, touch, touches.n_touches), _unit(segment_mean(nor, touch, touches.n_touches)),
            counts > 0)

def rigid_mount_guess(touches: TouchSet, skin: SkinModel, calib: SkinCalibration, target: str,
                      references: tuple, iterations: int = 6, trim: float = 0.25, fingertips: tuple = ()) -> np.ndarray:
    """Closed-form mount correction of ``target``: rigid fit of its touch points onto the references' (and, in the
    touches of ``fingertips``, onto the fingertip's sphere centre, which gives no normal).

    First per-touch centroids of all activations (pairing is meaningless while
    the mount is far off), then a few ICP rounds on the closest COP pairs
    with the worst ``trim`` share of touches left out (experimenter's hand).
    """
    skin = skin.with_kinematics(calib)   # a prior's kinematic corrections hold while the mount is guessed
    part = skin.parts[target]
    ref_sum = np.zeros((touches.n_touches, 3))
    ref_nor = np.zeros((touches.n_touches, 3))
    ref_ok = np.zeros(touches.n_touches, bool)
    for ref in references:
        c, n, ok = _touch_centroids(touches, skin, calib, ref, "base")
        use = ok & ~ref_ok
        ref_sum[use], ref_nor[use] = c[use], n[use]
        ref_ok |= ok
    for tip in fingertips:
        use = (touches.fingertip_of_touch == touches.fingertips.index(tip)) & ~ref_ok
        ref_sum[use] = fingertip_centres(touches, skin, calib, tip, np.flatnonzero(use))[0]
        ref_ok |= use
    own, own_nor, own_ok = _touch_centroids(touches, skin, calib, target, "local")
    both = np.flatnonzero(ref_ok & own_ok)
    if len(both) < 3:
        raise DataError(f"part '{target}': {len(both)} touches with a reference part, at least 3 needed for a mount fit")
    chain = chain_end_poses(touches, skin, target)[both]
    ref_local = se3.transform_points(se3.invert(chain), ref_sum[both])      # reference points in the chain-end frame
    # touching surfaces face each other: the target's normal maps onto minus the reference's
    ref_dirs = -se3.rotate_vectors(se3.invert(chain), ref_nor[both])
    # mount-frame coordinates of the target's points under the current correction
    mount_now = part.mount_nominal @ se3.pose_matrix(calib.parts[target].mount)
    own_mount = se3.transform_points(se3.invert(mount_now), own[both])
    own_dirs = se3.rotate_vectors(se3.invert(mount_now), own_nor[both])
    fit = se3.rigid_fit(own_mount, ref_local, None, own_dirs, ref_dirs, NORMAL_WEIGHT)   # chain-end <- mount
    for _ in range(iterations):
        resid = np.linalg.norm(se3.transform_points(fit, own_mount) - ref_local, axis=1)
        keep = resid <= np.quantile(resid, 1.0 - trim)
        fit = se3.rigid_fit(own_mount[keep], ref_local[keep], None, own_dirs[keep], ref_dirs[keep], NORMAL_WEIGHT)
    corr = calib.copy()
    corr.parts[target].mount = se3.pose_vector(se3.invert(part.mount_nominal) @ fit)
    # ICP on closest COP pairs: pairing becomes meaningful once the mount is near
    step = Step((target,), tuple(references), tuple((f, target) for f in fingertips))
    for _ in range(iterations):
        pairing = pair_step(touches, skin, corr, step, ("cop",))
        if pairing is None:
            break
        rows = select_rows(pairing, (KIND_COP, KIND_FINGERTIP))
        src, dst, src_n, dst_n = _cop_points(rows, touches, skin, corr, target)
        if len(src) < 3:
            break
        mount_now = part.mount_nominal @ se3.pose_matrix(corr.parts[target].mount)
        src_m = se3.transform_points(se3.invert(mount_now), src)
        src_mn = se3.rotate_vectors(se3.invert(mount_now), src_n)
        resid = np.linalg.norm(se3.transform_points(mount_now, src_m) - dst, axis=1)
        keep = resid <= np.quantile(resid, 1.0 - trim)
        fit = se3.rigid_fit(src_m[keep], dst[keep], None, src_mn[keep], -dst_n[keep], NORMAL_WEIGHT)
        corr.parts[target].mount = se3.pose_vector(se3.invert(part.mount_nominal) @ fit)
    return corr.parts[target].mount

def _cop_points(rows: Pairing, touches: TouchSet, skin: SkinModel, calib: SkinCalibration, target: str):
    """For COP rows: the target's COP and mean normal in its chain-end frame, and the
    reference COP and mean normal in the same frame (for a fingertip row, the fingertip's sphere centre, and
    no normal)."""
    tidx = touches.part_index(target)
    part = skin.parts[target]
    local, local_n = part.taxel_positions(calib.parts[target])
    m = len(rows.row_touch)
    is_target = rows.term_part == tidx
    row, slot, w = rows.term_row[is_target], rows.term_slot[is_target], np.abs(rows.term_weight[is_target])
    own, own_n = segment_mean(local[slot], row, m, w), segment_mean(local_n[slot], row, m, w)
    other, other_n = np.zeros((m, 3)), np.zeros((m, 3))
    for pidx in np.unique(rows.term_part[~is_target]):     # the reference parts (<= 3)
        sel = rows.term_part == pidx
        name = touches.part_names[pidx]
        loc, loc_n = skin.parts[name].taxel_positions(calib.parts[name])
        row, slot, w = rows.term_row[sel], rows.term_slot[sel], np.abs(rows.term_weight[sel])
        fk = chain_end_poses(touches, skin, name)[rows.row_touch[row]]
        other += segment_mean(se3.transform_points(fk, loc[slot]), row, m, w)
        other_n += segment_mean(se3.rotate_vectors(fk, loc_n[slot]), row, m, w)
    tip = rows.row_fingertip if rows.row_fingertip is not None else np.full(m, -1)
    for f in np.unique(tip[tip >= 0]):
        sel = np.flatnonzero(tip == f)
        other[sel] = fingertip_centres(touches, skin, calib, touches.fingertips[f], rows.row_touch[sel])[0]
    to_chain = se3.invert(chain_end_poses(touches, skin, target)[rows.row_touch])
    return (own, se3.transform_points(to_chain, other), _unit(own_n),
            _unit(se3.rotate_vectors(to_chain, other_n)))
