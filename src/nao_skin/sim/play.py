"""What the simulated robot plays live: the simulator's touches, and among fingertip touches its stray presses.

A live fingertip session must tell a fingertip's press from an experimenter's hand pressing the same part while
no fingertip is there (the recorder's :class:`~nao_skin.touch.fingertip.FingertipJudge`). Offline, the
simulator's experimenter presses during a touch (a second contact of that touch); live there are also presses of
their own: :func:`live_touches` adds, per fingertip touch with the simulator's ``experimenter_hand`` rate (times
``noise_scale``), a *stray press*: the part fires as that touch fired it, but the fingertip's arm rests by the
body, every fingertip at least :data:`STRAY_MIN_DISTANCE` from the pressed spot (ground truth). They sit at
random places among the touches, labelled ``stray`` (their ``touch_fingertip`` -1: no fingertip pressed).

Drawn from a random stream of their own beside ``simulate()``'s: the touches it returns for a seed are played
unchanged, and a session with no fingertip scene plays exactly ``simulate()``'s touches.
"""
from __future__ import annotations

import dataclasses

import numpy as np

from nao_skin import se3
from nao_skin.model.skin import SkinModel
from nao_skin.sim.params import SimParams
from nao_skin.sim.poses import idle_joints
from nao_skin.sim.simulate import SimResult, simulate

STRAY_STREAM = 0x57A7        # the stray presses' own random stream, beside simulate()'s
# m from the pressed spot to every fingertip's sphere at least: twice the recorder's default gate (30 mm), so a
# stray press is one no judge may take for a fingertip's
STRAY_MIN_DISTANCE = 0.06
STRAY_REDRAWS = 20           # rest postures drawn per stray press before it is given up (counted, not played)


def live_touches(skin: SkinModel, params: SimParams | dict | None, seed: int) -> SimResult:
    """``simulate(skin, params, seed)`` with its stray presses among the fingertip touches (module docstring);
    ``labels['stray']`` says which touches are stray presses, ``pairs['stray']`` how many were played."""
    result = simulate(skin, params, seed)
    touches = result.touches
    p = result.params
    tips = touches.fingertip_of_touch
    # originals only: a duplicate is the same message twice, not a second press to imitate
    rows = np.flatnonzero((tips >= 0) & (np.asarray(touches.labels["duplicate_of"]) < 0))
    share = p.scaled("experimenter_hand")
    n = int(round(share * len(rows)))
    touches.labels["stray"] = np.zeros(touches.n_touches, bool)
    if n == 0:
        return result
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), STRAY_STREAM]))
    copied = np.sort(rng.choice(rows, size=n, replace=False))
    strays = touches.subset(copied)
    q, ok = _away_from_fingertips(skin.with_kinematics(result.truth), result.truth, strays, rng)
    strays = dataclasses.replace(strays, joints=q, touch_fingertip=np.full(n, -1))
    strays.labels["stray"] = np.ones(n, bool)
    strays = strays.subset(ok)
    both = type(touches).concatenate([touches, strays])
    # the strays at random places among the touches, the touches in their order
    where = np.r_[np.arange(touches.n_touches), rng.uniform(-0.5, touches.n_touches - 0.5, size=strays.n_touches)]
    played = both.subset(np.argsort(where, kind="stable"))
    pairs = {**result.pairs, "stray": {"touches": int(strays.n_touches), "given_up": int(np.count_nonzero(~ok))}}
    return dataclasses.replace(result, touches=played, pairs=pairs)


def _away_from_fingertips(body: SkinModel, truth, strays, rng: np.random.Generator) -> tuple:
    """Joint readings of the stray presses: each touch's, with the arms of the fingertips that press its part at
    rest (the rest posture; the pressed part's own chain stays where it was), redrawn until each such true
    fingertip sphere is at least :data:`STRAY_MIN_DISTANCE` from the true pressed spot; ``(joints, which
    succeeded)``."""
    robot = body.robot
    q = strays.joints.copy()
    spot = np.asarray(strays.labels["contact_point"])
    target = np.array([str(pair).partition("-")[2] for pair in strays.labels["pair"]])
    ok = np.zeros(strays.n_touches, bool)
    for part in np.unique(target):           # <= the skin's parts; vectorised over the touches of each
        tips = [tip for tip, pressed in body.fingertip_touch.pairs() if pressed == part]
        held = set(robot.chain_joint_names(body.parts[part].chain)) if body.parts[part].chain else set()
        cols = np.array(sorted({robot.joint_names.index(j) for tip in tips
                                for j in robot.chain_joint_names(robot.fingertip(tip).chain) if j not in held}), int)
        rows = np.flatnonzero(target == part)
        for _ in range(STRAY_REDRAWS):
            todo = rows[~ok[rows]]
            if not len(todo):
                break
            q[np.ix_(todo, cols)] = idle_joints(body, len(todo), rng)[:, cols]
            near = np.full(len(todo), np.inf)
            for tip in tips:
                centre, radius = truth.fingertip_sphere(robot, tip)
                at = se3.transform_points(robot.fk(robot.fingertip(tip).chain, q[todo]), centre)
                near = np.minimum(near, np.linalg.norm(at - spot[todo], axis=1) - radius)
            ok[todo] = near >= STRAY_MIN_DISTANCE
    return q, ok
