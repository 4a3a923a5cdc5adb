"""The launch plan, built from the options without ROS: what runs (node specs, in order,
with their parameters), what is refused (one line, the exit status), and what ``--resume``
takes back; and the supervisor's restart policy on plain processes."""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys

import pytest
import yaml

from formation_ilc.cli.commands import build_parser
from formation_ilc.cli.runfile import plan_of as plan_of_args
from formation_ilc.config.runconfig import RunConfig
from formation_ilc.plan.specs import NO_RESTART, NoRun, RunPlan, finished


def options(*argv: str):
    return build_parser().parse_args(["launch", *argv])


def plan_of(tmp_path, *argv: str, out: str = "run") -> RunPlan:
    return plan_of_args(options(*argv, "--out", str(tmp_path / out)))


def refusal(tmp_path, *argv: str) -> NoRun:
    with pytest.raises(NoRun) as info:
        plan_of(tmp_path, *argv)
    return info.value


def params(spec) -> dict:
    return dict(spec.params)


def test_a_simulated_run_plans_one_process_per_node(tmp_path):
    plan = plan_of(tmp_path, "paper-triangle3", "--trials", "5", "--seed", "3",
                   "--domain-id", "42")
    assert [s.name for s in plan.nodes] == ["virtual_leader", "robot_sim", "link_emulator",
                                            "robot_1", "robot_2", "robot_3"]
    assert plan.out == (tmp_path / "run").resolve() and plan.out.is_dir()
    assert plan.domain == 42 and plan.namespace == "/formation"
    assert plan.config.mode == "lockstep" and plan.config.links == "emulated"
    assert plan.config.monitored and plan.config.run_id.startswith("r")
    assert plan.team.expected == ["robot_1", "robot_2", "robot_3", "robot_sim",
                                  "link_emulator", "monitor"]
    leader = plan.nodes[0]
    assert leader.command[1:3] == ["-m", "virtual_leader.node"]
    assert params(leader)["nodes_expected"] == plan.team.expected
    assert params(leader)["state_dir"] == str(plan.out / "state")
    # the leader's parameters are the run configuration's, and give it back
    cfg = RunConfig.from_params({k: v for k, v in params(leader).items()
                                 if k not in ("state_dir", "nodes_expected")})
    assert cfg.to_json() == plan.config.to_json()
    robot = plan.nodes[3]
    assert "robot_id:=1" in robot.command and robot.host is None
    assert params(robot) == {"robot_id": 1, "state_dir": str(plan.out / "state")}
    assert params(plan.nodes[1]) == {"timeout": 30.0}
    assert all(s.restart.max_restarts == 3 and s.restart.refused == NO_RESTART
               for s in plan.nodes)
    assert plan.run_json is not None and plan.resumed_at is None
    assert plan.reporters == ("robot_sim", "link_emulator")


def test_every_parameter_on_a_command_line_reads_back_as_given(tmp_path):
    plan = plan_of(tmp_path, "paper-triangle3", "--record", str(tmp_path / "r.mcap"),
                   "--namespace", "/team2", "--container", "2")
    for spec in plan.nodes:
        argv = spec.command
        assert argv[0] == sys.executable
        got = {a.split(":=", 1)[0]: yaml.safe_load(a.split(":=", 1)[1])
               for flag, a in zip(argv, argv[1:], strict=False) if flag == "-p"}
        assert got == {k: list(v) if isinstance(v, tuple) else v for k, v in spec.params}
        assert "__ns:=/team2" in argv and "/clock:=/team2/clock" in argv
    names = [s.name for s in plan.nodes]
    assert names == ["recorder", "virtual_leader", "robot_sim", "link_emulator",
                     "robots_1-2", "robots_3-3"]
    rec = plan.nodes[0]
    assert rec.passive and rec.command[3:5] == ["--output", str(tmp_path / "r.mcap")]
    assert plan.nodes[4].command[3:6] == ["--robots", "1", "2"]
    assert plan.team.passive == ("monitor", "recorder")
    assert plan.reporters[-1] == "recorder"


def test_real_robots_plan_bridges_and_fake_drivers(tmp_path):
    plan = plan_of(tmp_path, "paper-triangle3", "--plant", "pioneer", "--fake-drivers",
                   "--driver", "ros2aria", "--driver-ns", "/p{i}", "--cmd-type",
                   "twist_stamped", "--return-timeout", "40")
    assert plan.config.mode == "wallclock" and plan.config.links == "direct"
    assert [s.name for s in plan.nodes] == [
        "virtual_leader", "fake_pioneer_1", "bridge_1", "fake_pioneer_2", "bridge_2",
        "fake_pioneer_3", "bridge_3", "robot_1", "robot_2", "robot_3"]
    fake, bridge = plan.nodes[3], plan.nodes[4]
    assert fake.remaps == ("-r", "__ns:=/p2")
    assert params(fake) == {"seed": 2, "cmd_type": "twist_stamped", "driver": "ros2aria"}
    assert params(bridge) == {"robot_id": 2, "driver_ns": "/p2", "cmd_type": "twist_stamped",
                              "driver": "ros2aria", "return_timeout": 40.0}
    assert plan.team.plants == ("bridge_1", "bridge_2", "bridge_3")
    assert plan.final_wait == 3.0 + 40.0 + 2.0 and not plan.true_state
    assert plan.reporters == ("bridge_1", "bridge_2", "bridge_3")


@pytest.mark.parametrize(("extra", "sent", "bridge_has"), [
    ((), "twist_stamped", None),                       # Jazzy's TurtleBot 3: stamped
    (("--cmd-type", "twist"), "twist", "twist"),       # enable_stamped_cmd_vel false
])
def test_a_base_sends_its_presets_command_type_unless_another_is_asked(
        tmp_path, extra, sent, bridge_has):
    plan = plan_of(tmp_path, "paper-triangle3", "--plant", "base", "--base", "turtlebot3",
                   "--physics-bases", "--time-scale", "2.3", *extra)
    bridge = next(s for s in plan.nodes if s.name == "bridge_1")
    bases = next(s for s in plan.nodes if s.name == "physics_bases")
    assert params(bridge).get("cmd_type") == bridge_has
    assert params(bases)["cmd_type"] == sent


def test_an_initial_memory_reaches_every_robot_by_its_absolute_path(tmp_path, monkeypatch):
    from formation_ilc.cli import main

    monkeypatch.chdir(tmp_path)
    assert main(["simulate", "paper-triangle3", "--trials", "1", "--no-plots", "--out",
                 "sim"]) == 0
    plan = plan_of(tmp_path, "paper-triangle3", "--init-memory", "sim/memory.npz")
    robot = plan.nodes[-1]
    assert params(robot)["init_memory"] == str(tmp_path / "sim" / "memory.npz")
    assert str(plan.init_memory) == "sim/memory.npz"  # as given, for summary.json


@pytest.mark.parametrize(("argv", "message"), [
    (["--plant", "pioneer", "--mode", "lockstep"],
     "--plant pioneer runs --mode wallclock with --links direct (real robots have no "
     "simulated clock and no link emulator), got --mode lockstep --links None"),
    (["--plant", "pioneer", "--links", "emulated"], "got --mode None --links emulated"),
    (["--mode", "wallclock"], "--mode wallclock is for real robots: use it with --plant "
                              "pioneer"),
    (["--fake-drivers"], "--fake-drivers goes with --plant pioneer"),
    (["--lifecycle"], "argument --lifecycle: --plant sim does not use it (it goes with "
                      "--plant pioneer or base)"),
    (["--plant", "pioneer", "--fake-drivers", "--driver", "p2os2"],
     "--fake-drivers speak rosaria or ros2aria, not p2os2"),
    (["--max-restarts", "-1"], "--max-restarts must be >= 0"),
    (["--namespace", "team2"], "--namespace 'team2': an absolute ROS namespace like /team2 "
                               "is required"),
    (["--net-loss", "0.05"], "--net-delay-ms, --net-jitter-ms, --net-loss and --dds-profile "
                             "go with --hosts netns"),
    (["--hosts", "netns", "--net-loss", "1.5"], "--net-loss: a fraction in [0, 1) is "
                                                "required, got 1.5"),
    (["--hosts", "netns", "--container", "3"], "--hosts netns runs one process per robot"),
    # the run configuration's own rule, refused in one line (it was a traceback)
    (["--plant", "external", "--mode", "wallclock", "--links", "emulated"],
     "launch: mode wallclock needs links direct"),
])
def test_refusals_are_one_line_with_status_2(tmp_path, argv, message):
    exc = refusal(tmp_path, "paper-triangle3", *argv)
    assert exc.status == 2 and message in exc.message and "\n" not in exc.message


def test_refusals_come_before_anything_is_made(tmp_path):
    refusal(tmp_path, "paper-triangle3", "--fake-drivers")
    assert not (tmp_path / "run").exists()


def test_without_root_robots_on_hosts_are_refused(tmp_path, monkeypatch):
    monkeypatch.setattr(os, "geteuid", lambda: 1000)
    exc = refusal(tmp_path, "paper-triangle3", "--hosts", "netns")
    assert exc.message.startswith("--hosts netns: needs root") and exc.status == 2


def test_a_memory_for_another_team_is_refused(tmp_path):
    from formation_ilc.cli import main

    assert main(["simulate", "paper-hexagon6", "--trials", "1", "--no-plots", "--out",
                 str(tmp_path / "sim")]) == 0
    exc = refusal(tmp_path, "paper-triangle3", "--init-memory",
                  str(tmp_path / "sim" / "memory.npz"))
    assert exc.message.startswith("--init-memory ") and "learned for another run" in exc.message


def test_a_scenario_is_required(tmp_path):
    with pytest.raises(NoRun, match=r"a SCENARIO is required \(or --resume DIR\)"):
        plan_of_args(options())


def test_the_options_are_not_changed_and_run_json_holds_what_resume_needs(tmp_path):
    # (real Pioneers at the paper's spacing touch in a cold start: allowed, to plan it)
    args = options("paper-triangle3", "--out", str(tmp_path / "run"), "--plant", "pioneer",
                   "--allow-contact")
    before = dict(vars(args))
    plan = plan_of_args(args)
    assert vars(args) == before
    d = plan.run_json
    assert d["mode"] == "wallclock" and d["links"] == "direct"
    assert d["out"] == str(plan.out) and d["run_id"] == plan.config.run_id
    assert "command" not in d and "resume" not in d
    json.dumps(d)  # written as JSON


def test_resume_takes_the_runs_own_options(tmp_path):
    from formation_ilc.cli.launch import _save_run

    first = plan_of(tmp_path, "paper-triangle3", "--trials", "6", "--seed", "4",
                    "--record", str(tmp_path / "rec.mcap"))
    _save_run(first.out, first.run_json, first)
    (tmp_path / "rec.mcap").write_bytes(b"")
    # an option of the run given again is refused, not silently ignored (it was)
    with pytest.raises(NoRun) as exc:
        plan_of_args(options("--resume", str(first.out), "--max-restarts", "1", "--seed", "9"))
    assert exc.value.status == 2 and exc.value.message.startswith(
        "--resume takes the run's own options: --seed cannot change a run going on")
    # the launch's own options are honoured: --domain-id among them (it was ignored)
    again = plan_of_args(options("--resume", str(first.out), "--max-restarts", "1",
                               "--domain-id", "77"))
    assert again.config.to_json() == first.config.to_json()  # seed 4, same run id
    assert again.resumed_at == 0 and again.run_json is None
    assert again.max_restarts == 1 and again.out == first.out and again.domain == 77
    assert again.record == (tmp_path / "rec.resumed1.mcap").resolve()


def test_resume_refusals(tmp_path):
    exc = refusal(tmp_path, "--resume", str(tmp_path))
    assert exc.status == 2 and exc.message == (
        f"--resume {tmp_path}: no run.yaml or run.json there (not the output folder of a "
        f"`formation-ilc launch` run)")
    (tmp_path / "run.json").write_text("{not json")
    assert "run.json: unreadable:" in refusal(tmp_path, "--resume", str(tmp_path)).message
    (tmp_path / "run.json").write_text("{}")
    assert refusal(tmp_path, "paper-triangle3", "--resume", str(tmp_path)).message == (
        "--resume takes the run's own scenario and options: give no SCENARIO")


def test_resuming_a_finished_run_is_nothing_to_do(tmp_path, capsys):
    from formation_ilc.cli.launch import _save_run
    from formation_ilc.protocol.schedule import Schedule

    first = plan_of(tmp_path, "paper-triangle3", "--trials", "2")
    _save_run(first.out, first.run_json, first)
    s = Schedule(["robot_1"], {"robot_1"}, 2)
    s.committed = 2
    (first.out / "state").mkdir()
    s.save(first.out / "state" / "leader.json")
    with pytest.raises(NoRun) as info:
        plan_of_args(options("--resume", str(first.out)))
    assert info.value.status == 0
    assert info.value.report() == 0
    assert capsys.readouterr().out == f"{first.out}: all 2 trials are done; nothing to resume\n"


def test_a_run_is_finished_when_every_last_report_and_the_leaders_done_are_in(tmp_path):
    plan = plan_of(tmp_path, "paper-triangle3", "--trials", "4", "--record",
                   str(tmp_path / "r.mcap"))
    last = {"trial": 3}
    diag = {n: last for n in ("robot_1", "robot_2", "robot_3", "robot_sim", "link_emulator",
                              "recorder")}
    done = [{"event": "start"}, {"event": "done"}]
    assert finished(plan, diag, done)
    assert not finished(plan, diag, done[:1])
    for node in diag:
        assert not finished(plan, {**diag, node: {"trial": 2}}, done), node
        assert not finished(plan, {k: v for k, v in diag.items() if k != node}, done), node


def test_a_plan_is_built_without_ros(tmp_path):
    code = (
        "import sys\n"
        "for m in ('rclpy', 'rclpy.node', 'geometry_msgs', 'nav_msgs', 'std_msgs'):\n"
        "    sys.modules[m] = None\n"
        "from formation_ilc.cli.commands import build_parser\n"
        "from formation_ilc.cli.runfile import plan_of\n"
        f"a = build_parser().parse_args(['launch', 'paper-triangle3', '--out', "
        f"{str(tmp_path / 'run')!r}])\n"
        "print(len(plan_of(a).nodes))\n"
    )
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=120)
    assert res.returncode == 0, res.stderr
    assert res.stdout.strip() == "6"


# --------------------------------------------------------------------------- supervisor
def _plan_running(tmp_path, *codes: str, max_restarts: int = 2) -> tuple[RunPlan, dict]:
    """A plan whose processes are plain Python one-liners."""
    from dataclasses import replace

    from formation_ilc.plan.specs import NodeSpec, RestartPolicy

    plan = plan_of(tmp_path, "paper-triangle3")
    policy = RestartPolicy(max_restarts)
    nodes = tuple(NodeSpec(f"p{i}", "x", restart=policy, passive=i == 0)
                  for i in range(len(codes)))
    return replace(plan, nodes=nodes), dict(zip((n.name for n in nodes), codes, strict=True))


def test_the_supervisor_restarts_within_the_policy(tmp_path, capsys):
    from formation_ilc.cli.supervisor import Supervisor

    plan, codes = _plan_running(tmp_path, "raise SystemExit(1)", "import time; "
                                "time.sleep(60)")
    downs = []
    sup = Supervisor(plan, dict(os.environ),
                     place=lambda s: [sys.executable, "-c", codes[s.name]],
                     on_down=lambda name, pid: downs.append(name))
    sup.start()
    try:
        failure = None
        while failure is None:
            sup.stack.procs["p0"].wait(timeout=30)
            failure = sup.watch()
        assert failure.spec.name == "p0" and failure.code == 1 and failure.status == 1
        assert sup.restarts == {"p0": 2} and downs == ["p0", "p0"]
        assert sup.report(failure) == 1
    finally:
        sup.stop()
    cap = capsys.readouterr()
    assert "p0 exited with status 1: starting it again (1/2)" in cap.out
    assert "; the trial it interrupted" not in cap.out  # p0 is passive
    assert "error: node process p0 exited with status 1 after 2 restarts (log: " in cap.err
    assert sup.stack.procs["p1"].poll() is not None  # stopped


def test_the_supervisor_says_down_for_an_active_process_it_starts_again(tmp_path):
    """Every restart is announced (the launcher's monitor then says the node is down, and
    the readers of shared topics free its name for its successor's participant:
    protocol.writers), not only a passive process's."""
    from formation_ilc.cli.supervisor import Supervisor

    plan, codes = _plan_running(tmp_path, "import time; time.sleep(60)",
                                "raise SystemExit(1)", max_restarts=1)
    downs = []
    sup = Supervisor(plan, dict(os.environ),
                     place=lambda s: [sys.executable, "-c", codes[s.name]],
                     on_down=lambda name, pid: downs.append((name, pid)))
    sup.start()
    try:
        first = sup.stack.procs["p1"].pid
        failure = None
        while failure is None:
            sup.stack.procs["p1"].wait(timeout=30)
            failure = sup.watch()
        assert failure.spec.name == "p1" and not failure.spec.passive
        assert downs == [("p1", first)]  # the pid of the process that died
    finally:
        sup.stop()


def test_an_optional_node_that_keeps_failing_is_left_behind(tmp_path, capsys):
    """The live view is optional: its failures end nothing; the run goes on without it."""
    from dataclasses import replace

    from formation_ilc.cli.supervisor import Supervisor

    plan, codes = _plan_running(tmp_path, "import time; time.sleep(60)",
                                "raise SystemExit(1)", max_restarts=1)
    nodes = (plan.nodes[0], replace(plan.nodes[1], passive=False, optional=True))
    sup = Supervisor(replace(plan, nodes=nodes), dict(os.environ),
                     place=lambda s: [sys.executable, "-c", codes[s.name]])
    sup.start()
    try:
        for _ in range(2):  # the first exit is restarted, the second left behind
            sup.stack.procs["p1"].wait(timeout=30)
            assert sup.watch() is None
        assert "p1" not in sup.stack.procs and sup.watch() is None
        assert sup.stack.procs["p0"].poll() is None  # the run goes on
    finally:
        sup.stop()
    out = capsys.readouterr().out
    assert "p1 exited with status 1: starting it again (1/1)\n" in out  # no trial re-run
    assert "p1 exited with status 1 after 1 restarts: the run goes on without it" in out
    plan = plan_of(tmp_path, "paper-triangle3", "--live", str(_free_port_for_plan()),
                   out="live")
    assert [n.optional for n in plan.nodes if n.name == "liveview"] == [True]
    assert not any(n.optional for n in plan.nodes if n.name != "liveview")


def test_a_node_that_refuses_is_not_started_again(tmp_path, capsys):
    from formation_ilc.cli.supervisor import Supervisor

    plan, codes = _plan_running(tmp_path, "pass", f"raise SystemExit({NO_RESTART})")
    sup = Supervisor(plan, dict(os.environ), place=lambda s: [sys.executable, "-c",
                                                              codes[s.name]])
    sup.start()
    try:
        sup.stack.procs["p1"].wait(timeout=30)
        sup.stack.procs["p0"].wait(timeout=30)
        failure = sup.watch()
        # p0 (exit 0, listed first) is restarted; p1 refused: status 2, no restart
        assert failure is not None and failure.spec.name == "p1" and failure.status == 2
        assert sup.restarts == {"p0": 1}
        assert sup.report(failure) == 2
    finally:
        sup.stop()
    assert "error: node process p1 exited with status 2 (log: " in capsys.readouterr().err


def test_live_plans_a_bridge_on_localhost_and_refuses_a_taken_port(tmp_path):
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    # the view topics come from the bridge itself when nothing records
    plan = plan_of(tmp_path, "paper-triangle3", "--live", str(port))
    live = [n for n in plan.nodes if n.name == "liveview"]
    assert len(live) == 1 and live[0].module == "formation_ilc.nodes.liveview"
    # the simulator publishes a preview of the team's poses (msgs_schema.PREVIEW)
    assert live[0].args == ("--host", "127.0.0.1", "--port", str(port), "--observe",
                            "--preview")
    assert "liveview" not in plan.team.expected  # the run never waits for a viewer
    # ... and from the recorder when it records
    plan = plan_of(tmp_path, "paper-triangle3", "--live", str(port), "--record",
                   str(tmp_path / "r.mcap"), out="rec")
    live = [n for n in plan.nodes if n.name == "liveview"]
    assert "--observe" not in live[0].args
    assert options("paper-triangle3", "--live").live == 8765  # the default port
    assert all(n.name != "liveview" for n in plan_of(tmp_path, "paper-triangle3",
                                                     out="none").nodes)
    with socket.socket() as s:
        s.bind(("127.0.0.1", port))
        s.listen()
        r = refusal(tmp_path, "paper-triangle3", "--live", str(port))
    assert r.status == 2 and f"--live {port}: cannot serve on 127.0.0.1:{port}" in r.message


def test_live_rate_reaches_the_bridge_and_bad_rates_are_refused(tmp_path):
    port = str(_free_port_for_plan())
    plan = plan_of(tmp_path, "paper-triangle3", "--live", port, "--live-rate", "12.5")
    live = [n for n in plan.nodes if n.name == "liveview"][0]
    assert live.args[-2:] == ("--rate", "12.5")
    plan = plan_of(tmp_path, "paper-triangle3", "--live", port, "--live-rate", "0", out="r0")
    assert [n for n in plan.nodes if n.name == "liveview"][0].args[-2:] == ("--rate", "0.0")
    for argv, why in ((("--live", port, "--live-rate", "-1"), "a rate >= 0"),
                      (("--live", port, "--live-rate", "nan"), "a rate >= 0"),
                      (("--live-rate", "5"), "only with --live")):
        r = refusal(tmp_path, "paper-triangle3", *argv)
        assert r.status == 2 and why in r.message, r.message


def _free_port_for_plan() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def test_the_callers_ros_domain_id_is_honoured(tmp_path, monkeypatch):
    monkeypatch.setenv("ROS_DOMAIN_ID", "7")
    assert plan_of(tmp_path, "paper-triangle3", "--trials", "2", out="a").domain == 7
    # --domain-id still wins; without either a free-looking one is picked
    assert plan_of(tmp_path, "paper-triangle3", "--trials", "2",
                   "--domain-id", "42", out="b").domain == 42
    monkeypatch.delenv("ROS_DOMAIN_ID")
    assert 30 <= plan_of(tmp_path, "paper-triangle3", "--trials", "2", out="c").domain <= 100
    monkeypatch.setenv("ROS_DOMAIN_ID", "abc")
    with pytest.raises(NoRun, match="ROS_DOMAIN_ID='abc': a domain id 0..232 is required"):
        plan_of(tmp_path, "paper-triangle3", "--trials", "2", out="d")


def test_emulated_clocks_reach_the_leader_and_are_refused_in_lockstep(tmp_path):
    """--clock-offset-ms / --clock-drift-ppm / --no-clock-sync / --clock-fallback: the
    settings go to the leader (which broadcasts them in the configuration), with the
    origin kept for --resume; without them the leader's command line is as before."""
    plan = plan_of(tmp_path, "paper-triangle3", "--mode", "realtime", "--clock-offset-ms",
                   "300", "--clock-drift-ppm", "100", "--clock-fallback", "own")
    cs = plan.config.clocks
    assert (cs.offset_ms, cs.drift_ppm, cs.fallback, cs.sync) == (300.0, 100.0, "own", True)
    assert cs.origin_ns > 0 and plan.run_json is not None
    assert plan.run_json["clock_origin_ns"] == cs.origin_ns
    leader = params(plan.nodes[0])
    assert json.loads(leader["clocks"]) == cs.to_json()
    assert plan.roster.lineup.clocks  # the exchanges' topics are the robots' and leader's
    plain = plan_of(tmp_path, "paper-triangle3", "--mode", "realtime", out="plain")
    assert "clocks" not in params(plain.nodes[0]) and plain.config.clocks.sync
    off = plan_of(tmp_path, "paper-triangle3", "--mode", "realtime", "--no-clock-sync",
                  out="off")
    assert json.loads(params(off.nodes[0])["clocks"])["sync"] is False
    assert not plan_of(tmp_path, "paper-triangle3", out="lock").roster.lineup.clocks
    exc = refusal(tmp_path, "paper-triangle3", "--clock-offset-ms", "300")
    assert exc.status == 2 and exc.message.startswith(
        "argument --clock-offset-ms: emulated clocks need --mode realtime or wallclock")
    exc = refusal(tmp_path, "paper-triangle3", "--clock-drift-ppm", "5")
    assert exc.message.startswith("argument --clock-drift-ppm:")
    with pytest.raises(SystemExit) as e:
        options("paper-triangle3", "--clock-offset-ms", "-3")
    assert e.value.code == 2


def test_values_no_run_can_have_are_refused_before_anything_starts(tmp_path):
    """Each was accepted before (issue 31): the physics plant refused its rate only after
    every node had started (38 s), and ran 1 Hz as 5 Hz; a netns delay of 1e12 ms never
    moved; an invalid driver namespace reached the bridges; a memory of 1e300 made the
    monitor raise inside rclpy (a FATAL stack)."""
    import numpy as np

    from formation_ilc.config.scenario import load_scenario
    from formation_ilc.store.memoryfile import save_memory

    phys = ["paper-triangle3", "--plant", "physics", "--allow-contact"]
    assert refusal(tmp_path, *phys, "--physics-rate", "1e9").message == (
        "--physics-rate 1e+09: 1e+09 Hz is outside 1 .. 100000 engine steps a second")
    assert refusal(tmp_path, *phys, "--physics-rate", "1").message == (
        "--physics-rate 1: 1 Hz is 0.2 engine steps a sample of 0.2 s: at least one (5 Hz) "
        "is needed")
    assert "which would run at 240 Hz" in refusal(tmp_path, *phys, "--physics-rate",
                                                  "241").message
    delay = refusal(tmp_path, "paper-triangle3", "--hosts", "netns", "--net-delay-ms", "1e12")
    assert delay.message == "--net-delay-ms: at most 10000 ms per direction, got 1e+12"
    ns = refusal(tmp_path, "paper-triangle3", "--plant", "pioneer", "--fake-drivers",
                 "--driver-ns", "x{i}{j}")
    assert ns.message == ("argument --driver-ns: 'x{i}{j}': robot 1's namespace 'x1{j}': an "
                          "absolute ROS namespace starts with /")
    assert "'p1{j}' is no ROS name" in refusal(tmp_path, "paper-triangle3", "--plant",
                                               "pioneer", "--driver-ns", "/p{i}{j}").message
    sc = load_scenario("paper-triangle3")
    huge = tmp_path / "huge.npz"
    save_memory(huge, np.full((sc.n, sc.samples, 2), 1e300), sc)
    msg = refusal(tmp_path, "paper-triangle3", "--init-memory", str(huge)).message
    assert msg.startswith(f"--init-memory {huge}: robot 1's v at sample 0 is 1e+300, beyond "
                          f"1e+06 (m/s, rad/s)")
    assert not (tmp_path / "run" / "logs").exists()


def test_live_without_foxglove_sdk_is_refused_before_anything_starts(tmp_path, monkeypatch):
    import importlib.util

    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec",
                        lambda name, *a: None if name == "foxglove" else real(name, *a))
    r = refusal(tmp_path, "paper-triangle3", "--live")
    assert r.status == 2 and r.message.startswith("argument --live: needs foxglove-sdk")
