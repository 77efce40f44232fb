"""Every bag nao-skin writes opens with rosbags' ``AnyReader``, and the bags named otherwise before still read.

``AnyReader`` takes a path named ``*.bag`` for a ROS 1 bag file: a rosbag2 directory named so (the simulator's
``touches.bag`` of earlier versions) was refused ("Could not open file ...: Is a directory"). nao-skin reads
through rosbags' rosbag2 ``Reader``, which takes any name, so a user's ``something.bag`` rosbag2 directory, and an
earlier simulator output holding ``touches.bag``, are still read and replaced as before. Real bag files only.
"""
from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import pytest
import yaml

from nao_skin.cli import main as cli_main
from nao_skin.formats.bag import SIMULATED, BagWriter, default_bag_name, read_touches, write_touch_bag
from nao_skin.formats.inputs import find_bag, recording_of
from nao_skin.formats.outdir import MARKER, RECORDING, read_marker, write_marker
from nao_skin.live.playback import Playback
from nao_skin.paths import package_dir
from nao_skin.session.recording import TouchRecording
from nao_skin.sim.simulate import BAG_NAME, simulate
from nao_skin.touch.datasets import deduplicate
from nao_skin.touch.events import LIVE_CONFIG
from recorded_touches import play_streams

PAIR = {"pairs": [["l_hand", "torso"]], "n_touches": 4}


def any_reader_read(bag: Path) -> dict:
    """What rosbags' AnyReader reads of ``bag``: messages per topic, every one deserialized (the Jazzy types)."""
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    counts: dict = {}
    with AnyReader([bag], default_typestore=get_typestore(Stores.ROS2_JAZZY)) as reader:
        assert reader.is2, bag
        for conn, _, raw in reader.messages():
            msg = reader.deserialize(raw, conn.msgtype)
            assert msg.header.stamp.sec > 0, (bag, conn.topic)
            counts[conn.topic] = counts.get(conn.topic, 0) + 1
    return counts


def listed(bag: Path) -> dict:
    """Messages per topic as the bag's metadata.yaml lists them (rosbags wrote it on close)."""
    info = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    return {t["topic_metadata"]["name"]: t["message_count"] for t in info["topics_with_message_count"]}


@pytest.mark.parametrize("storage", ["sqlite3", "mcap"])
def test_the_simulators_bag_opens_with_any_reader(tmp_path, storage, capsys):
    assert cli_main(["simulate", "--seed", "3", "--touches-per-pair", "2", "--storage", storage,
                     "--out", str(tmp_path / "sim")]) == 0
    bag = tmp_path / "sim" / BAG_NAME
    assert str(bag) in capsys.readouterr().out.splitlines()          # the path it says it wrote
    assert read_marker(tmp_path / "sim")["entries"][1] == BAG_NAME
    counts = any_reader_read(bag)
    assert counts == listed(bag) and counts["/joint_states"] > 0
    assert find_bag(tmp_path / "sim") == bag                          # the directory names its one bag


def test_the_bundled_recording_opens_with_any_reader():
    bag = package_dir() / "bags" / "sim_default" / "touches"
    assert any_reader_read(bag) == listed(bag)
    assert listed(bag)["/joint_states"] == 4123


@pytest.mark.parametrize("storage", ["sqlite3", "mcap"])
def test_a_touch_bag_under_the_recorders_default_name_opens_with_any_reader(skin, tmp_path, storage):
    touches = simulate(skin, PAIR, seed=4).touches
    bag = tmp_path / default_bag_name()
    write_touch_bag(bag, touches, skin, storage=storage)
    counts = any_reader_read(bag)
    assert counts == listed(bag) and counts["/joint_states"] == touches.n_touches


def test_a_record_sessions_bag_under_its_default_name_opens_with_any_reader(skin, tmp_path, monkeypatch):
    """The recorder of ``nao-skin record`` (pairing_recorder's TouchRecording, live: a provisional metadata.yaml
    until it closes) given no bag name, fed the streams a simulated robot sends."""
    monkeypatch.chdir(tmp_path)
    touches, _ = deduplicate(simulate(skin, PAIR, seed=5).touches)
    recording = TouchRecording(skin, LIVE_CONFIG, default_bag_name(), "sqlite3", recorded_from=SIMULATED)
    play_streams(recording, Playback(touches, skin, period=0.6, press=0.2, hold=0.05), start=1.7e9)
    assert recording.close().startswith(f"wrote {touches.n_touches} touches to ")
    [bag] = [p for p in tmp_path.iterdir() if p.name.startswith("nao_skin_touches_")]
    assert recording.bag_path == bag.resolve()
    counts = any_reader_read(bag)
    assert counts == listed(bag) and counts["/joint_states"] == touches.n_touches


def test_metadata_is_version_9_as_jazzy_writes_it(skin, tmp_path):
    """rosbag2 v9 (Jazzy): QoS profiles a YAML list (v8: a string), ros_distro, custom_data, type hashes; the
    provisional metadata of a live bag says the same version."""
    bag = tmp_path / "touches"
    with BagWriter(bag, "sqlite3", kind="touches", live=True):
        provisional = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert provisional["version"] == 9
    shutil.rmtree(bag)
    write_touch_bag(bag, simulate(skin, PAIR, seed=6).touches, skin)
    info = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert info["version"] == 9 and info["ros_distro"] and info["custom_data"] == {"nao_skin.bag_kind": "touches"}
    for topic in info["topics_with_message_count"]:
        meta = topic["topic_metadata"]
        assert meta["offered_qos_profiles"] == [] and meta["type_description_hash"].startswith("RIHS01_"), meta


# ------------------------------------------------------------------------------ bags named before
def test_a_users_rosbag2_directory_named_dot_bag_is_still_read(skin, tmp_path, capsys):
    touches = simulate(skin, PAIR, seed=7).touches
    bag = tmp_path / "sitting.bag"            # the user's own name: nao-skin never renames it
    write_touch_bag(bag, touches, skin)
    back, report = read_touches(bag, skin)
    assert back.n_touches == touches.n_touches and report.n_skipped == 0
    assert find_bag(tmp_path) == bag and recording_of(bag / "sitting.bag.db3") == bag.resolve()
    assert cli_main(["stats", str(bag), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)


def test_simulate_force_replaces_an_earlier_output_holding_touches_dot_bag(tmp_path, capsys):
    """An output of an earlier version (its bag ``touches.bag``, its marker listing that) is replaced whole by
    ``--force``, as any earlier simulate output; without ``--force`` it is refused in one line, untouched."""
    out = tmp_path / "sim"
    assert cli_main(["simulate", "--seed", "1", "--touches-per-pair", "2", "--out", str(out)]) == 0
    os.rename(out / BAG_NAME, out / "touches.bag")
    (out / MARKER).unlink()
    write_marker(out, "simulate", RECORDING, stamp=False)       # what the earlier version's marker listed
    assert "touches.bag/metadata.yaml" in read_marker(out)["entries"]
    before = sorted(p.relative_to(out).as_posix() for p in out.rglob("*"))
    capsys.readouterr()
    assert cli_main(["simulate", "--seed", "2", "--touches-per-pair", "2", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "touches.bag" in err and "--force" in err, err
    assert sorted(p.relative_to(out).as_posix() for p in out.rglob("*")) == before
    assert cli_main(["simulate", "--seed", "2", "--touches-per-pair", "2", "--out", str(out), "--force"]) == 0
    assert not (out / "touches.bag").exists() and (out / BAG_NAME / "metadata.yaml").is_file()
    assert BAG_NAME in read_marker(out)["entries"] and "touches.bag" not in read_marker(out)["entries"]
    assert any_reader_read(out / BAG_NAME)
