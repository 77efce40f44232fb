"""One pipeline from recordings to a calibration on disk, for `nao-skin calibrate`, the demo and the calibrate node.

check the output directory -> load every input -> drop exact duplicates ->
calibrate -> write (atomically, marked as ours). The output is checked before
anything is read, so a mistaken output costs nothing and destroys nothing.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Sequence

from nao_skin.calibration import scenes
from nao_skin.calibration.engine import CalibrationResult, FitState, calibrate
from nao_skin.calibration.options import CalibrationOptions
from nao_skin.calibration.report import write_outputs
from nao_skin.calibration.evaluation import contact_figure, measured
from nao_skin.calibration.splits import kinematics_kept_text, split_spread, spread_figures, spread_text
from nao_skin.errors import DataError
from nao_skin.formats.inputs import load_touches
from nao_skin.formats.outdir import CALIBRATION, as_checked, check_output_dir
from nao_skin.model.skin import SkinCalibration, SkinModel
from nao_skin.touch.datasets import LoadReport, deduplicate
from nao_skin.touch.touches import TouchSet


@dataclass
class PipelineRun:
    """What one run of the pipeline did."""

    result: CalibrationResult
    out_dir: Path
    load_report: LoadReport
    n_touches: int               # after removing duplicates
    n_duplicates: int


def check_output(out_dir, inputs: Sequence, force: bool = False, label: str = "--out") -> Path:
    """The pipeline's first step, on its own: callers may check before they build anything else."""
    return check_output_dir(out_dir, CALIBRATION, inputs=[p for p in inputs if p], force=force, label=label)


def calibrate_recordings(inputs: Sequence, skin: SkinModel, options: CalibrationOptions, out_dir,
                         prior: SkinCalibration | None = None, truth: SkinCalibration | None = None,
                         force: bool = False, plots: bool = True, protected: Sequence = (), splits: int = 1,
                         cross_scene: bool = False,
                         command: str = "calibrate", label: str = "--out", extra=None, replacing=None,
                         beside: str | None = None,
                         log: Callable[[str], None] | None = None,
                         summary: Callable[[str], None] | None = None) -> PipelineRun:
    """Calibrate the skin from recordings and write the result where users apply it.

    ``protected``: other files the run reads (a prior, a truth) that the output
    must not touch; the skin model's own files are protected too, however they
    were named (a layout named only inside the skin config). ``truth`` overrides a simulator's ground truth
    found beside a recording. ``log`` gets progress; ``summary`` what loading
    skipped, even when ``log`` is silent. ``extra(directory)`` adds files to
    the output before it is moved into place; ``replacing`` and ``beside``: what the output may replace, and
    where it goes when another process took its place meanwhile (see :func:`write_outputs`; default: what the
    check of ``out_dir`` saw, and ``.new``).
    ``splits`` > 1: the report also gives each figure's mean and spread over that
    many seeded splits (:func:`~nao_skin.calibration.splits.split_spread`); the
    calibration written is the first split's.
    ``cross_scene``: the report also predicts each scene of the inputs from the others and gives each part's
    placement spread (:func:`~nao_skin.calibration.scenes.cross_scene`); the calibration written is every
    scene's together.
    """
    log = log or (lambda msg: None)
    check_output(out_dir, [*inputs, *protected, *skin.source_files()], force=force, label=label)
    if replacing is None:    # what the check saw, nothing else: another output written there meanwhile stays
        replacing, beside = as_checked(out_dir), beside or ".new"
    result, touches, load_report, n_dup = calibrate_inputs(inputs, skin, options, prior, truth, log, summary)
    if splits > 1:
        log(f"the same calibration on {splits - 1} more splits (seeds {options.seed + 1}..{options.seed + splits - 1})")
        result.report.splits = split_spread(touches, skin, options, splits, prior=prior, first=result)
    if cross_scene:
        log("each scene predicted from the others")
        predictions, results = scenes.cross_scene(touches, skin, options, prior=prior, together=result, say=log)
        result.report.scenes = scenes.scenes_report(predictions, scenes.placement_spread(skin, results))
    out = write_outputs(result, skin, out_dir, prior=prior, plots=plots, command=command, extra=extra,
                        replacing=replacing, beside=beside)
    if Path(out) != Path(out_dir) and summary is not None:
        summary(f"{out_dir}: another output was written there while this calibration ran and is left as it is;"
                f" this one goes to {out}")
    return PipelineRun(result, Path(out), load_report, touches.n_touches, n_dup)


@dataclass
class LoadedInputs:
    """Every input read and its exact duplicates removed: what a calibration starts from."""

    touches: TouchSet
    load_report: LoadReport
    n_duplicates: int
    truth: SkinCalibration | None       # a simulator's ground truth found beside a recording
    files: list


def load_inputs(inputs: Sequence, skin: SkinModel, log: Callable[[str], None] | None = None,
                summary: Callable[[str], None] | None = None, followed=None) -> LoadedInputs:
    """The pipeline's load step: read every input, drop exact duplicates.

    ``followed``: recordings read again and again while they grow (see :func:`load_touches`).
    """
    log = log or (lambda msg: None)
    touches, load_report, found_truth = load_touches(inputs, skin, log=log, summary=summary, followed=followed)
    touches, n_dup = deduplicate(touches)
    log(f"{touches.n_touches} touches after removing {n_dup} exact duplicates")
    return LoadedInputs(touches, load_report, n_dup, found_truth, [str(p) for p in inputs])


def calibrate_loaded(loaded: LoadedInputs, skin: SkinModel, options: CalibrationOptions,
                     prior: SkinCalibration | None = None, truth: SkinCalibration | None = None,
                     log: Callable[[str], None] | None = None, warm: Sequence[str] = (),
                     anchor: SkinCalibration | None = None, resume: FitState | None = None) -> CalibrationResult:
    """The pipeline's calibrate step; the report says what was read.

    ``warm``, ``anchor``, ``resume``: a live update's (see :func:`calibrate`).
    """
    result = calibrate(loaded.touches, skin, options, prior=prior, truth=truth or loaded.truth, progress=log,
                       warm=warm, anchor=anchor, resume=resume)
    report = loaded.load_report
    # what was read is counted in messages for a bag, in touches for the thesis' text format
    result.report.input = {"files": loaded.files, f"{report.unit.replace(' ', '_')}_read": report.n_read,
                           "touches_loaded": report.n_loaded, "skipped": dict(report.skipped),
                           "notes": [*report.info, *report.notes], "duplicates_removed": loaded.n_duplicates}
    return result


def calibrate_inputs(inputs: Sequence, skin: SkinModel, options: CalibrationOptions,
                     prior: SkinCalibration | None = None, truth: SkinCalibration | None = None,
                     log: Callable[[str], None] | None = None,
                     summary: Callable[[str], None] | None = None) -> tuple:
    """Load, deduplicate and calibrate, nothing written: ``(result, touches, load report, duplicates removed)``."""
    loaded = load_inputs(inputs, skin, log, summary)
    try:
        result = calibrate_loaded(loaded, skin, options, prior, truth, log)
    except DataError as exc:    # what the touches together cannot give: the line names the recordings they came from
        raise type(exc)(f"{', '.join(map(str, inputs))}: {exc}") from None
    return result, loaded.touches, loaded.load_report, loaded.n_duplicates


def summary_line(result: CalibrationResult) -> str:
    """The figures of a calibration in one line: what was calibrated and how close the touches came."""
    final = result.report.final

    # test_fraction 0 holds no touch out: the train figures alone, not "nan"
    splits = ("train", "test") if final["test"].get("n_touches") else ("train",)

    def train_test(key):
        return " / ".join(f"{final[split].get(key, float('nan')):.2f}" for split in splits)

    said = {"cop_mean_mm": "closest COP {} mm", "taxel_mean_mm": "closest taxel {} mm",
            "contact_taxel_mean_mm": "(selected contacts' {} mm)", "fingertip_mean_mm": "fingertip to its contact {} mm",
            "fired_f1": "fired taxels predicted F1 {} %"}
    figures = [said[f].format(train_test(f)) for f in measured(final["train"], said)]
    line = (f"calibrated {', '.join(result.report.plan)}: "
            + ", ".join(figures).replace(", (", " (")
            + f" ({' / '.join(splits) if len(splits) > 1 else 'train; no touch held out'})")
    if "truth_taxel_error_mm" in final:
        t = final["truth_taxel_error_mm"]["all"]
        line += f"; true taxel error median {t['median']:.2f} mm, p95 {t['p95']:.2f} mm"
    aside = final.get("train_set_aside")
    if aside:        # far apart under any calibration: the figures above count them, the judgement does not
        label, far = contact_figure(aside)
        line += (f"; {aside['n_touches']} training touches set aside ({label} {far:.1f} mm;"
                 f" the {final['train_kept']['n_touches']} kept: {contact_figure(final['train_kept'])[1]:.2f} mm)")
    kin = result.report.kinematics
    if kin:
        line += (f"; kinematics {kin['mode']}: " + (f"{len(kin['corrections'])} corrected, {len(kin['held'])} held"
                                                   if kin.get("accepted") else "not kept"))
    if result.report.left_out:
        line += "; left out (too few touches): " + ", ".join(f"{e['pair']} ({e['touches']})"
                                                             for e in result.report.left_out)
    spread = result.report.splits
    if spread:
        shown = [f for f in spread_figures(spread) if f != "contact_taxel_mean_mm"]
        line += (f"; over {spread['k']} splits (mean ± std): "
                 + ", ".join(said[f].format(spread_text(spread, f)) for f in shown))
        if kinematics_kept_text(spread):
            line += f", {kinematics_kept_text(spread)}"
    return line
