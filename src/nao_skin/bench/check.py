"""How well ``nao-skin check`` tells a skin part that moved from one that did not (``nao-skin bench-check``).

Per seed the touches of a simulated recording (ground truth beside it) are shuffled: ``reference`` of them
make the calibration, the check runs on ``size`` others of the same skin. A skin part that moved after its
calibration is, to the check, a calibration whose frame of that part is off by the move: the moved part's
mount is translated in the calibration by ``move`` mm, in a direction drawn per seed (0: nothing moved).
The check runs as the command does: at the fabric the new touches imply under the calibration.
Each check is judged by what it names: the moved part (found), or a part that did not move (a false alarm).
"""
from __future__ import annotations

import time

import numpy as np

from nao_skin.calibration.check import MOVED, NOT_CHECKED, check_calibration
from nao_skin.calibration.engine import calibrate
from nao_skin.calibration.options import CalibrationOptions
from nao_skin.model.skin import SkinModel
from nao_skin.touch.touches import TouchSet


def check_rows(touches: TouchSet, skin: SkinModel, seeds, sizes, moves, part: str, reference: int,
               say=lambda msg: None) -> list:
    """One row per seed, size and move: what the check said of each part, and its seconds."""
    rows = []
    for seed in seeds:
        rng = np.random.default_rng(seed)
        order = rng.permutation(touches.n_touches)
        made = calibrate(touches.subset(np.sort(order[:reference])), skin, CalibrationOptions())
        direction = rng.normal(size=3)
        direction /= np.linalg.norm(direction)
        for size in sizes:
            new = touches.subset(np.sort(order[reference:reference + size]))
            for move in moves:
                calibration = made.calibration.copy()
                calibration.parts[part].mount[:3] += direction * move / 1000.0
                start = time.perf_counter()
                result = check_calibration(new, skin, calibration)
                seconds = time.perf_counter() - start
                rows.append({"seed": seed, "touches": size, "move_mm": move, "part": part, "seconds": seconds,
                             "verdicts": {n: p.verdict for n, p in result.parts.items()},
                             "moved_mm": {n: p.moved_mm["median"] for n, p in result.parts.items() if p.moved_mm},
                             "gain_low": {n: p.held_out_cop_mm["gain_low"] for n, p in result.parts.items()
                                          if p.held_out_cop_mm}})
            say(f"bench-check: seed {seed}, {size} touches: {', '.join(_said(r) for r in rows[-len(moves):])}")
    return rows


def _said(row: dict) -> str:
    named = [n for n, v in row["verdicts"].items() if v == MOVED]
    return f"{row['move_mm']:g} mm -> {'+'.join(named) or 'none moved'}"


def summary(rows: list) -> list:
    """Per move and size: runs, the moved part found, parts that did not move called moved (of those checked),
    parts not checked, seconds."""
    out = []
    for move in sorted({r["move_mm"] for r in rows}):
        for size in sorted({r["touches"] for r in rows}):
            rs = [r for r in rows if r["move_mm"] == move and r["touches"] == size]
            found = sum(r["verdicts"][r["part"]] == MOVED for r in rs) if move > 0 else None
            still = [v for r in rs for n, v in r["verdicts"].items() if move == 0 or n != r["part"]]
            out.append({"move_mm": move, "touches": size, "runs": len(rs), "found": found,
                        "false_alarms": still.count(MOVED), "checks": len(still) - still.count(NOT_CHECKED),
                        "not_checked": sum(v == NOT_CHECKED for r in rs for v in r["verdicts"].values()),
                        "seconds_median": float(np.median([r["seconds"] for r in rs]))})
    return out


def summary_table(rows: list) -> list:
    lines = ["| move mm | new touches | runs | moved part named | parts called moved that did not move"
             " (of those checked) | parts not checked | seconds (median) |", "|---|---|---|---|---|---|---|"]
    for s in summary(rows):
        found = "-" if s["found"] is None else f"{s['found']} of {s['runs']}"
        lines.append(f"| {s['move_mm']:g} | {s['touches']} | {s['runs']} | {found} | {s['false_alarms']} of"
                     f" {s['checks']} | {s['not_checked']} | {s['seconds_median']:.2f} |")
    return lines
