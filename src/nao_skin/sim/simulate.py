"""Self-touch simulator with ground truth: a Nao whose skin truly sits off its nominal layout.

``simulate(skin, params, seed)`` draws the true skin placement (hand mounts
~160 deg off, as on the real robot), finds self-touch poses for each pair
(:mod:`nao_skin.sim.poses`), fires the taxels the true geometry presses
(:mod:`nao_skin.sim.contact`), adds the defects of a real recording (encoder
noise, missed / stray taxels, duplicates, the experimenter's hand) and returns
the touches as a :class:`~nao_skin.touch.touches.TouchSet` with per-touch truth in
``labels``. No ROS, no physics engine. The same seed gives the same result
(and the same bytes when written with :func:`write_outputs`).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml

from nao_skin.errors import ConfigError, OutputError, os_reason
from nao_skin.model.skin import SkinCalibration, SkinModel
from nao_skin.sim import contact as sim_contact
from nao_skin.sim.fingertip import find_fingertip_poses, fingertip_truth, fire_fingertip
from nao_skin.sim.params import SimParams, check_pairs, make_params, pair_list
from nao_skin.sim.poses import find_poses
from nao_skin.sim.truth import draw_kinematics, draw_truth
from nao_skin.touch.contacts import cluster_labels
from nao_skin.touch.touches import TouchSet

BAG_NAME = "touches"     # the touch bag in a simulator output directory: a rosbag2 directory is named without
                         # ".bag", which rosbags' AnyReader (and ROS 1 tools) take for a ROS 1 bag file
DUPLICATE_DELAY = (0.02, 0.1)   # s: a repeated message arrives right after the original
NON_SELF_MIN_DISTANCE = 0.03    # m: activations this far from the contact are not explained by it
OTHER_EVENT, STRAY_EVENT = 1000, 1001   # event numbers of the experimenter's hand and stray taxels


@dataclass
class SimResult:
    touches: TouchSet                 # what the robot would have recorded (noisy joints, defects)
    truth: SkinCalibration            # true corrections of every part (what calibration should find), and
                                      # in .kinematics how the true robot differs from the config
    true_taxels: dict                 # part -> (positions (S, 3), normals (S, 3)) true, chain-end frame
    params: SimParams
    seed: int
    pairs: dict = field(default_factory=dict)   # "hand-target" -> {touches, attempted, unreachable, ...}


def true_robot(skin: SkinModel, p: SimParams, pairs, rng_truth: np.random.Generator) -> SkinCalibration:
    """The true skin, kinematics and fingertips of a simulated robot, drawn from ``rng_truth`` (the first of a
    seed's streams): what :func:`simulate` and the simulated body (:mod:`nao_skin.sim.body`) share."""
    truth = draw_truth(skin, list(skin.parts), p, rng_truth)
    # drawn after the skin's truth from the same stream: presets with the config's robot stay bit-identical
    truth.kinematics = draw_kinematics(skin, p, rng_truth)
    # then the fingertips' (nothing drawn without fingertip pairs: self-touch presets stay bit-identical)
    truth.fingertips = fingertip_truth(skin, dict.fromkeys(h for h, _ in pairs if h in skin.robot.fingertips), p,
                                       rng_truth)
    return truth


def simulate(skin: SkinModel, params: SimParams | dict | None, seed: int) -> SimResult:
    """Simulate ``params.n_touches`` self-touches for each pair; see the module docstring."""
    p = make_params(params or {}) if not isinstance(params, SimParams) else make_params(params)
    pairs = pair_list(p)
    check_pairs(pairs, skin)
    # independent streams: the truth does not change when touch counts or pairs change
    streams = np.random.SeedSequence(int(seed)).spawn(2 + 2 * len(pairs))
    rng_truth, rng_record = (np.random.default_rng(s) for s in streams[:2])
    truth = true_robot(skin, p, pairs, rng_truth)
    # the true body poses and fires; the joints record as they read (the config's kinematics)
    body = skin.with_kinematics(truth)

    per_pair, report = [], {}
    for i, (hand, target) in enumerate(pairs):
        rng_pose = np.random.default_rng(streams[2 + 2 * i])
        rng_skin = np.random.default_rng(streams[3 + 2 * i])
        spare = p.n_touches + p.n_touches // 10 + 2      # a press that fires too little is no recorded touch
        if hand in skin.robot.fingertips:
            poses = find_fingertip_poses(body, truth, hand, target, spare, p, rng_pose)
            poses, silent = _keep_fingertip_firing(body, truth, hand, target, poses, p.n_touches, p, rng_skin)
            acts = _fingertip_activations(body, truth, hand, target, poses, p, rng_skin)
        else:
            poses = find_poses(body, truth, hand, target, spare, p, rng_pose)
            poses, silent = _keep_firing(body, truth, hand, target, poses, p.n_touches, p, rng_skin)
            acts = _pair_activations(body, truth, hand, target, poses, p, rng_skin)
        per_pair.append((hand, target, poses, acts))
        report[f"{hand}-{target}"] = {"touches": int(len(poses.q)), "attempted": poses.attempted,
                                      "unreachable": poses.unreachable, "silent": silent}
    if not any(len(poses.q) for _, _, poses, _ in per_pair):      # nothing to assemble: say why, not IndexError
        tried = sum(info["attempted"] for info in report.values())
        raise ConfigError(f"simulation parameters: no touch of {', '.join(report)} could be posed and fired"
                          f" ({tried} target spots tried); a size in the parameters (e.g. spot_radius,"
                          f" fabric_thickness, hand_mount_offset, link_errors) is out of reach, or the robot"
                          f" config's body box ({skin.robot.source}) holds the poses")
    touches = _assemble(skin, per_pair, p, rng_record)
    for name, info in report.items():
        rows = touches.labels["pair"] == name
        info.update(recorded=int(rows.sum()), outliers=int(touches.labels["outlier"][rows].sum()),
                    duplicates=int((touches.labels["duplicate_of"][rows] >= 0).sum()))
    true_taxels = {name: part.taxel_positions(truth.parts[name]) for name, part in skin.parts.items()}
    return SimResult(touches, truth, true_taxels, p, int(seed), report)


# ---------------------------------------------------------------------------- one pair
def _keep_firing(skin, truth, hand, target, poses, n, p: SimParams, rng):
    """The first ``n`` poses whose press fires both parts, and how many did not.

    The probe is the weakest press the activation model can draw (one central
    spot, smallest size and reach): whatever is drawn later fires at least that.
    """
    probe = SimParams(**{**p.to_dict(), "pressure_spots": [1, 1], "spot_size": [p.spot_size[0]] * 2,
                         "press_reach": [p.press_reach[0]] * 2})
    touch, side, *_ = sim_contact.fire(skin, truth, hand, target, poses.q, poses.contact, poses.normal,
                                       poses.gap, probe, rng)
    both = np.zeros((len(poses.q), 2), bool)
    both[touch, side] = True
    fires = both.all(axis=1)
    rows = np.flatnonzero(fires)[:n]
    return poses.take(rows), int(np.count_nonzero(~fires))


def _keep_fingertip_firing(skin, truth, fingertip, target, poses, n, p: SimParams, rng):
    """The first ``n`` poses whose press fires the touched part, and how many did not (as :func:`_keep_firing`)."""
    probe = SimParams(**{**p.to_dict(), "fingertip_spots": [1, 1], "fingertip_spot_size": [p.fingertip_spot_size[0]] * 2,
                         "press_reach": [p.press_reach[0]] * 2})
    touch, *_ = fire_fingertip(skin, truth, fingertip, target, poses, probe, rng)
    fires = np.zeros(len(poses.q), bool)
    fires[touch] = True
    return poses.take(np.flatnonzero(fires)[:n]), int(np.count_nonzero(~fires))


def _fingertip_activations(skin, truth, fingertip, target, poses, p: SimParams, rng):
    """Flat activations ``(touch, side, slot, pressure, event)`` (side 1: the touched part, the only one that
    fires) and per-touch defect flags of one fingertip scene: the experimenter's hand pressing the part away from
    the fingertip, a contact that is not the fingertip's (the part fired elsewhere), one stray taxel."""
    n = len(poses.q)
    touch, slot, pressure, event = fire_fingertip(skin, truth, fingertip, target, poses, p, rng)
    side = np.ones(len(touch), int)
    experimenter = rng.uniform(size=n) < p.scaled("experimenter_hand")
    non_self = rng.uniform(size=n) < p.scaled("non_self_contact")
    spurious = rng.uniform(size=n) < p.scaled("spurious_taxel")
    extra = []
    for flags, drop, event_no in ((experimenter, False, OTHER_EVENT), (non_self, True, OTHER_EVENT)):
        if not flags.any():
            continue
        rows = np.flatnonzero(flags)
        if drop:             # the fingertip's contact replaced by one elsewhere on the part
            keep = ~np.isin(touch, rows)
            touch, side, slot, pressure, event = (a[keep] for a in (touch, side, slot, pressure, event))
        centre = poses.contact[rows]
        t, s, pr = sim_contact.patch_activation(
            skin, truth, target, poses.q[rows],
            lambda pos, nor: np.linalg.norm(pos - centre[:, None], axis=2) > NON_SELF_MIN_DISTANCE + 0.015, rng)
        extra.append((rows[t], np.ones(len(t), int), s, pr, np.full(len(t), event_no)))
    if spurious.any():
        rows = np.flatnonzero(spurious)
        extra.append((rows, np.ones(len(rows), int), rng.choice(skin.parts[target].slots, size=len(rows)),
                      np.round(rng.uniform(1.0, 60.0, size=len(rows))), np.full(len(rows), STRAY_EVENT)))
    acts = (touch, side, slot, pressure, event)
    if extra:
        acts = tuple(np.concatenate([a, *(e[i] for e in extra)]) for i, a in enumerate(acts))
    return _one_reading(acts, n, p, rng), {"experimenter_hand": experimenter, "non_self_contact": non_self,
                                           "spurious": spurious}


def _pair_activations(skin, truth, hand, target, poses, p: SimParams, rng):
    """Flat activations ``(touch, side, slot, pressure)`` and per-touch defect flags of one pair."""
    n = len(poses.q)
    touch, side, slot, pressure, event = sim_contact.fire(skin, truth, hand, target, poses.q, poses.contact,
                                                   poses.normal, poses.gap, p, rng)
    experimenter = rng.uniform(size=n) < p.scaled("experimenter_hand")
    non_self = rng.uniform(size=n) < p.scaled("non_self_contact")
    spurious = rng.uniform(size=n) < p.scaled("spurious_taxel")
    extra = []
    if experimenter.any():   # the experimenter holds the hand on its far side, away from the target
        rows = np.flatnonzero(experimenter)
        away = poses.normal[rows]
        t, s, pr = sim_contact.patch_activation(
            skin, truth, hand, poses.q[rows],
            lambda pos, nor: np.einsum("nsk,nk->ns", nor, away) > 0.3, rng)
        extra.append((rows[t], np.zeros(len(t), int), s, pr, np.full(len(t), OTHER_EVENT)))
    if non_self.any():       # the hand's own contact is replaced by one somewhere else on the hand
        rows = np.flatnonzero(non_self)
        drop = np.isin(touch, rows) & (side == 0)
        touch, side, slot, pressure, event = (a[~drop] for a in (touch, side, slot, pressure, event))
        centre = poses.contact[rows]
        t, s, pr = sim_contact.patch_activation(
            skin, truth, hand, poses.q[rows],
            lambda pos, nor: np.linalg.norm(pos - centre[:, None], axis=2) > NON_SELF_MIN_DISTANCE + 0.015, rng)
        extra.append((rows[t], np.zeros(len(t), int), s, pr, np.full(len(t), OTHER_EVENT)))
    if spurious.any():       # one stray taxel on either part
        rows = np.flatnonzero(spurious)
        which = rng.integers(0, 2, size=len(rows))
        stray_slot = np.empty(len(rows), int)
        for sd, part in enumerate((hand, target)):   # two parts, vectorised over touches
            sel = which == sd
            stray_slot[sel] = rng.choice(skin.parts[part].slots, size=int(sel.sum()))
        extra.append((rows, which, stray_slot, np.round(rng.uniform(1.0, 60.0, size=len(rows))),
                      np.full(len(rows), STRAY_EVENT)))
    acts = (touch, side, slot, pressure, event)
    if extra:
        acts = tuple(np.concatenate([a, *(e[i] for e in extra)]) for i, a in enumerate(acts))
    flags = {"experimenter_hand": experimenter, "non_self_contact": non_self, "spurious": spurious}
    return _one_reading(acts, n, p, rng), flags


def _one_reading(acts, n: int, p: SimParams, rng):
    """Activations ``(touch, side, slot, pressure, event)`` with one reading per taxel (where two causes press the
    same taxel, the stronger wins) and the missed taxels taken out, never the last one of a part in a touch."""
    order = np.lexsort((-acts[3], acts[2], acts[1], acts[0]))
    touch, side, slot, pressure, event = (a[order] for a in acts)
    first = np.ones(len(touch), bool)
    first[1:] = (np.diff(touch) != 0) | (np.diff(side) != 0) | (np.diff(slot) != 0)
    touch, side, slot, pressure, event = (a[first] for a in (touch, side, slot, pressure, event))
    # missed taxels, but never the last one of a part in a touch (the touch would not be recorded)
    missed = rng.uniform(size=len(touch)) < p.scaled("missed_taxel")
    group = touch * 2 + side
    _, last_of_group = np.unique(group[::-1], return_index=True)
    survivors = np.bincount(group[~missed], minlength=2 * n)
    keep_last = np.zeros(len(touch), bool)
    keep_last[len(touch) - 1 - last_of_group] = True
    keep = ~missed | (keep_last & (survivors[group] == 0))
    return tuple(a[keep] for a in (touch, side, slot, pressure, event))


# ---------------------------------------------------------------------------- recording
def _assemble(skin: SkinModel, per_pair, p: SimParams, rng) -> TouchSet:
    """All pairs in recording order, with duplicates, stamps, noisy joints and contacts."""
    used = {part for hand, target, _, _ in per_pair for part in (hand, target) if part in skin.parts}
    part_names = tuple(n for n in skin.parts if n in used)     # the skin config's order: names are data
    robot = skin.robot
    pair_of, q_true, contact, normal, gap, tip_of = [], [], [], [], [], []
    fingertips = tuple(dict.fromkeys(hand for hand, _, _, _ in per_pair if hand not in skin.parts))
    act = []
    flags = {"experimenter_hand": [], "non_self_contact": [], "spurious": []}
    offset = 0
    for hand, target, poses, ((touch, side, slot, pressure, event), fl) in per_pair:
        n = len(poses.q)
        pair_of += [f"{hand}-{target}"] * n
        tip_of += [fingertips.index(hand) if hand in fingertips else -1] * n
        q_true.append(poses.q)
        contact.append(poses.contact)
        normal.append(poses.normal)
        gap.append(poses.gap)
        for k in flags:
            flags[k].append(fl[k])
        part_idx = np.array([part_names.index(hand) if hand in skin.parts else -1, part_names.index(target)])
        act.append((touch + offset, part_idx[side], slot, pressure, event))
        offset += n
    n_total = offset
    q_true = np.concatenate(q_true) if q_true else np.zeros((0, len(robot.joint_names)))
    a_touch, a_part, a_slot, a_pressure, a_event = (np.concatenate(x) for x in zip(*act))
    flags = {k: np.concatenate(v) for k, v in flags.items()}

    # exact duplicates: the same message recorded twice, right after the original
    dup = rng.uniform(size=n_total) < p.scaled("duplicate")
    src = np.repeat(np.arange(n_total), 1 + dup)                      # final row -> original row
    is_copy = np.zeros(len(src), bool)
    is_copy[1:] = src[1:] == src[:-1]
    duplicate_of = np.where(is_copy, np.arange(len(src)) - 1, -1)     # a copy follows its original
    joints = np.clip(q_true + rng.normal(0.0, p.scaled("joint_noise"), size=q_true.shape),
                     robot.limits[:, 0], robot.limits[:, 1])
    intervals = np.where(is_copy, rng.uniform(*DUPLICATE_DELAY, size=len(src)),
                         rng.uniform(*p.touch_interval, size=len(src)))
    stamps = np.round(p.start_stamp + np.cumsum(intervals) - intervals[0], 6)

    # activations of every final row: those of its original row
    starts = np.searchsorted(a_touch, np.arange(n_total + 1))
    counts = np.diff(starts)[src]
    gather = np.repeat(starts[src] - np.cumsum(counts) + counts, counts) + np.arange(counts.sum())
    f_touch = np.repeat(np.arange(len(src)), counts)
    f_part, f_slot, f_pressure, f_event = a_part[gather], a_slot[gather], a_pressure[gather], a_event[gather]

    # contacts: per touch, part and skin event, clusters of neighbouring activated taxels on
    # the robot's own (nominal) taxel positions, as skinManager does
    nominal = np.zeros((len(f_slot), 3))
    for pi, name in enumerate(part_names):      # <= 4 parts, vectorised over activations
        sel = f_part == pi
        nominal[sel] = skin.parts[name].positions[f_slot[sel]]
    group = (f_touch * len(part_names) + f_part) * (STRAY_EVENT + 1) + f_event
    order = np.lexsort((f_slot, f_event, f_part, f_touch))
    f_touch, f_part, f_slot, f_pressure, nominal, group = (x[order] for x in
                                                           (f_touch, f_part, f_slot, f_pressure, nominal, group))
    comp = cluster_labels(nominal, group, p.cluster_distance)
    n_contacts = int(comp.max()) + 1 if len(comp) else 0
    contact_touch = np.zeros(n_contacts, int)
    contact_part = np.zeros(n_contacts, int)
    contact_touch[comp] = f_touch
    contact_part[comp] = f_part
    weight = np.bincount(comp, weights=f_pressure, minlength=n_contacts)
    cop = np.stack([np.bincount(comp, weights=f_pressure * nominal[:, k], minlength=n_contacts)
                    for k in range(3)], axis=1) / weight[:, None]
    # clusters numbered by first appearance follow (touch, part, slot) order already
    outlier = flags["experimenter_hand"] | flags["non_self_contact"] | flags["spurious"]
    labels = {
        "pair": np.array(pair_of, dtype=str)[src] if n_total else np.zeros(0, dtype=str),
        "outlier": outlier[src],
        "duplicate_of": duplicate_of,
        "experimenter_hand": flags["experimenter_hand"][src],
        "non_self_contact": flags["non_self_contact"][src],
        "spurious": flags["spurious"][src],
        "joints_true": q_true[src],
        "contact_point": np.concatenate(contact)[src],
        "contact_normal": np.concatenate(normal)[src],
        "gap": np.concatenate(gap)[src],
    }
    return TouchSet(part_names, tuple(robot.joint_names), stamps, [f"{s:.6f}" for s in stamps],
                    joints[src], contact_touch, contact_part, np.arange(n_contacts), cop,
                    comp, f_slot, f_pressure.astype(float), labels, fingertips,
                    np.array(tip_of, int)[src] if fingertips else None)


# ---------------------------------------------------------------------------- files
def write_outputs(result: SimResult, skin: SkinModel, out_dir: str | Path, preset: str = "",
                  storage: str = "sqlite3", with_bag: bool = True, replacing=None) -> list:
    """Write the recording and its ground truth; returns the paths written.

    ``touches`` (rosbag2 directory, via :mod:`nao_skin.formats.bag`; named without ``.bag``, which rosbags'
    ``AnyReader`` takes for a ROS 1 bag), ``truth_calibration.yaml``
    (the calibration format), ``truth_taxels/<part>.txt`` (true taxel positions,
    skinManager format) and ``simulation.yaml`` (parameters, seed, counts).
    Written into a temporary sibling and moved into place at the end (an
    earlier output in ``out_dir`` is replaced only as :mod:`nao_skin.outdir`
    allows, and only the one ``replacing`` names, :func:`~nao_skin.formats.outdir.replace_dir`), so a failed
    run leaves no half-written recording.
    """
    import os
    import shutil

    from nao_skin.formats.outdir import RECORDING, replace_dir, staging_dir, write_marker

    out = Path(out_dir)
    final = Path(os.path.realpath(out))
    tmp = staging_dir(final)
    written = []
    try:
        truth_path = tmp / "truth_calibration.yaml"
        result.truth.save(truth_path, skin, comment=f"ground truth of nao-skin simulate (seed {result.seed}"
                                                     + (f", preset {preset}" if preset else "") + ")")
        written.append(truth_path)
        taxel_dir = tmp / "truth_taxels"
        taxel_dir.mkdir(exist_ok=True)
        for name, part in skin.parts.items():
            path = taxel_dir / f"{name}.txt"
            part.write_taxel_file(path, result.truth.parts[name])
            written.append(path)
        meta = {"format": "nao_skin/simulation/1", "seed": result.seed, "preset": preset or "custom",
                "skin": _skin_name(skin), "pairs": result.pairs,
                "params": result.params.record(fingertips=bool(result.truth.fingertips))}
        meta_path = tmp / "simulation.yaml"
        command = (f"nao-skin simulate --preset {preset or 'default'} --seed {result.seed}"
                   f" --touches-per-pair {result.params.n_touches} --out <this directory>")
        meta_path.write_text("# parameters and seed of this simulated recording; the same bytes again with\n"
                             f"#   {command}\n" + yaml.safe_dump(meta, sort_keys=False, width=120))
        written.append(meta_path)
        if with_bag:
            from nao_skin.formats.bag import write_touch_bag  # the bag writer of the capture pipeline

            bag = tmp / BAG_NAME
            write_touch_bag(bag, result.touches, skin, storage=storage, label=out / BAG_NAME)
            written.append(bag)
        # no time in the marker: the same seed gives the same bytes, marker included
        write_marker(tmp, "simulate", RECORDING, stamp=False)
        replace_dir(tmp, final, replacing=replacing)
    except (OSError, OutputError) as exc:      # e.g. a full disk: nothing of this run stays
        shutil.rmtree(tmp, ignore_errors=True)
        reason = os_reason(exc) if isinstance(exc, OSError) else str(exc).replace(f"{tmp}{os.sep}", "")
        raise OutputError(f"{out}: cannot write the simulated recording ({reason}); nothing written") from None
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return [out / p.relative_to(tmp) for p in written]


def _skin_name(skin: SkinModel) -> str:
    """The skin config's file name, and the layouts given beside it (``--taxels``) by theirs: what the recording's
    simulation.yaml says it was simulated on, the same text in any checkout."""
    config, *layouts = skin.source.split(" + ")
    return " + ".join([Path(config).name] + [Path(f.strip()).name for f in ", ".join(layouts).split(", ") if f])
