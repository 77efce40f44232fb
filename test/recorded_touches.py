"""Touches written into a bag the way the pairing recorder writes them (tests of live recordings).

Also imported by the writer process of ``test_recording_survives.py``: one definition for both. And the
streams a robot sends while a playback plays, into a ``TouchRecording`` (tests of the recorder without ROS).
"""
from __future__ import annotations

import numpy as np

from nao_skin.formats.pointcloud import contacts_topic, taxels_topic, xyz


def write_recorded(bag, skin, touches, rows) -> None:
    """The touches ``rows`` into the open ``BagWriter``: per touch a JointState, then each touching part's taxels."""
    names = np.array(touches.part_names)
    for t in rows:
        stamp = int(round(touches.stamps[t] * 1e9))
        bag.write_joint_state(stamp, touches.joint_names, touches.joints[t])
        a = np.flatnonzero(touches.act_touch == t)
        for p in np.unique(touches.act_part[a]):
            sel = a[touches.act_part[a] == p]
            part = skin.part(names[p])
            slots = touches.act_slot[sel]
            bag.write_taxels(stamp, names[p], part.parent_frame, part.positions[slots], slots,
                             touches.act_pressure[sel], touches.contact_id[touches.act_contact[sel]])


def play_streams(recording, playback, start: float, skin_hz: float = 50.0, joint_hz: float = 100.0,
                 held: tuple | None = None, no_joints: tuple = (0.0, 0.0)) -> float:
    """The streams a robot sends while ``playback`` plays, in the order they arrive (stamps from ``start``); the
    last arrival. ``held`` ``(t0, t1, {topic: s})``: what would arrive from ``t0`` to ``t1`` (s of the play)
    arrives at ``t1``, a topic's that many s later still (a recorder held up, its topics' backlogs delivered one
    after another); each topic keeps its order. ``no_joints`` ``(t0, t1)``: no joint state is sent in these
    seconds of the play (the joint states' driver stalled)."""
    times = sorted([(t, "joints") for t in np.arange(0.0, playback.duration, 1.0 / joint_hz)
                    if not no_joints[0] <= t < no_joints[1]]
                   + [(t, "skin") for t in np.arange(0.003, playback.duration, 1.0 / skin_hz)])
    sent = []                      # (arrival, topic, call, args)
    for t, kind in times:
        stamp = start + float(t)
        if kind == "joints":
            sent.append((stamp + 0.002, "/joint_states", recording.joint_state,
                         (stamp, playback.joint_names, playback.joints_at(t))))
            continue
        k = playback.touch_at(t)
        for part in playback.part_names:
            sample = playback.samples[k].get(part) if k >= 0 else None
            if sample is None:
                sent.append((stamp + 0.003, taxels_topic(part), recording.taxels,
                             (part, stamp, np.zeros(0, int), np.zeros(0), np.zeros(0, int))))
                continue
            taxels, contacts = sample          # what a skin driver sends of this press
            sent.append((stamp + 0.003, contacts_topic(part), recording.contacts,
                         (part, stamp, contacts["contact"], xyz(contacts))))
            sent.append((stamp + 0.003, taxels_topic(part), recording.taxels,
                         (part, stamp, taxels["slot"].astype(int), taxels["pressure"].astype(float),
                          taxels["contact"].astype(int))))
    if held is not None:
        sent = held_up(sent, held, start)
    order = sorted(range(len(sent)), key=lambda i: (sent[i][0], i))
    for i in order:
        arrived, _, call, args = sent[i]
        call(*args, arrived=arrived)
    return sent[order[-1]][0]


def held_up(sent: list, held: tuple, start: float = 0.0) -> list:
    """``sent`` (``(arrival, topic, ...)`` in the order sent) as a recorder held up gets it: what would arrive
    from ``t0`` to ``t1`` s after ``start`` (``held``: ``(t0, t1, {topic: s})``) arrives at ``t1``, a topic's
    that many s later still (DDS delivers each topic's backlog on its own); each topic keeps its order."""
    t0, t1, later = held
    last: dict = {}           # a topic's messages come in order: none before its backlog
    out = []
    for arrived, topic, *rest in sent:
        if start + t0 <= arrived < start + t1:
            arrived = start + t1 + later.get(topic, 0.0)
        last[topic] = arrived = max(arrived, last.get(topic, arrived))
        out.append((arrived, topic, *rest))
    return out
