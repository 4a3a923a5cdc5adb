"""The virtual leader's decisions without ROS (formation_ilc.protocol.leader): the start
gate, readies refused and remembered, samples in order, repeated starts, aborts, the
watchdog's reports, retries and give-up, another formation, wall-clock trials, done.

The node around it (virtual_leader.node) is a shell: tests/virtual_leader/ runs it
in-process; the stack tests run it as a process."""

from __future__ import annotations

from typing import Any

import pytest

from formation_ilc.config.runconfig import make_config
from formation_ilc.core.clock import Rejected
from formation_ilc.protocol.leader import ABORT_REPEAT, FIRST_START_WAIT, Leader
from formation_ilc.protocol.plant import RESEND_S
from formation_ilc.protocol.schedule import Ready, TrialEvent
from formation_ilc.protocol.watchdog import STUCK, Bounds

NODES = ["robot_1", "robot_2", "robot_3", "robot_sim", "monitor"]


class FakeIO:
    """The node's side, recorded; its start gate opens when ``gate`` is empty."""

    def __init__(self) -> None:
        self.events: list[TrialEvent] = []
        self.refs: list[tuple[int, int]] = []
        self.diags: list[dict[str, Any]] = []
        self.logs: list[tuple[str, str]] = []
        self.alerts: list[str] = []
        self.drops: list[tuple[str, str]] = []
        self.failed: tuple[str, int] | None = None
        self.rereads = 0
        self.gate: list[str] = []
        self.readers = True
        self.writers = 1

    def publish_event(self, event: TrialEvent) -> None:
        self.events.append(event)

    def publish_reference(self, t: int, stamp_ns: int) -> None:
        self.refs.append((t, stamp_ns))

    def publish_diagnostics(self, report: dict[str, Any]) -> None:
        self.diags.append(report)

    def log(self, level: str, text: str) -> None:
        self.logs.append((level, text))

    def alert(self, text: str) -> None:
        self.alerts.append(text)

    def drop(self, reason: str, topic: str, why: str) -> None:
        self.drops.append((reason, topic))

    def fail(self, text: str, code: int) -> None:
        self.failed = (text, code)

    def reread_readies(self) -> None:
        self.rereads += 1

    def start_gate(self) -> list[str]:
        return list(self.gate)

    def events_read(self) -> bool:
        return self.readers

    def config_writers(self) -> int:
        return self.writers

    def kinds(self) -> list[str]:
        return [e.event for e in self.events]


class Clocks:
    def __init__(self) -> None:
        self.now = 100.0
        self.wall = 1_700_000_000_000_000_000

    def monotonic(self) -> float:
        return self.now

    def wall_ns(self) -> int:
        return self.wall


def leader(mode: str = "lockstep", trials: int = 2, nodes: list[str] | None = None,
           **kw: Any) -> tuple[Leader, FakeIO, Clocks]:
    cfg = make_config("paper-triangle3", trials=trials, mode=mode, monitored=True,
                      links="direct", run_id="rtest")
    io, clk = FakeIO(), Clocks()
    core = Leader(cfg, nodes or NODES, io, namespace="/formation", monotonic=clk.monotonic,
                  wall_ns=clk.wall_ns, **kw)
    return core, io, clk


def all_ready(core: Leader, trial: int = 0, boot: str = "b0", seen: int = -1) -> None:
    for n in core.expected:
        core.on_ready(Ready(n, trial, boot, seen, passive=n == "monitor",
                            run="rtest").to_json())


def started(core: Leader, io: FakeIO, clk: Clocks) -> TrialEvent:
    clk.now += FIRST_START_WAIT
    all_ready(core)
    assert io.kinds() == ["start"], io.events
    return io.events[-1]


def test_the_first_trial_starts_once_all_are_ready_the_gate_is_open_and_discovery_had_time():
    core, io, clk = leader()
    all_ready(core)
    assert io.events == []  # discovery has not had FIRST_START_WAIT yet
    clk.now += FIRST_START_WAIT
    io.gate = ["reference: 0 of 1 readers"]
    core.maybe_start()
    assert io.events == [] and core.start_waits_for() == ["reference: 0 of 1 readers"]
    io.gate = []
    core.maybe_start()
    (ev,) = io.events
    assert (ev.event, ev.trial, ev.slot, ev.seq, ev.run) == ("start", 0, 0, 0, "rtest")
    assert ev.stamp_ns == core.clock.stamp_ns(0, 0) and ev.start_wall_ns is None
    assert core.sched.running and core.t == -1


def test_one_node_missing_holds_the_start_and_is_named():
    core, io, clk = leader()
    clk.now += FIRST_START_WAIT
    for n in NODES[:-2]:
        core.on_ready(Ready(n, 0, "b0").to_json())
    assert io.events == []
    assert any("robot_sim" in w for w in core.start_waits_for())


def test_a_second_formations_leader_before_trial_0_stops_this_one():
    core, io, clk = leader()
    clk.now += FIRST_START_WAIT
    io.writers = 2
    all_ready(core)
    assert io.events == [] and io.failed is not None and io.failed[1] == 2
    assert "another formation's leader" in io.failed[0]


def test_readies_it_refuses_and_remembers():
    core, io, _ = leader()
    with pytest.raises(Rejected, match="not waited for") as info:
        core.on_ready(Ready("robot_9", 0, "b").to_json())
    assert info.value.reason == "unexpected" and "robot_9" not in core.refused
    with pytest.raises(Rejected) as info:
        core.on_ready(Ready("robot_1", 0, "b", run="rother").to_json())
    assert info.value.reason == "foreign" and "robot_1" not in core.refused
    with pytest.raises(Rejected) as info:
        core.on_ready(Ready("robot_1", 5, "b", run="rtest").to_json())
    assert info.value.reason == "future" and core.refused["robot_1"].startswith("future: ")
    assert "robot_1" in " ".join(core.start_waits_for())  # named, with why
    core.on_ready(Ready("robot_1", 0, "b", run="rtest").to_json())
    assert "robot_1" not in core.refused
    # the monitor and the recorder say ready once for the whole run
    core.on_ready(Ready("monitor", 7, "b", passive=True).to_json())
    with pytest.raises(Rejected):
        core.on_ready({"node": 3, "trial": 0})


def test_samples_in_order_get_their_reference_and_sample_t_ends_the_trial():
    core, io, clk = leader(trials=2)
    start = started(core, io, clk)
    T = core.T
    for t in range(3):
        core.on_clock(core.clock.stamp_ns(start.slot, t))
    assert io.refs == [(t, core.clock.stamp_ns(0, t)) for t in range(3)] and core.t == 2
    # the plant sent sample 2 again: its reference again, and the copy is a duplicate
    with pytest.raises(Rejected) as info:
        core.on_clock(core.clock.stamp_ns(0, 2))
    assert info.value.reason == "duplicate" and io.refs[-1] == (2, core.clock.stamp_ns(0, 2))
    for t, reason in ((1, "out_of_order"), (5, "future")):
        with pytest.raises(Rejected) as info:
            core.on_clock(core.clock.stamp_ns(0, t))
        assert info.value.reason == reason
    with pytest.raises(Rejected) as info:
        core.on_clock(core.clock.stamp_ns(1, 0))  # the next slot has not started
    assert info.value.reason == "future"
    for t in range(3, T + 1):
        core.on_clock(core.clock.stamp_ns(0, t))
    assert io.kinds() == ["start", "end"] and io.events[-1].slot == 0
    assert io.diags[-1]["node"] == "virtual_leader" and not core.sched.running
    with pytest.raises(Rejected) as info:
        core.on_clock(core.clock.stamp_ns(0, T))
    assert info.value.reason == "stale"


def test_a_whole_run_ends_with_done_once():
    core, io, clk = leader(trials=2)
    started(core, io, clk)
    for k in range(2):
        for t in range(core.T + 1):
            core.on_clock(core.clock.stamp_ns(k, t))
        all_ready(core, trial=k + 1)
    assert io.kinds() == ["start", "end", "start", "end", "done"]
    assert [e.trial for e in io.events] == [0, 0, 1, 1, 2]
    core.maybe_start()
    assert io.kinds().count("done") == 1 and ("info", "done: 2 trials") in io.logs


def test_a_start_goes_out_again_while_its_slot_does_not_move():
    core, io, clk = leader()
    start = started(core, io, clk)
    core.start_again()
    assert io.kinds() == ["start"]  # not yet
    clk.now += RESEND_S / 2 + 0.01
    core.start_again()
    assert io.events[-1] == start and core.repeat.count == 1
    core.on_clock(core.clock.stamp_ns(0, 0))  # the slot moves: no repeat until it stalls
    core.start_again()
    assert core.repeat.count == 1
    clk.now += RESEND_S / 2 + 0.01
    core.start_again()
    assert core.repeat.count == 2


def test_a_node_restarted_during_a_trial_aborts_it_and_the_abort_is_repeated():
    core, io, clk = leader()
    started(core, io, clk)
    core.on_ready(Ready("robot_2", 0, "b1").to_json())  # a new process: it restarted
    assert io.kinds() == ["start", "abort"] and io.events[-1].slot == 0
    assert core.sched.abort_pending == 0 and core.wall is None
    assert any(level == "warning" and "aborted" in text for level, text in io.logs)
    core.maybe_start()
    assert io.kinds().count("abort") == 1  # too soon to repeat
    clk.now += ABORT_REPEAT + 0.1
    io.readers = False
    core.maybe_start()
    assert io.kinds().count("abort") == 1  # nobody reads the events yet
    io.readers = True
    core.maybe_start()
    assert io.kinds().count("abort") == 2
    # every node answers the abort: the same iteration runs again in the next slot
    for n in NODES:
        core.on_ready(Ready(n, 0, "b1" if n == "robot_2" else "b0", core.sched.seq,
                            passive=n == "monitor").to_json())
    assert io.kinds()[-1] == "start" and io.events[-1].trial == 0 and io.events[-1].slot == 1


def test_a_start_it_did_not_send_is_reasserted():
    core, io, clk = leader()
    started(core, io, clk)
    core.on_event(TrialEvent("start", 0, 7, 99, run="rtest").to_json())
    assert io.drops == [("unexpected", "leader/trial_events")]
    assert io.kinds()[-1] == "abort" and core.sched.foreign_events == 1
    core.on_event(TrialEvent("start", 0, 7, 99, run="rother").to_json())  # another run's
    core.on_event({"event": "nonsense"})
    assert io.drops == [("unexpected", "leader/trial_events")]


def test_another_formations_configuration():
    core, io, clk = leader()
    core.on_config({"run_id": "rtest"})  # its own
    assert io.failed is None and io.drops == []
    started(core, io, clk)
    core.on_config({"run_id": "rother"})  # an established run goes on
    assert io.failed is None and io.drops == [("foreign", "config")]
    fresh, io2, _ = leader()
    fresh.on_config({"run_id": "rother"})
    assert io2.failed is not None and io2.failed[1] == 2 and "run rother" in io2.failed[0]


def test_a_secure_leader_waits_out_its_team_s_handshakes_before_it_acts():
    """Under SROS2 the first start-up may take the pairs' handshakes longer: past the
    insecure bound a secure leader is still quiet, an insecure one already says whom it
    waits for."""
    for secure in (False, True):
        core, io, clk = leader(secure=secure)
        core.on_watchdog()
        plain = Bounds.for_run(core.cfg.scenario.dt, len(core.expected), core.cfg.mode,
                               core.cfg.timeout)
        clk.now += plain.startup + 1
        core.on_watchdog()
        assert (io.alerts == []) == secure, io.alerts
        clk.now += core.watchdog.bounds.startup - plain.startup
        core.on_watchdog()
        assert len(io.alerts) >= 1 and "in start-up (bound" in io.alerts[0], io.alerts


def test_the_watchdog_reports_then_retries_then_gives_up():
    core, io, clk = leader()
    started(core, io, clk)
    core.on_clock(core.clock.stamp_ns(0, 0))
    core.on_watchdog()
    assert io.alerts == []
    bound = core.watchdog.bound("sample")
    clk.now += bound + 1
    core.on_watchdog()
    assert len(io.alerts) == 1 and "no new sample" in io.alerts[0]
    assert io.diags[-1]["watchdog"]["count"] == 1
    for _ in range(20):
        if io.failed is not None:
            break
        clk.now += bound + 1
        core.on_watchdog()
    assert "abort" in io.kinds()  # a stuck slot is aborted to run again
    assert io.failed is not None and io.failed[1] == STUCK
    assert io.failed[0].startswith("stuck: ") and "giving up" in io.alerts[-1]


def test_the_watchdog_reads_the_readies_anew_between_trials():
    core, io, clk = leader()
    clk.now += FIRST_START_WAIT
    for n in NODES[:-1]:
        core.on_ready(Ready(n, 0, "b0").to_json())
    bound = core.watchdog.bound(core.phase())
    for _ in range(4):
        clk.now += bound + 1
        core.on_watchdog()
    assert io.rereads >= 1 and "monitor" in io.alerts[0]


def test_report_wait_names_whom_it_waits_for():
    core, io, clk = leader()
    core.report_wait()
    assert io.logs == []  # it has not waited long
    clk.now += 6.0
    core.report_wait()
    assert io.logs[-1][0] == "warning" and "waits for ready from robot_1" in io.logs[-1][1]
    io.gate = ["/clock: 0 of 1 writers"]
    all_ready(core)
    clk.now += 6.0
    core.report_wait()
    assert io.logs[-1] == ("warning", "trial 0: waiting for /clock: 0 of 1 writers")
    io.gate = []
    core.maybe_start()
    clk.now += 6.0
    core.report_wait()
    assert io.logs[-1] == ("warning", "trial 0 (slot 0) has not ended (last clock: None)")


def test_wall_clock_trials_agree_a_start_and_follow_the_wall_timer():
    core, io, clk = leader(mode="wallclock", nodes=["robot_1", "robot_2", "robot_3",
                                                    "bridge_1", "bridge_2", "bridge_3"],
                           start_margin=1.0)
    start = started(core, io, clk)
    assert start.start_wall_ns is not None and start.start_wall_ns >= clk.wall + 10**9
    assert start.start_wall_ns == core.clock.stamp_ns(start.slot, 0)
    core.on_wall_timer()
    assert io.refs == []  # sample 0 is not due yet
    dt_ns = core.clock.dt_ns
    clk.wall = start.start_wall_ns + 2 * dt_ns + 1  # the timer fell behind: the newest only
    core.on_wall_timer()
    assert io.refs == [(2, start.start_wall_ns + 2 * dt_ns)]
    clk.wall = start.start_wall_ns + core.T * dt_ns
    core.on_wall_timer()
    assert io.refs[-1][0] == core.T and io.kinds() == ["start", "end"] and core.wall is None


def test_a_leader_goes_on_from_its_state_file(tmp_path):
    state = tmp_path / "leader.json"
    core, io, clk = leader(state_file=state)
    assert core.restored is None
    started(core, io, clk)
    again, _, _ = leader(state_file=state)
    assert again.restored is not None and "slot 0 was open and is aborted" in again.restored
    state.write_text('{"committed": 999, "slot": 999, "seq": 999, "open": false}')
    with pytest.raises(ValueError, match="remove the file"):
        leader(state_file=state)


def test_a_node_that_runs_another_configuration_is_named_with_both_values_and_stops_the_run():
    """A robot started from its own parameters says in its ready what it runs; the leader
    compares it with its own configuration and stops (status 2) naming the field and both
    values; a node that runs the same is taken."""
    core, io, clk = leader()
    clk.now += FIRST_START_WAIT
    same = core.cfg.agreement()
    core.on_ready(Ready("robot_1", 0, "b0", run="rtest", config=same).to_json())
    assert io.failed is None and "robot_1" not in core.refused
    other = make_config("paper-triangle3", links="emulated", seed=7).agreement()
    with pytest.raises(Rejected):
        core.on_ready(Ready("robot_2", 0, "b0", run="rtest", config=other).to_json())
    text, code = io.failed
    assert code == 2
    assert "seed: robot_2 runs 7, virtual_leader 1" in text
    assert "links: robot_2 runs emulated, virtual_leader direct" in text
    assert io.events == []  # no trial starts with robot_2's ready
    # a bridge says only what it runs with; a ready's config is bounded
    bridge = {k: same[k] for k in ("scenario", "scenario_text", "mode", "gap")}
    assert Ready.from_json(Ready("bridge_1", 0, config=bridge).to_json()).config == bridge
    with pytest.raises(Rejected):
        Ready.from_json({"node": "robot_1", "trial": 0, "config": {str(i): i for i in range(40)}})


def test_a_first_start_up_that_cannot_complete_names_the_endpoints_and_stops_within_its_bound():
    # robot_2 never matches its pose's writer: it says so in its diagnostics (waiting);
    # the leader's first start-up has no retries: past the bound it names robot_2 with
    # what it waits for and reads the readies anew, a quarter bound later it gives up
    core, io, clk = leader()
    core.on_waiting({"node": "robot_2", "waiting": ["/formation/robot_2/pose: 0 of 1 writers"]})
    core.on_waiting({"node": "stranger", "waiting": ["x"]})  # not waited for: ignored
    core.on_waiting({"node": "robot_3", "waiting": "not a list"})  # malformed: ignored
    assert core.waiting == {"robot_2": "/formation/robot_2/pose: 0 of 1 writers"}
    clk.now += FIRST_START_WAIT
    for n in NODES:
        if n != "robot_2":
            core.on_ready(Ready(n, 0, "b0", passive=n == "monitor", run="rtest").to_json())
    bound = core.watchdog.bound(core.phase())
    clk.now += bound + 1
    core.on_watchdog()
    assert len(io.alerts) == 1 and io.failed is None and io.rereads == 1
    assert ("robot_2 has not said ready (never seen); it waits for "
            "/formation/robot_2/pose: 0 of 1 writers") in io.alerts[0], io.alerts
    assert "reading the readies anew" in io.alerts[0]
    clk.now += 0.25 * bound + 1
    core.on_watchdog()
    assert io.failed is not None and io.failed[1] == STUCK
    assert "the readies read anew once without progress" in io.failed[0], io.failed
    # the give-up names the whole wait, not only its last quarter bound
    assert (f"(bound {bound:.0f} s, then {0.25 * bound:.0f} s after reading the readies "
            f"anew)") in io.failed[0], io.failed


def test_a_nodes_first_ready_is_progress_of_the_start_up_and_ends_its_waiting_report():
    core, io, clk = leader()
    core.on_waiting({"node": "robot_1", "waiting": ["/formation/robot_1/cmd_vel: 0 of 1 readers"]})
    bound = core.watchdog.bound(core.phase())
    clk.now += 0.9 * bound
    core.on_ready(Ready("robot_1", 0, "b0", run="rtest").to_json())
    assert "robot_1" not in core.waiting
    clk.now += 0.9 * bound  # 1.8 bounds since the leader began, 0.9 since the last ready
    core.on_watchdog()
    assert io.alerts == [] and io.failed is None
