"""What one live update costs: a warm-started update against a calibration from scratch, at a session's size.

A live session recalibrates every ``live_every_touches`` new touches over all
touches so far, warm-started from its last accepted calibration
(:func:`~nao_skin.calibration.engine.calibrate` with ``warm``). The state
before an update is rebuilt from a recording with ground truth: ``n`` random
touches of it, of which the last ``step`` are new; the previous calibration
is made from scratch on the other ``n - step`` (not timed). Timed, one after
the other on the same touches: the warm update and a calibration from
scratch. Each size runs ``repeat`` random subsets (seeded 0, 1, ...); the
times quoted are their median and spread, with the true taxel error of both.
Reading the recording before an update is timed apart, both ways: a whole
read of a bag of exactly ``n`` touches, and what the node does, a
:class:`~nao_skin.formats.bag.GrowingBag` reading the last ``step`` touches
of a live bag (mcap, never closed, as the recorder writes it) after it read
the first ``n - step``.
"""
from __future__ import annotations

import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from nao_skin.calibration.engine import CalibrationOptions, calibrate
from nao_skin.formats.bag import BagWriter, GrowingBag, read_touches, touch_messages, write_touch_bag
from nao_skin.live.updates import UpdateSchedule
from nao_skin.model.skin import SkinCalibration, SkinModel
from nao_skin.touch.touches import TouchSet

LIVE_SIZES = (1000, 4000)
LIVE_STEP = UpdateSchedule.every_touches     # new touches per update, as the calibrate node's default
LIVE_TARGET_SECONDS = 0.3            # median warm update at 1000 touches (issue 17)


@dataclass
class UpdateTiming:
    touches: int
    warm_seconds: list
    cold_seconds: list
    warm_error: list                 # true taxel error median over every part, mm
    cold_error: list
    warm_p95: list
    cold_p95: list
    read_seconds: float              # a whole read of the bag
    read_new_seconds: float          # the GrowingBag's read of the last ``step`` touches

    def median(self, name: str) -> float:
        return float(np.median(getattr(self, name)))

    def spread(self, name: str) -> tuple:
        values = getattr(self, name)
        return float(np.min(values)), float(np.max(values))


def update_timings(touches: TouchSet, skin: SkinModel, truth: SkinCalibration, sizes=LIVE_SIZES,
                   step: int = LIVE_STEP, repeat: int = 5, say=lambda msg: None) -> list:
    """One :class:`UpdateTiming` per size that the recording can fill (sizes above its touches are skipped)."""
    options = CalibrationOptions()
    out = []
    for n in sizes:
        if n > touches.n_touches:
            say(f"live update: {n} touches asked, the recording has {touches.n_touches}; skipped")
            continue
        t = UpdateTiming(n, [], [], [], [], [], [], _read_seconds(touches, skin, n),
                         _read_new_seconds(touches, skin, n, step))
        for r in range(repeat):
            order = np.random.default_rng(r).permutation(touches.n_touches)
            now = touches.subset(np.sort(order[:n]))
            before = calibrate(touches.subset(np.sort(order[:n - step])), skin, options)
            t0 = time.perf_counter()
            warm = calibrate(now, skin, options, prior=before.calibration, warm=before.report.parts,
                             resume=before.state, truth=truth)
            t.warm_seconds.append(time.perf_counter() - t0)
            t0 = time.perf_counter()
            cold = calibrate(now, skin, options, truth=truth)
            t.cold_seconds.append(time.perf_counter() - t0)
            for kind, result in (("warm", warm), ("cold", cold)):
                err = result.report.final["truth_taxel_error_mm"]["all"]
                getattr(t, f"{kind}_error").append(err["median"])
                getattr(t, f"{kind}_p95").append(err["p95"])
            say(f"live update, {n} touches, subset {r}: warm {t.warm_seconds[-1]:.2f} s, from scratch"
                f" {t.cold_seconds[-1]:.2f} s")
        out.append(t)
    return out


def _read_seconds(touches: TouchSet, skin: SkinModel, n: int) -> float:
    with tempfile.TemporaryDirectory(prefix="nao_skin_bench_read_") as tmp:
        bag = Path(tmp) / "touches"
        write_touch_bag(bag, touches.subset(np.arange(n)), skin)
        t0 = time.perf_counter()
        read_touches(bag, skin)
        return time.perf_counter() - t0


def _read_new_seconds(touches: TouchSet, skin: SkinModel, n: int, step: int) -> float:
    with tempfile.TemporaryDirectory(prefix="nao_skin_bench_read_") as tmp:
        messages = list(touch_messages(touches.subset(np.arange(n)), skin))
        with BagWriter(Path(tmp) / "touches", "mcap", kind="touches", live=True) as bag:
            follower = GrowingBag(bag.path, skin)
            for batch in (messages[:n - step], messages[n - step:]):
                for touch in batch:
                    bag.write_touch(*touch)
                bag.flush()
                t0 = time.perf_counter()
                follower.read()
                seconds = time.perf_counter() - t0
        return seconds


def update_table(timings: list) -> list:
    """Markdown lines: per size, warm and from-scratch seconds and true error side by side."""
    lines = ["| touches | warm update (s), median [min, max] | from scratch (s) | true error median / p95 (mm),"
             " warm | from scratch | reading the bag (s): whole / what is new |", "|---|---|---|---|---|---|"]
    for t in timings:
        lines.append(f"| {t.touches} | {t.median('warm_seconds'):.2f} [{t.spread('warm_seconds')[0]:.2f},"
                     f" {t.spread('warm_seconds')[1]:.2f}] | {t.median('cold_seconds'):.2f} |"
                     f" {t.median('warm_error'):.2f} / {t.median('warm_p95'):.2f} |"
                     f" {t.median('cold_error'):.2f} / {t.median('cold_p95'):.2f} | {t.read_seconds:.2f} /"
                     f" {t.read_new_seconds:.3f} |")
    return lines


def update_target_line(timings: list) -> str:
    at = [t for t in timings if t.touches == 1000]
    if not at:
        return "warm update at 1000 touches: not measured"
    median = at[0].median("warm_seconds")
    return (f"warm update at 1000 touches: median {median:.2f} s (target <= {LIVE_TARGET_SECONDS:g} s):"
            f" {'met' if median <= LIVE_TARGET_SECONDS else 'NOT met'}")
