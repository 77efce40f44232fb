"""touch.inorder.InOrder: the live streams back in the order of their stamps (the recorder's, before its touch
detector); the recorder over DDS, held up for seconds: test_record_session.py."""
from __future__ import annotations

from nao_skin.touch.inorder import InOrder


def test_streams_that_arrive_out_of_step_come_out_in_the_order_of_their_stamps():
    merge = InOrder(wait=5.0)
    out = merge.push("joints", 1.00, 10.0, "j1.00")
    out += merge.push("torso", 1.01, 10.0, "t1.01")
    assert out == ["j1.00"]                          # the torso may still bring an earlier one than j1.01
    # the joints' backlog first, then the torso's, as a recorder held up gets them
    for k in range(2, 6):
        out += merge.push("joints", k, 12.0, f"j{k}")
    assert out == ["j1.00", "t1.01"]                 # the torso's next is not in yet
    for stamp in (2.5, 3.5, 4.5):
        out += merge.push("torso", stamp, 12.5, f"t{stamp}")
    assert out == ["j1.00", "t1.01", "j2", "t2.5", "j3", "t3.5", "j4", "t4.5"]
    assert merge.drain() == ["j5"]


def test_each_stream_keeps_its_own_order_whatever_its_stamps():
    """A mis-stamped message goes on where its stream sent it: the detector judges it, as before."""
    merge = InOrder(wait=5.0)
    out = merge.push("joints", 1.0, 0.0, "j1")
    out += merge.push("torso", 2.0, 0.0, "t2")
    out += merge.push("joints", 99.0, 0.0, "j99 (stamped ahead)")
    out += merge.push("joints", 3.0, 0.0, "j3")
    out += merge.push("torso", 4.0, 0.0, "t4")
    assert out == ["j1", "t2", "t4"]
    assert merge.ready(4.9) == []
    assert merge.ready(5.0) == ["j99 (stamped ahead)", "j3"]     # its wait ran out; j3 behind it, in order


def test_a_quiet_stream_holds_the_others_up_for_wait_at_most_and_not_once_it_stopped():
    merge = InOrder(wait=5.0, forget=30.0)
    out = merge.push("contacts", 0.0, 0.0, "c0")     # a driver that sends contacts only while pressed
    out += merge.push("joints", 1.0, 1.0, "j1")
    assert out == ["c0"]
    out = merge.push("joints", 2.0, 2.0, "j2")
    assert out == []                                 # the contacts may still bring an earlier one
    assert merge.ready(5.9) == [] and merge.ready(6.0) == ["j1"] and merge.ready(7.0) == ["j2"]
    # quiet for longer than forget: it stopped, nothing waits for it
    assert merge.push("joints", 40.0, 40.0, "j40") == ["j40"]
    # back: waited for again
    assert merge.push("contacts", 41.0, 41.0, "c41") == []       # the joints may still bring an earlier one
    assert merge.push("joints", 42.0, 42.0, "j42") == ["c41"]
    assert merge.drain() == ["j42"]


def test_drain_gives_everything_in_the_order_of_the_stamps_and_ties_in_the_order_they_came():
    merge = InOrder()
    out = merge.push("a", 1.0, 0.0, "a1")            # the only stream heard from: nothing to wait for
    out += merge.push("b", 1.0, 0.0, "b1")
    out += merge.push("b", 0.5, 0.0, "b0.5 (behind its stream)")
    out += merge.push("a", 3.0, 0.0, "a3")
    out += merge.push("a", 2.0, 0.0, "a2")
    assert out == ["a1", "b1", "b0.5 (behind its stream)"] and merge.drain() == ["a3", "a2"]
