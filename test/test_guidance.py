"""Guided capture: the guidance's ranking, its poses, the simulator on demand, the report's coverage table."""
from __future__ import annotations

import json

import numpy as np
import pytest

from nao_skin import se3
from nao_skin.bench.capture import CaptureSetup, honesty, run_capture
from nao_skin.calibration.engine import calibrate
from nao_skin.calibration.report import coverage_lines, markdown_report, report_coverage
from nao_skin.guidance.capture import guidance
from nao_skin.model.skin import load_skin
from nao_skin.sim.capture import Aim, CaptureSim
from nao_skin.touch.datasets import deduplicate
from nao_skin.touch.touches import TouchSet

PAIRS = [["l_hand", "torso"], ["r_hand", "torso"]]


@pytest.fixture(scope="module")
def skin():
    return load_skin()


@pytest.fixture(scope="module")
def captured(skin):
    """A capture of two pairs, calibrated: the state guidance starts from."""
    cap = CaptureSim(skin, {"pairs": PAIRS}, 5)
    touches, _ = deduplicate(cap.random(120))
    result = calibrate(touches, skin, truth=cap.truth)
    return cap, touches, result


def _row(part, tid):
    return int(np.flatnonzero(part.triangle_ids == tid)[0])


def test_held_triangle_ranks_above_well_covered(skin, captured):
    """Without a posterior (a calibration file, nominal before the first update) the tiers rank the targets."""
    _, touches, result = captured
    g = guidance(touches, skin, result.calibration, held=result.report.held, calibrated_parts=result.report.parts,
                 max_targets=200, poses=False, pairs=[tuple(p) for p in PAIRS])
    assert all(t.gain_mm2 is None for t in g.targets)
    cov = g.coverage["torso"]
    acts = np.array(cov.activations)
    assert cov.total == len(skin.parts["torso"].triangle_ids) and cov.enough == int(np.sum(acts >= cov.needed))
    held = [t for t in g.targets if t.part == "torso" and t.activations < t.needed]
    assert held, "a 120-touch capture leaves some torso triangle held"
    rank = {(t.part, t.triangle_id): i for i, t in enumerate(g.targets)}
    for well in np.flatnonzero(acts >= 2 * cov.needed):     # well covered: no target at all
        assert ("torso", cov.triangle_ids[well]) not in rank
    weak = [t for t in g.targets if t.reason == "weak"]
    if weak:
        assert max(rank[(t.part, t.triangle_id)] for t in held) < min(rank[(t.part, t.triangle_id)] for t in weak)
    scores = [t.score for t in g.targets]
    assert scores == sorted(scores, reverse=True)
    json.dumps(g.to_dict())     # JSON-ready


def test_with_the_calibration_s_posterior_the_reachable_targets_are_ranked_by_expected_gain(skin, captured):
    """A calibration result carries its posterior: the targets a pose reaches come by the taxel variance a press
    there removes, highest first; the same seed, the same advice."""
    _, touches, result = captured
    pairs = [tuple(p) for p in PAIRS]
    assert result.posterior is not None
    g = guidance(touches, skin, result, max_targets=30, seed=4, pairs=pairs)
    reachable = [t for t in g.targets if t.pose is not None]
    gains = [t.gain_mm2 for t in reachable]
    assert len(reachable) >= 10 and all(v is not None and v > 0 for v in gains), gains
    assert gains == sorted(gains, reverse=True)
    assert g.targets.index(reachable[-1]) == len(reachable) - 1       # unreachable ones after them
    again = guidance(touches, skin, result, max_targets=30, seed=4, pairs=pairs)
    assert [(t.part, t.triangle_id, t.gain_mm2) for t in again.targets] == [
        (t.part, t.triangle_id, t.gain_mm2) for t in g.targets]


def test_guidance_changes_after_its_targets_are_touched(skin, captured):
    cap, touches, result = captured
    pairs = [tuple(p) for p in PAIRS]
    g = guidance(touches, skin, result, max_targets=4, seed=1, pairs=pairs)
    top = [(t.part, t.triangle_id) for t in g.targets if t.pose is not None]
    assert top
    before = {(t.part, t.triangle_id): t.activations for t in g.targets}
    cap2 = CaptureSim(skin, {"pairs": PAIRS}, 5)    # same truth; this test must not change the fixture's sim
    cap2.next_stamp = cap.next_stamp
    aims = [Aim(t.hand, t.touched, t.hand_triangle_id, t.touched_triangle_id) for t in g.targets
            if t.pose is not None for _ in range(6)]
    more = cap2.aimed(aims)
    assert more.n_touches > 0 and np.all(more.labels["aimed"])
    joined = TouchSet.concatenate([touches, more])
    assert len(set(joined.keys)) == joined.n_touches
    joined, _ = deduplicate(joined)
    result2 = calibrate(joined, skin, prior=result.calibration, truth=cap.truth)
    g2 = guidance(joined, skin, result2, max_targets=200, poses=False, pairs=pairs)
    rank2 = {(t.part, t.triangle_id): i for i, t in enumerate(g2.targets)}
    held2 = {(t.part, t.triangle_id) for t in g2.targets if t.reason == "held"}
    freed = 0
    for key in top:
        cov = g2.coverage[key[0]]
        now = cov.activations[cov.triangle_ids.index(key[1])]
        assert now > before[key]     # the touches landed there
        if now >= cov.needed:        # enough to estimate it: no longer a held target
            assert key not in held2
            freed += 1
        # one still short stays held, and ranks the higher the closer it is to being freed
    assert freed >= 1
    assert [k for k in rank2][:len(top)] != top


def test_suggested_poses_within_limits_and_reach_the_target_under_truth(skin, captured):
    cap, touches, result = captured
    g = guidance(touches, skin, result, max_targets=8, seed=2, pairs=[tuple(p) for p in PAIRS])
    robot = skin.robot
    reached = [t for t in g.targets if t.pose is not None]
    assert len(reached) >= 4
    for t in reached:
        q = np.zeros((1, len(robot.joint_names)))
        for name, value in t.pose.items():
            j = robot.joint_names.index(name)
            assert robot.limits[j, 0] <= value <= robot.limits[j, 1], name
            q[0, j] = value
        # the chosen spots, carried from the calibrated triangle frames to the true ones, meet at the pose
        spots = []
        for part_name, tid, pt in ((t.hand, t.hand_triangle_id, t.hand_point), (t.touched, t.touched_triangle_id,
                                                                             t.touched_point)):
            part = skin.parts[part_name]
            r = _row(part, tid)
            _, _, cal = part.frame_poses(result.calibration.parts[part_name])
            _, _, true = part.frame_poses(cap.truth.parts[part_name])
            local = se3.transform_points(np.linalg.inv(cal[r]), np.asarray(pt))
            end = robot.fk(part.chain, q)[0]
            spots.append(se3.transform_points(end, se3.transform_points(true[r], local)))
        assert np.linalg.norm(spots[0] - spots[1]) < 0.006, t      # a few mm: the calibration's error + fabric
        assert t.point == (t.hand_point if t.part == t.hand else t.touched_point)


def test_capture_batches_concatenate_and_simulate_unchanged(skin):
    from nao_skin.sim.simulate import simulate

    cap = CaptureSim(skin, {"pairs": PAIRS}, 3)
    ref = simulate(skin, {"pairs": PAIRS, "n_touches": 3}, 3)
    for name in skin.parts:
        assert np.allclose(cap.truth.parts[name].mount, ref.truth.parts[name].mount)
        assert np.allclose(cap.truth.parts[name].triangles, ref.truth.parts[name].triangles)
    a = cap.random(10)
    r = int(a.labels["target_triangle_row"][a.labels["pair"] == "l_hand-torso"][0])    # a torso triangle reached
    b = cap.aimed([Aim("l_hand", "torso", None, int(skin.parts["torso"].triangle_ids[r]))] * 3)
    assert b.n_touches >= 3
    both = TouchSet.concatenate([a, b])
    assert both.n_touches == a.n_touches + b.n_touches and len(set(both.keys)) == both.n_touches
    assert np.all(np.diff(both.stamps) > 0)
    assert np.all(b.labels["target_triangle_row"] == r)
    # the simulator itself gives the same touches as before the capture module existed
    again = simulate(skin, {"pairs": PAIRS, "n_touches": 3}, 3)
    assert again.touches.keys == ref.touches.keys and np.array_equal(again.touches.act_slot, ref.touches.act_slot)


def test_a_guided_batch_fills_what_its_aims_did_not_reach_with_random_touches(skin):
    """The simulated robot played only the touches its aims reached (3 of a batch of 5), and with aims that
    all missed fell back on random touches while its log said "aimed": one batch as the capture benchmark
    makes it, for both, says how many were aimed."""
    cap = CaptureSim(skin, {"pairs": PAIRS}, 3)
    a = cap.random(10)
    r = int(a.labels["target_triangle_row"][a.labels["pair"] == "l_hand-torso"][0])    # a torso triangle reached
    aim = Aim("l_hand", "torso", None, int(skin.parts["torso"].triangle_ids[r]))
    touches, aimed = cap.guided([aim, aim], 5)
    kept, _ = deduplicate(touches)
    assert aimed == 2 and kept.n_touches == 5
    assert np.sum(np.asarray(touches.labels["aimed"])[np.asarray(touches.labels["duplicate_of"]) < 0]) == 2
    touches, aimed = cap.guided([], 4)                       # no aim: a random batch
    assert aimed == 0 and deduplicate(touches)[0].n_touches == 4 and not np.any(touches.labels["aimed"])


def test_random_touches_split_over_the_pairs_by_weight(skin):
    """The oracle strategy of bench-capture sends a batch where the weights say; uniform without weights."""
    cap = CaptureSim(skin, {"pairs": PAIRS}, 2)
    only_second = cap.random(12, [0.0, 1.0])
    assert set(only_second.labels["pair"]) == {"r_hand-torso"}
    def pressed(batch):         # the n of random() counts presses: a touch recorded twice is one press
        return list(batch.labels["pair"][batch.labels["duplicate_of"] < 0])

    pairs = pressed(cap.random(12, [3.0, 1.0]))
    assert pairs.count("l_hand-torso") == 9 and pairs.count("r_hand-torso") == 3
    uniform = pressed(cap.random(12))
    assert uniform.count("l_hand-torso") == 6 and uniform.count("r_hand-torso") == 6


def test_report_coverage_table_lists_held_triangles(skin, captured):
    _, _, result = captured
    cov = report_coverage(result, skin)
    assert set(cov) == set(result.report.parts)
    held = [h for h in result.report.held if "/triangle_" in h and " " not in h]
    assert held
    text = markdown_report(result.report.to_dict(), cov)
    assert "## Coverage" in text
    for entry in held:
        part, frame = entry.split("/")
        tid = int(frame.split("_")[1])
        assert tid in cov[part]["held_triangles"]
        row = next(line for line in coverage_lines(cov) if line.startswith(f"| {part} |"))
        assert str(tid) in row.split("|")[4]
    assert markdown_report(result.report.to_dict()) == markdown_report(result.report.to_dict(), None)


def _activated(touches: TouchSet, part: str, triangle_row: int) -> np.ndarray:
    """(touches,) whether ``part``'s triangle at ``triangle_row`` has an activated taxel in each touch."""
    on = (touches.contact_part[touches.act_contact] == touches.part_index(part)) & \
        (touches.act_slot // 12 == triangle_row)
    hit = np.zeros(touches.n_touches, bool)
    hit[touches.contact_touch[touches.act_contact[on]]] = True
    return hit


def test_an_aimed_touch_fires_its_target_far_more_often_than_a_random_touch(skin, captured):
    """What following the guidance does: each aimed touch presses the triangle it was sent to. (How many fewer
    touches it needs to an accuracy target than random capture is measured: docs/decisions.md, "Guidance by
    expected gain"; ``nao-skin bench-capture``.)"""
    _, touches, result = captured
    g = guidance(touches, skin, result, max_targets=8, seed=3, pairs=[tuple(p) for p in PAIRS])
    targets = [t for t in g.targets if t.pose is not None and t.hand_triangle_id is not None]
    assert len(targets) >= 4
    sim = CaptureSim(skin, {"pairs": PAIRS}, 6)
    aimed = sim.aimed([Aim(t.hand, t.touched, t.hand_triangle_id, t.touched_triangle_id) for t in targets
                       for _ in range(3)])
    random = sim.random(200)
    fired, by_chance = [], []
    for t in targets:
        row = _row(skin.parts[t.part], t.triangle_id)
        label = aimed.labels["target_triangle_row" if t.part == t.touched else "hand_triangle_row"]
        fired_parts = aimed.parts_of_touch()
        if not {t.hand, t.touched} <= set(aimed.part_names):
            continue    # every aim of this pair missed (no pose reached it): with numpy 1.26 / scipy 1.11 (Ubuntu
            #             24.04's) this seed misses all of l_hand's, where numpy 2.4 / scipy 1.17 reach three
        sent = ((np.asarray(label) == row) & fired_parts[:, aimed.part_index(t.hand)]
                & fired_parts[:, aimed.part_index(t.touched)])
        fired.extend(_activated(aimed, t.part, row)[sent])
        by_chance.append(_activated(random, t.part, row).mean())
    assert len(fired) >= len(targets)     # aimed touches that fired both parts: one a target at least, on average
    # measured over simulator seeds 6-11: 0.62-0.75 of the aimed touches against 0.09-0.12 of the random
    # ones (a press between two triangles can fire the neighbour alone); ranked by expected gain the targets
    # include well-covered triangles, which random touches fire more often (0.20 here)
    assert np.mean(fired) >= max(0.5, 3 * np.mean(by_chance)), (np.mean(fired), np.mean(by_chance))


def test_the_capture_benchmark_follows_the_live_status_and_goes_on_until_done_only_when_asked(skin):
    """The benchmark replays the calibrate node's updates: each trace entry carries the parts' live states and
    their predicted error. With ``until_done`` a run met at its start goes on (the touches needed stay those of
    the first crossing) until every part is done or the cap: here the cap, with a margin no prediction meets;
    with the node's margin the loose target is predicted met at once, and the run stops at its first update."""
    loose = dict(start=60, batch=25, cap=110, median_mm=50.0, p95_mm=100.0, sim={"pairs": PAIRS})
    stops = run_capture(skin, 0, "random", CaptureSetup(**loose))
    goes_on = run_capture(skin, 0, "random", CaptureSetup(**loose, until_done=True, done_margin=1000.0))
    assert stops["needed"] == goes_on["needed"] == stops["touches"] == 60
    assert goes_on["touches"] == 110 and [t["touches"] for t in goes_on["trace"]] == [60, 85, 110]
    assert goes_on["done_at"] is None and goes_on["done_worst_median_mm"] is None
    states = [t["states"] for t in goes_on["trace"]]
    assert all(set(s) == {"l_hand", "r_hand", "torso"} for s in states)
    assert all(s == {"l_hand": "converging", "r_hand": "converging", "torso": "converging"} for s in states), states
    predicted = goes_on["trace"][0]["predicted"]
    assert set(predicted) == {"l_hand", "r_hand", "torso"}
    assert all(0 < v["median"] < v["p95"] < 100.0 for v in predicted.values()), predicted
    # and, per update, how far the truth may lie from that prediction were the posterior exact (its own draws)
    exact = goes_on["trace"][0]["exact"]
    assert 0.5 < exact["p10"] < 1.0 < exact["p90"] < 2.0 and 0.0 < exact["within"] <= 1.0, exact
    assert "exact" in honesty([goes_on])["all"]
    done = run_capture(skin, 0, "random", CaptureSetup(**loose, until_done=True))
    assert done["done_at"] == done["touches"] == 60 and len(done["trace"]) == 1
    assert done["done_worst_median_mm"] == done["trace"][0]["worst_median_mm"]
