"""Touch bags: real rosbag2 files (sqlite3 and mcap) written with rosbags, read back through the event detector.

The real recording is read in place (see real_data.py); bags are written to tmp_path.
"""
import shutil

import warnings

from pathlib import Path

import numpy as np
import pytest
import yaml

from nao_skin.calibration.pairing import metrics
from nao_skin.calibration.rows import pair_touches
from nao_skin.errors import DataError
from nao_skin.formats.bag import BagWriter, detected_touch_messages, read_touches, touch_messages, write_touch_bag
from nao_skin.touch.events import LIVE_CONFIG, ContactRecord, TouchRecord
from nao_skin.touch.inorder import InOrder
from recorded_touches import held_up


def canonical_pairs(touches, pairing):
    """Rows as comparable tuples: touch stamp, kind, parts, and each side's sorted (slot, weight) terms."""
    out = []
    for r in range(pairing.n_rows):
        sel = pairing.term_row == r
        terms = tuple(sorted(zip(pairing.term_part[sel].tolist(), pairing.term_slot[sel].tolist(),
                                 np.round(pairing.term_weight[sel], 12).tolist())))
        out.append((round(float(touches.stamps[pairing.row_touch[r]]), 6), int(pairing.row_kind[r]),
                    tuple(touches.part_names[p] for p in pairing.row_parts[r]), terms,
                    round(float(pairing.distance[r]), 12)))
    return sorted(out)


# ---------------------------------------------------------------------- round trip of the real recording
def test_the_recorder_writes_the_messages_a_touch_bag_holds(real, real_skin):
    """What the recorder node writes of the touches its detector emits is what write_touch_bag writes of the same
    touches: contact normals, geometric centres and pressures included (they were NaN in recorded bags)."""
    touches = real.subset(np.arange(40))
    records = []
    for t in range(touches.n_touches):
        contacts = [ContactRecord(int(touches.contact_part[c]), int(touches.contact_id[c]), touches.contact_cop[c],
                                  touches.act_slot[touches.act_contact == c],
                                  touches.act_pressure[touches.act_contact == c])
                    for c in np.flatnonzero(touches.contact_touch == t)]
        records.append(TouchRecord(float(touches.stamps[t]), touches.joints[t], contacts))
    recorded = list(detected_touch_messages(records, real_skin, touches.part_names, touches.joint_names))
    written = list(touch_messages(touches, real_skin))
    assert len(recorded) == len(written) == 40
    for (stamp, names, joints, parts, tip), (stamp_w, names_w, joints_w, parts_w, tip_w) in zip(recorded, written):
        assert (stamp, tuple(names), tip) == (stamp_w, tuple(names_w), tip_w) and tip is None
        np.testing.assert_array_equal(joints, joints_w)
        assert [part.name for part, _, _ in parts] == [part.name for part, _, _ in parts_w]
        for (_, taxels, contacts), (_, taxels_w, contacts_w) in zip(parts, parts_w):
            assert taxels.dtype == taxels_w.dtype and taxels.tobytes() == taxels_w.tobytes()    # NaN pressures too
            assert contacts.dtype == contacts_w.dtype and contacts.tobytes() == contacts_w.tobytes()
            assert np.isfinite(contacts["nx"]).all() and np.isfinite(contacts["gx"]).all()
    assert list(detected_touch_messages([], real_skin, touches.part_names, touches.joint_names)) == []



@pytest.mark.parametrize("storage", ["sqlite3", "mcap"])
def test_real_touches_round_trip_with_identical_pairs(real, real_skin, tmp_path, storage):
    touches = real if storage == "sqlite3" else real.subset(np.arange(200))
    bag = tmp_path / "touches"
    write_touch_bag(bag, touches, real_skin, storage=storage)
    back, report = read_touches(bag, real_skin)
    assert report.n_loaded == touches.n_touches and report.n_skipped == 0
    np.testing.assert_array_equal(back.stamps, touches.stamps)
    np.testing.assert_array_equal(back.joints, touches.joints)
    assert len(back.contact_touch) == len(touches.contact_touch)
    assert sorted(back.contact_id.tolist()) == sorted(touches.contact_id.tolist())
    np.testing.assert_allclose(np.sort(back.contact_cop, axis=0), np.sort(touches.contact_cop, axis=0), atol=1e-7)
    assert canonical_pairs(back, pair_touches(back, real_skin)) == canonical_pairs(touches, pair_touches(touches, real_skin))
    if storage == "sqlite3":
        m = metrics(pair_touches(back, real_skin))
        assert m["n_touches"] == 810 and 74.0 < m["cop_mean_mm"] < 80.0


def test_bag_metadata_is_jazzy_readable_and_self_describing(real, real_skin, tmp_path):
    bag = tmp_path / "touches"
    write_touch_bag(bag, real.subset(np.arange(5)), real_skin)
    info = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert info["version"] == 9 and info["storage_identifier"] == "sqlite3"
    assert info["custom_data"] == {"nao_skin.bag_kind": "touches"}
    topics = {t["topic_metadata"]["name"]: (t["topic_metadata"]["type"], t["message_count"])
              for t in info["topics_with_message_count"]}
    assert topics == {"/joint_states": ("sensor_msgs/msg/JointState", 5),
                      "/skin/l_hand/taxels": ("sensor_msgs/msg/PointCloud2", 5),
                      "/skin/l_hand/contacts": ("sensor_msgs/msg/PointCloud2", 5),
                      "/skin/torso/taxels": ("sensor_msgs/msg/PointCloud2", 5),
                      "/skin/torso/contacts": ("sensor_msgs/msg/PointCloud2", 5)}
    # someone with only the bag: a plain rosbags read shows frames, fields, NAOqi names
    from rosbags.rosbag2 import Reader
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_JAZZY)
    with Reader(bag) as reader:
        for conn, _, raw in reader.messages():
            msg = store.deserialize_cdr(raw, conn.msgtype)
            if conn.topic == "/skin/l_hand/taxels":
                assert msg.header.frame_id == real_skin.parts["l_hand"].parent_frame
                assert [f.name for f in msg.fields] == ["x", "y", "z", "slot", "pressure", "contact"]
            if conn.topic == "/joint_states":
                assert "LShoulderPitch" in msg.name


def test_a_bag_kind_this_version_does_not_know_is_refused_not_read_as_a_stream(real, real_skin, tmp_path):
    """A metadata.yaml naming another kind was read as a stream bag: 80 touches of 81, without a word."""
    bag = tmp_path / "touches"
    write_touch_bag(bag, real.subset(np.arange(5)), real_skin)
    meta = bag / "metadata.yaml"
    meta.write_text(meta.read_text().replace("nao_skin.bag_kind: touches", "nao_skin.bag_kind: banana"))
    with pytest.raises(DataError, match=r"its metadata names the bag kind 'banana' \(nao_skin.bag_kind\); this"
                                        r" version reads touches and stream$"):
        read_touches(bag, real_skin)


def test_truncated_bags(real, real_skin, tmp_path):
    touches = real.subset(np.arange(300))
    for storage, suffix in (("mcap", ".mcap"), ("sqlite3", ".db3")):
        bag = tmp_path / storage
        write_touch_bag(bag, touches, real_skin, storage=storage)
        data = next(bag.glob(f"*{suffix}"))
        data.write_bytes(data.read_bytes()[: data.stat().st_size // 2])
        if storage == "mcap":
            # a cut mcap keeps every complete record before the cut
            back, report = read_touches(bag, real_skin)
            assert 100 < back.n_touches < 300
            assert report.skipped["truncated bag"] == 1
            line = [m for m in report.messages if "damaged" in m][0]
            assert str(bag) in line and "the rest is lost" in line and "\n" not in line
            np.testing.assert_array_equal(back.joints, touches.joints[: back.n_touches])
        else:
            # sqlite cannot be read past a cut: one clear line, nothing guessed
            with pytest.raises(DataError) as err:
                read_touches(bag, real_skin)
            assert str(bag) in str(err.value) and "\n" not in str(err.value)


def test_an_mcap_cut_after_its_messages_loses_nothing_and_says_so(real, real_skin, tmp_path):
    """Cut in its footer (a copy that stopped 40 bytes short): every message metadata.yaml lists is read, and
    the report had said "the rest is lost"."""
    touches = real.subset(np.arange(60))
    bag = tmp_path / "mcap"
    write_touch_bag(bag, touches, real_skin, storage="mcap")
    data = next(bag.glob("*.mcap"))
    data.write_bytes(data.read_bytes()[:-40])
    back, report = read_touches(bag, real_skin)
    assert back.n_touches == 60 and not report.skipped
    assert any(f"{data.name} is damaged after its messages" in n and "read all 300 messages its metadata.yaml"
               " lists, 60 touches, nothing lost" in n for n in report.notes), report.notes


def test_an_mcap_with_a_damaged_record_is_read_up_to_it(real, real_skin, tmp_path):
    touches = real.subset(np.arange(60))
    bag = tmp_path / "mcap"
    write_touch_bag(bag, touches, real_skin, storage="mcap")
    data = next(bag.glob("*.mcap"))
    raw = bytearray(data.read_bytes())
    topic = raw.index(b"/joint_states")             # the first channel record's topic, in the first chunk
    raw[topic + 1] = 0xFF                           # no longer UTF-8: the record is damaged
    data.write_bytes(bytes(raw[:-100]))             # and no summary: rosbags cannot open it, salvage reads it
    back, report = read_touches(bag, real_skin)
    assert report.skipped["truncated bag"] == 1
    line = [m for m in report.messages if "damaged" in m][0]
    assert str(bag) in line and "has a damaged record at byte" in line and "\n" not in line


def test_a_whole_mcap_under_a_broken_metadata_yaml_loses_nothing_and_says_so(real, real_skin, tmp_path):
    """rosbags refuses the bag for its metadata.yaml alone: the mcap, read to its closing magic, gives every
    touch, nothing is counted as lost, and the note says what failed; cut short, the same bag says what is lost."""
    touches = real.subset(np.arange(60))
    bag = tmp_path / "mcap"
    write_touch_bag(bag, touches, real_skin, storage="mcap")
    (bag / "metadata.yaml").write_text("rosbag2_bagfile_information: [\n")
    back, report = read_touches(bag, real_skin)
    assert back.n_touches == touches.n_touches and report.n_skipped == 0
    np.testing.assert_array_equal(back.joints, touches.joints)
    note = [n for n in report.notes if "nothing lost" in n]
    assert len(note) == 1 and "its metadata.yaml is unreadable (not YAML" in note[0] and "whole to its end" in note[0]
    data = next(bag.glob("*.mcap"))
    data.write_bytes(data.read_bytes()[:-8])        # the closing magic gone: no longer a whole file
    _, report = read_touches(bag, real_skin)
    assert report.skipped["truncated bag"] == 1 and not any("nothing lost" in n for n in report.notes)


@pytest.mark.parametrize("storage", ["sqlite3", "mcap"])
@pytest.mark.parametrize("damage", ["broken", "not rosbag2", "missing", "storage file alone"])
def test_a_closed_bag_without_a_usable_metadata_yaml_is_read_whole_as_a_touch_bag(real, real_skin, tmp_path,
                                                                                   storage, damage):
    """A closed bag's storage file holds its metadata too (rosbag2 from Iron on, rosbags): read from it, a touch
    bag stays a touch bag. Read as a stream (live tolerances), touches 50 ms apart merge into presses: 3 of a
    simulated bag's 83 touches had gone without a word."""
    touches = real.subset(np.arange(40))
    touches.stamps[:] = 100.0 + 0.05 * np.arange(40)
    bag = tmp_path / "bag"
    write_touch_bag(bag, touches, real_skin, storage=storage)
    data = next(bag.glob("*.db3" if storage == "sqlite3" else "*.mcap"))
    source = bag
    if damage == "broken":
        (bag / "metadata.yaml").write_text("rosbag2_bagfile_information: [\n")
    elif damage == "not rosbag2":
        (bag / "metadata.yaml").write_text("rosbag2_bagfile_information:\n")
    elif damage == "missing":
        (bag / "metadata.yaml").unlink()
    else:
        source = data
    back, report = read_touches(source, real_skin)
    assert back.n_touches == 40 and report.n_skipped == 0, report.lines()
    np.testing.assert_array_equal(back.joints, touches.joints)
    assert not any("Error" in line for line in report.lines())      # no exception's name in what users read
    if damage != "storage file alone":
        note = [n for n in report.notes if "nothing lost" in n]
        assert len(note) == 1 and (storage == "mcap" or f"{data.name} holds its metadata too" in note[0]), report.notes
        if damage == "missing":
            assert "it has no metadata.yaml" in note[0]
        if damage == "broken":
            assert "metadata.yaml is unreadable (not YAML from line 2:" in note[0]
        if damage == "not rosbag2":
            assert "(not rosbag2 metadata: no 'rosbag2_bagfile_information' mapping)" in note[0]


def list_more_joint_states(bag, n: int) -> None:
    """The bag's metadata.yaml lists ``n`` more /joint_states messages than its storage file holds."""
    meta = yaml.safe_load((bag / "metadata.yaml").read_text())
    info = meta["rosbag2_bagfile_information"]
    joints = next(t for t in info["topics_with_message_count"] if t["topic_metadata"]["name"] == "/joint_states")
    joints["message_count"] += n
    info["message_count"] += n
    (bag / "metadata.yaml").write_text(yaml.safe_dump(meta, sort_keys=False))


@pytest.mark.parametrize("storage", ["sqlite3", "mcap"])
def test_a_storage_file_that_ends_early_without_an_error_says_what_is_lost(real, real_skin, tmp_path, storage):
    """A damaged mcap chunk can end the messages early without the reader raising: 47 of 83 touches were read
    with nothing said. The metadata's counts say what is missing (here: it lists 50 messages more than the
    storage file holds)."""
    bag = tmp_path / "bag"
    write_touch_bag(bag, real.subset(np.arange(40)), real_skin, storage=storage)
    list_more_joint_states(bag, 50)
    back, report = read_touches(bag, real_skin)
    assert back.n_touches == 40
    assert report.skipped["truncated bag"] == 50
    line = [m for m in report.messages if "could be read" in m][0]
    assert line.startswith(f"{bag}: ") and "of the " in line and "messages its metadata lists could be read" in line


def test_a_topic_the_storage_file_does_not_hold_is_named_not_called_a_truncated_bag(real, real_skin, tmp_path):
    """metadata.yaml lists the torso's topics, the storage file (edited, or another recording's) holds none of
    their messages: every one was counted as a "truncated bag", which it is not."""
    import sqlite3

    bag = tmp_path / "bag"
    write_touch_bag(bag, real.subset(np.arange(20)), real_skin, storage="sqlite3")
    (db,) = bag.glob("*.db3")
    with sqlite3.connect(db) as con:
        ids = [row[0] for row in con.execute("SELECT id FROM topics WHERE name LIKE '/skin/torso/%'")]
        assert len(ids) == 2
        con.execute(f"DELETE FROM messages WHERE topic_id IN ({','.join(map(str, ids))})")
    _, report = read_touches(bag, real_skin)
    assert "truncated bag" not in report.skipped
    assert report.skipped["topic not in storage"] == 40
    lines = [m for m in report.messages if "the storage file holds none of them" in m]
    assert sorted(line.split(": ")[1].split(" (")[0] for line in lines) == ["/skin/torso/contacts", "/skin/torso/taxels"]
    # where another topic is cut short too, the file is damaged: what it lacks is lost to that, not absent
    list_more_joint_states(bag, 5)
    _, report = read_touches(bag, real_skin)
    assert dict(report.skipped) == {"truncated bag": 45}, report.lines()


@pytest.mark.parametrize("storage", ["sqlite3", "mcap"])
@pytest.mark.parametrize("edit", ["version: 99", "a storage file it does not have", "storage_identifier: foo"])
def test_a_metadata_yaml_that_reads_but_does_not_open_costs_nothing(real, real_skin, tmp_path, storage, edit):
    """A metadata.yaml of another version, or naming a storage file or plugin the bag does not have: an mcap
    bag was read from its file, a sqlite3 one refused ("Rosbag2 version 99 not supported")."""
    bag = tmp_path / "bag"
    write_touch_bag(bag, real.subset(np.arange(30)), real_skin, storage=storage)
    whole, _ = read_touches(bag, real_skin)
    meta = yaml.safe_load((bag / "metadata.yaml").read_text())
    info = meta["rosbag2_bagfile_information"]
    if edit == "version: 99":
        info["version"] = 99
    elif edit == "storage_identifier: foo":
        info["storage_identifier"] = "foo"
    else:
        info["relative_file_paths"] = ["other" + Path(info["relative_file_paths"][0]).suffix]
    (bag / "metadata.yaml").write_text(yaml.safe_dump(meta, sort_keys=False))
    back, report = read_touches(bag, real_skin)
    assert back.n_touches == whole.n_touches == 30 and not report.skipped, report.lines()
    assert any("nothing lost" in note for note in report.notes), report.notes


def test_a_topic_of_another_message_type_is_said_not_dropped_silently(real, real_skin, tmp_path):
    bag = tmp_path / "bag"
    write_touch_bag(bag, real.subset(np.arange(40)), real_skin)
    text = (bag / "metadata.yaml").read_text()
    meta = yaml.safe_load(text)
    topics = meta["rosbag2_bagfile_information"]["topics_with_message_count"]
    skin = next(t for t in topics if t["topic_metadata"]["name"].startswith("/skin/"))
    skin["topic_metadata"]["type"] = "std_msgs/msg/String"
    (bag / "metadata.yaml").write_text(yaml.safe_dump(meta, sort_keys=False))
    _, report = read_touches(bag, real_skin)
    name = skin["topic_metadata"]["name"]
    assert report.skipped["unexpected message type"] == skin["message_count"]
    assert any(m == f"{bag}: topic '{name}' holds std_msgs/msg/String, not sensor_msgs/msg/PointCloud2; its"
                    f" {skin['message_count']} messages skipped" for m in report.messages), report.messages


def test_a_folder_with_both_storage_files_and_no_metadata_to_choose_is_refused(real, real_skin, tmp_path):
    """Read without its metadata, one of two storage files would silently leave the other's touches out."""
    touches = real.subset(np.arange(20))
    write_touch_bag(tmp_path / "s", touches, real_skin, storage="sqlite3")
    write_touch_bag(tmp_path / "m", touches, real_skin, storage="mcap")
    bag = tmp_path / "s"
    shutil.copy(next((tmp_path / "m").glob("*.mcap")), bag)
    for broken in ("rosbag2_bagfile_information: [\n", None):
        if broken is None:
            (bag / "metadata.yaml").unlink()
        else:
            (bag / "metadata.yaml").write_text(broken)
        with pytest.raises(DataError) as err:
            read_touches(bag, real_skin)
        line = str(err.value)
        assert line.startswith(f"{bag}: holds both ") and ".db3" in line and ".mcap" in line and "\n" not in line


# ---------------------------------------------------------------------- streams and bad input, small bags
def stream_bag(path, skin, storage="sqlite3", bad_slot=False, extra_part=False, nan_joint=False):
    """A raw stream: joints at 100 Hz, l_hand and torso skin at 50 Hz, one press from 0.2 to 0.6 s."""
    hand = skin.parts["l_hand"].slots[[0, 1, 2, 40, 41]]         # two far-apart groups: clustered into contacts
    torso = skin.parts["torso"].slots[:3]
    names = skin.robot.joint_names
    with BagWriter(path, storage) as bag:
        for k in range(100):
            t = int(k * 10_000_000)
            q = np.full(len(names), 0.1 * k / 100)
            if nan_joint and 20 <= k <= 60:
                q[skin.robot.joint_index["LElbowRoll"]] = np.nan
            bag.write_joint_state(t, names, q)
            if k % 2 == 0:
                for part, slots, phase in (("l_hand", hand, 3_000_000), ("torso", torso, 7_000_000)):
                    on = 20 <= k < 60
                    s = slots if on else slots[:0]
                    if bad_slot and part == "torso" and on:
                        s = np.r_[s, 500]
                    frame = skin.parts[part].parent_frame
                    bag.write_taxels(t + phase, part, frame, skin.parts[part].positions[np.minimum(s, 383)], s,
                                     np.full(len(s), 2.0), np.full(len(s), -1))
                if extra_part:
                    bag.write_taxels(t, "l_foot", "l_ankle", np.zeros((1, 3)), [0], [1.0], [-1])


def test_stream_bag_gives_one_touch_per_press_with_clustered_contacts(skin, tmp_path):
    stream_bag(tmp_path / "stream", skin)
    touches, report = read_touches(tmp_path / "stream", skin)
    assert touches.n_touches == 1 and report.n_skipped == 0
    assert touches.stamps[0] == pytest.approx(0.207)
    np.testing.assert_allclose(touches.joints[0], 0.1 * 0.207, atol=1e-12)   # interpolated between 0.20 and 0.21
    hand = touches.part_index("l_hand")
    assert (touches.contact_part == hand).sum() == 2                          # maxNeighborDist split the hand
    np.testing.assert_allclose(touches.act_pressure, 2.0)


def test_a_stream_bag_whose_recorder_was_held_up_gives_every_press_once(skin, tmp_path):
    """Seven presses of the hand on the torso, recorded by a recorder held up from 1.0 to 2.5 s: it got what was
    sent meanwhile at 2.5 s, the torso's 1 s later still (DDS delivers each topic's backlog on its own), so
    the bag holds the torso's samples of two presses after the hand's. Read in the bag's order, their
    moments never met (3 of 7 presses, nothing counted); read in the order of their stamps, as the live
    recorder reads them, every press is one touch."""
    hand, torso = skin.parts["l_hand"].slots[:3], skin.parts["torso"].slots[:3]
    names = skin.robot.joint_names
    sent = []           # (received s, topic, write)
    for k in range(400):
        t = k * 0.01
        sent.append((t, "joints", lambda bag, t=t, r=None: bag.write_joint_state(
            int(t * 1e9), names, np.full(len(names), 0.05 * t), received_ns=r)))
        if k % 2:
            continue
        on = 20 <= k % 60 < 40                               # a press from 0.2 to 0.4 s of every 0.6
        for part, slots in (("l_hand", hand), ("torso", torso)):
            s = slots if on else slots[:0]
            sent.append((t + 0.003, part, lambda bag, t=t, part=part, s=s, r=None: bag.write_taxels(
                int(t * 1e9), part, skin.parts[part].parent_frame, skin.parts[part].positions[s], s,
                np.full(len(s), 2.0), np.full(len(s), -1), received_ns=r)))
    sent = held_up(sent, (1.0, 2.5, {"torso": 1.0}))
    with BagWriter(tmp_path / "held", "sqlite3") as bag:
        for received, _, write in sorted(sent, key=lambda m: m[0]):
            write(bag, r=int(received * 1e9))
    touches, report = read_touches(tmp_path / "held", skin)
    assert report.n_skipped == 0 and not report.skipped
    assert touches.n_touches == 7
    np.testing.assert_allclose(touches.stamps, 0.01 * (20 + 60 * np.arange(7)), atol=1e-9)


def test_one_joint_state_stamped_far_ahead_makes_nothing_wait_to_the_end_of_a_stream_bag(skin, tmp_path, monkeypatch):
    """A stream bag whose hand skin sends only while pressed and stops after 4 s, and one joint state in it
    stamped 1000 s ahead (where its recorder got it). Taken as the bag's clock, that stamp made every later
    message wait for the quiet hand to the end of the bag (3902 messages held at once here); the clock moves
    at most a second per message, so at most the 10 s a message waits are held."""
    most = [0]
    push = InOrder.push

    def counted(self, *args):
        out = push(self, *args)
        most[0] = max(most[0], len(self))
        return out

    monkeypatch.setattr(InOrder, "push", counted)
    hand, torso = skin.parts["l_hand"].slots[:3], skin.parts["torso"].slots[:3]
    names = skin.robot.joint_names
    with BagWriter(tmp_path / "ahead", "sqlite3") as bag:
        for k in range(3000):                                # 30 s: joints at 100 Hz, skin at 50 Hz
            t = k * 0.01
            bag.write_joint_state(int(t * 1e9), names, np.full(len(names), 0.001 * t))
            if k == 50:
                bag.write_joint_state(int(1000e9), names, np.zeros(len(names)), received_ns=int(t * 1e9))
            if k % 2:
                continue
            on = 20 <= k % 60 < 40
            for part, slots in (("l_hand", hand), ("torso", torso)):
                if part == "l_hand" and (not on or k > 400):
                    continue
                s = slots if on else slots[:0]
                bag.write_taxels(int(t * 1e9), part, skin.parts[part].parent_frame, skin.parts[part].positions[s],
                                 s, np.full(len(s), 2.0), np.full(len(s), -1))
    touches, report = read_touches(tmp_path / "ahead", skin)
    assert touches.n_touches == 7 and dict(report.skipped) == {"joint state stamped ahead": 1}
    assert most[0] <= 1600                                  # 10 s of 150 messages a second, and a few


def test_bad_slot_unknown_part_and_nan_joints_are_counted(skin, tmp_path):
    stream_bag(tmp_path / "bad", skin, storage="mcap", bad_slot=True, extra_part=True)
    touches, report = read_touches(tmp_path / "bad", skin)
    assert touches.n_touches == 0
    assert report.skipped["bad taxel slot"] == 20 and report.skipped["unknown skin part"] == 50
    text = " | ".join(report.messages)
    assert "topic '/skin/torso/taxels'" in text and "slot 500 out of range" in text
    assert "'/skin/l_foot/taxels'" in text and "not configured" in text
    assert all("\n" not in m for m in report.messages)

    stream_bag(tmp_path / "nan", skin, nan_joint=True)
    touches, report = read_touches(tmp_path / "nan", skin)
    assert touches.n_touches == 0 and report.skipped["missing joint"] == 1
    assert any("'LElbowRoll'" in m for m in report.messages)


def test_a_slot_field_of_a_float_type_is_read_when_whole_and_refused_when_not(skin, tmp_path):
    """A producer that writes uint32 slots under a float32 PointField must not make every slot 0; a NaN slot is
    refused like any other that is no whole number, without numpy's cast warning on stderr."""
    from nao_skin.formats.pointcloud import TAXEL_DTYPE, taxels_array, taxels_topic
    float_slot = np.dtype([(n, "<f4" if n == "slot" else TAXEL_DTYPE.fields[n][0]) for n in TAXEL_DTYPE.names])
    hand, torso = skin.parts["l_hand"], skin.parts["torso"]
    for name, as_float in (("floats", True), ("integer_bits", False), ("nan", None)):
        with BagWriter(tmp_path / name) as bag:
            for k in range(60):
                t = k * 10_000_000
                bag.write_joint_state(t, skin.robot.joint_names, np.zeros(len(skin.robot.joint_names)))
                for part in (hand, torso):
                    slots = part.slots[:3] if 20 <= k < 40 else part.slots[:0]
                    pts = taxels_array(slots, part.positions[slots], np.full(len(slots), 2.0))
                    if as_float is False:         # uint32 bits under a float32 field
                        cloud = pts.view(float_slot)
                    else:                         # slot values written as float32 numbers (or NaN)
                        cloud = np.zeros(len(pts), float_slot)
                        for n in TAXEL_DTYPE.names:
                            cloud[n] = pts[n]
                        if as_float is None:
                            cloud["slot"] = np.nan
                    bag._write_cloud(taxels_topic(part.name), t + 3_000_000, part.parent_frame, cloud)
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            touches, report = read_touches(tmp_path / name, skin)
        if as_float:
            assert touches.n_touches == 1 and report.n_skipped == 0
            hand_act = touches.act_slot[touches.act_part == touches.part_index("l_hand")]
            np.testing.assert_array_equal(np.sort(hand_act), np.sort(hand.slots[:3]))
        else:
            assert touches.n_touches == 0 and report.skipped["bad message"] == 40
            assert "field 'slot'" in report.messages[0] and "is not a whole number" in report.messages[0]
            assert report.unknown_slots == {}      # not blamed on the layout


@pytest.mark.parametrize("kind, case, says", [
    ("touches", "apart", "of its 10 skin samples with a taxel on, none met another part's at one stamp: nothing in it"
                         " is a self-touch (a touch bag stores each touch's messages at one stamp: are its stamps"
                         " rewritten?)"),
    ("stream", "apart", f"of its 10 skin samples with a taxel on, none met another part's within"
                        f" {LIVE_CONFIG.skin_tolerance:g} s of each other:"
                        " nothing in it is a self-touch"),
    ("stream", "released", "none of its skin samples has a taxel on: nothing was pressed"),
])
def test_a_bag_without_a_touch_says_why_in_its_one_line(skin, tmp_path, kind, case, says):
    """Every message read and none dropped, yet no touch: the line says what it saw (a touch bag whose stamps
    were rewritten per message had said only "0 touches loaded of 415")."""
    from nao_skin.formats.inputs import load_touches
    hand, torso = skin.parts["l_hand"], skin.parts["torso"]
    names = skin.robot.joint_names
    with BagWriter(tmp_path / "bag", kind=kind) as bag:
        for k in range(5):
            t = 1_000_000_000 * (k + 1)
            bag.write_joint_state(t, names, np.zeros(len(names)))
            for part, shift in ((hand, 0), (torso, 400_000_000)):     # each part pressed at its own moment
                slots = part.slots[:0] if case == "released" else part.slots[:3]
                bag.write_taxels(t + shift, part.name, part.parent_frame, part.positions[slots], slots,
                                 np.full(len(slots), 2.0), np.full(len(slots), -1))
            bag.write_joint_state(t + 500_000_000, names, np.zeros(len(names)))
    with pytest.raises(DataError) as err:
        load_touches([tmp_path / "bag"], skin, log=lambda line: None)
    line = str(err.value)
    assert "\n" not in line and "0 touches loaded of" in line
    assert line.endswith(f"; {tmp_path / 'bag'}: {says}"), line


def test_not_a_bag_and_no_overwrite(skin, tmp_path):
    with pytest.raises(DataError, match="cannot open as a rosbag2"):
        read_touches(tmp_path / "missing", skin)
    (tmp_path / "empty").mkdir()
    with pytest.raises(DataError) as err:
        read_touches(tmp_path / "empty", skin)
    assert str(tmp_path / "empty") in str(err.value)
    stream_bag(tmp_path / "s", skin)
    with pytest.raises(DataError, match="exists already"):
        stream_bag(tmp_path / "s", skin)
    shutil.rmtree(tmp_path / "s")


def test_touches_written_at_one_stamp_are_said_not_read_as_one_touch_of_every_part(real, real_skin, tmp_path):
    """A touch bag whose stamps were never set (all 0) was read as one touch in which every part touched every
    other, with no word of the rest; a touch at stamp 0 alone is a time (a thesis file's index key 0)."""
    touches = real.subset(np.arange(6))
    messages = list(touch_messages(touches, real_skin))
    bag = tmp_path / "shared"
    with BagWriter(bag, kind="touches") as writer:
        for n, (_, *rest) in enumerate(messages):
            writer.write_touch(0 if n < 3 else (5 + n) * 10 ** 9, *rest)     # the first three at stamp 0
    back, report = read_touches(bag, real_skin)
    assert back.n_touches == 3 and back.stamps.tolist() == [8.0, 9.0, 10.0]
    assert report.skipped == {"touches at one stamp": 3}
    assert any("3 touches were written at 1 stamps shared with another touch (the first at 0.000000000 s)" in m
               and "were its stamps unset or rewritten?" in m for m in report.messages)
    zero = tmp_path / "zero"
    write_touch_bag(zero, touches.subset(np.arange(2)), real_skin)    # keys '0' and '1': stamps 0 and 1 s
    back, report = read_touches(zero, real_skin)
    assert back.stamps.tolist() == [0.0, 1.0] and not report.skipped


def test_two_touches_that_would_share_a_stamp_are_not_written(real, real_skin, tmp_path):
    """'a' (a name: its row, 0) and '0', or keys apart by less than a nanosecond, would be one touch in the bag:
    the import said it wrote them all."""
    touches = real.subset(np.arange(3))
    touches.keys = ["a", "0", "2"]
    touches.stamps = np.array([0.0, 0.0, 2.0])
    with pytest.raises(DataError) as err:
        write_touch_bag(tmp_path / "bag", touches, real_skin, label="touches")
    assert str(err.value) == ("touches: touches 'a' and '0' would be written at one stamp (0.000000000 s) and"
                              " read back as one touch; nothing written")
    assert not (tmp_path / "bag").exists()


@pytest.mark.parametrize("sec, nanosec, zero, says", [
    (0, 0, False, "header stamp 0.000000000 s is not set"),
    (-1, 0, True, "header stamp -1.000000000 s is before 1970"),
    (5, 2_000_000_000, True, "header stamp 5.2000000000 s is no time (nanosec 2000000000 is not below 1e9)"),
])
def test_a_header_stamp_that_is_no_time_is_said(sec, nanosec, zero, says):
    from types import SimpleNamespace

    from nao_skin.formats.pointcloud import NoTime, header_seconds

    with pytest.raises(NoTime) as err:
        header_seconds(SimpleNamespace(sec=sec, nanosec=nanosec), "bag: topic '/joint_states'", zero=zero)
    assert str(err.value) == f"bag: topic '/joint_states': {says}: the message cannot be placed in time"
    assert header_seconds(SimpleNamespace(sec=0, nanosec=0), "bag") == 0.0          # in a bag, 0 is a time


# ---------------------------------------------------------------------- commands: import, stats
def test_import_and_stats_commands(skin, tmp_path, capsys):
    import json

    from nao_skin.cli import main

    hand, torso = skin.parts["l_hand"].slots, skin.parts["torso"].slots
    joints = {n: 0.1 for n in skin.robot.joint_names}
    def contact(part, slots):
        return {"cop": None, "force": None, "moment": None, "averagePressure": None, "skinPart": part,
                "taxelInfo": {str(s): [0.0] * 6 for s in slots}}
    data = {"0": [{0: contact("l_hand", hand[:3]), 1: contact("torso", torso[:2])}, joints],
            "1": [{0: contact("l_hand", hand[:3]), 1: contact("torso", torso[:2])}, joints],
            "2": [{0: contact("l_hand", hand[5:9]), 1: contact("torso", torso[7:9]), 2: contact("l_foot", [1])},
                  joints],
            "3": [{0: contact("l_hand", hand[5:9]), 1: contact("torso", torso[7:9])}, dict(joints, LWristYaw=-0.3)]}
    legacy = tmp_path / "data.txt"
    legacy.write_text(repr(data))
    assert main(["import", str(legacy), "-o", str(tmp_path / "bag"), "--storage", "mcap"]) == 0
    out = capsys.readouterr().out
    assert "3 touches loaded of 4 touches read" in out and "unknown skin part" in out and "'l_foot'" in out
    assert main(["stats", str(tmp_path / "bag"), "--json"]) == 0
    stats = json.loads(capsys.readouterr().out)
    assert stats["touches"] == 3 and stats["exact_duplicates"] == 1 and stats["pairs"] == {"l_hand+torso": 3}
    assert stats["n_touches"] == 3 and stats["cop_mean_mm"] > 0
    # the same figures straight from the legacy file
    assert main(["stats", str(legacy), "--json"]) == 0
    direct = json.loads(capsys.readouterr().out)
    assert direct["cop_mean_mm"] == stats["cop_mean_mm"] and direct["taxel_mean_mm"] == stats["taxel_mean_mm"]
    # bad input ends with one line on stderr and exit code 2
    assert main(["import", str(tmp_path / "nope.txt"), "-o", str(tmp_path / "b2")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "nope.txt" in err


def test_a_bag_another_recording_makes_meanwhile_is_one_line_and_left_alone(tmp_path, monkeypatch):
    """Two sessions started on one bag: the second one's checks pass, then the first makes the directory while
    the second builds its type store (~0.25 s) or before it opens: rosbags' WriterError was a traceback."""
    import nao_skin.formats.bag as bag_module

    target = tmp_path / "bag"
    build = bag_module._typestore

    def other_recording_first():
        target.mkdir()
        (target / "theirs.mcap").write_bytes(b"their touches")
        return build()

    monkeypatch.setattr(bag_module, "_typestore", other_recording_first)
    with pytest.raises(DataError, match=r"bag: exists already \(made meanwhile by another recording\); a bag is"
                                        r" never overwritten$"):
        BagWriter(target, storage="mcap", kind="touches", live=True)
    monkeypatch.setattr(bag_module, "_typestore", build)
    late = tmp_path / "late"
    writer = BagWriter(late, storage="mcap", kind="touches", live=True)
    late.mkdir()
    (late / "theirs.mcap").write_bytes(b"their touches")
    with pytest.raises(DataError, match=r"late: exists already \(made meanwhile by another recording\)"):
        with writer:
            pass
    for directory in (target, late):
        assert [p.name for p in directory.iterdir()] == ["theirs.mcap"]
        assert (directory / "theirs.mcap").read_bytes() == b"their touches"


def test_a_write_that_fails_for_want_of_space_says_so_and_another_does_not(tmp_path):
    """The recorder advises freeing space after a full disk; after a refused permission it had said the same."""
    import errno
    import sqlite3

    from nao_skin.errors import DiskFull, OutputError

    with BagWriter(tmp_path / "bag", storage="mcap", kind="touches") as bag:
        for exc, full in ((OSError(errno.ENOSPC, "No space left on device"), True),
                          (OSError(errno.EFBIG, "File too large"), True),
                          (sqlite3.OperationalError("database or disk is full"), True),
                          (PermissionError(errno.EPERM, "Operation not permitted"), False),
                          (sqlite3.OperationalError("attempt to write a readonly database"), False)):
            said = bag._cannot_write(exc)
            assert isinstance(said, OutputError) and isinstance(said, DiskFull) == full, exc
            assert str(said).startswith(f"{tmp_path / 'bag'}: cannot write the bag (")


def test_a_bag_is_never_written_into_another(tmp_path):
    """``record --bag <bag>/inner`` was accepted: a second recording inside the first one's directory."""
    outer = tmp_path / "outer"
    with BagWriter(outer, storage="mcap", kind="touches"):
        pass
    before = sorted(p.name for p in outer.iterdir())
    with pytest.raises(DataError, match=rf"inner: lies inside the bag {outer}; a bag is never written into another,"
                                        r" choose a place outside it$"):
        BagWriter(outer / "deeper" / "inner", storage="mcap", kind="touches")
    assert sorted(p.name for p in outer.iterdir()) == before


def test_a_simulation_into_a_bag_names_the_place_given_not_its_staging_directory(tmp_path, capsys):
    """``simulate --out <bag>/sim`` was refused naming ``<bag>/.sim.<pid>.<random>/touches``, a directory the
    user never made nor sees (an adversarial review, 2026-11-28)."""
    from nao_skin.cli import main as cli_main

    outer = tmp_path / "outer"
    with BagWriter(outer, storage="mcap", kind="touches"):
        pass
    before = sorted(p.name for p in outer.iterdir())
    assert cli_main(["simulate", "--seed", "1", "--touches-per-pair", "2", "--out", str(outer / "sim")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"nao-skin simulate: error: {outer / 'sim' / 'touches'}: lies inside the bag {outer}; a bag"
                   f" is never written into another, choose a place outside it"], err
    assert sorted(p.name for p in outer.iterdir()) == before


def test_a_simulation_into_a_bag_is_refused_before_it_simulates(tmp_path, capsys):
    """The place was refused only once the touches were simulated (minutes for a large preset). A preset
    that fails while simulating (a link_errors entry the robot config does not name) tells the order: the
    place's line comes first."""
    from nao_skin.cli import main as cli_main

    outer = tmp_path / "outer"
    with BagWriter(outer, storage="mcap", kind="touches"):
        pass
    params = tmp_path / "sim.yaml"
    params.write_text("defaults:\n  n_touches: 2\npresets:\n  broken:\n    link_errors: {NoSuchLink: 0.01}\n")
    outside = tmp_path / "elsewhere"
    assert cli_main(["simulate", "--params", str(params), "--preset", "broken", "--out", str(outside)]) == 2
    assert "NoSuchLink" in capsys.readouterr().err          # the preset does fail while simulating
    assert cli_main(["simulate", "--params", str(params), "--preset", "broken", "--out", str(outer / "sim")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "lies inside the bag" in err[0] and "NoSuchLink" not in err[0], err


def test_a_touch_bag_whose_last_touch_came_long_after_the_one_before_reads_every_touch(default_skin, tmp_path):
    """A touch bag holds a joint state at each touch only. The detector counts the latest joint state only once a
    next one confirms it when it lies more than joint_history (5 s) past the one before (a mis-stamped state must
    not age out the real ones); at the end of the bag nothing comes to confirm it, and the last touch of a session
    whose operator paused before it was left out on reading: "no joint state at or after it" (found in the
    capture's end-to-end bag: 4 written, 3 read)."""
    from nao_skin.sim.simulate import simulate

    touches = simulate(default_skin, {"pairs": [["l_hand", "torso"]], "n_touches": 4}, seed=3).touches
    touches.stamps[:] = 1000.0 + np.array([0.0, 1.0, 2.0, 12.0])       # a 10-s pause before the last touch
    bag = tmp_path / "touches"
    write_touch_bag(bag, touches, default_skin)
    got, report = read_touches(bag, default_skin)
    assert got.n_touches == touches.n_touches and not report.skipped, report.lines()
    assert np.allclose(np.sort(got.stamps), np.sort(touches.stamps))
