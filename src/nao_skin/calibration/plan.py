"""Which parts to fit against which: the thesis' multi-session plan, from the pairs in the data."""
from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from nao_skin.errors import TooFewTouches
from nao_skin.model.skin import SelfTouch, pair_label, part_rank, scene_label
from nao_skin.touch.datasets import pose_groups
from nao_skin.touch.touches import TouchSet

if TYPE_CHECKING:   # only for annotations: calibrate imports this module
    from nao_skin.calibration.options import CalibrationOptions

@dataclass
class Step:
    """Fit ``targets`` against touches with ``references`` (fixed unless simultaneous) and, in ``fingertips``,
    against the ``(fingertip, part)`` pairs whose fingertip touches press a target (each fingertip's contact
    sphere free with the targets)."""

    targets: tuple
    references: tuple
    fingertips: tuple = ()

    @property
    def name(self) -> str:
        against = self.references + tuple(dict.fromkeys(f for f, _ in self.fingertips))
        return "+".join(self.targets) + (" from " + "+".join(against) if against else "")

    def chains(self, skin) -> list:
        """The chains the step's parts and fingertips hang off (what its kinematic unknowns are of), sorted."""
        parts = {skin.parts[p].chain for p in self.targets + self.references}
        return sorted((parts | {skin.robot.fingertip(f).chain for f in self.fingertip_names}) - {None})

    @property
    def fingertip_names(self) -> tuple:
        """The fingertips whose spheres the step frees, each once."""
        return tuple(dict.fromkeys(f for f, _ in self.fingertips))

def pair_counts(touches: TouchSet) -> dict:
    """``{frozenset(part names): touches where both fire}`` of every pair that fires together at least once."""
    fired = touches.parts_of_touch()
    names = touches.part_names
    out = {}
    for i in range(len(names)):
        for j in range(i + 1, len(names)):
            n = int(np.sum(fired[:, i] & fired[:, j]))
            if n:
                out[frozenset((names[i], names[j]))] = n
    return out


def fingertip_poses(touches: TouchSet) -> dict:
    """``{(fingertip, part): distinct poses}`` of the fingertip touches that fire the part (as :func:`pair_poses`)."""
    from nao_skin.calibration.fingertip import fingertip_pairs

    groups = pose_groups(touches)
    fired, tip = touches.parts_of_touch(), touches.fingertip_of_touch
    return {(f, p): len(np.unique(groups[(tip == touches.fingertips.index(f)) & fired[:, touches.part_index(p)]]))
            for f, p in fingertip_pairs(touches)}


def pair_poses(touches: TouchSet) -> dict:
    """``{frozenset(part names): distinct poses}`` of the touches where both fire: what pins a mount. A press
    held still is recorded as several touches at one pose (:func:`~nao_skin.touch.datasets.pose_groups`);
    thirty such touches at three poses determine a mount no better than three."""
    fired = touches.parts_of_touch()
    groups = pose_groups(touches)
    names = touches.part_names
    out = {}
    for i in range(len(names)):
        for j in range(i + 1, len(names)):
            both = fired[:, i] & fired[:, j]
            if np.any(both):
                out[frozenset((names[i], names[j]))] = len(np.unique(groups[both]))
    return out


def too_few(n_touches: int, n_poses: int, need: int) -> str:
    """The words for touches that cannot pin a mount: ``need`` poses at least."""
    at = f" at {n_poses} poses (a press held still is one pose)" if n_poses < n_touches else ""
    return (f"{n_touches} training touch{'' if n_touches == 1 else 'es'}{at}; a mount needs at least {need}"
            f"{' poses' if at else ''}")


def touching_pairs(touches: TouchSet) -> set:
    """Pairs of part names that fire together in at least one touch."""
    return set(pair_counts(touches))


def left_out_pairs(touches: TouchSet, options: "CalibrationOptions") -> list:
    """The pairs (and fingertip scenes) too few poses connect to calibrate from (yet): ``[(pair name, touches,
    poses)]``."""
    from nao_skin.calibration.fingertip import fingertip_pairs

    poses = pair_poses(touches)
    counts = sorted(pair_counts(touches).items(), key=lambda kv: sorted(kv[0], key=part_rank))
    tip_poses = fingertip_poses(touches)
    return ([(pair_label(p), n, poses[p]) for p, n in counts if poses[p] < options.min_mount_touches]
            + [(scene_label(*k), n, tip_poses[k]) for k, n in fingertip_pairs(touches).items()
               if tip_poses[k] < options.min_mount_touches])



def pairs_outside_roles(touches: TouchSet, options: "CalibrationOptions", roles: SelfTouch) -> list:
    """Names of the pairs the plan calibrates from (enough poses) that the skin config's ``self_touch`` does
    not name: fitted one from the other, without the plan's order (a config or a recording of another robot?)."""
    named = {frozenset(pair) for pair in roles.pairs()}
    poses = pair_poses(touches)
    return sorted((pair_label(p) for p in pair_counts(touches) if p not in named
                   and poses[p] >= options.min_mount_touches), key=lambda name: [part_rank(n) for n in name.split("+")])


def plan_steps(touches: TouchSet, options: "CalibrationOptions", roles: SelfTouch) -> list:
    """The multi-session plan the thesis found best, restricted to the pairs the data supports.

    ``roles`` (the skin's :class:`~nao_skin.model.skin.SelfTouch`): which parts touch and which are
    touched. A pair with touches at fewer than ``min_mount_touches`` poses is left out (its parts
    stay at their prior unless another pair calibrates them): partial is fine. Fingertip scenes join the
    step whose target they press (its fingertip's sphere free there), or are a step of their own.
    """
    counts = pair_counts(touches)
    tip_poses = fingertip_poses(touches)
    if not counts and not tip_poses:
        one = touches.n_touches and touches.parts_of_touch().sum(axis=1).max() == 1
        raise TooFewTouches("no touch has two skin parts active together: nothing to calibrate from"
                            + ("; each fires one part, as a fingertip's touches do: name the fingertip that pressed"
                               " them (--fingertip NAME)" if one else ""))
    poses = pair_poses(touches)
    need = options.min_mount_touches
    pairs = {p for p in counts if poses[p] >= need}
    tips = sorted((k for k, n in tip_poses.items() if n >= need), key=lambda k: (part_rank(k[1]), k[0]))
    if not pairs and not tips:
        from nao_skin.calibration.fingertip import fingertip_pairs

        tip_counts = fingertip_pairs(touches)
        best = max([(poses[p], counts[p], " and ".join(sorted(p, key=part_rank)) + " together") for p in counts]
                   + [(tip_poses[k], n, f"part {k[1]} under fingertip {k[0]}") for k, n in tip_counts.items()])
        raise TooFewTouches(f"{'parts ' if 'together' in best[2] else ''}{best[2]}: "
                            f"{too_few(best[1], best[0], need)} (about"
                            f" {int(np.ceil(need / (1 - options.test_fraction)))} before the"
                            f" {int(options.test_fraction * 100)} % test split)")
    steps = _self_touch_steps(pairs, options, roles) if pairs else []
    for tip, part in tips:
        at = next((s for s in steps if part in s.targets), None)
        if at is None:
            steps.append(Step((part,), (), ((tip, part),)))
        else:
            steps[steps.index(at)] = Step(at.targets, at.references, at.fingertips + ((tip, part),))
    return steps


def joint_step(steps: list) -> Step:
    """Every part of the plan's steps free at once, against every fingertip scene: the joint refinement's step."""
    return Step(tuple(sorted({p for s in steps for p in s.targets + s.references}, key=part_rank)), (),
                tuple(dict.fromkeys(fp for s in steps for fp in s.fingertips)))


def _self_touch_steps(pairs: set, options: "CalibrationOptions", roles: SelfTouch) -> list:
    """The plan's steps of the self-touch pairs with enough poses."""
    present = sorted({p for pair in pairs for p in pair}, key=part_rank)
    if options.reference == "simultaneous":
        return [Step(tuple(present), ())]
    steps = []
    calibrated = set()
    for hand in roles.touching:             # hands from the torso (or, lacking it, from the head)
        for body in roles.touched:
            if frozenset((hand, body)) in pairs:
                steps.append(Step((hand,), (body,)))
                calibrated.add(hand)
                break
    for body in roles.touched:              # then torso and head from the calibrated hands
        refs = tuple(h for h in roles.touching if h in calibrated and frozenset((h, body)) in pairs)
        if refs and not any(s.targets == (body,) for s in steps):
            steps.append(Step((body,), refs))
    for pair in sorted(pairs, key=lambda p: sorted(map(part_rank, p))):   # anything else (e.g. two hands):
        # fit the second from the first
        a, b = sorted(pair, key=part_rank)
        if not any(set(s.targets) | set(s.references) >= {a, b} for s in steps):
            steps.append(Step((b,), (a,)))
    return steps
