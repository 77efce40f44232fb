"""Simulated capture on demand: the next batch of self-touches, random or aimed at given triangles.

:class:`CaptureSim` draws the true skin placement once per seed (the same
truth :func:`~nao_skin.sim.simulate.simulate` draws for that seed and those
parameters) and then records batches of touches as an operator would:

* **random** -- each touch on one of the pairs (the batch spread evenly over
  the pairs, the remainder on randomly chosen ones); its target spot near a
  triangle centre of the touched part drawn *uniformly* over that part's
  triangles, and the hand spot likewise uniformly over the hand's triangles.
  A spot pair no pose reaches (inside the joint limits, without pushing
  through the body) is skipped and drawn again, so the recorded touches are
  uniform over what each part can reach. No coverage balancing, no
  calibration knowledge: the baseline without guidance.
* **aimed** -- one touch per :class:`Aim`: the spot weight concentrated on
  the aimed triangle(s) (a spot near that triangle's centre), the other side
  uniform when not given. An aim no pose reaches within ``AIM_RETRIES``
  spot draws is not recorded (counted in :attr:`CaptureSim.missed`).

Both use the simulator's pose solver (:func:`~nao_skin.sim.poses.solve_poses`)
under the truth, its probe for presses that fire both parts, its firing model
and its recording defects (encoder noise, missed / stray taxels, duplicates,
the experimenter's hand) through the very functions ``simulate`` uses, so the
touches are recorded exactly as the simulator records them. Batches have
increasing stamps (keys), so they concatenate into one
:class:`~nao_skin.touch.touches.TouchSet` (``TouchSet.concatenate``).
``simulate()`` itself is untouched: the capture draws from its own random
stream.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from nao_skin.errors import ConfigError
from nao_skin.model.skin import SkinModel
from nao_skin.sim.params import SimParams, check_pairs, make_params, pair_list
from nao_skin.sim.poses import PoseSet, Spots, choose_spots, solve_spots
from nao_skin.sim.simulate import _assemble, _keep_firing, _pair_activations
from nao_skin.sim.truth import draw_truth
from nao_skin.touch.datasets import deduplicate
from nao_skin.touch.touches import TouchSet

CAPTURE_STREAM = 0xCA97       # the capture's own random stream, beside simulate()'s
AIM_RETRIES = 4               # spot draws per aim (each with pose_restarts hand spots)
MAX_ROUNDS = 12               # rounds of a random batch before it gives up on a pair


@dataclass(frozen=True)
class Aim:
    """Press ``hand`` on ``touched``, near ``hand_triangle`` / ``touched_triangle`` (ids; None: anywhere)."""

    hand: str
    touched: str
    hand_triangle: int | None = None
    touched_triangle: int | None = None


class CaptureSim:
    """A simulated robot with fixed true skin that records the batches asked for; see the module docstring."""

    def __init__(self, skin: SkinModel, params: SimParams | dict | None = None, seed: int = 0):
        self.skin = skin
        self.params = make_params(params or {}) if not isinstance(params, SimParams) else make_params(params)
        self.pairs = pair_list(self.params)
        check_pairs(self.pairs, skin)
        self.seed = int(seed)
        # the truth exactly as simulate() draws it for this seed and these parameters
        streams = np.random.SeedSequence(self.seed).spawn(2 + 2 * len(self.pairs))
        self.truth = draw_truth(skin, list(skin.parts), self.params, np.random.default_rng(streams[0]))
        self.rng = np.random.default_rng(np.random.SeedSequence([self.seed, CAPTURE_STREAM]))
        self.next_stamp = float(self.params.start_stamp)
        self.recorded = 0           # touches recorded so far (duplicates included)
        self.attempted = 0          # spot pairs tried
        self.missed = 0             # aims not recorded (no pose reached them, or the press fired one part only)

    # ------------------------------------------------------------------ batches
    def random(self, n: int, pair_weights=None) -> TouchSet:
        """``n`` touches (before duplicates), uniform over pairs (or split by ``pair_weights``, one per pair in
        :attr:`pairs`) and over each part's reachable triangles."""
        if pair_weights is None:
            counts = np.full(len(self.pairs), n // len(self.pairs))
            extra = self.rng.choice(len(self.pairs), size=n % len(self.pairs), replace=False)
            counts[extra] += 1
        else:       # largest remainders: the counts sum to n and follow the weights
            share = n * np.asarray(pair_weights, float) / np.sum(pair_weights)
            counts = np.floor(share).astype(int)
            counts[np.argsort(counts - share)[:n - counts.sum()]] += 1
        per_pair = []
        for (hand, target), m in zip(self.pairs, counts):
            if m:
                uniform_h = np.ones(len(self.skin.parts[hand].triangle_ids))
                uniform_t = np.ones(len(self.skin.parts[target].triangle_ids))
                poses = self._uniform_poses(hand, target, int(m), uniform_h, uniform_t)
                per_pair.append((hand, target, poses))
        return self._record(per_pair, aimed=False)

    def aimed(self, aims) -> TouchSet:
        """One touch per aim (those no pose reaches are skipped and counted in :attr:`missed`)."""
        groups: dict = {}
        for aim in aims:
            if (aim.hand, aim.touched) not in self.pairs:
                raise ConfigError(f"aim {aim.hand}-{aim.touched}: not one of the simulated pairs")
            groups.setdefault((aim.hand, aim.touched), []).append(aim)
        per_pair = []
        for (hand, target), group in groups.items():
            poses = self._aimed_poses(hand, target, group)
            self.missed += len(group) - len(poses.q)
            if len(poses.q):
                per_pair.append((hand, target, poses))
        return self._record(per_pair, aimed=True)

    def guided(self, aims, n: int) -> tuple:
        """``n`` touches as a robot following the guidance makes them: one aimed at each of ``aims[:n]``, random
        ones for the rest, the aims no pose reached among them: ``(touches, how many were aimed)``."""
        aims = list(aims)[:n]
        got = self.aimed(aims) if aims else None
        batches, aimed = [], 0
        if got is not None and got.n_touches:
            batches.append(got)
            aimed = deduplicate(got)[0].n_touches
        if n - aimed > 0:
            batches.append(self.random(n - aimed))
        return (batches[0] if len(batches) == 1 else TouchSet.concatenate(batches)), aimed

    # ------------------------------------------------------------------ poses
    def _solve(self, hand, target, t_spots: Spots, h_spots: Spots):
        poses, ok, _ = solve_spots(self.skin, hand, target, t_spots, h_spots, self.truth, self.params, self.rng)
        self.attempted += len(ok)
        return poses, ok

    def _firing(self, hand, target, poses: PoseSet, rows: np.ndarray) -> tuple:
        """The poses of ``rows`` whose press fires both parts, and which of ``rows`` they are."""
        # _keep_firing keeps the first n firing poses, in order: with n = all, every firing one
        kept, _ = _keep_firing(self.skin, self.truth, hand, target, poses.take(rows), len(rows), self.params,
                               self.rng)
        return kept

    def _uniform_poses(self, hand, target, n, w_h, w_t) -> PoseSet:
        p, k = self.params, self.params.pose_restarts
        kept, got, rate = [], 0, 0.5
        for _ in range(MAX_ROUNDS):
            need = n - got
            if need <= 0:
                break
            m = int(np.ceil(need / rate * 1.2) + 2)
            t_spots = choose_spots(self.skin, target, self.truth, m, w_t, p, self.rng)
            h_spots = choose_spots(self.skin, hand, self.truth, m * k, w_h, p, self.rng)
            poses, ok = self._solve(hand, target, t_spots, h_spots)
            firing = self._firing(hand, target, poses, np.flatnonzero(ok))
            rate = max(len(firing.q) / m, 0.05)
            firing = firing.take(np.arange(min(need, len(firing.q))))
            kept.append(firing)
            got += len(firing.q)
        return PoseSet.concat(kept, len(self.skin.robot.joint_names))

    def _aimed_poses(self, hand, target, aims) -> PoseSet:
        p, k, r = self.params, self.params.pose_restarts, AIM_RETRIES
        sp_h, sp_t = self.skin.parts[hand], self.skin.parts[target]
        t_parts, h_parts = [], []
        for aim in aims:
            t_parts.append(choose_spots(self.skin, target, self.truth, r, _one_hot(sp_t, aim.touched_triangle), p,
                                        self.rng))
            h_parts.append(choose_spots(self.skin, hand, self.truth, r * k, _one_hot(sp_h, aim.hand_triangle), p,
                                        self.rng))
        t_spots = Spots(*(np.concatenate([getattr(s, f) for s in t_parts]) for f in ("triangle", "point", "normal")))
        h_spots = Spots(*(np.concatenate([getattr(s, f) for s in h_parts]) for f in ("triangle", "point", "normal")))
        poses, ok = self._solve(hand, target, t_spots, h_spots)
        # per aim: the first retry that reaches and fires
        firing_rows = []
        for a in range(len(aims)):
            for row in range(a * r, (a + 1) * r):
                if ok[row]:
                    firing_rows.append(row)
        if not firing_rows:
            return PoseSet.empty(len(self.skin.robot.joint_names))
        firing_rows = np.array(firing_rows)
        probe = self._firing_mask(hand, target, poses, firing_rows)
        chosen, done = [], set()
        for row, fires in zip(firing_rows, probe):
            if fires and row // r not in done:
                done.add(row // r)
                chosen.append(row)
        return poses.take(chosen)

    def _firing_mask(self, hand, target, poses, rows) -> np.ndarray:
        """Which of ``rows`` fire both parts under the simulator's probe press."""
        sub = poses.take(rows)
        tagged = dataclasses.replace(sub, target_triangle=np.arange(len(rows)))   # carry the row through
        kept, _ = _keep_firing(self.skin, self.truth, hand, target, tagged, len(rows), self.params, self.rng)
        mask = np.zeros(len(rows), bool)
        mask[kept.target_triangle] = True
        return mask

    # ------------------------------------------------------------------ recording
    def _record(self, per_pair, aimed: bool) -> TouchSet:
        per_pair = [(h, t, poses) for h, t, poses in per_pair if len(poses.q)]
        if not per_pair:
            return TouchSet.empty(tuple(self.skin.parts), tuple(self.skin.robot.joint_names))
        p = dataclasses.replace(self.params, start_stamp=self.next_stamp)
        acts = [(h, t, poses, _pair_activations(self.skin, self.truth, h, t, poses, p, self.rng))
                for h, t, poses in per_pair]
        touches = _assemble(self.skin, acts, p, self.rng)
        touches.labels["aimed"] = np.full(touches.n_touches, aimed)
        touches.labels["hand_triangle_row"] = np.concatenate([poses.hand_triangle for _, _, poses in per_pair])[
            _original_rows(touches)]
        touches.labels["target_triangle_row"] = np.concatenate([poses.target_triangle for _, _, poses in per_pair])[
            _original_rows(touches)]
        self.recorded += touches.n_touches
        self.next_stamp = float(touches.stamps[-1]) + float(self.rng.uniform(*self.params.touch_interval))
        return touches


def _original_rows(touches: TouchSet) -> np.ndarray:
    """Row of each recorded touch among the poses (a duplicate maps to its original)."""
    dup = np.asarray(touches.labels["duplicate_of"])
    return np.cumsum(dup < 0) - 1


def _one_hot(part, triangle_id) -> np.ndarray:
    w = np.ones(len(part.triangle_ids)) if triangle_id is None else np.zeros(len(part.triangle_ids))
    if triangle_id is not None:
        rows = np.flatnonzero(part.triangle_ids == int(triangle_id))
        if len(rows) != 1:
            raise ConfigError(f"{part.name}: no triangle {triangle_id}")
        w[rows] = 1.0
    return w
