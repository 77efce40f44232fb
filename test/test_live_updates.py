"""Live calibration's core, without ROS: a warm-started update, and what decides that it is published
and that a part is done (the node over real DDS: test_live_calibration.py)."""
import shutil
from pathlib import Path

import numpy as np
import pytest

from nao_skin.calibration.engine import CalibrationOptions, calibrate
from nao_skin.errors import TooFewTouches
from nao_skin.live.updates import PartStates, WarmStart, rejection, taxel_displacement_mm
from nao_skin.sim.params import load_params
from nao_skin.sim.simulate import simulate
from nao_skin.touch.datasets import deduplicate


@pytest.fixture(scope="module")
def session(skin):
    """Two pairs of simulated touches (the robot's body stands in), their truth, and a first calibration
    on all but the last 20 touches: the state of a live session before its next update."""
    params = load_params("default", {"pairs": [["r_hand", "torso"], ["l_hand", "torso"]], "n_touches": 80})
    sim = simulate(skin, params, seed=4)
    touches, _ = deduplicate(sim.touches)
    earlier = touches.subset(np.arange(touches.n_touches - 20))
    first = calibrate(earlier, skin, CalibrationOptions(), truth=sim.truth)
    return touches, sim.truth, first


def test_a_warm_update_skips_what_the_prior_settled_and_lands_as_close(skin, session):
    touches, truth, first = session
    cold = calibrate(touches, skin, CalibrationOptions(), truth=truth)
    warm = calibrate(touches, skin, CalibrationOptions(), prior=first.calibration, warm=first.report.parts,
                     truth=truth)
    # the fixed-reference steps of the settled parts are gone: only the joint refinement runs
    assert [s["name"] for s in cold.report.stages][:1] == ["r_hand from torso: mount"]
    assert all(s["name"].startswith("joint refinement") for s in warm.report.stages)
    assert len(warm.report.stages) == 3 < len(cold.report.stages)
    # final figures only: nothing measured before or per stage (not even the conditioning), nor the subsets
    # a self-contact explains
    assert warm.report.before == {} and "train" not in warm.report.stages[0]
    assert all(s["condition"] is None for s in warm.report.stages)
    # a stage that estimates nothing has no conditioning: here a fixed-reference step's triangles, each with
    # too few activations against the one reference (the fabric waits for the joint refinement)
    assert all(s["condition"] >= 1.0 if s["condition"] is not None else
               " from " in s["name"] and s["name"].endswith(": triangle") and s["iterations"] == 0
               for s in cold.report.stages), [(s["name"], s["condition"]) for s in cold.report.stages]
    assert cold.report.stages[-1]["condition"] >= 1.0
    assert {"train", "test"} <= set(warm.report.final) and "test_accepted" not in warm.report.final
    assert "test_accepted" in cold.report.final
    cold_err = cold.report.final["truth_taxel_error_mm"]["all"]["median"]
    warm_err = warm.report.final["truth_taxel_error_mm"]["all"]["median"]
    assert warm_err <= 1.1 * cold_err + 0.05, (warm_err, cold_err)


def test_a_part_new_to_the_prior_gets_the_whole_plan(skin, session):
    touches, truth, first = session
    warm = calibrate(touches, skin, CalibrationOptions(), prior=first.calibration, warm=("r_hand", "torso"),
                     truth=truth)
    names = [s["name"] for s in warm.report.stages]
    assert "l_hand from torso: mount" in names and "r_hand from torso: mount" not in names


def test_a_warm_update_pairs_each_stage_once_and_a_part_new_to_it_until_settled(skin, session):
    """A warm update is one step of the pairing's fixed point (options.warm_repairings); the next update
    takes the next. A stage that fits a part the last update did not calibrate re-pairs as usual."""
    touches, truth, first = session
    warm = calibrate(touches, skin, CalibrationOptions(), prior=first.calibration, warm=first.report.parts)
    assert [s["repairings"] for s in warm.report.stages] == [1, 1, 1]
    longer = calibrate(touches, skin, CalibrationOptions(warm_repairings=8), prior=first.calibration,
                       warm=first.report.parts)
    assert max(s["repairings"] for s in longer.report.stages) > 1
    new = calibrate(touches, skin, CalibrationOptions(), prior=first.calibration, warm=("r_hand", "torso"))
    repairings = {s["name"]: s["repairings"] for s in new.report.stages}
    assert max(v for k, v in repairings.items() if k.startswith("l_hand from torso")) > 1
    assert max(v for k, v in repairings.items() if k.startswith("joint refinement")) > 1   # l_hand is in it


def test_a_warm_update_goes_on_from_the_last_prior_widths(skin, session):
    """The frames alone are not all a fit learnt: a warm update that restarted from the assumed prior widths
    pulled the real skin's patches back to them each time (train closest taxel 1.94 -> 2.15 mm there)."""
    from nao_skin.calibration.engine import FitState

    touches, _, first = session
    assert first.state == FitState(first.report.prior_sigma) and first.state.prior_sigma
    resumed = FitState({k: 2.0 * v for k, v in first.state.prior_sigma.items()})
    args = dict(prior=first.calibration, warm=first.report.parts)
    went_on = calibrate(touches, skin, CalibrationOptions(), resume=resumed, **args)
    mount = went_on.report.stages[0]
    assert mount["name"].endswith(": mount") and mount["prior_sigma"] == resumed.prior_sigma
    assert calibrate(touches, skin, CalibrationOptions(), **args).report.stages[0]["prior_sigma"] != resumed.prior_sigma
    # an update from scratch starts from the options, whatever it is given
    scratch = calibrate(touches, skin, CalibrationOptions(max_repairings=1), resume=resumed)
    assert scratch.report.stages[0]["prior_sigma"] != resumed.prior_sigma


def test_too_few_touches_is_its_own_error(skin, session):
    touches, _, _ = session
    with pytest.raises(TooFewTouches):
        calibrate(touches.subset(np.arange(8)), skin, CalibrationOptions())


def test_a_diverged_update_is_rejected_and_a_first_calibration_is_not(skin, session):
    touches, _, first = session
    nominal = skin.zero_calibration()
    moved = taxel_displacement_mm(skin, nominal, first.calibration, first.report.parts)
    # the first calibration of a hand moves it a long way (mount ~160 deg off): fine, it was not calibrated
    assert max(moved.values()) > 20.0
    assert rejection(skin, first.calibration, moved, (), 20.0) is None
    # the same move of a part the last update had calibrated is a divergence
    why = rejection(skin, first.calibration, moved, first.report.parts, 20.0)
    assert why is not None and "diverged" in why
    broken = first.calibration.copy()
    broken.parts["torso"].patches[0, 0] = np.nan
    assert "non-finite" in rejection(skin, broken, {}, (), 20.0)


def test_a_part_an_update_leaves_out_keeps_its_last_frames_and_stays_guarded(skin, session):
    """A part calibrated before and left out of an update (its training touches fell below the minimum under a
    new split) was published back at the session's start by an update from scratch, called "not calibrated" by
    the guidance while the status said "converging", and the next update that calibrated it again was not
    checked for divergence. Now it keeps its last accepted frames, says so, and stays guarded."""
    import dataclasses

    from nao_skin.errors import DataError
    from nao_skin.live.updates import LiveUpdates

    touches, _, first = session
    assert {"r_hand", "l_hand", "torso"} <= set(first.report.parts)
    fired = touches.parts_of_touch()
    left = np.flatnonzero(fired[:, touches.part_index("l_hand")])
    few_left = touches.subset(np.concatenate([np.flatnonzero(~fired[:, touches.part_index("l_hand")]), left[:5]]))
    live = LiveUpdates(skin, skin.zero_calibration(), scratch_below=0)
    live.update(30, lambda args: first)

    def from_scratch_only(args):
        if args["warm"]:
            raise TooFewTouches("the warm update failed")
        return calibrate(few_left, skin, CalibrationOptions(max_repairings=1), **args)

    result, moved, arguments = live.update(few_left.n_touches, from_scratch_only)
    # not calibrated (no displacement of its own), but held: part of what is written, its taxel file too
    assert not arguments["warm"] and "l_hand" not in moved and "l_hand" in result.report.parts
    for frames in ("mount", "patches", "triangles"):
        assert np.array_equal(getattr(result.calibration.parts["l_hand"], frames),
                              getattr(first.calibration.parts["l_hand"], frames))
    assert any("part 'l_hand': not calibrated by this update" in w for w in result.report.warnings)
    assert "l_hand" in live.calibrated_parts
    # calibrated again, 50 mm away: a divergence, as for any part calibrated before
    far = first.calibration.copy()
    far.parts["l_hand"].mount[0] += 0.05
    with pytest.raises(DataError, match="part 'l_hand': its taxels would move"):
        live.update(few_left.n_touches + 20, lambda args: dataclasses.replace(first, calibration=far))


def test_done_when_the_predicted_error_meets_the_target_with_margin():
    states = PartStates(median_mm=0.5, p95_mm=1.5, margin=1.2)
    assert states.states(["r_hand", "l_hand"]) == {"r_hand": "collecting", "l_hand": "collecting"}
    states.add({"r_hand": {"median": 0.45, "p95": 1.0}, "all": {"median": 0.1, "p95": 0.2}})
    # within the target, not within it with the margin (0.45 x 1.2 > 0.5); 'all' is no part
    assert states.states(["r_hand", "l_hand", "all"]) == {"r_hand": "converging", "l_hand": "collecting",
                                                          "all": "collecting"}
    states.add({"r_hand": {"median": 0.41, "p95": 1.3}})          # median with margin, p95 not (1.56 > 1.5)
    assert states.states(["r_hand"]) == {"r_hand": "converging"}
    states.add({"r_hand": {"median": 0.41, "p95": 1.2}})
    assert states.states(["r_hand"]) == {"r_hand": "done"}
    states.add({"l_hand": {"median": 0.3, "p95": 0.9}})           # an update without r_hand: its state stays
    assert states.states(["r_hand", "l_hand"]) == {"r_hand": "done", "l_hand": "done"}


def test_a_done_part_stays_done_until_its_prediction_misses_the_target_itself():
    """The margin is a band: a prediction wavering about the threshold does not flip the state; one beyond the
    target (a new touch contradicts the calibration, the rows' noise grew) does; NaN is no prediction met."""
    states = PartStates(median_mm=0.5, p95_mm=1.5, margin=1.1)
    states.add({"torso": {"median": 0.44, "p95": 1.0}})
    assert states.states(["torso"]) == {"torso": "done"}
    for median in (0.47, 0.5, 0.43):
        states.add({"torso": {"median": median, "p95": 1.0}})
        assert states.states(["torso"]) == {"torso": "done"}
    states.add({"torso": {"median": 0.45, "p95": 1.51}})
    assert states.states(["torso"]) == {"torso": "converging"}
    states.add({"torso": {"median": 0.47, "p95": 1.0}})             # back within the target, not the margin
    assert states.states(["torso"]) == {"torso": "converging"}
    states.add({"torso": {"median": float("nan"), "p95": 1.0}})
    assert states.states(["torso"]) == {"torso": "converging"} and states.updates == 7


def test_an_update_from_scratch_whenever_the_touches_doubled(skin, session):
    """Warm updates between updates from scratch, which start where the session started; a warm update's
    prior is centred there too (not on the last update, which the same touches made)."""
    touches, _, first = session
    start = skin.zero_calibration()
    updates = WarmStart(start, refresh=2.0, scratch_below=0)
    assert updates.arguments(30) == {"prior": start, "warm": (), "anchor": None, "resume": None}
    updates.accepted(first, 30, updates.arguments(30))
    warm = updates.arguments(45)
    assert warm["prior"] is first.calibration and warm["anchor"] is start and warm["resume"] == first.state
    assert set(warm["warm"]) == set(first.report.parts)
    updates.accepted(first, 45, warm)
    assert updates.arguments(59)["warm"] and not updates.arguments(60)["warm"]
    # what the engine makes of them: a warm update is the joint refinement alone
    result = calibrate(touches, skin, CalibrationOptions(), **warm)
    assert all(s["name"].startswith("joint refinement") for s in result.report.stages)


def test_below_scratch_below_touches_every_update_is_the_calibration_from_scratch_alone(skin, session):
    """As nao-skin calibrate on the same touches (live equals offline): no warm update beside it, the final one
    of a session too; from scratch_below touches on the warm chain and its refreshes take over."""
    touches, _, first = session
    updates = WarmStart(skin.zero_calibration(), refresh=2.0, scratch_below=50)
    updates.accepted(first, 30, updates.arguments(30))
    ran = []

    def run(args):
        ran.append(bool(args["warm"]))
        return first

    for n, final in ((35, False), (40, True), (49, False)):
        result, arguments = updates.update(n, run, warm_only=final)
        assert ran == [False] and not updates.refreshed and arguments["prior"] is updates.start, (n, final)
        updates.accepted(result, n, arguments)
        ran.clear()
    updates.update(50, run)              # 50 < 2 x 49: warm from here on
    assert ran == [True]


def test_a_refresh_keeps_the_warm_update_when_its_held_out_touches_pair_closer(skin, session):
    """At a refresh the warm update runs beside the one from scratch and the closer on the test split wins;
    either way the next refresh waits for the touches to double again."""
    touches, _, first = session
    updates = WarmStart(skin.zero_calibration(), refresh=2.0, scratch_below=0)
    updates.accepted(first, 30, updates.arguments(30))
    ran = []

    def run(args):
        ran.append(bool(args["warm"]))
        return calibrate(touches, skin, CalibrationOptions(), **args)

    result, arguments = updates.update(60, run)              # 60 >= 2 x 30: a refresh
    assert ran == [False, True] and updates.refreshed         # said in the status: its seconds are both runs
    scratch, warm = (calibrate(touches, skin, CalibrationOptions(), **a)
                     for a in ({"prior": updates.start}, {"prior": first.calibration, "warm": first.report.parts,
                                                          "anchor": updates.start, "resume": first.state}))
    figures = {False: scratch.report.final["test"]["taxel_mean_mm"], True: warm.report.final["test"]["taxel_mean_mm"]}
    assert bool(arguments["warm"]) == (figures[True] < figures[False]), figures
    assert result.report.final["test"]["taxel_mean_mm"] == min(figures.values())
    updates.accepted(result, 60, arguments)
    ran.clear()
    updates.update(100, run)                                  # < 2 x 60: warm only
    assert ran == [True] and not updates.refreshed


def test_a_final_update_goes_on_warm_where_a_refresh_was_due(skin, session):
    """A session's end adds the touches since the last accepted update to it (warm, a fraction of a refresh's
    time), also when the touches have doubled since the last update from scratch; a refresh comes after."""
    _, _, first = session
    updates = WarmStart(skin.zero_calibration(), refresh=2.0, scratch_below=0)
    updates.accepted(first, 30, updates.arguments(30))
    ran = []
    result, arguments = updates.update(60, lambda args: ran.append(bool(args["warm"])) or first, warm_only=True)
    assert ran == [True] and not updates.refreshed and arguments["prior"] is first.calibration
    assert not updates.arguments(60)["warm"]                  # otherwise: 60 >= 2 x 30, a refresh


def test_a_refresh_stands_alone_when_the_warm_update_fails(skin, session):
    touches, _, first = session
    updates = WarmStart(skin.zero_calibration(), refresh=2.0, scratch_below=0)
    updates.accepted(first, 30, updates.arguments(30))

    def run(args):
        if args["warm"]:
            raise TooFewTouches("the warm update failed")
        return calibrate(touches, skin, CalibrationOptions(max_repairings=1), **args)

    result, arguments = updates.update(60, run)
    assert not arguments["warm"] and result.report.stages[0]["name"] == "r_hand from torso: mount"


def test_a_live_session_updates_waits_and_fails_without_raising(skin, session, tmp_path):
    """LiveCalibration, what the calibrate node runs as touches arrive, on a real bag: too few touches is
    `waiting`, then an update from scratch, then warm ones; a diverged update is `failed` and the last
    accepted calibration stays; a recording that is not there is one line, never an exception."""
    from nao_skin.formats.bag import write_touch_bag
    from nao_skin.formats.salvage import LOCK_FILE, write_lock
    from nao_skin.session.live import LiveCalibration

    touches, _, _ = session
    few, bag = tmp_path / "few", tmp_path / "touches"
    write_touch_bag(few, touches.subset(np.arange(8)), skin, storage="mcap")

    def recorded(n):        # the bag as the recorder has written it by now (replaced: read again from its start)
        shutil.rmtree(bag, ignore_errors=True)
        write_touch_bag(bag, touches.subset(np.arange(n)), skin, storage="mcap")

    n = touches.n_touches
    recorded(n - 20)

    def live(recording, max_move_mm=20.0):
        return LiveCalibration(skin, CalibrationOptions(), recording, skin.zero_calibration(), 2.0, PartStates(),
                               max_move_mm, scratch_below=0)

    waiting = live(few).update()
    assert waiting.status["state"] == "waiting" and waiting.accepted is None and waiting.touches.n_touches == 8
    assert set(waiting.status["parts"].values()) == {"collecting"}

    session_live = live(bag)
    first = session_live.update()
    assert first.status["state"] == "updated" and first.status["from_scratch"], first.status
    assert first.accepted is session_live.last and first.status["touches"] == n - 20
    assert set(first.status["pairs"]) == {"r_hand+torso", "l_hand+torso"}
    assert sum(first.status["pairs"].values()) == n - 20
    recorded(n - 10)
    second = session_live.update()
    assert second.status["state"] == "updated" and not second.status["from_scratch"]
    assert not first.status["refresh"] and not second.status["refresh"]
    assert set(second.status["parts"]) == set(skin.parts)
    # the session's report.md: a warm update measured its final figures only; its other rows said 0 touches
    from nao_skin.calibration.report import markdown_report
    warm_md, cold_md = (markdown_report(o.accepted.report.to_dict()) for o in (second, first))
    assert "| before |" not in warm_md and "| final | test |" in warm_md and "measured on no split" in warm_md
    assert "| before | train |" in cold_md and "measured on no split" not in cold_md
    accepted, counted = session_live.last, session_live.updates.part_states.updates
    # no touch in the bag since, while it is being recorded (the recorder counted one it has not flushed yet):
    # nothing runs, no status, and no update counted twice (a rehearsal showed 'taxels moved up to 0.00 mm')
    write_lock(bag)                                   # the bag open in its recorder: this process
    same = session_live.update()
    assert same.status == {} and same.accepted is None and session_live.last is accepted
    assert session_live.updates.part_states.updates == counted
    # a closed recording is calibrated again each time it is asked (bench-live's --update-input)
    (bag / LOCK_FILE).unlink()
    again = session_live.update()
    assert again.status["state"] == "updated" and again.status["touches"] == n - 10
    recorded(n)
    session_live.updates.max_move_mm = 1e-9       # any move of a part calibrated before is now a divergence
    third = session_live.update()
    assert third.status["state"] == "failed" and "diverged" in third.status["error"], third.status
    assert third.accepted is None and session_live.last is again.accepted and third.touches is not None

    gone = live(tmp_path / "nowhere").update()
    assert gone.status["state"] == "failed" and "nowhere" in gone.status["error"] and gone.touches is None
    assert "\n" not in gone.status["error"]


def test_the_session_end_writes_beside_an_out_dir_written_during_the_session(tmp_path):
    """The last live calibration goes to out_dir unless another command wrote there meanwhile: then it goes
    beside it, and the warning says so; the calibration requested of the node during the session is the node's
    own, and the session's last replaces it there (it went to <out_dir>.live, where the README did not say)."""
    from nao_skin.formats.outdir import output_stamp
    from nao_skin.session.live import session_end_out_dir

    out = tmp_path / "bag_calibration"
    assert session_end_out_dir(out, output_stamp(out), None) == (out, (), None)   # still absent
    at_start = output_stamp(out)
    out.mkdir()
    (out / "calibration.yaml").write_text("parts: {}\n")
    beside, replacing, said = session_end_out_dir(out, at_start, None)
    assert beside == f"{out}.live" and not Path(beside).exists() and replacing == ()
    assert said == (f"out_dir {out} was written by another command during the session and is left as it is; the"
                    f" session's last live calibration goes to {beside}")
    assert session_end_out_dir(out, at_start, output_stamp(out)) == (out, output_stamp(out), None)


def test_the_node_never_replaces_a_calibration_it_did_not_write(tmp_path):
    """An out_dir that held a calibration when the node started (an earlier run's) stays as it is: a requested
    calibration goes to <out_dir>.new, then replaces only its own; the session's live one goes to .live."""
    from nao_skin.formats.outdir import output_stamp
    from nao_skin.session.live import request_out_dir, session_end_out_dir

    out = tmp_path / "nao_skin_calibration"
    assert request_out_dir(out, None) == (out, (), None)          # new: the node's to take, while it is free
    out.mkdir()
    assert request_out_dir(out, None) == (out, (), None)          # empty: too
    (out / "calibration.yaml").write_text("parts: {}\n")
    at_start = output_stamp(out)
    target, replacing, said = request_out_dir(out, None)
    assert target == f"{out}.new" and replacing == () and said.startswith(f"out_dir {out} holds a calibration this node did not write")
    Path(target).mkdir()
    own = (target, output_stamp(target))
    assert request_out_dir(out, own) == (target, own[1], None)    # its own output: replaced by the next request
    beside, _, said = session_end_out_dir(out, at_start, output_stamp(target))
    assert beside == f"{out}.live" and said == (f"out_dir {out} held an earlier calibration when the session started"
                                                f" and is left as it is; the session's last live calibration goes"
                                                f" to {beside}")
    # the user put something of theirs where the node's output was (the inode may well be reused): not the node's
    import time

    Path(target).rmdir()
    time.sleep(0.01)
    Path(target).mkdir()
    (Path(target) / "mine.txt").write_text("the user's\n")
    assert request_out_dir(out, own)[0] == f"{out}.new2"


def test_a_chmod_of_the_nodes_output_leaves_it_the_nodes_own(tmp_path):
    """Its output marker tells the node's output from another's, not the change time: a chmod or a permission
    change of the directory made the node disown it (a request went to <out_dir>.new, the session's end said
    "written by another command during the session"); another command's output in its place is still not its own."""
    import os

    from nao_skin.formats.outdir import output_stamp, write_marker
    from nao_skin.session.live import request_out_dir, session_end_out_dir

    out = tmp_path / "touches_calibration"
    out.mkdir()
    (out / "calibration.yaml").write_text("parts: {}\n")
    write_marker(out, "calibrate (node)", "calibration")
    own = (out, output_stamp(out))
    os.chmod(out, 0o775)
    assert request_out_dir(out, own) == (out, own[1], None)
    assert session_end_out_dir(out, None, output_stamp(out)) == (out, output_stamp(out), None)
    write_marker(out, "calibrate", "calibration")      # another command's output, written in the same place
    assert request_out_dir(out, own)[0] == f"{out}.new"
