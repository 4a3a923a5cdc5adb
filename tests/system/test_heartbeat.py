"""Heartbeats (formation_ilc.system.heartbeat): a process that stops beating with its main
thread idle is frozen after the bound, one whose main thread is busy only after the longer
bound, one that beats never; the supervisor names a frozen process, kills it and starts
it again like a crashed one."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

from formation_ilc.system.heartbeat import BEAT_ENV, Board, beat

BEATER = ("from formation_ilc.system.heartbeat import beat\n"
          "import time\n"
          "beat('warming up')\n"
          "while True:\n"
          "    beat('looping')\n"
          "    time.sleep(0.05)\n")
#: beats once, then works without beating (a main thread that never returns)
BUSY = ("from formation_ilc.system.heartbeat import beat\n"
        "beat('computing')\n"
        "while True:\n"
        "    pass\n")
#: beats once, then its main thread waits on a thread that works (as a main thread waits
#: on a lock a DDS thread holds while it processes discovery)
WAITING = ("from formation_ilc.system.heartbeat import beat\n"
           "import threading\n"
           "beat('creating a publisher')\n"
           "def work():\n"
           "    while True:\n"
           "        sum(range(10000))\n"
           "t = threading.Thread(target=work)\n"
           "t.start()\n"
           "t.join()\n")


def _child(board: Board, name: str, code: str) -> subprocess.Popen[bytes]:
    env = {**os.environ, BEAT_ENV: board.slot(name)}
    p = subprocess.Popen([sys.executable, "-c", code], env=env)
    board.started(name, p.pid)
    return p


def _wait_beats(board: Board, name: str, n: int, timeout: float = 60.0) -> None:
    deadline = time.monotonic() + timeout
    while board.beats(name) < n:
        assert time.monotonic() < deadline, f"{name} never beat {n} times"
        time.sleep(0.02)  # polling the board, bounded by the deadline


def test_beat_without_a_slot_is_nothing(monkeypatch):
    monkeypatch.delenv(BEAT_ENV, raising=False)
    beat("anything")  # no supervisor: no error, nothing written


def test_a_stopped_process_is_frozen_a_busy_one_later_a_beating_one_never(tmp_path):
    board = Board(tmp_path / "heartbeats", freeze_s=1.5, every=0.1)
    procs = {"stopped": _child(board, "stopped", BEATER),
             "beating": _child(board, "beating", BEATER),
             "busy": _child(board, "busy", BUSY),
             "waiting": _child(board, "waiting", WAITING)}
    try:
        for name in procs:
            _wait_beats(board, name, 1 if name in ("busy", "waiting") else 2)
        os.kill(procs["stopped"].pid, signal.SIGSTOP)
        stopped_at = time.monotonic()
        alive = {n: p.pid for n, p in procs.items()}
        seen: dict[str, tuple[float, object]] = {}
        deadline = time.monotonic() + 120
        while not {"busy", "waiting"} <= set(seen):  # the longest bound (8 x 1.5 s)
            assert time.monotonic() < deadline, seen
            for f in board.frozen(alive):
                seen.setdefault(f.name, (time.monotonic(), f))
            time.sleep(0.05)  # the board looks every 0.1 s
        assert "beating" not in seen
        when, stopped = seen["stopped"]
        assert 1.5 <= when - stopped_at < board.busy_s, when - stopped_at
        assert stopped.pid == procs["stopped"].pid and stopped.idle  # type: ignore[attr-defined]
        assert stopped.doing == "looping"  # type: ignore[attr-defined]
        assert "stopped (pid " in stopped.line() and "last: looping" in stopped.line()  # type: ignore[attr-defined]
        busy_when, busy = seen["busy"]
        # its main thread works all along: not frozen before the longer bound
        assert busy_when - stopped_at >= board.busy_s - 1.0
        assert not busy.idle and busy.doing == "computing"  # type: ignore[attr-defined]
        # its main thread waits, another of its threads works: not before it either
        waiting_when, waiting = seen["waiting"]
        assert waiting_when - stopped_at >= board.busy_s - 1.0
        assert not waiting.idle  # type: ignore[attr-defined]
        assert waiting.doing == "creating a publisher"  # type: ignore[attr-defined]
    finally:
        for p in procs.values():
            p.kill()
            p.wait(timeout=30)
        board.close()


def test_nothing_is_judged_while_the_gate_holds(tmp_path):
    board = Board(tmp_path / "heartbeats", freeze_s=0.5, every=0.1)
    p = _child(board, "waiting", "import time; time.sleep(60)")  # never beats
    try:
        board.hold(True)
        t0 = time.monotonic()
        while time.monotonic() - t0 < 1.5:
            assert board.frozen({"waiting": p.pid}) == []
            time.sleep(0.1)
        board.hold(False)
        deadline = time.monotonic() + 60
        found: list = []
        while not found:
            assert time.monotonic() < deadline
            found = board.frozen({"waiting": p.pid})
            time.sleep(0.1)
        assert found[0].name == "waiting" and found[0].doing == ""
    finally:
        p.kill()
        p.wait(timeout=30)
        board.close()


def test_a_command_that_never_beats_is_watched_only_once_it_beats(tmp_path):
    """A process not started through the node runner (a plain command) may never beat:
    it is not taken for frozen for that."""
    board = Board(tmp_path / "heartbeats", freeze_s=0.3, every=0.1)
    env = {**os.environ, BEAT_ENV: board.slot("plain")}
    p = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"], env=env)
    board.started("plain", p.pid, watch=False)
    try:
        t0 = time.monotonic()
        while time.monotonic() - t0 < 1.5:
            assert board.frozen({"plain": p.pid}) == []
            time.sleep(0.1)
    finally:
        p.kill()
        p.wait(timeout=30)
        board.close()


def test_the_supervisor_names_kills_and_restarts_a_frozen_process(tmp_path, capsys):
    from formation_ilc.cli.supervisor import Supervisor
    from tests.cli.test_plan import _plan_running

    plan, codes = _plan_running(tmp_path, BEATER, BEATER)
    sup = Supervisor(plan, dict(os.environ),
                     place=lambda s: [sys.executable, "-c", codes[s.name]])
    sup.stack.board.freeze_s, sup.stack.board.every = 1.0, 0.1
    sup.start()
    try:
        _wait_beats(sup.stack.board, "p1", 2)
        first = sup.stack.procs["p1"].pid
        os.kill(first, signal.SIGSTOP)
        deadline = time.monotonic() + 120
        while sup.restarts.get("p1", 0) < 1:
            assert time.monotonic() < deadline
            assert sup.watch() is None
            time.sleep(0.05)
        assert sup.stack.procs["p1"].pid != first
        _wait_beats(sup.stack.board, "p1", 2)  # the new one beats in the same slot
        assert sup.restarts == {"p1": 1}
    finally:
        sup.stop()
    out = capsys.readouterr().out
    assert f"p1 (pid {first}) froze: no heartbeat for " in out, out
    assert "the process idle; last: looping: stopping it" in out, out
    assert f"p1 froze (pid {first}): starting it again (1/2)" in out, out
    assert "beats again" not in out, out
    log = (plan.out / "logs" / "p1.log").read_text()
    assert "stopped by the launcher" in log and "--- restarted (1) ---" in log


def test_a_process_that_worked_through_a_silence_is_said_late_not_frozen(tmp_path):
    """Its main thread waits past the bound on a thread that works (as on a Fast DDS lock
    while discovery runs), then beats again: it is not frozen, and the board says how long
    it was silent."""
    board = Board(tmp_path / "heartbeats", freeze_s=1.0, every=0.1)
    code = ("from formation_ilc.system.heartbeat import beat\n"
            "import threading, time\n"
            "beat('first')\n"
            "def work(end):\n"
            "    while time.monotonic() < end:\n"
            "        sum(range(10000))\n"
            "t = threading.Thread(target=work, args=(time.monotonic() + 2.5,))\n"
            "t.start()\n"
            "t.join()\n"
            "beat('back')\n"
            "time.sleep(60)\n")
    p = _child(board, "slow", code)
    try:
        _wait_beats(board, "slow", 1)
        deadline = time.monotonic() + 60
        while not board.late:
            assert time.monotonic() < deadline
            assert board.frozen({"slow": p.pid}) == []
            time.sleep(0.05)
        (name, silent, doing), = board.late
        assert name == "slow" and silent >= 1.0 and doing == "back"
    finally:
        p.kill()
        p.wait(timeout=30)
        board.close()


def test_a_process_that_stops_while_it_starts_has_the_longer_bound(tmp_path):
    """Stopped while it builds its node (where a starting node waits, idle, on Fast DDS's
    locks between processes): frozen only after STARTUP_FACTOR times the bound."""
    from formation_ilc.system.heartbeat import STARTUP_FACTOR

    board = Board(tmp_path / "heartbeats", freeze_s=0.5, every=0.1)
    p = _child(board, "starting", "from formation_ilc.system.heartbeat import beat\n"
                                  "import time\n"
                                  "beat('building its node')\n"
                                  "time.sleep(60)\n")
    try:
        _wait_beats(board, "starting", 1)
        t0 = time.monotonic()
        deadline = t0 + 60
        found: list = []
        while not found:
            assert time.monotonic() < deadline
            found = board.frozen({"starting": p.pid})
            time.sleep(0.05)
        assert time.monotonic() - t0 >= STARTUP_FACTOR * 0.5 - 0.2
        assert found[0].idle and found[0].doing == "building its node"
    finally:
        p.kill()
        p.wait(timeout=30)
        board.close()


def test_a_frozen_process_that_ignores_sigterm_is_killed(tmp_path, capsys):
    """A frozen process is continued and terminated first (one stopped by a signal then
    ends cleanly, its Fast DDS locks freed); one that does not end (deadlocked: here it
    ignores SIGTERM) gets SIGKILL after the grace, and is started again all the same."""
    from formation_ilc.cli.supervisor import Supervisor
    from tests.cli.test_plan import _plan_running

    stuck = ("from formation_ilc.system.heartbeat import beat\n"
             "import signal, threading\n"
             "signal.signal(signal.SIGTERM, signal.SIG_IGN)\n"
             "beat('waiting for ever')\n"
             "threading.Event().wait()\n")
    plan, codes = _plan_running(tmp_path, BEATER, stuck)
    sup = Supervisor(plan, dict(os.environ),
                     place=lambda s: [sys.executable, "-c", codes[s.name]])
    sup.stack.board.freeze_s, sup.stack.board.every = 1.0, 0.1
    sup.start()
    try:
        _wait_beats(sup.stack.board, "p1", 1)
        first = sup.stack.procs["p1"]
        deadline = time.monotonic() + 120
        while sup.restarts.get("p1", 0) < 1:
            assert time.monotonic() < deadline
            assert sup.watch() is None
            time.sleep(0.05)
        assert first.returncode == -signal.SIGKILL
    finally:
        sup.stop()
    out = capsys.readouterr().out
    assert f"p1 (pid {first.pid}) froze: no heartbeat for " in out, out
    assert "last: waiting for ever: stopping it" in out, out


def test_a_start_up_silence_within_its_longer_bound_is_not_said(tmp_path):
    """A node importing for longer than the bound (a loaded machine) is no news: only a
    silence past the bound that applies to what it said is."""
    board = Board(tmp_path / "heartbeats", freeze_s=0.5, every=0.1)
    p = _child(board, "importer", "from formation_ilc.system.heartbeat import beat\n"
                                  "import time\n"
                                  "beat('importing')\n"
                                  "time.sleep(1.2)\n"
                                  "beat('spinning')\n"
                                  "time.sleep(60)\n")
    try:
        deadline = time.monotonic() + 60
        while board.doing("importer") != "spinning":
            assert time.monotonic() < deadline
            assert board.frozen({"importer": p.pid}) == []
            time.sleep(0.05)
        time.sleep(0.2)
        board.frozen({"importer": p.pid})
        assert board.late == []
    finally:
        p.kill()
        p.wait(timeout=30)
        board.close()


def test_a_team_process_that_spins_unseen_by_the_graph_is_started_again(tmp_path, capsys):
    """Start-up: a node that spins (its executor runs, it beats) but that no node of the
    team discovered is named and started again once it has spun for the bound; one the
    graph shows is left alone."""
    from formation_ilc.cli.supervisor import Supervisor
    from tests.cli.test_plan import _plan_running

    spinner = ("from formation_ilc.system.heartbeat import beat\n"
               "import time\n"
               "while True:\n"
               "    beat('spinning')\n"
               "    time.sleep(0.05)\n")
    plan, codes = _plan_running(tmp_path, spinner, spinner)
    sup = Supervisor(plan, dict(os.environ),
                     place=lambda s: [sys.executable, "-c", codes[s.name]])
    sup.team = {"p0", "p1"}
    sup.start()
    try:
        _wait_beats(sup.stack.board, "p1", 2)
        first = sup.stack.procs["p1"].pid
        deadline = time.monotonic() + 120
        while sup.restarts.get("p1", 0) < 1:
            assert time.monotonic() < deadline
            sup.unseen({"p0"}, bound=1.0)  # p0 is in the graph, p1 is not
            assert sup.watch() is None
            time.sleep(0.05)
        assert sup.restarts == {"p1": 1}
    finally:
        sup.stop()
    out = capsys.readouterr().out
    assert f"p1 (pid {first}) has spun 1 s and is not in the ROS graph" in out, out
    assert f"p1 was not in the graph (pid {first}): starting it again (1/2)" in out, out
    assert "p0 (pid" not in out, out
    assert "is not in the ROS graph" in (plan.out / "logs" / "p1.log").read_text()
