"""Calibration options as data: every field with its default, the values it takes (a :class:`Rule`) and its help.

The command line (``--set`` and the flags), the calibrate node's parameters
and the checks before any data is read all come from this one table
(:data:`OPTION_FIELDS`). The defaults follow the thesis.
"""
from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field, fields, replace
from typing import TYPE_CHECKING

from nao_skin.calibration.kinds import (KIND_COP, KIND_COP_SKIN, KIND_PLANE_A, KIND_PLANE_B, KIND_SURFACE, KIND_TAXEL,
                                        KIND_TAXEL5, LEVELS, PLANE_WEIGHTS)
from nao_skin.errors import DataError
from nao_skin.paths import yaml_value
from nao_skin.rules import Rule

if TYPE_CHECKING:       # the engine's own types: imported where a run builds them, not for the help text
    from nao_skin.calibration.pairing import RowRules
    from nao_skin.calibration.solver import SolveOptions

# what each value of the ``pairs`` and ``mount_pairs`` options puts into the residuals: rows of these kinds
# ("plane": point-to-plane rows both ways, "plane_b" / "plane_a": one side's taxels against the other's surface)
KIND_ROWS = {"cop": (KIND_COP,), "taxel": (KIND_TAXEL,), "both": (KIND_COP, KIND_TAXEL), "taxel5": (KIND_TAXEL5,),
             "cop+taxel5": (KIND_COP, KIND_TAXEL5), "cop+plane": (KIND_COP, KIND_PLANE_B, KIND_PLANE_A),
             "cop+plane_b": (KIND_COP, KIND_PLANE_B), "cop+plane_a": (KIND_COP, KIND_PLANE_A),
             "both+plane": (KIND_COP, KIND_TAXEL, KIND_PLANE_B, KIND_PLANE_A),
             "cop+surface": (KIND_COP, KIND_SURFACE), "both+surface": (KIND_COP, KIND_TAXEL, KIND_SURFACE),
             "cop_skin": (KIND_COP_SKIN,), "cop_skin+taxel": (KIND_COP_SKIN, KIND_TAXEL),
             "cop_skin+surface": (KIND_COP_SKIN, KIND_SURFACE)}


# mm: how far a refit must carry a part's taxels for nao-skin check to call it moved; about what a
# calibration from a full recording is sure of (docs/method.md, "Has the skin moved?"). Here beside the
# table, as the check's help text reads it without the engine.
DEFAULT_TOLERANCE_MM = 1.0


def option(default, rule: Rule, help: str):
    """A field of :class:`CalibrationOptions`: its default, what it accepts, and what it does."""
    return field(default=default, metadata={"rule": rule, "help": help})


_LEVELS_RULE = Rule(tuple, choices=LEVELS)
_PAIRS = tuple(KIND_ROWS)


@dataclass
class CalibrationOptions:
    """Everything that changes how calibration runs; the defaults follow the thesis.

    Each field carries its :class:`Rule` and help text (``dataclasses.fields(...)[i].metadata``):
    the command line's ``--set`` and the calibrate node check values with them.
    """

    strategy: str = option("sequential", Rule(str, ("sequential", "all-at-once")),
                           "sequential (mount, then patches, then triangles) or all-at-once")
    reference: str = option("fixed", Rule(str, ("fixed", "simultaneous")),
                            "fixed (one part is the reference while the other is fitted) or simultaneous")
    # the thesis boxes patch and triangle corrections in; on the real recording the box binds and costs
    # accuracy, on the simulator it hardly binds, so the prior alone holds them by default (docs/method.md,
    # "9. The prior on patches and triangles")
    bounded: bool = option(False, Rule(bool), "bound patch and triangle corrections to patch_bounds and"
                                              " triangle_bounds (thesis); off: the Gaussian prior alone")
    patch_bounds: tuple = option((0.003, math.pi / 30), Rule(tuple, low=1e-6, high=10.0, length=2),
                                 "|translation| m, |rotation| rad per component of a patch correction: the box of"
                                 " bounded, the prior's scale (bound / prior_strength) either way")
    triangle_bounds: tuple = option((0.0005, math.pi / 40), Rule(tuple, low=1e-6, high=10.0, length=2),
                                    "|translation| m, |rotation| rad per component of a triangle correction: the box"
                                    " of bounded, the prior's scale (bound / prior_strength) either way")
    # a closest taxel pair carries the two taxel lattices' offset (1.3-1.6 mm even at the true skin) and,
    # while the frames are still off, wrong neighbours; a COP row averages a contact's taxels. So COP rows
    # estimate the frames, and the closing stage, which starts where they are nearly right, adds the taxel pairs
    # (docs/method.md, "Which rows")
    pairs: str = option("cop_skin", Rule(str, _PAIRS), "paired points in the residuals of patch and triangle stages"
                                                  " (closing stage: closing_pairs; warm: warm_pairs)")
    closing_pairs: str = option("both", Rule(str, _PAIRS), "paired points in the residuals of the closing stage")
    mount_pairs: str = option("cop", Rule(str, _PAIRS), "paired points of the mount stages (robust while far off)")
    # a warm stage frees every level from the last update: with the closing stage's rows it drifts from where
    # a calibration from scratch of the same touches ends (bags/sim_default, 1000 touches, 4 subsets: true
    # median 0.039 mm worse on average; 0.018 with cop_skin+taxel, 0.004 with these; docs/method.md, "The
    # contact model")
    warm_pairs: str = option("cop_skin", Rule(str, _PAIRS), "paired points in the residuals of a live update's"
                                                            " warm stages")
    # "cop+plane" is not the default: the simulator's flat triangles meet exactly at the fabric, which
    # flatters point-to-plane rows; the real skin's do not (docs/method.md, "Point-to-plane rows")
    plane_weight: str = option("touch", Rule(str, PLANE_WEIGHTS),
                               "weight of the point-to-plane rows (pairs with 'plane'): equal (1 each), touch"
                               " (a touch's rows weigh as one row) or pressure (as touch, by each taxel's share of"
                               " its contact's pressure)")
    plane_scale: float = option(1.0, Rule(float, low=0.0, low_open=True, high=1e3),
                                "times the point-to-plane rows' weight (plane_weight)")
    loss: str = option("huber", Rule(str, ("huber", "linear")), "robust (huber) or plain (linear) least squares")
    # at the residual noise (residual_sigma); farther rows are mostly wrong closest pairs (simulator,
    # every preset: true error lower than at 4 mm)
    f_scale: float = option(0.002, Rule(float, low=0.0, low_open=True, high=1.0),
                            "m: where the Huber loss starts to discount a row")
    # touching surfaces face each other: each closest taxel pair (COP pair in mount stages) also asks
    # its two normals to cancel
    normal_weight: float = option(0.005, Rule(float, low=0.0, high=1.0), "m per rad of the normal rows (0: off)")
    # the mounts' rotation about a band of contacts is left free by points; at patch and triangle level
    # the layout's own normals (plane fits) are no better than the few degrees being estimated
    normal_levels: tuple = option(("mount",), _LEVELS_RULE, "stages whose unknowns include these use normal rows")
    jacobian: str = option("analytic", Rule(str, ("analytic", "2-point")), "analytic or finite-difference Jacobian")
    initial_guess: str = option("rigid-fit", Rule(str, ("rigid-fit", "none")),
                                "closed-form rigid fit of the mounts first (finds a 160 deg mount error), or none")
    min_triangle_activations: int = option(10, Rule(int, low=1, high=1e6),
                                           "a triangle with fewer paired activations is held (thesis: 10)")
    min_mount_touches: int = option(10, Rule(int, low=1, high=1e6),
                                    "training touches with a reference at fewer poses (a press held still is one):"
                                    " the mount is not determined")
    min_patch_touches: int = option(20, Rule(int, low=1, high=1e6), "patches need about twice the mount's data (thesis)")
    condition_limit: float = option(1e7, Rule(float, low=1.0, low_open=True),
                                    "of the Jacobi-scaled normal equations: weaker directions are held")
    max_repairings: int = option(8, Rule(int, low=1, high=1000), "re-pairings of the touches per stage at most")
    # a fixed-reference step is where the joint refinement starts, not where the calibration ends: it need
    # not settle its pairing (docs/method.md, "Inexact solves")
    reference_repairings: int = option(3, Rule(int, low=1, high=1000),
                                       "re-pairings per stage at most in a fixed-reference step that a joint"
                                       " refinement follows (it frees the same frames again); at most"
                                       " max_repairings")
    # a warm update is one step of the pairing's fixed-point iteration, the next update the next step
    # (docs/method.md, "Live calibration")
    warm_repairings: int = option(1, Rule(int, low=1, high=1000),
                                  "re-pairings per stage at most in a live update warm-started from the last one")
    repair_tolerance: float = option(0.01, Rule(float, low=0.0, high=1.0),
                                     "stop re-pairing when fewer touches than this share change pairs")
    max_iterations: int = option(50, Rule(int, low=1, high=1e4), "solver iterations per solve at most")
    # alternating pairing and solving (as ICP does), a solve need not converge on a pairing the next
    # step replaces (docs/method.md, "Inexact solves")
    repair_iterations: int = option(2, Rule(int, low=1, high=1e4),
                                    "solver iterations per solve before a stage's last allowed re-pairing (the"
                                    " pairing changes under it); that last one, and a warm update's, solves to"
                                    " max_iterations (a stage whose pairing settles earlier ends where its last"
                                    " solve left it, and the next stage goes on from there)")
    gate_mm: float = option(15.0, Rule(float, low=0.0, high=1e4),
                            "mm: touches farther apart than this after the mount fit are set aside (0: off)")
    test_fraction: float = option(0.3, Rule(float, low=0.0, high=1.0, high_open=True,
                                            why="the share of touches held out for testing; 1 leaves no touch"
                                                " to train on"),
                                  "share of the touches held out for the test figures")
    seed: int = option(0, Rule(int, low=0, high=2 ** 32 - 1), "seed of the train/test split")
    split_by: str = option("pose", Rule(str, ("pose", "touch")),
                           "what the train/test split keeps together: pose (touches whose joint angles agree within"
                           " 0.5 deg, one press sampled several times, on one side: the held-out figure meets no pose"
                           " it was trained on) or touch (each on its own)")
    # a recording samples one press held still many times: counted as independent touches, the presses
    # held longest would pull the fit toward themselves (docs/method.md, "Presses held still")
    pose_weight: float = option(0.5, Rule(float, low=0.0, high=1.0),
                                "each training touch weighs n^-pose_weight, n the touches at its pose (joint"
                                " angles within 0.5 deg: one press sampled several times): 0 every touch alike,"
                                " 1 every pose alike")
    max_touches: int | None = option(None, Rule(int, low=1, high=1e8, optional=True),
                                     "use only this many training touches (speed/error sweeps); null: all")
    # touching skins meet at their fabric surfaces, 2 x this apart at the taxel centres
    fabric_thickness: float = option(0.001, Rule(float, low=0.0, high=0.01), "m of fabric over the taxels of each part")
    estimate_fabric: bool = option(True, Rule(bool),
                                   "estimate the (pressed) fabric thickness from the touches, within fabric_bounds (the"
                                   " joint refinement starts it over from fabric_thickness: against a fixed"
                                   " reference it stands in for that reference's error too)")
    fabric_bounds: tuple = option((0.0, 0.003), Rule(tuple, low=0.0, high=0.01, length=2), "m: lowest and highest fabric")
    prior_strength: float = option(3.0, Rule(float, low=0.0, high=1e6),
                                   "patch/triangle prior std starts at bound / this (0: no prior)")
    prior_scale: str = option("empirical", Rule(str, ("empirical", "fixed")),
                              "prior width: empirical (widened to what the touches determine, evidence"
                              " approximation) or fixed (bound / prior_strength)")
    residual_sigma: float = option(0.002, Rule(float, low=0.0, low_open=True, high=1.0),
                                   "m: noise per coordinate of a paired-point difference")
    # model only what the scene determines: a lab whose touches do not reach the triangles drops that
    # level (docs/method.md, "Levels")
    levels: tuple = option(LEVELS, _LEVELS_RULE, "what the stages free, of mount, patch and triangle (the others"
                                                 " stay where they start)")
    joint_levels: tuple = option(LEVELS, _LEVELS_RULE, "what the joint refinement frees (of levels)")
    # the triangles once more from where the joint refinement left them, their prior centred there with the
    # widths the touches gave it: the triangles were fitted while the patches still moved (docs/method.md,
    # "Closing stage")
    closing_levels: tuple = option(("triangle",), _LEVELS_RULE,
                                   "after the joint refinement, these levels (of levels) once more, one stage each,"
                                   " starting where it ended ([]: none; a live update, warm, runs none)")
    rounds: int = option(1, Rule(int, low=1, high=100), "passes over the plan of fixed-reference steps")
    # a part fitted to a fixed reference inherits that reference's error, which a joint solve of all
    # parts removes (measured on simulated truth)
    joint_refinement: bool = option(True, Rule(bool), "finish with every part free at once")
    # a COP row is not zero at the true skin: the two parts sample the pressed spot at their own taxels; the press
    # model predicts that part at the calibration reached, and the plan is run again on the rows less it
    # (docs/method.md, "The contact model")
    press_model: bool = option(False, Rule(bool), "calibrate again, fitting the COP rows less what the simulator's"
                                                  " press model expects of them at the calibration first reached")
    # a constant mount correction cannot absorb a joint-angle offset or a link length upstream of it
    kinematics: str = option("off", Rule(str, ("off", "on", "auto")),
                             "also estimate the arm and head joint-angle offsets and link lengths the touches"
                             " determine, with every mount free: auto (kept only when the test split's closest"
                             " taxel distance at the fabric surfaces improves by kinematics_min_gain at 95 %"
                             " confidence), on (kept whatever the figures) or off")
    # extra unknowns always buy a little on the test split too, even where they make the skin worse; a
    # kinematic error the config lacks buys much more (docs/method.md, "Kinematics"): auto asks for a clear gain
    # the closest taxel pairs and the whole COPs put the arm's minimum about a millimetre off the true one (the
    # kinematic-error preset, kinematics on, seeds 0-5: worst part's median 1.20 mm with closing_pairs' rows,
    # 0.89 with cop_skin+taxel, 0.69 with cop_skin; docs/method.md, "The contact model")
    kinematics_pairs: str = option("cop_skin", Rule(str, _PAIRS), "paired points in the residuals of every stage of"
                                                                  " the kinematic path (kinematics=on or auto)")
    kinematics_passes: int = option(3, Rule(int, low=0, high=100),
                                    "after the kinematic stage: passes of the skin plan on the corrected robot,"
                                    " each followed by the kinematic stage again, until they settle")
    kinematics_min_gain: float = option(0.1, Rule(float, low=0.0, high=1.0, high_open=True),
                                        "kinematics=auto keeps the kinematic unknowns when they lower the test"
                                        " split's closest taxel mean at the fabric surfaces by at least this share"
                                        " (a one-sided 95 % lower bound over the test touches)")

    def solve_options(self, last: bool = True) -> SolveOptions:
        """The options of one solve: ``last`` the stage's last allowed re-pairing (else at most
        ``repair_iterations`` iterations)."""
        from nao_skin.calibration.solver import SolveOptions

        iterations = self.max_iterations if last else min(self.repair_iterations, self.max_iterations)
        return SolveOptions(loss=self.loss, f_scale=self.f_scale, max_iterations=iterations,
                            jacobian=self.jacobian)

    def row_rules(self, press: dict | None = None) -> RowRules:
        """How the stages make their rows: point-to-plane rows weighted as ``plane_weight`` and ``plane_scale``
        say; ``press``: the rows' expectations (:func:`~nao_skin.calibration.press.press_offsets`)."""
        from nao_skin.calibration.pairing import PlaneRows, RowRules

        return RowRules(plane=PlaneRows(self.plane_weight, self.plane_scale), press=press)

    def in_place(self) -> "CalibrationOptions":
        """The options of the closing stage, and of a linearisation at an estimate or the truth (the predicted
        error, the bound): its rows are ``closing_pairs``."""
        return replace(self, pairs=self.closing_pairs)

    @classmethod
    def from_mapping(cls, values: Mapping, where: str = "calibration option {name}={value!r}") -> "CalibrationOptions":
        """Options from ``{name: value}`` (a node's parameters, a bench's overrides, :meth:`as_mapping` read back),
        each checked by its rule (``where``: how a refusal names the value), then together."""
        options = cls()
        for name, value in values.items():
            options.set(name, value, where=where.format(name=name, value=value))
        options.validate()
        return options

    def as_mapping(self) -> dict:
        """``{name: value}`` as a report writes them (lists for tuples): :meth:`from_mapping` reads it back."""
        return {name: list(value) if isinstance(value, tuple) else value for name, value in asdict(self).items()}

    def set(self, name: str, value, where: str | None = None) -> None:
        """Set option ``name`` to ``value`` (an int where a float is asked is fine), checked by its rule."""
        spec = OPTION_FIELDS.get(name)
        if spec is None:
            raise DataError(f"{where or name}: unknown calibration option '{name}'"
                            f" (options: {', '.join(OPTION_FIELDS)})")
        setattr(self, name, spec.metadata["rule"].check(where or f"calibration option {name}={value!r}", value))

    def validate(self) -> None:
        for name, spec in OPTION_FIELDS.items():
            value = getattr(self, name)
            setattr(self, name, spec.metadata["rule"].check(f"calibration option {name}={value!r}", value))
        if not self.levels:
            raise DataError("calibration option levels=[]: frees nothing; give at least one of"
                            f" {', '.join(LEVELS)}")
        low, high = self.fabric_bounds
        if low > high:
            raise DataError(f"calibration option fabric_bounds={list(self.fabric_bounds)}: the lower bound is"
                            f" above the upper one")


OPTION_FIELDS = {f.name: f for f in fields(CalibrationOptions)}


def options_help(width: int = 79) -> str:
    """Every option of the table with its default and help, one paragraph each (``nao-skin calibrate --help``)."""
    import textwrap

    lines = ["calibration options (--set OPTION=VALUE: a number or a list in YAML, a choice as its word, a"
             " switch true or false):"]
    for name, spec in OPTION_FIELDS.items():
        default = list(spec.default) if isinstance(spec.default, tuple) else spec.default
        lines += textwrap.wrap(f"{name} (default {default}): {spec.metadata['help']}", width,
                               initial_indent="  ", subsequent_indent="      ")
    return "\n".join(lines)


def set_once(options: CalibrationOptions, name: str, value, where: str, given: dict) -> None:
    """``options.set`` that refuses an option ``given`` already holds (option -> the argument that set it):
    given twice, the second would silently win."""
    if name in given:
        raise DataError(f"{where}: option {name} is already given by {given[name]}; give it once")
    options.set(name, value, where=where)
    given[name] = where


def set_items(options: CalibrationOptions, items, given: dict | None = None) -> dict:
    """Apply ``--set OPTION=VALUE`` items to ``options``, each read by its option's rule (:func:`option_value`),
    checked by it and given once (see :func:`set_once`); returns ``given`` with the items' options added."""
    given = {} if given is None else given
    for item in items:
        key, sep, raw = item.partition("=")
        if not sep or not key:
            raise DataError(f"--set {item!r}: expected OPTION=VALUE, e.g. --set normal_weight=0.01")
        spec = OPTION_FIELDS.get(key.strip())
        value = option_value(spec.metadata["rule"], raw) if spec else raw
        set_once(options, key.strip(), value, f"--set {item}", given)
    return given


def option_value(rule: Rule, text: str):
    """The value of an option given as text, read by the option's own rule: a choice is its word as written and
    a switch ``true`` or ``false`` (YAML 1.1 took yes, on and ON for true, and kinematics=yes for on); a
    number or list is YAML. What the rule does not take stays text, for the rule to refuse by name."""
    text = text.strip()
    if rule.kind is bool:
        return {"true": True, "false": False}.get(text, text)
    if rule.kind is str:
        return text
    return yaml_value(text)
