"""Benchmark of autonomous fingertip capture in the pure simulator, against a random manual session.

Per seed one simulated robot (:class:`~nao_skin.sim.body.SimBody`: the seed's true skin and fingertips, the
``fingertip-torso`` preset, its virtual clock) is driven by the capture loop with both fingertips (:mod:`nao_skin.capture`, planned
under the NOMINAL skin, as on a robot never calibrated) until ``touches`` presses, then ``cap``; the presses
are recorded as the simulator records (:meth:`SimBody.record`). The random manual session of the same seed is
:func:`~nao_skin.sim.simulate.simulate` of the same scene (its truth is the same draw).

Figures per seed:

* ``to_target``: touches (duplicates removed) until the torso's TRUE taxel error has median <= ``median_mm``
  and p95 <= ``p95_mm``, calibrating every ``every`` touches from scratch (as the live calibrate node does
  below 1000 touches); ``to_done``: until the calibration's own predicted error, times the live status's
  margin, meets the same target (the status's "done");
* ``fired``: the share of the taxels the capture found a pose for (touches aborted there included) that fired
  at least once, by ``touches``;
* ``press_mm``: the farthest a press went on beyond where the skin first fired, along the true normal (the
  simulator's ground truth, mm); ``below_mm``: the deepest the true fingertip went below the true fabric
  surface in a touch (the simulator fires nothing where the sphere lands between taxels: such a press fires
  late), ``nocontact_mm`` in an approach aborted for no contact;
* ``robot_min``: the body's clock at the ``touches``-th press (moves, approaches, holds; planning is free);
* ``beyond``: commands beyond the joint limits less the margin (must be 0).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from nao_skin.calibration.engine import CalibrationOptions, calibrate
from nao_skin.calibration.evaluation import truth_error
from nao_skin.capture.loop import CaptureLoop
from nao_skin.capture.plan import CaptureOptions, Planner, TargetChooser
from nao_skin.capture.safety import SafetyGate
from nao_skin.errors import NaoSkinError
from nao_skin.live.updates import TARGET_MM, PartStates
from nao_skin.model.skin import SkinModel
from nao_skin.sim.body import SimBody
from nao_skin.sim.params import load_params
from nao_skin.sim.simulate import simulate
from nao_skin.touch.datasets import deduplicate
from nao_skin.touch.touches import TouchSet

# the torso pressed by both fingertips (each reaches about two thirds of it, together nearly all); the manual
# session it is held against is the preset's, the right fingertip anywhere a pose reaches (the simulator's)
PRESET, FINGERTIPS, PART = "fingertip-torso", ("r_finger", "l_finger"), "torso"
RECORD_STREAM = 0xA070       # the recording's random stream of a seed


@dataclass(frozen=True)
class AutonomousSetup:
    touches: int = 250          # presses the figures are taken at
    cap: int = 500              # presses and random touches at most, for the touches to the target
    every: int = 50             # touches between two calibrations
    median_mm: float = TARGET_MM["median"]
    p95_mm: float = TARGET_MM["p95"]


def autonomous_capture(skin: SkinModel, seed: int, presses: int, options: CaptureOptions | None = None) -> dict:
    """Drive the simulated body through ``presses`` touches: ``{body, loop, results, q, robot_s}`` (``q``: the
    true joint angles of each press, ``robot_s``: the body's clock after each)."""
    options = options or CaptureOptions()
    body = SimBody(skin, FINGERTIPS, PART, load_params(PRESET), seed=seed)
    planners = [Planner(skin, skin.zero_calibration(), tip, PART, options) for tip in FINGERTIPS]
    chooser = TargetChooser(planners[0].points, planners[0].slots, arms=len(planners))
    gate = SafetyGate(options.stale_after, lambda: False, lambda: 0.0)
    loop = CaptureLoop(planners, chooser, body, body, gate, body.clock)
    q, robot_s, fired_by = [], [], None
    loop.start()
    while len(q) < presses:
        result = loop.touch()
        if result is None:
            break
        if result.outcome == "touched":
            q.append(body.full(loop.planner.arm.names, result.pressed[None])[0])
            robot_s.append(body.clock.now())
            if len(q) == presses:
                fired_by = chooser.fired.copy()
    loop.finish()
    return {"body": body, "loop": loop, "chooser": chooser, "planners": planners, "q": np.array(q),
            "robot_s": np.array(robot_s), "fired_by": fired_by if fired_by is not None else chooser.fired.copy()}


def _to_target(skin: SkinModel, touches: TouchSet, truth, setup: AutonomousSetup) -> dict:
    """Calibrating the first n of ``touches`` every ``every``: ``to_target`` (touches until the torso meets the
    target by its true error), ``to_done`` (by its predicted error times the live status's margin; None: not
    within them), and the torso's true median and p95 (mm) at ``setup.touches`` touches."""
    margin = PartStates().margin
    out = {"to_target": None, "to_done": None, "median_mm": None, "p95_mm": None}
    for n in range(setup.every, touches.n_touches + 1, setup.every):
        sub, _ = deduplicate(touches.subset(np.arange(n)))
        try:
            result = calibrate(sub, skin, CalibrationOptions(), truth=truth)
        except NaoSkinError:           # too few touches yet
            continue
        err = truth_error(skin, result.calibration, truth, [PART]).get(PART)
        if n == setup.touches and err:
            out.update(median_mm=err["median"], p95_mm=err["p95"])
        if out["to_target"] is None and err and err["median"] <= setup.median_mm and err["p95"] <= setup.p95_mm:
            out["to_target"] = sub.n_touches
        pred = (result.report.final.get("predicted_taxel_error_mm") or {}).get(PART)
        if out["to_done"] is None and pred and pred["median"] * margin <= setup.median_mm and \
                pred["p95"] * margin <= setup.p95_mm:
            out["to_done"] = sub.n_touches
        if None not in (out["to_target"], out["to_done"]) and n >= setup.touches:
            break
    return out


def run_seed(skin: SkinModel, seed: int, setup: AutonomousSetup) -> dict:
    run = autonomous_capture(skin, seed, setup.cap)
    body, chooser, planners = run["body"], run["chooser"], run["planners"]
    auto = body.record(run["q"], np.random.default_rng([seed, RECORD_STREAM]))
    manual = simulate(skin, {**load_params(PRESET).to_dict(), "n_touches": setup.cap}, seed=seed).touches
    reachable = ~chooser.out_of_reach
    results = run["loop"].results
    outcomes = [r.outcome for r in results]
    depth = -1000.0 * np.array(body.presses)
    touched = np.array(body.fired_presses, bool)
    k = min(setup.touches, len(run["robot_s"])) - 1
    return {"seed": seed, "presses": len(run["q"]), "unreachable": int(chooser.out_of_reach.sum()),
            "aborted": outcomes.count("aborted"), "reachable": int(reachable.sum()), "taxels": len(chooser.slots),
            "fired": float(np.mean(run["fired_by"][reachable] > 0)) if reachable.any() else 0.0,
            "press_mm": 1000.0 * max(body.beyond) if body.beyond else None,
            "below_mm": float(depth[touched].max()) if touched.any() else None,
            "nocontact_mm": float(depth[~touched].max()) if (~touched).any() else None,
            "robot_min": float(run["robot_s"][k]) / 60.0 if k >= 0 else None,
            "beyond": _beyond_limits(body, planners),
            "auto": _to_target(skin, auto, body.truth, setup), "manual": _to_target(skin, manual, body.truth, setup)}


def _beyond_limits(body: SimBody, planners) -> int:
    """Commands the body was sent beyond their arm's limits less the margin."""
    arms = {p.arm.names: p.arm for p in planners}
    return sum(int(not arms[tuple(names)].within(np.array(angles))[0])
               for kind, _, names, angles, _ in body.log if kind == "command")


def summary(rows: list, setup: AutonomousSetup) -> dict:
    def med(values):
        values = [v for v in values if v is not None]
        return float(np.median(values)) if values else None

    out = {"seeds": len(rows), "fired_min": min(r["fired"] for r in rows), "fired_median": med(r["fired"] for r in rows),
           "press_mm_max": max((r["press_mm"] or 0.0) for r in rows),
           "below_mm_max": max((r["below_mm"] or 0.0) for r in rows),
           "nocontact_mm_max": max((r["nocontact_mm"] or 0.0) for r in rows),
           "robot_min_max": max(r["robot_min"] or 0.0 for r in rows), "beyond": sum(r["beyond"] for r in rows),
           "reachable_median": med(r["reachable"] for r in rows), "aborted_median": med(r["aborted"] for r in rows)}
    for what in ("median_mm", "p95_mm"):
        out[what] = {"auto_median": med(r["auto"][what] for r in rows),
                     "manual_median": med(r["manual"][what] for r in rows)}
    for what in ("to_target", "to_done"):
        a, m = [r["auto"][what] for r in rows], [r["manual"][what] for r in rows]
        out[what] = {"auto_median": med(a), "manual_median": med(m),
                     "auto_not_more": sum(x is not None and (y is None or x <= y) for x, y in zip(a, m)),
                     "auto_reached": sum(x is not None for x in a), "manual_reached": sum(y is not None for y in m)}
    return out


def table(rows: list) -> str:
    """One line per seed: the figures of :func:`run_seed`."""
    def cell(v, fmt="{:.2f}"):
        return "-" if v is None else fmt.format(v)

    lines = ["| seed | reachable taxels | fired by the 250th | aborted | press beyond first contact (mm) | below the"
             " surface: touched / no contact (mm) | robot min at 250 | commands beyond | to target: auto / manual |"
             " to done: auto / manual | torso median at 250 (mm): auto / manual |", "|" + "---|" * 11]
    for r in rows:
        lines.append(f"| {r['seed']} | {r['reachable']} of {r['taxels']} | {100 * r['fired']:.1f} % | {r['aborted']} |"
                     f" {cell(r['press_mm'])} | {cell(r['below_mm'])} / {cell(r['nocontact_mm'])} |"
                     f" {cell(r['robot_min'], '{:.1f}')} | {r['beyond']} |"
                     f" {cell(r['auto']['to_target'], '{}')} / {cell(r['manual']['to_target'], '{}')} |"
                     f" {cell(r['auto']['to_done'], '{}')} / {cell(r['manual']['to_done'], '{}')} |"
                     f" {cell(r['auto']['median_mm'])} / {cell(r['manual']['median_mm'])} |")
    return "\n".join(lines)
