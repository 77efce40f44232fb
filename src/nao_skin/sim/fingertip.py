"""Fingertip touches of the simulator: a fingertip of the robot pressed on a skin part, only that part fires.

The true fingertip is a sphere (the robot config's, moved by the ground truth: ``fingertip_offset`` of its
centre, ``fingertip_radius_error`` of its radius). A pose puts its centre over a spot of the touched part at the fabric gap
plus its radius along the part's outward normal (:func:`find_fingertip_poses`, the batched
Levenberg-Marquardt of :mod:`nao_skin.sim.poses` over the fingertip's arm and the touched part's chain), so the
point of the sphere that meets the skin moves over it with the pose, as on the real hand. The part's taxels fire
by the skin's own press rule (:mod:`nao_skin.touch.press`): under a pressure spot, where the sphere's surface
comes within the press's reach beyond the gap (:func:`fire_fingertip`).
"""
from __future__ import annotations

import dataclasses

import numpy as np

from nao_skin import se3
from nao_skin.model.skin import SkinCalibration, SkinModel
from nao_skin.sim.contact import draw_spots, taxels_in_base
from nao_skin.sim.params import SimParams
from nao_skin.sim.poses import (LIMIT_MARGIN, MAX_ROUNDS, PoseSet, _chain_joint_columns, _spot_kinematics,
                                choose_spots, idle_joints, levenberg_marquardt, outside_body)
from nao_skin.touch.press import contact_frame, press_pressure


def fingertip_truth(skin: SkinModel, fingertips, p: SimParams, rng: np.random.Generator) -> dict:
    """``{fingertip: (4,) correction}`` of the true contact spheres: each centre off the config's by up to
    ``fingertip_offset`` per axis (uniform), its radius by ``fingertip_radius_error``."""
    from nao_skin.errors import ConfigError

    for name in fingertips:
        if skin.robot.fingertip(name).radius + p.fingertip_radius_error <= 0.0:
            raise ConfigError(f"simulation fingertip_radius_error {p.fingertip_radius_error:g} m: fingertip {name}'s"
                              f" radius in {skin.robot.source} is {skin.robot.fingertip(name).radius:g} m; the true"
                              f" one must stay above 0 (a point fires no taxel)")
    return {name: np.r_[rng.uniform(-1.0, 1.0, size=3) * p.fingertip_offset, p.fingertip_radius_error]
            for name in fingertips}


def _residual(skin, tip_chain, target_chain, q, centre, ts, tn, lift, fcols, tcols):
    """Centre of the sphere minus where it must be (the spot lifted along its normal), and the Jacobian."""
    fp, _, fdp, _ = _spot_kinematics(skin, tip_chain, q, centre[None].repeat(len(q), 0), np.zeros((len(q), 3)), fcols)
    tp, _, tdp, _ = _spot_kinematics(skin, target_chain, q, ts + lift[:, None] * tn, tn, tcols)
    return fp - tp, np.concatenate([fdp, -tdp], axis=2)


def find_fingertip_poses(body: SkinModel, truth: SkinCalibration, fingertip: str, target: str, n: int,
                         p: SimParams, rng: np.random.Generator) -> PoseSet:
    """``n`` poses of the true robot (``body``) pressing ``fingertip`` on ``target``, spread over the part: as
    :func:`~nao_skin.sim.poses.find_poses`, in rounds that favour the triangles touched least."""
    robot = body.robot
    tip_chain, target_chain = robot.fingertip(fingertip).chain, body.parts[target].chain
    centre, radius = truth.fingertip_sphere(robot, fingertip)
    fcols, tcols = _chain_joint_columns(body, tip_chain), _chain_joint_columns(body, target_chain)
    cols = np.array([c for _, c in fcols + tcols], dtype=int)
    lo, hi = robot.limits[cols, 0] + LIMIT_MARGIN, robot.limits[cols, 1] - LIMIT_MARGIN
    sp = body.parts[target]
    counts, tries, works = (np.zeros(len(sp.triangle_ids)) for _ in range(3))
    k, kept, accepted, rate = p.pose_restarts, [], 0, 0.5
    for _ in range(MAX_ROUNDS):
        need = n - accepted
        if need <= 0:
            break
        m = int(min(np.ceil(need / rate * 1.2) + 4, max(n / 3 / rate, 24)))
        spots = choose_spots(body, target, truth, m, ((works + 0.5) / (tries + 1.0)) ** 2 / (1.0 + counts), p, rng)
        gap = np.maximum(p.fabric_thickness + rng.normal(0.0, p.scaled("fabric_jitter"), size=m), 0.0)
        rep = lambda a: np.repeat(a, k, axis=0)  # noqa: E731 - rows of every restart
        ts, tn, lift = rep(spots.point), rep(spots.normal), rep(gap + radius)
        q = rep(idle_joints(body, m, rng))
        q[:, cols] = rng.uniform(lo, hi, size=(m * k, len(cols)))
        q, res = levenberg_marquardt(
            lambda qq: _residual(body, tip_chain, target_chain, qq, centre, ts, tn, lift, fcols, tcols),
            q, cols, lo, hi, p.pose_iterations)
        ok = np.linalg.norm(res, axis=1) <= p.pose_tolerance
        ok[ok] &= outside_body(body, tip_chain, q[ok])
        ok[ok] &= _approaches_from_outside(body, tip_chain, target_chain, q[ok], ts[ok], tn[ok])
        cost = np.einsum("ij,ij->i", res, res)
        best = np.argmin(np.where(ok, cost, 1e9 + cost).reshape(m, k), axis=1) + np.arange(m) * k
        reached = ok[best]
        np.add.at(tries, spots.triangle, 1)
        np.add.at(works, spots.triangle, reached)
        rate = max(reached.mean(), 0.05)
        rows = np.flatnonzero(reached)[:need]
        qb = q[best[rows]]
        end = robot.fk(target_chain, qb)
        normal = se3.rotate_vectors(end, spots.normal[rows])
        contact = se3.transform_points(end, spots.point[rows]) + gap[rows, None] * normal
        kept.append(PoseSet(qb, contact, normal, gap[rows], np.full(len(rows), -1), spots.triangle[rows], m,
                            int(np.count_nonzero(~reached))))
        np.add.at(counts, spots.triangle[rows], 1)
        accepted += len(rows)
    return PoseSet.concat(kept, len(robot.joint_names))


def _approaches_from_outside(body: SkinModel, tip_chain: str, target_chain, q, spot, normal) -> np.ndarray:
    """The arm reaches the spot from the skin's side: its end frame's origin (the elbow... the wrist of the DH
    chain) lies on the outward side of the touched surface's tangent plane, not behind the part."""
    end = body.robot.fk(tip_chain, q)[:, :3, 3]
    t_end = body.robot.fk(target_chain, q)
    rel = end - se3.transform_points(t_end, spot)
    return np.einsum("nk,nk->n", rel, se3.rotate_vectors(t_end, normal)) > 0.0


def fire_fingertip(body: SkinModel, truth: SkinCalibration, fingertip: str, target: str, poses: PoseSet,
                   p: SimParams, rng: np.random.Generator) -> tuple:
    """Activations of the touched part for the poses: ``(touch, slot, pressure, event)`` (event: the pressure
    spot that fired the taxel). The sphere's surface over a taxel (along the contact normal) is its height
    ``r - sqrt(r^2 - l^2)`` at lateral distance ``l`` from the contact; a taxel fires under a spot when its
    separation from that surface exceeds the gap by less than the press's reach, as two skins' taxels do."""
    n = len(poses.q)
    if n == 0:
        empty = np.zeros(0, dtype=int)
        return empty, empty, np.zeros(0), empty
    _, radius = truth.fingertip_sphere(body.robot, fingertip)
    fingertip_press = dataclasses.replace(p, footprint_radius=p.fingertip_footprint, pressure_spots=p.fingertip_spots,
                                          spot_size=p.fingertip_spot_size)
    centres, spot_radius = draw_spots(n, fingertip_press, rng)
    reach = rng.uniform(*p.press_reach, size=n)
    pos, nor, slots = taxels_in_base(body, target, poses.q, truth)
    lat, height = contact_frame(pos, poses.contact, poses.normal)
    lateral = np.linalg.norm(lat, axis=2)
    facing = np.einsum("nsk,nk->ns", nor, poses.normal) > 0.0
    # the sphere above the contact point, touching it: its surface's height over each taxel's lateral place
    surface = np.where(lateral < radius, radius - np.sqrt(np.maximum(radius ** 2 - lateral ** 2, 0.0)), np.inf)
    slack = surface - height - poses.gap[:, None]
    depth = np.where(facing, 1.0 - slack / reach[:, None], -1.0)
    sd = np.linalg.norm(lat[:, :, None] - centres[:, None], axis=3)
    rad = spot_radius[:, None]
    closeness = np.where(rad > 0, 1.0 - (sd / np.where(rad > 0, rad, 1.0)) ** 2, -1.0)
    spot = np.argmax(closeness, axis=2)
    central = np.take_along_axis(closeness, spot[..., None], axis=2)[..., 0]
    t, s = np.nonzero((central > 0) & (depth > 0))
    return t, slots[s], np.round(press_pressure(depth[t, s], central[t, s])), spot[t, s]
