"""The pure pieces under the nodes: message translation, skinManager bottles, heat-map colours, back-off."""
from __future__ import annotations

import numpy as np
import pytest

from nao_skin.errors import DataError, NaoSkinError
from nao_skin.formats.pointcloud import (BadSlot, contacts_array, decode_cloud, read_contacts, read_taxels,
                                         taxels_array, xyz)
from nao_skin.formats.skinmanager import activated_taxels, format_skin_events, parse_bottle_text, parse_skin_events
from nao_skin.live.heatmap import (NEVER_INDEX, PRESSED_INDEX, SCALE_LEVELS, ActivationCounts, colour_index, palette,
                                   triangle_slots)
from nao_skin.live.reconnect import Backoff
from nao_skin.model.skin import load_skin

messages = pytest.importorskip("nao_skin.nodes.messages")


def test_taxel_cloud_roundtrip_keeps_every_field():
    pts = taxels_array([5, 17, 383], [[0.1, 0.2, 0.3], [-1, 0, 1], [0, 0, 0]], [1.0, np.nan, 255.0], [2, 2, -1])
    stamp = messages.stamp_to_msg(1234.000000123)
    msg = messages.cloud_from_array(pts, "l_wrist", stamp)
    assert (msg.width, msg.height, msg.point_step) == (3, 1, 24)
    back = decode_cloud(msg, "/skin/l_hand/taxels")
    np.testing.assert_array_equal(back["slot"], [5, 17, 383])
    np.testing.assert_array_equal(back["contact"], [2, 2, -1])
    np.testing.assert_allclose(xyz(back), [[0.1, 0.2, 0.3], [-1, 0, 1], [0, 0, 0]], atol=1e-7)
    assert np.isnan(back["pressure"][1]) and back["pressure"][2] == 255.0
    assert (msg.header.stamp.sec, msg.header.stamp.nanosec) == (1234, 123)


def test_cloud_with_other_field_order_and_missing_field():
    pts = taxels_array([1, 2], np.zeros((2, 3)))
    reordered = pts[["contact", "slot", "x", "y", "z", "pressure"]]     # same fields, other offsets
    packed = np.zeros(2, np.dtype([("contact", "<i4"), ("slot", "<u4"), ("x", "<f4"), ("y", "<f4"),
                                   ("z", "<f4"), ("pressure", "<f4")]))
    for n in packed.dtype.names:
        packed[n] = reordered[n]
    msg = messages.cloud_from_array(packed, "torso", messages.stamp_to_msg(0))
    back = decode_cloud(msg, "t")
    np.testing.assert_array_equal(back["slot"], [1, 2])
    msg.fields = [f for f in msg.fields if f.name != "slot"]
    with pytest.raises(DataError, match="t: PointCloud2 has no field 'slot'"):
        read_taxels(msg, load_skin().parts["torso"], "t")


def test_big_endian_padded_rows_and_bad_slots_read_like_a_bag():
    torso = load_skin().parts["torso"]
    slots = torso.slots[[3, 4, 7, 9]]
    pts = taxels_array(slots, torso.positions[slots], [1.0, 2.0, 3.0, 4.0], [5, 5, -1, 6])
    msg = messages.cloud_from_array(pts, "torso", None)
    # two rows of two points, each row padded by 8 bytes, big-endian
    big = pts.astype(pts.dtype.newbyteorder(">")).tobytes()
    msg.data = big[:48] + bytes(8) + big[48:] + bytes(8)
    msg.is_bigendian, msg.width, msg.height, msg.row_step = True, 2, 2, 56
    got_slots, pressures, contacts = read_taxels(msg, torso, "t")
    np.testing.assert_array_equal(got_slots, slots)
    np.testing.assert_array_equal(pressures, [1.0, 2.0, 3.0, 4.0])
    np.testing.assert_array_equal(contacts, [5, 5, -1, 6])
    msg.data = msg.data[:-20]
    with pytest.raises(DataError, match="t: malformed point cloud"):
        read_taxels(msg, torso, "t")
    # no point in rows of a huge stride: empty, not a padded copy of 2 PiB (a MemoryError in every node)
    msg.width, msg.height, msg.row_step = 0, 2 ** 20, 2 ** 31
    assert len(read_taxels(msg, torso, "t")[0]) == 0
    n = torso.n_slots + 1
    many = messages.cloud_from_array(taxels_array(np.resize(slots, n), np.zeros((n, 3))), "torso", None)
    with pytest.raises(BadSlot, match=f"t: {n} points for part 'torso' of {torso.n_slots} slots"):
        read_taxels(many, torso, "t")
    # nor more contacts than slots: 2M contacts held the recorder 0.8 s a message, and its touches were lost
    contacts = messages.cloud_from_array(contacts_array(np.arange(n), np.zeros((n, 3))), "torso", None)
    with pytest.raises(DataError, match=f"t: {n} contacts for part 'torso' of {torso.n_slots} slots"):
        read_contacts(contacts, torso, "t")
    contacts = messages.cloud_from_array(contacts_array(np.arange(3), np.ones((3, 3))), "torso", None)
    np.testing.assert_array_equal(read_contacts(contacts, torso, "t")[0], [0, 1, 2])
    absent = np.flatnonzero(~torso.present)[0]
    for slot, says in ((torso.n_slots, "out of range"), (absent, "is not a taxel of the 'torso' layout")):
        bad = messages.cloud_from_array(taxels_array([slots[0], slot], np.zeros((2, 3))), "torso", None)
        with pytest.raises(BadSlot, match=f"t: field 'slot': slot {slot} {says}") as err:
            read_taxels(bad, torso, "t")
        assert err.value.part == "torso" and "\n" not in str(err.value)


def test_skin_event_text_roundtrip_and_errors():
    text = ("((3 1 6 7) (0.1 0.2 0.3) (0 0 1.5) (0 0 0) (0.1 0.2 0.3) (0 0 1) (12 13 14) 42.5) "
            "((4 3 6 4) (1 2 3) (0 0 0) (0 0 0) (1 2 3) (0 1 0) () 0)")
    ev = parse_skin_events(text, "port /x")
    np.testing.assert_array_equal(ev.skin_part, [7, 4])
    np.testing.assert_array_equal(ev.contact_id, [3, 4])
    np.testing.assert_array_equal(ev.taxel_id, [12, 13, 14])
    np.testing.assert_array_equal(ev.taxel_contact, [0, 0, 0])
    np.testing.assert_allclose(ev.pressure, [42.5, 0.0])
    again = parse_skin_events(format_skin_events(ev), "again")
    for name in ("skin_part", "contact_id", "taxel_id", "cop", "force", "normal", "pressure"):
        np.testing.assert_array_equal(getattr(again, name), getattr(ev, name))
    assert parse_skin_events("", "empty").n_contacts == 0
    bad = {
        "((3 1 6) (0 0 0) (0 0 0) (0 0 0) (0 0 0) (0 0 1) (1) 1)": "contactId bodyPart linkNumber skinPart",
        "((3 1 6 7) (0 0) (0 0 0) (0 0 0) (0 0 0) (0 0 1) (1) 1)": "cop must be a list of 3",
        "((3 1 6 7) (0 0 0) (0 0 0) (0 0 0) (0 0 0) (0 0 1) (1 x) 1)": "taxel ids holds 'x'",
        "((3 1 6 7) (0 0 0) (0 0 0) (0 0 0) (0 0 0) (0 0 1) (-1) 1)": "taxel id -1",
        "((3 1 6 7) (0 0 0) (0 0 0)": "unbalanced",
        "((3 1 6 7) (0 0 0) (0 0 0) (0 0 0) (0 0 0) (0 0 1) (1) nan)": "finite number",
        # published as int32 and float32: these became "no contact" and inf without a word
        "((99999999999999999999999 1 6 7) (0 0 0) (0 0 0) (0 0 0) (0 0 0) (0 0 1) (1) 1)":
            "contactId 99999999999999999999999 is outside 0..2147483647",
        "((1099511627776 1 6 7) (0 0 0) (0 0 0) (0 0 0) (0 0 0) (0 0 1) (1) 1)": "contactId 1099511627776 is outside",
        "((3 1 6 7) (1e300 0 0) (0 0 0) (0 0 0) (0 0 0) (0 0 1) (1) 1)": "not a finite float32",
        "((3 1 6 7) (0 0 0) (0 0 0) (0 0 0) (0 0 0) (0 0 1) (1) 1e300)": "finite number",
    }
    for text, what in bad.items():
        with pytest.raises(NaoSkinError, match=what) as info:
            parse_skin_events(text, "port /skin_events")
        assert "\n" not in str(info.value) and str(info.value).startswith("port /skin_events")
    assert parse_bottle_text('1 "a b" (2.5)', "w") == [1, "a b", [2.5]]


def test_compensated_vector():
    slots, vals = activated_taxels([0, 0, 100, 0, 3], 0.0, "p", 384)
    np.testing.assert_array_equal(slots, [2, 4])
    np.testing.assert_array_equal(vals, [100, 3])
    with pytest.raises(DataError, match="more than the part's 4 slots"):
        activated_taxels(np.zeros(5), 0.0, "p", 4)


def test_activation_counts_count_presses_not_samples():
    h = ActivationCounts({"a": 10, "b": 4})
    for _ in range(5):                    # one long press of slots 1, 2: counts once
        h.update("a", [1, 2])
    h.update("a", [])
    h.update("a", [2, 3])                 # a new press
    np.testing.assert_array_equal(h.counts["a"], [0, 1, 2, 1, 0, 0, 0, 0, 0, 0])
    np.testing.assert_array_equal(h.pressed["a"], np.isin(np.arange(10), [2, 3]))
    idx = h.colour_indices("a")
    assert idx[0] == NEVER_INDEX and idx[2] == PRESSED_INDEX and idx[3] == PRESSED_INDEX
    assert 0 <= idx[1] < SCALE_LEVELS
    assert h.coverage("a", np.ones(10, bool)) == pytest.approx(0.3)
    top = colour_index(np.array([1, 4, 16]), np.zeros(3, bool), 16)
    assert top[0] < top[1] < top[2] == SCALE_LEVELS - 1            # more activations, further up the scale
    assert palette().shape == (SCALE_LEVELS + 2, 4)


def test_a_part_whose_skin_stream_goes_silent_is_released():
    """A skin stream stopped mid-press (skinManager gone, a bridge killed: no released sample comes) left its
    taxels red, "pressed now", for the rest of the session."""
    h = ActivationCounts({"a": 10, "b": 4})
    h.update("a", [1, 2], when=10.0)
    h.update("b", [0], when=10.0)
    h.release_silent(10.4)                                  # streaming at ~50 Hz: a pause this short is no gap
    assert h.pressed["a"].sum() == 2
    h.update("b", [0], when=10.5)
    h.release_silent(10.6)                                  # 'a' silent for 0.6 s: released; 'b' still pressed
    assert not h.pressed["a"].any() and h.pressed["b"][0]
    np.testing.assert_array_equal(h.counts["a"][[1, 2]], [1, 1])            # what was pressed is still counted
    h.update("a", [1, 2], when=11.0)                        # pressed again: a new press
    np.testing.assert_array_equal(h.counts["a"][[1, 2]], [2, 2])


def test_triangle_slots_cover_every_present_taxel_once():
    skin = load_skin()
    for part in skin.parts.values():
        groups = triangle_slots(part)
        allslots = np.concatenate([s for _, s in groups])
        np.testing.assert_array_equal(np.sort(allslots), part.slots)
        assert all(np.all(s // 12 == t) for t, s in groups)


def test_backoff_logs_once_per_outage():
    b = Backoff("robot", initial=1.0, maximum=4.0)
    assert b.due(0.0)
    assert b.failed(0.0, "down") == "robot: down; retrying every 1-4 s (logged once per outage)"
    assert not b.due(0.5) and b.due(1.0)
    assert b.failed(1.0, "down") is None and b.next_attempt == 3.0
    assert b.failed(3.0, "down") is None and b.next_attempt == 7.0
    assert b.failed(7.0, "down") is None and b.next_attempt == 11.0          # capped at 4 s
    assert b.succeeded(8.0) == "robot: connected after 8.0 s (4 failed attempts)"    # never connected before
    assert not b.due(9.0)
    assert "retrying" in b.failed(20.0, "lost again") and b.outages == 2
    assert b.succeeded(21.0) == "robot: connected again after 1.0 s (1 failed attempts)"
    # a fixed period says one number (it said 'every 0.5-0.5 s')
    assert Backoff("port", 1.0, 1.0).failed(0.0, "gone") == "port: gone; retrying every 1 s (logged once per outage)"


def test_a_float_contact_field_that_is_no_whole_number_is_no_contact():
    """A producer's float 'contact' field holding NaN was cast to contact 0: every such taxel of a sample
    joined one contact. Now it is -1 (no skinManager contact: grouped by where the taxels are)."""
    from nao_skin.formats.pointcloud import TAXEL_DTYPE, _contact_ids, taxels_array

    pts = taxels_array([0, 1, 2, 3], np.zeros((4, 3)), None, [5, 5, 7, 7])
    float_contact = np.dtype([(n, "<f4" if n == "contact" else TAXEL_DTYPE.fields[n][0]) for n in TAXEL_DTYPE.names])
    cloud = np.zeros(4, float_contact)
    for n in TAXEL_DTYPE.names:
        cloud[n] = pts[n]
    cloud["contact"] = [5.0, np.nan, 7.5, np.inf]
    np.testing.assert_array_equal(_contact_ids(cloud, "t"), [5, -1, -1, -1])
    np.testing.assert_array_equal(_contact_ids(pts, "t"), [5, 5, 7, 7])          # the int32 field as it is
