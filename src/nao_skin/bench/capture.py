"""Benchmark of guided capture: touches needed until every part is calibrated well, random against guided.

Per seed one simulated robot (:class:`~nao_skin.sim.capture.CaptureSim`: its
true skin drawn once) is captured twice from scratch, with the same loop:

1. a small random start (``start`` touches spread evenly over the pairs);
2. calibrate (deduplicated touches, default options) as the live calibrate
   node updates (:class:`~nao_skin.live.updates.LiveUpdates` with the node's
   defaults: warm-started from the last accepted calibration, from scratch
   whenever the touches doubled, a diverged update refused; each part's
   state, collecting / converging / done, as the node's status says it);
3. stop when EVERY part's true taxel error (``truth_error``: every present
   taxel's distance from its true position, chain-end frame) has median <=
   ``median_mm`` and p95 <= ``p95_mm`` (with ``until_done``: and the status
   calls every part done), or the touches reach ``cap``;
4. else record the next batch of ``batch`` touches and go to 2:

   * **random** -- :meth:`CaptureSim.random`: uniform over the pairs and over
     each part's reachable triangles, no guidance;
   * **guided** -- :func:`nao_skin.guidance.capture.guidance` on the touches and
     the last calibration; one aimed touch at each of its top ``max_targets``
     targets that a pose reaches (:meth:`CaptureSim.aimed`), as the simulated
     robot follows the guidance (``nodes.sim_robot``); the rest of the batch,
     and the aims the true robot cannot reach, random touches, so every batch
     has the same size;
   * **oracle** -- random touches, the batch split over the pairs by how far
     each pair's worse part is from the target under the TRUE error (share
     ``max(median / median_mm, p95 / p95_mm) ** 4``): what no capture at the
     robot can know, so an upper bound of what sending the touches to the
     parts that need them most can buy.

Touches counted: presses recorded (duplicates of the recording removed), the
x axis of the plot and the "touches needed". Both strategies share the
calibration options, the stop rule, the start size, the batch size and the
truth; the random start of a seed is the same for both.
"""
from __future__ import annotations

import time
from dataclasses import asdict, dataclass, field
from typing import Callable

import numpy as np

from nao_skin.bench import TARGET_MM
from nao_skin.calibration.engine import CalibrationOptions, calibrate
from nao_skin.calibration.evaluation import truth_error
from nao_skin.errors import NaoSkinError, one_line
from nao_skin.guidance.capture import guidance
from nao_skin.live.updates import LiveUpdates, PartStates, UpdateSchedule
from nao_skin.model.skin import SkinModel
from nao_skin.sim.capture import Aim, CaptureSim
from nao_skin.touch.datasets import deduplicate
from nao_skin.touch.touches import TouchSet

STRATEGIES = ("random", "guided", "oracle")
ORACLE_POWER = 4        # the oracle's batch share of a pair: (its worse part's distance to the target) ** 4


@dataclass
class CaptureSetup:
    start: int = 60                 # random touches before the first calibration (15 per pair)
    batch: int = UpdateSchedule.every_touches   # touches per batch: one live update's, as the node's default
    cap: int = 1500                 # give up at this many touches
    median_mm: float = TARGET_MM["median"]   # every part's true taxel error median at most
    p95_mm: float = TARGET_MM["p95"]         # and p95 at most
    max_targets: int = 8            # guided: one aim at each of this many top targets per batch
    until_done: bool = False        # after the target, go on until the live status calls every part done (or
                                    # the cap): how far from the truth "done" is
    done_margin: float = PartStates.margin   # the status's "done" margin (the node's live_done_margin)
    to_cap: bool = False            # go on to the cap whatever is met: when the target was met for good, and the
                                    # prediction's honesty over every touch count
    warm_start: bool = True         # update as the live calibrate node does (live.updates.WarmStart); False: from
                                    # nominal each time
    sim: dict = field(default_factory=dict)     # simulator parameter overrides (e.g. pairs)
    options: dict = field(default_factory=dict)  # calibration option overrides

    def calibration_options(self) -> CalibrationOptions:
        return CalibrationOptions.from_mapping(self.options)


QUICK_SETUP = CaptureSetup(start=60, batch=20, cap=400, median_mm=1.0, p95_mm=2.0)


def _met(err: dict, parts, setup: CaptureSetup) -> bool:
    return all(p in err and err[p]["median"] <= setup.median_mm and err[p]["p95"] <= setup.p95_mm for p in parts)


def run_capture(skin: SkinModel, seed: int, strategy: str, setup: CaptureSetup | None = None,
                say: Callable[[str], None] = lambda msg: None) -> dict:
    """One capture from scratch; returns ``{seed, strategy, needed (touches or None), trace, ...}``."""
    setup = setup or CaptureSetup()
    if strategy not in STRATEGIES:
        raise ValueError(f"strategy {strategy!r}: expected one of {', '.join(STRATEGIES)}")
    cap = CaptureSim(skin, setup.sim, seed)
    parts = sorted({p for pair in cap.pairs for p in pair})
    options = setup.calibration_options()
    t0 = time.perf_counter()
    batches = [cap.random(setup.start)]
    calib, result = None, None
    live = LiveUpdates(skin, skin.zero_calibration(),
                       part_states=PartStates(setup.median_mm, setup.p95_mm, setup.done_margin))
    trace, needed, failures, guide_s, done = [], None, 0, [], None
    while True:
        touches, _ = deduplicate(TouchSet.concatenate(batches))
        try:
            if setup.warm_start:
                result, _, _ = live.update(touches.n_touches,
                                           lambda args: calibrate(touches, skin, options, truth=cap.truth, **args))
            else:
                result = calibrate(touches, skin, options, truth=cap.truth)
            calib = result.calibration
        except NaoSkinError as exc:      # too few touches of a pair yet, or diverged: the last calibration stays
            failures += 1
            say(f"seed {seed} {strategy} at {touches.n_touches}: {one_line(exc)}")
        err = truth_error(skin, calib, cap.truth, parts) if calib is not None else {}
        worst_med = max((err[p]["median"] for p in parts if p in err), default=float("nan"))
        worst_p95 = max((err[p]["p95"] for p in parts if p in err), default=float("nan"))
        states = live.states(parts) if setup.warm_start else None
        trace.append({"touches": touches.n_touches, "worst_median_mm": worst_med, "worst_p95_mm": worst_p95,
                      "per_part": {p: err[p] for p in parts if p in err},
                      "held": len(result.report.held) if result is not None else None, "states": states,
                      # the calibration's own predicted taxel error then (per part: median, p95, mm)
                      "predicted": {p: dict(v) for p, v in (result.report.final.get("predicted_taxel_error_mm") or {}
                                                            ).items() if p in parts} if result is not None else {},
                      "exact": _exact_spread(result, parts)})
        if done is None and states and set(states.values()) == {"done"}:
            done = trace[-1]
        if needed is None and calib is not None and _met(err, parts, setup):
            needed = touches.n_touches
        if not setup.to_cap and needed is not None and (done is not None or not setup.until_done):
            break
        if touches.n_touches >= setup.cap:
            break
        n = min(setup.batch, setup.cap - touches.n_touches)
        if strategy == "random" or result is None:
            batches.append(cap.random(n))
            continue
        if strategy == "oracle":
            far = {p: max(err[p]["median"] / setup.median_mm, err[p]["p95"] / setup.p95_mm) for p in parts if p in err}
            batches.append(cap.random(n, [max(far.get(h, 1.0), far.get(b, 1.0)) ** ORACLE_POWER for h, b in cap.pairs]))
            continue
        tg = time.perf_counter()
        g = guidance(touches, skin, result, options, max_targets=setup.max_targets, seed=seed * 1000 + len(batches),
                     pairs=cap.pairs, calibrated_parts=live.calibrated_parts if setup.warm_start else None)
        guide_s.append(time.perf_counter() - tg)
        # as the simulated robot follows the guidance (nodes.sim_robot): each target a pose reaches, once
        aims = [Aim(t.hand, t.touched, t.hand_triangle_id, t.touched_triangle_id) for t in g.targets
                if t.pose is not None and t.hand_triangle_id is not None and (t.hand, t.touched) in cap.pairs][:n]
        batches.append(cap.guided(aims, n)[0])
    final = trace[-1]
    return {"seed": seed, "strategy": strategy, "needed": needed, "touches": final["touches"],
            "worst_median_mm": final["worst_median_mm"], "worst_p95_mm": final["worst_p95_mm"],
            "missed_aims": cap.missed, "calibration_failures": failures, "seconds": time.perf_counter() - t0,
            # when the live status first called every part done, and how far from the truth they were then
            "done_at": done["touches"] if done else None,
            "done_worst_median_mm": done["worst_median_mm"] if done else None,
            "done_worst_p95_mm": done["worst_p95_mm"] if done else None,
            "kept_at": _kept_at(trace, parts, setup),
            "guidance_ms_median": 1000 * float(np.median(guide_s)) if guide_s else None, "trace": trace}


def _exact_spread(result, parts) -> dict | None:
    """Were the calibration's posterior exact: its predicted worst part's median over the worst part's median in
    each of its draws (:meth:`~nao_skin.calibration.uncertainty.Posterior.median_draws`), as
    ``{p10, p90, within}`` (``within``: the share inside :data:`HONEST`). The spread of predicted / true that
    no prediction from the touches removes: the truth's own scatter about what the touches say."""
    post = getattr(result, "posterior", None)
    if post is None:
        return None
    draws = post.median_draws(parts, samples=128)
    if set(draws) != set(parts):
        return None
    meds = np.array([draws[p] for p in parts])
    ratio = meds.mean(axis=1).max() / meds.max(axis=0)
    return {"p10": float(np.percentile(ratio, 10)), "p90": float(np.percentile(ratio, 90)),
            "within": float(np.mean((ratio >= HONEST[0]) & (ratio <= HONEST[1])))}


def _kept_at(trace: list, parts, setup: CaptureSetup):
    """The touches from which every later update of the run met the target (None: the last one did not)."""
    kept = None
    for t in trace:
        met = _met(t["per_part"], parts, setup)
        kept = (kept if kept is not None else t["touches"]) if met else None
    return kept


HONEST = (0.77, 1.3)     # the band for predicted / true


def _predicted_against_true(rows: list) -> list:
    """``[(strategy, touches, true worst part's median, predicted worst part's median, exact spread or None)]``
    of every update of every run where every part was calibrated and predicted."""
    out = []
    for r in rows:
        for t in r.get("trace", []):
            pred, true = t.get("predicted") or {}, t.get("per_part") or {}
            if true and set(true) <= set(pred):
                out.append((r["strategy"], t["touches"], t["worst_median_mm"], max(v["median"] for v in pred.values()),
                            t.get("exact")))
    return out


def honesty(rows: list) -> dict:
    """The live status's prediction against the truth, per update of every run: the worst part's predicted
    median over its true median (updates where every part was calibrated and predicted), overall and by touches:
    ``{band: {updates, median, p10, p90, within}}``, ``within`` the share (%) inside :data:`HONEST`."""
    pairs = [(n, predicted / true, exact) for _, n, true, predicted, exact in _predicted_against_true(rows)]
    out = {}
    for label, lo, hi in (("all", 0, np.inf), ("< 300", 0, 300), ("300-999", 300, 1000), (">= 1000", 1000, np.inf)):
        v = np.array([ratio for n, ratio, _ in pairs if lo <= n < hi])
        if len(v):
            out[label] = {"updates": int(len(v)), "median": float(np.median(v)), "p10": float(np.percentile(v, 10)),
                          "p90": float(np.percentile(v, 90)),
                          "within": float(100.0 * np.mean((v >= HONEST[0]) & (v <= HONEST[1])))}
            exact = [e for n, _, e in pairs if lo <= n < hi and e]
            if exact:       # the same, were each update's posterior exact: the floor of the spread
                out[label]["exact"] = {"p10": float(np.median([e["p10"] for e in exact])),
                                       "p90": float(np.median([e["p90"] for e in exact])),
                                       "within": float(100.0 * np.mean([e["within"] for e in exact]))}
    return out


def _one(args):
    skin, seed, strategy, setup = args
    try:
        return run_capture(skin, seed, strategy, setup)
    except Exception as exc:   # a failing run is a row, the benchmark goes on
        return {"seed": seed, "strategy": strategy, "needed": None, "error": one_line(exc), "trace": []}


def capture_matrix(skin: SkinModel, seeds, setup: CaptureSetup | None = None, jobs: int = 1,
                   say: Callable[[str], None] = print, strategies=STRATEGIES) -> list:
    """Every seed x strategy (in ``jobs`` worker processes); rows in seed, strategy order."""
    setup = setup or CaptureSetup()
    work = [(skin, s, st, setup) for s in seeds for st in strategies]
    rows = []
    if jobs > 1:
        from nao_skin.bench.pool import worker_pool

        with worker_pool(jobs, len(work)) as pool:
            for row in pool.map(_one, work):
                say(_row_line(row))
                rows.append(row)
    else:
        for w in work:
            row = _one(w)
            say(_row_line(row))
            rows.append(row)
    return rows


def _row_line(row: dict) -> str:
    if row.get("error"):
        return f"seed {row['seed']} {row['strategy']}: FAILED {row['error']}"
    got = f"{row['needed']} touches" if row["needed"] is not None else f"not reached in {row['touches']} touches"
    return (f"seed {row['seed']} {row['strategy']}: {got} (worst part median {row['worst_median_mm']:.2f} mm,"
            f" p95 {row['worst_p95_mm']:.2f} mm, {row['seconds']:.0f} s)")


def _needed(rows: list, strategy: str, setup: CaptureSetup) -> list:
    """Touches needed per seed; a run that did not get there counts as the cap (a lower bound)."""
    return [r["needed"] if r.get("needed") is not None else setup.cap for r in rows if r["strategy"] == strategy]


def summary(rows: list, setup: CaptureSetup) -> dict:
    out = {}
    for st in STRATEGIES:
        if not any(r["strategy"] == st for r in rows):
            continue
        n = np.array(_needed(rows, st, setup), float)
        reached = sum(1 for r in rows if r["strategy"] == st and r.get("needed") is not None)
        out[st] = {"median": float(np.median(n)) if len(n) else None,
                   "p25": float(np.percentile(n, 25)) if len(n) else None,
                   "p75": float(np.percentile(n, 75)) if len(n) else None,
                   "min": float(n.min()) if len(n) else None, "max": float(n.max()) if len(n) else None,
                   "reached": reached, "runs": int(len(n))}
    seeds = sorted({r["seed"] for r in rows})
    ratios = []
    for s in seeds:
        by = {r["strategy"]: r for r in rows if r["seed"] == s}
        if "random" in by and "guided" in by:
            rn = by["random"]["needed"] if by["random"].get("needed") is not None else setup.cap
            gn = by["guided"]["needed"] if by["guided"].get("needed") is not None else setup.cap
            ratios.append(rn / gn)
    out["ratio_random_over_guided"] = {"median": float(np.median(ratios)) if ratios else None,
                                       "min": float(np.min(ratios)) if ratios else None}
    if setup.until_done or setup.to_cap:
        out["done"] = _done_summary(rows, setup)
    out["goal"] = {"at_least_1_25x_fewer": bool(ratios and np.median(ratios) >= 1.25)}
    out["honesty"] = honesty(rows)
    return out


def _done_summary(rows: list, setup: CaptureSetup) -> dict:
    """Per strategy: when the live status first called every part done, and the worst part's true error then."""
    out = {}
    for st in STRATEGIES:
        runs = [r for r in rows if r["strategy"] == st and not r.get("error")]
        done = [r for r in runs if r.get("done_at") is not None]
        if not runs:
            continue
        med = np.array([r["done_worst_median_mm"] for r in done], float)
        p95 = np.array([r["done_worst_p95_mm"] for r in done], float)
        late = [r["done_at"] / r["kept_at"] for r in done if r.get("kept_at")]
        out[st] = {"runs": len(runs), "done": len(done),
                   # done / the touches from which the target stayed met (runs that went on to the cap)
                   "done_over_kept_median": float(np.median(late)) if late and setup.to_cap else None,
                   "done_within_1_25x_kept": int(sum(x <= 1.25 for x in late)) if setup.to_cap else None,
                   "kept_runs": len(late),
                   "touches_median": float(np.median([r["done_at"] for r in done])) if done else None,
                   "worst_median_mm_median": float(np.median(med)) if done else None,
                   "worst_median_mm_max": float(med.max()) if done else None,
                   "worst_p95_mm_max": float(p95.max()) if done else None,
                   "within_target": int(np.sum((med <= setup.median_mm) & (p95 <= setup.p95_mm)))}
    return out


def table(rows: list, setup: CaptureSetup) -> str:
    def cell(r):
        if r is None:
            return "–"
        if r.get("error"):
            return f"FAILED ({r['error']})"
        if r["needed"] is None:
            return f"> {r['touches']} (worst {r['worst_median_mm']:.2f} / {r['worst_p95_mm']:.2f} mm)"
        return f"{r['needed']}"

    lines = ["| seed | random: touches | guided: touches | random / guided | guided misses | guidance ms |"
             " oracle: touches |", "|---|---|---|---|---|---|---|"]
    for s in sorted({r["seed"] for r in rows}):
        by = {r["strategy"]: r for r in rows if r["seed"] == s}
        rn, gn, on = by.get("random"), by.get("guided"), by.get("oracle")
        ratio = "–"
        if rn and gn and not rn.get("error") and not gn.get("error"):
            a = rn["needed"] if rn["needed"] is not None else setup.cap
            b = gn["needed"] if gn["needed"] is not None else setup.cap
            ratio = f"{a / b:.2f}" + (" (at least)" if rn["needed"] is None and gn["needed"] is not None else "")
        gms = gn.get("guidance_ms_median") if gn else None
        lines.append(f"| {s} | {cell(rn)} | {cell(gn)} | {ratio} | {gn.get('missed_aims', '–') if gn else '–'} |"
                     f" {f'{gms:.0f}' if gms is not None else '–'} | {cell(on)} |")
    sm = summary(rows, setup)
    lines += ["", "| strategy | median | p25–p75 | min–max | reached |", "|---|---|---|---|---|"]
    for st in STRATEGIES:
        v = sm.get(st)
        if v is None or v["median"] is None:
            continue
        lines.append(f"| {st} | {v['median']:.0f} | {v['p25']:.0f}–{v['p75']:.0f} | {v['min']:.0f}–{v['max']:.0f} |"
                     f" {v['reached']}/{v['runs']} |")
    r = sm["ratio_random_over_guided"]
    if r["median"] is not None:
        lines += ["", f"Random / guided touches needed per seed: median {r['median']:.2f}, lowest {r['min']:.2f}"
                      f" (a run that did not reach the target counts as the cap, {setup.cap}: a lower bound)."]
    goal = sm["goal"]
    if "guided" in sm and "random" in sm:
        lines.append(f"Goal (issue 51): guided at least 1.25x fewer touches than random (median):"
                     f" {'met' if goal['at_least_1_25x_fewer'] else 'NOT met'}.")
    for st, d in sm.get("done", {}).items():
        if d["done"]:
            lines.append(f"Live status 'done' for every part ({st}): {d['done']}/{d['runs']} runs, at"
                         f" {d['touches_median']:.0f} touches (median); the worst part's true error then: median"
                         f" {d['worst_median_mm_median']:.2f} mm (highest {d['worst_median_mm_max']:.2f}), p95 at most"
                         f" {d['worst_p95_mm_max']:.2f} mm; within the target in {d['within_target']}/{d['done']}."
                         + (f" Done / the touches from which the target stayed met: median"
                            f" {d['done_over_kept_median']:.2f}, within 1.25x in {d['done_within_1_25x_kept']} of"
                            f" {d['kept_runs']} runs whose target stayed met by the cap."
                            if d.get("done_over_kept_median") is not None else ""))
        else:
            lines.append(f"Live status 'done' for every part ({st}): in none of {d['runs']} runs by {setup.cap}"
                         f" touches.")
    for band, h in sm["honesty"].items():
        lines.append(f"Predicted / true worst part's median ({band} touches, {h['updates']} updates): median"
                     f" {h['median']:.2f} (10th–90th percentile {h['p10']:.2f}–{h['p90']:.2f}), within"
                     f" {HONEST[0]}–{HONEST[1]} in {h['within']:.0f} %."
                     + (f" Were each posterior exact (its own draws): {h['exact']['p10']:.2f}–{h['exact']['p90']:.2f},"
                        f" within in {h['exact']['within']:.0f} %." if "exact" in h else ""))
    if "oracle" in sm and "random" in sm:
        o = [_needed(rows, st, setup) for st in ("random", "oracle")]
        ratios = [a / b for a, b in zip(*o)]
        lines.append(f"Random / oracle touches needed per seed: median {np.median(ratios):.2f}, highest"
                     f" {np.max(ratios):.2f}: what sending touches where the true error is would buy.")
    return "\n".join(lines)


def plot(rows: list, setup: CaptureSetup, path) -> None:
    """Worst part's true taxel error (median and p95) against touches, both strategies: seeds thin, median thick."""
    from matplotlib.figure import Figure   # no pyplot: no backend or global figure state

    fig = Figure(figsize=(12, 4.5))
    axes = fig.subplots(1, 2)
    colours = {"random": "tab:gray", "guided": "tab:blue", "oracle": "tab:green"}
    for ax, key, goal in ((axes[0], "worst_median_mm", setup.median_mm), (axes[1], "worst_p95_mm", setup.p95_mm)):
        for st in STRATEGIES:
            runs = [r for r in rows if r["strategy"] == st and r.get("trace")]
            grid = np.arange(setup.start, setup.cap + setup.batch, setup.batch)
            curves = []
            for r in runs:
                x = np.array([t["touches"] for t in r["trace"]], float)
                y = np.array([t[key] for t in r["trace"]], float)
                ax.plot(x, y, color=colours[st], lw=0.6, alpha=0.45)
                # after the stop the error is taken as staying where it was
                curves.append(np.interp(grid, x, y, right=y[-1]) if len(x) else np.full(len(grid), np.nan))
            if curves:
                last = max(max(t["touches"] for t in r["trace"]) for r in runs)
                keep = grid <= last
                ax.plot(grid[keep], np.nanmedian(np.array(curves), axis=0)[keep], color=colours[st], lw=2.5,
                        label=f"{st} (median of {len(runs)} seeds)")
        ax.axhline(goal, color="tab:red", ls="--", lw=1, label=f"target {goal:g} mm")
        ax.set_yscale("log")
        ax.set_xlabel("touches recorded")
        ax.set_ylabel(f"worst part: true taxel error {'median' if 'median' in key else 'p95'} (mm)")
        ax.legend(fontsize=8)
        ax.grid(alpha=0.3)
    fig.suptitle("Capture: random, guided, and the oracle's split over the pairs (every part must meet both"
                 " targets)", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def plot_honesty(rows: list, path) -> None:
    """The live status's predicted worst part median against the true one, every update of every run."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(5.5, 5))
    ax = fig.subplots()
    colours = {"random": "tab:gray", "guided": "tab:blue", "oracle": "tab:green"}
    for st in STRATEGIES:
        pts = [(true, predicted, n) for s, n, true, predicted, _ in _predicted_against_true(rows) if s == st]
        if pts:
            x, y, n = np.array(pts).T
            ax.scatter(x, y, s=6 + 14 * n / n.max(), color=colours[st], alpha=0.5, label=f"{st} ({len(pts)} updates)")
    ax.set_xscale("log")
    ax.set_yscale("log")
    lo, hi = ax.get_xlim()
    grid = np.array([lo, hi])
    ax.plot(grid, grid, color="k", lw=1, label="predicted = true")
    ax.fill_between(grid, HONEST[0] * grid, HONEST[1] * grid, color="tab:orange", alpha=0.15,
                    label=f"{HONEST[0]}–{HONEST[1]} x true")
    ax.set_xlabel("worst part's true taxel error median (mm)")
    ax.set_ylabel("worst part's predicted median (mm)")
    ax.legend(fontsize=7)
    ax.grid(alpha=0.3, which="both")
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def setup_dict(setup: CaptureSetup) -> dict:
    return asdict(setup)
