"""No silent freeze: a node process that stops beating (``formation_ilc.system.heartbeat``)
is named (its name, pid and what it last did), killed and started again like a crashed
one, and the run ends equal to the batch simulator.

The freezes are SIGSTOPs: one robot while it starts (before the first trial), another in
trial 1 (where the lockstep team waits on it, as the team of issue 56 waited on its frozen
robot_11 until the run gave up as stuck, 324 s later)."""

from __future__ import annotations

import json
import os
import re
import signal
import threading
import time

import numpy as np
import pytest

from formation_ilc.core.metrics import read_metrics
from formation_ilc.system.heartbeat import FREEZE_ENV

from ..procs import find_child, stop_group
from .test_faults import SEED, TOL, TRIALS, batch, start, wait_rows

pytestmark = [pytest.mark.ros, pytest.mark.multiprocess]

#: [s] the launcher's freeze bound here (its default is 15 s)
FREEZE = 5.0


class Lines:
    """The launcher's output, read as it comes (a thread), for a test to wait on."""

    def __init__(self, proc):
        self.lines: list[str] = []
        self.cond = threading.Condition()
        self.thread = threading.Thread(target=self._read, args=(proc,), daemon=True)
        self.thread.start()

    def _read(self, proc) -> None:
        for line in proc.stdout:
            with self.cond:
                self.lines.append(line.rstrip("\n"))
                self.cond.notify_all()

    def wait_for(self, pattern: str, timeout: float = 300.0) -> re.Match[str]:
        deadline = time.monotonic() + timeout
        rx = re.compile(pattern)
        with self.cond:
            while True:
                for ln in self.lines:
                    m = rx.search(ln)
                    if m:
                        return m
                left = deadline - time.monotonic()
                assert left > 0, f"no line like {pattern!r} in:\n" + "\n".join(self.lines)
                self.cond.wait(left)

    def text(self) -> str:
        self.thread.join(timeout=60)
        return "\n".join(self.lines)


def test_robots_frozen_in_start_up_and_in_trial_1_are_named_and_restarted(ros_env, tmp_path):
    env = {**ros_env, FREEZE_ENV: str(FREEZE)}
    proc = start(env, tmp_path, "paper-triangle3", "--trials", str(TRIALS), "--seed",
                 str(SEED))
    lines = Lines(proc)
    stopped: list[int] = []
    try:
        dom = env["ROS_DOMAIN_ID"]
        # start-up: robot_2 stopped as soon as its process is there (importing, or at
        # the gate), so that the first trial cannot start without it
        first = find_child(dom, "robot_id:=2", time.monotonic() + 120)
        os.kill(first, signal.SIGSTOP)
        stopped.append(first)
        m = lines.wait_for(rf"^robot_2 \(pid {first}\) froze: no heartbeat for \d+ s, "
                           rf"the process idle; last: (.*): stopping it$")
        print("start-up freeze named:", m.group(0))
        lines.wait_for(rf"^robot_2 froze \(pid {first}\): starting it again \(1/")
        assert not (tmp_path / "metrics.csv").exists() or \
            len((tmp_path / "metrics.csv").read_text().splitlines()) <= 1, \
            "robot_2 was stopped after the first trial ended"
        # trial 1: robot_3 stopped once trial 0's row is written
        wait_rows(proc, tmp_path / "metrics.csv", 1, timeout=300)
        second = find_child(dom, "robot_id:=3", time.monotonic() + 10)
        os.kill(second, signal.SIGSTOP)
        stopped.append(second)
        m = lines.wait_for(rf"^robot_3 \(pid {second}\) froze: no heartbeat for \d+ s, "
                           rf"the process idle; last: (.*): stopping it$")
        print("trial-1 freeze named:", m.group(0))
        assert m.group(1) == "spinning", m.group(0)  # it froze inside its executor's loop
        lines.wait_for(rf"^robot_3 froze \(pid {second}\): starting it again \(1/.*; the "
                       rf"trial it interrupted runs again")
        proc.wait(timeout=600)
    finally:
        stop_group(proc)
        for pid in stopped:  # a stopped process left by a failing test: let it end
            try:
                os.kill(pid, signal.SIGCONT)
            except ProcessLookupError:
                pass
    out = lines.text()
    assert proc.returncode == 0, out
    got = read_metrics(tmp_path / "metrics.csv")
    np.testing.assert_array_equal(got[:, 0], np.arange(TRIALS))
    np.testing.assert_allclose(got[:, 1:], batch()[:, 1:], rtol=0, atol=TOL)
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["restarts"] == {"robot_2": 1, "robot_3": 1}, out
    # nobody else was taken for frozen on the way
    assert len(re.findall(r"\) froze: ", out)) == 2, out
