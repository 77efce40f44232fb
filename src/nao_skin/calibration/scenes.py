"""One robot, every scene: each scene of a calibration's touches predicted from the others, and where the scenes
place each part.

A *scene* is one kind of touch of the inputs: a self-touch pair (``l_hand+torso``) or a fingertip scene
(``r_finger-torso``). A calibration fits its touches; the figure that says where the skin is, is how well a
calibration from the *other* scenes predicts a scene's touches (:func:`cross_scene`):

* its own figures: the scene calibrated alone, on its training split (by pose), measured on its test split;
* its predicted figures: the other scenes calibrated together, then only what belongs to the scene alone fitted on
  its training split (a fingertip's sphere no other scene saw; a part no other scene touches is no prediction),
  measured on the same test split.

The placement spread of a part (:func:`placement_spread`): the median distance of its taxels between the
calibration of every scene together and each calibration that placed it from fewer scenes (each scene alone, each
leave-one-out).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from nao_skin.calibration.engine import CalibrationResult, calibrate
from nao_skin.calibration.evaluation import FIGURES, evaluate, measured
from nao_skin.calibration.options import CalibrationOptions
from nao_skin.calibration.plan import Step, plan_steps
from nao_skin.model.skin import SkinCalibration, SkinModel, pair_label, part_rank, scene_label
from nao_skin.touch.touches import TouchSet

SCENE_FIGURES = ("cop_mean_mm", "taxel_mean_mm", "fingertip_mean_mm", "fired_f1")


def scene_labels(touches: TouchSet) -> np.ndarray:
    """Each touch's scene: ``hand+part`` for a self-touch (its parts that fire), ``fingertip-part`` for a
    fingertip's."""
    fired = touches.parts_of_touch()
    tip = touches.fingertip_of_touch
    out = []
    for t in range(touches.n_touches):
        parts = [p for p, f in zip(touches.part_names, fired[t]) if f]
        out.append(scene_label(touches.fingertips[tip[t]], parts[0]) if tip[t] >= 0 else pair_label(parts))
    return np.array(out, dtype=object)


@dataclass
class ScenePrediction:
    """One scene of :func:`cross_scene`: its own figures, the predicted ones and what was fitted for them."""

    scene: str
    touches: int
    own: dict                            # the scene alone: {"train": figures, "test": figures}
    predicted: dict = field(default_factory=dict)    # test figures under the others' calibration (empty: none)
    fitted: list = field(default_factory=list)       # what belongs to the scene alone, fitted on its training split
    together: dict = field(default_factory=dict)     # test figures of its touches in every scene's calibration
    reason: str = ""                     # why there is no prediction, if there is none

    def ratios(self) -> dict:
        """Predicted over own test figure, per measured distance figure."""
        return {f: self.predicted[f] / self.own["test"][f] for f in measured(self.predicted, SCENE_FIGURES)
                if f != "fired_f1" and f in measured(self.own["test"], (f,))}


def _figures(touches: TouchSet, skin: SkinModel, calib: SkinCalibration, steps: list) -> dict:
    out = evaluate(touches, skin, calib, steps, fired=True)
    return {f: out[f] for f in measured(out, tuple(FIGURES))} | {"n_touches": out.get("n_touches", 0)}


def _fit_own(train: TouchSet, skin: SkinModel, calib: SkinCalibration, tips: tuple, options: CalibrationOptions) \
        -> SkinCalibration:
    """``calib`` with the spheres of ``tips`` (fingertips no other scene saw) fitted on ``train``, every frame held."""
    from nao_skin.calibration.stages import Stage, StageStart, run_stage

    parts = tuple(p for p in train.part_names if p in skin.parts)
    # the parts as references (held where the others put them), the spheres of the step's fingertips free
    step = Step((), parts, tuple((f, p) for f in tips for p in parts if (f, p) in skin.fingertip_touch.pairs()))
    fabric = calib.fabric_thickness if calib.fabric_thickness is not None else options.fabric_thickness
    stage = run_stage(train, skin, Stage(step, frozenset({"mount"}), options), StageStart(calib, fabric),
                      lambda msg: None)
    return stage.calibration


def cross_scene(touches: TouchSet, skin: SkinModel, options: CalibrationOptions | None = None,
                prior: SkinCalibration | None = None, together: CalibrationResult | None = None,
                say=lambda msg: None) -> tuple:
    """``([ScenePrediction], {scene or "all": CalibrationResult})``: each scene of ``touches``
    calibrated alone and predicted from the others (module docstring), and the calibrations made on the way (each
    scene alone, every scene but one as ``"all but <scene>"``, and every scene together as ``"all"``: ``together``
    when given, the calibration of these very touches)."""
    options = options or CalibrationOptions()
    labels = scene_labels(touches)
    names = sorted(set(labels), key=lambda n: (("-" in n), [part_rank(p) for p in n.replace("-", "+").split("+")]))
    results: dict = {}
    out = []
    for name in names:
        scene = touches.subset(labels == name)
        say(f"{name}: calibrated alone ({scene.n_touches} touches)")
        alone = results[name] = calibrate(scene, skin, options, prior=prior)
        steps = plan_steps(alone.train, options, skin.self_touch)
        own = {split: _figures(t, skin, alone.calibration, steps) for split, t in
               (("train", alone.train), ("test", alone.test))}
        row = ScenePrediction(name, scene.n_touches, own)
        out.append(row)
        if len(names) < 2:
            row.reason = "the only scene"
            continue
        say(f"{name}: predicted from the other scenes")
        others = results[f"all but {name}"] = calibrate(touches.subset(labels != name), skin, options, prior=prior)
        parts = set(alone.report.parts)
        lacking = sorted(parts - set(others.report.parts), key=part_rank)
        if lacking:
            row.reason = f"{', '.join(lacking)} only in this scene: the others do not place it"
            continue
        tips = tuple(f for f, _ in {s for st in steps for s in st.fingertips}
                     if f not in {g for st in plan_steps(others.train, options, skin.self_touch)
                                  for g, _ in st.fingertips})
        calib = others.calibration
        if tips:
            calib = _fit_own(alone.train, skin, calib, tuple(dict.fromkeys(tips)), options)
            row.fitted = [f"the sphere of {f}" for f in dict.fromkeys(tips)]
        row.predicted = _figures(alone.test, skin, calib, steps)
    if len(names) > 1:
        say(f"every scene together ({touches.n_touches} touches)")
        together = results["all"] = together or calibrate(touches, skin, options, prior=prior)
        # each scene's touches in the test split of every scene's calibration (split by pose over them all)
        steps = plan_steps(together.train, options, skin.self_touch)
        test_labels = scene_labels(together.test)
        for row in out:
            if np.any(test_labels == row.scene):
                row.together = _figures(together.test.subset(test_labels == row.scene), skin, together.calibration,
                                        steps)
    return out, results


def placement_spread(skin: SkinModel, results: dict) -> dict:
    """``{part: {calibration name: median mm}}``: how far each part's taxels lie from where every scene together
    placed them, in each calibration that placed the part from fewer scenes (:func:`cross_scene`'s results)."""
    together = results.get("all")
    if together is None:
        return {}
    out = {}
    for part in together.report.parts:
        sp = skin.parts[part]
        ref = sp.taxel_positions(together.calibration.parts[part], normals=False)[sp.present]
        out[part] = {}
        for name, result in results.items():
            if name == "all" or part not in result.report.parts:
                continue
            pos = sp.taxel_positions(result.calibration.parts[part], normals=False)[sp.present]
            out[part][name] = 1000.0 * float(np.median(np.linalg.norm(pos - ref, axis=1)))
    return out


def scenes_report(predictions: list, spread: dict) -> dict:
    """What ``report.json`` holds of :func:`cross_scene` (``scenes``): per scene its own, predicted figures and
    their ratios, and each part's placement spread."""
    return {"scenes": [{"scene": p.scene, "touches": p.touches, "own": p.own, "predicted": p.predicted,
                        "ratio": p.ratios(), "together": p.together, "fitted": p.fitted,
                        **({"reason": p.reason} if p.reason else {})}
                       for p in predictions],
            "placement_spread_mm": spread}


def scenes_markdown(scenes: dict) -> list:
    """report.md lines of :func:`scenes_report`'s dict."""
    if not scenes or not scenes.get("scenes"):
        return []
    lines = ["", "## Each scene predicted from the others", "",
             "Own: the scene calibrated alone, its test split; predicted: every other scene calibrated together (what"
             " belongs to the scene alone fitted on its training split), the same test split. Ratio: predicted / own."
             " Together: the scene's touches in the test split of every scene calibrated together.",
             "", "| scene | touches | figure | own test | predicted | ratio | together |", "|---|---|---|---|---|---|---|"]
    for s in scenes["scenes"]:
        figures = [f for f in SCENE_FIGURES if f != "fired_f1" and f in s["own"].get("test", {})]
        for f in figures:
            pred, ratio = s["predicted"].get(f), s["ratio"].get(f)
            lines.append(f"| {s['scene']} | {s['touches']} | {FIGURES[f]} | {s['own']['test'][f]:.2f} |"
                         f" {_number(pred)} | {_number(ratio)} | {_number(s.get('together', {}).get(f))} |")
        if s.get("reason"):
            lines.append(f"| {s['scene']} | {s['touches']} | not predicted: {s['reason']} | | | | |")
    if scenes.get("placement_spread_mm"):
        lines += ["", "Placement spread: each part's taxels from where every scene together places them (median, mm):", ""]
        for part, by in scenes["placement_spread_mm"].items():
            lines.append(f"- {part}: " + ", ".join(f"{name} {mm:.1f}" for name, mm in by.items()))
    return lines


def _number(value) -> str:
    return "–" if value is None else f"{value:.2f}"
