"""One record session per ROS domain on this machine (``nao_skin.session.claim``).

Two sessions on one ROS_DOMAIN_ID recorded each other's touches (a review found 494 touches in a bag whose robot
played 25, a pair r_hand+l_hand mixing two robots, and each calibrate node answering the other's requests): the
second now gets one line and starts nothing. Real processes hold the claims here; the last test runs two
``nao-skin record`` sessions over real DDS.
"""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys

import pytest
from ros_harness import Listener, Proc, ros_env, unique_domain_id

from nao_skin.errors import ConfigError
from nao_skin.session.claim import claim_domain, domain_id


@pytest.mark.parametrize("text,expected", [("", 0), ("  ", 0), ("0", 0), ("17", 17), ("232", 232)])
def test_the_domain_is_read_as_rcl_reads_it(text, expected):
    assert domain_id({"ROS_DOMAIN_ID": text}) == expected
    assert domain_id({}) == 0


@pytest.mark.parametrize("text", ["abc", "233", "-1", "1.5", "\u0663", "9" * 40])
def test_a_domain_rcl_cannot_take_is_one_line(text):
    with pytest.raises(ConfigError) as err:
        domain_id({"ROS_DOMAIN_ID": text})
    line = str(err.value)
    assert line.startswith("ROS_DOMAIN_ID=") and "from 0 to 232" in line and "\n" not in line


class Holder:
    """Another process holding a claim (as a running record session does) until it is told to end."""

    def __init__(self, domain: int, lock_dir):
        code = ("import sys; from nao_skin.session.claim import claim_domain;"
                f" c = claim_domain({domain}, {str(lock_dir)!r}); print('held', flush=True); sys.stdin.read();"
                " c.release() if len(sys.argv) > 1 else None")
        self.popen = subprocess.Popen([sys.executable, "-c", code, "release"], stdin=subprocess.PIPE,
                                      stdout=subprocess.PIPE, text=True)
        assert self.popen.stdout.readline() == "held\n"
        self.pid = self.popen.pid

    def kill(self):
        self.popen.kill()
        self.popen.communicate()

    def end(self):
        self.popen.communicate("")


def test_a_domain_held_by_a_running_session_is_refused_and_a_killed_sessions_is_free(tmp_path):
    holder = Holder(41, tmp_path)
    try:
        with pytest.raises(ConfigError) as err:
            claim_domain(41, tmp_path)
        line = str(err.value)
        assert f"another nao-skin session (pid {holder.pid}) runs on ROS_DOMAIN_ID 41 on this machine" in line
        assert "ROS_DOMAIN_ID=42 nao-skin record" in line and "\n" not in line, line
        claim_domain(40, tmp_path).release()      # another domain is free
        claim_domain(41, tmp_path, "/nao2").release()   # so is another namespace of the same domain
        with pytest.raises(ConfigError, match="runs on ROS_DOMAIN_ID 41 in namespace /nao2"):
            second = claim_domain(41, tmp_path, "/nao2")
            claim_domain(41, tmp_path, "/nao2")
        second.release()
    finally:
        holder.kill()                            # kill -9: no clean-up ran, the kernel released the lock
    claim = claim_domain(41, tmp_path)
    assert (tmp_path / "nao_skin_ros_domain_41.lock").read_text() == f"{os.getpid()}\n"
    claim.release()


def test_a_claim_is_held_until_released_or_dropped_and_two_claims_at_once_get_one(tmp_path):
    claim = claim_domain(7, tmp_path)
    with pytest.raises(ConfigError, match=f"another nao-skin session \\(pid {os.getpid()}\\)"):
        claim_domain(7, tmp_path)                # one per domain, this process's second claim too
    claim.release()
    claim = claim_domain(7, tmp_path)
    del claim                                    # dropped: released
    # many processes at once: exactly one gets it
    code = ("import sys, time; from nao_skin.errors import ConfigError; from nao_skin.session.claim import"
            f" claim_domain\ntry:\n    c = claim_domain(9, {str(tmp_path)!r}); print('got', flush=True);"
            " time.sleep(2)\nexcept ConfigError:\n    print('refused', flush=True)")
    runs = [subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True) for _ in range(6)]
    outcomes = sorted(p.communicate()[0].strip() for p in runs)
    assert outcomes == ["got"] + ["refused"] * 5, outcomes


def test_a_lock_file_of_any_content_is_claimed_when_no_session_holds_it(tmp_path):
    (tmp_path / "nao_skin_ros_domain_3.lock").write_text("{not a pid")
    claim_domain(3, tmp_path).release()


def test_a_fifo_where_a_lock_file_goes_does_not_hold_up_a_refusal(tmp_path):
    """/tmp is everybody's: a FIFO at the next domain's lock path made the refusal's suggestion of a free
    domain wait for a writer for ever (opened to read, blocking; an adversarial review, 2026-11-28)."""
    os.mkfifo(tmp_path / "nao_skin_ros_domain_42.lock")
    holder = Holder(41, tmp_path)
    try:     # in a process of its own: a wait for ever fails the test instead of holding up the suite
        run = subprocess.run([sys.executable, "-c", "from nao_skin.session.claim import claim_domain;"
                              f" claim_domain(41, {str(tmp_path)!r})"], capture_output=True, text=True, timeout=60)
    finally:
        holder.kill()
    assert run.returncode == 1 and "ConfigError: another nao-skin session" in run.stderr, run.stderr[-2000:]
    assert "ROS_DOMAIN_ID=42 nao-skin record" in run.stderr       # no session holds 42: a FIFO is no claim


def test_an_unwritable_lock_directory_leaves_the_session_unclaimed_and_says_so(tmp_path):
    claim = claim_domain(5, tmp_path / "no" / "such" / "dir")
    assert claim.fd is None and claim.problem.startswith("cannot claim ROS_DOMAIN_ID 5 (")
    assert "a second session there would not be refused" in claim.problem


@pytest.mark.middleware
def test_a_second_record_session_on_the_domain_is_refused_in_one_line_and_the_first_goes_on(tmp_path):
    from std_msgs.msg import String
    from test_record_session import record_cmd

    from nao_skin.formats.bag import read_touches
    from nao_skin.model.skin import load_skin
    from nao_skin.nodes.topics import PROGRESS_TOPIC

    domain = unique_domain_id()
    listener = first = None
    try:
        listener = Listener(domain)
        progress = listener.subscribe(String, PROGRESS_TOPIC, keep=lambda m: json.loads(m.data))
        first = Proc(record_cmd(tmp_path / "first", seed=3, per_pair=3) + ["--param", "calibrate.live=false"],
                     ros_env(domain), tmp_path, "first")
        assert listener.spin_until(lambda: progress and progress[-1]["touches"] >= 1, timeout=60, procs=[first])
        second = subprocess.run(record_cmd(tmp_path / "second", seed=4, per_pair=3), env=ros_env(domain),
                                capture_output=True, text=True, timeout=60)
        listener.spin_for(1.0)
        assert first.alive()
    finally:
        if listener is not None:
            listener.close()
        code = first.stop(signal.SIGINT) if first is not None else None
    err = [line for line in second.stderr.splitlines() if line.strip()]
    assert second.returncode == 2 and len(err) == 1, err
    assert err[0].startswith(f"nao-skin record: error: another nao-skin session (pid {first.popen.pid}) runs on"
                             f" ROS_DOMAIN_ID {domain} on this machine"), err
    assert not (tmp_path / "second").exists()
    assert code == 0, first.stderr()[-3000:]
    touches, _ = read_touches(tmp_path / "first", load_skin())
    assert touches.n_touches >= 1 and "has 2 publishers" not in first.stderr()
    # the domain is free again once the first session ended: the claim a next session takes is granted
    claim_domain(domain).release()
