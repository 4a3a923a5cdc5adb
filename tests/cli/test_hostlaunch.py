"""The ground station's view of the other hosts (formation_ilc.cli.hostlaunch.HostWatch),
without ROS: which hosts a stuck run waits for, said cause first with the command that
starts each, and the host rows of the report."""

from __future__ import annotations

from formation_ilc.cli.commands import build_parser, main
from formation_ilc.cli.hostlaunch import HostWatch, host_command
from formation_ilc.cli.runfile import plan_of


def ground_plan(tmp_path):
    path = tmp_path / "team.yaml"
    assert main(["run-file", "paper-triangle3", "--host-per-robot", "--domain-id", "42", "-o",
                 str(path)]) == 0
    args = build_parser().parse_args(["launch", str(path), "--host", "ground", "--out",
                                      str(tmp_path / "run")])
    return plan_of(args)


def test_the_command_of_another_host_is_this_launchers_with_its_host():
    assert host_command("r2", ["launch", "team.yaml", "--host", "ground"]) == (
        "formation-ilc launch team.yaml --host r2")
    assert host_command("r2", ["launch", "a b.yaml", "--host=ground"]) == (
        "formation-ilc launch 'a b.yaml' --host=r2")
    assert host_command("r1", ["launch", "team.yaml"]) == (
        "formation-ilc launch team.yaml --host r1")


def test_a_stuck_runs_cause_names_the_missing_host_first_and_what_to_do(tmp_path):
    watch = HostWatch(ground_plan(tmp_path))
    here = {"virtual_leader", "monitor", "robot_sim", "link_emulator", "robot_1", "robot_3"}
    assert watch.update(0.0, here) == []
    cause = watch.cause(here, 1.0)
    assert cause is not None and cause.startswith("host r2 (robot_2) never joined: start `")
    assert "--host r2`" in cause and "r1" not in cause
    watch.update(2.0, here | {"robot_2"})
    assert watch.cause(here | {"robot_2"}, 3.0) is None
    watch.update(10.0, here)  # r2 left
    cause = watch.cause(here, 40.0)
    assert cause is not None and cause.startswith("host r2 (robot_2) left 30 s ago: start `")


def ready(node: str, boot: str, down: bool = False):
    from formation_ilc.protocol.schedule import Ready

    return Ready(node, 3, boot, down=down)


def test_a_host_restarted_faster_than_the_graph_sees_it_go_left_once(tmp_path):
    """r2's launcher SIGKILLed and started again within the DDS lease: robot_2's name never
    leaves the graph (the old participant's lease still runs), but its ready comes from a
    new launcher: the host left once (it said "present throughout")."""
    from formation_ilc.protocol.schedule import boot_id, boot_launcher

    a, b = boot_id("aaaa1111"), boot_id("bbbb2222")
    assert boot_launcher(a) == "aaaa1111" and boot_launcher(boot_id()) is None
    watch = HostWatch(ground_plan(tmp_path))
    every = {"virtual_leader", "monitor", "robot_sim", "link_emulator", "robot_1", "robot_2",
             "robot_3"}
    readies = {"robot_1": ready("robot_1", boot_id("11")), "robot_2": ready("robot_2", a),
               "robot_3": ready("robot_3", boot_id("33"))}
    assert watch.update(0.0, every, readies) == []
    # robot_2 restarted by its own launcher (the same one): no departure of the host
    readies["robot_2"] = ready("robot_2", boot_id("aaaa1111"))
    assert watch.update(1.0, every, readies) == []
    # a down said of it, with a pid for a boot: nothing
    readies["robot_2"] = ready("robot_2", "4242", down=True)
    assert watch.update(1.5, every, readies) == []
    readies["robot_2"] = ready("robot_2", b)  # a new launcher
    lines = watch.update(2.0, every, readies)
    assert len(lines) == 1 and lines[0].startswith("host r2: its launcher was started again")
    assert watch.update(3.0, every, readies) == []  # said once
    rows = watch.report()
    assert any(r.startswith("  r2 ") and "robot_2: left 1 time(s)" in r for r in rows), rows
    assert any(r.startswith("  r1 ") and "present throughout" in r for r in rows), rows
    # a departure the graph shows, then the new launcher's ready: still one more, not two
    gone = every - {"robot_2"}
    assert watch.update(4.0, gone, readies)[0].startswith("host r2: its members (robot_2) left")
    assert watch.update(9.0, every, readies) == ["host r2: back after 5.0 s"]
    readies["robot_2"] = ready("robot_2", boot_id("cccc3333"))
    assert watch.update(9.5, every, readies) == []
    assert watch.rows["r2"]["left"] == 2 and watch.rows["r2"]["quick_returns"] == 1


def test_a_host_launcher_needs_the_runs_domain_known_to_every_machine(tmp_path, monkeypatch):
    import pytest

    from formation_ilc.plan.specs import NoRun

    path = tmp_path / "team.yaml"
    assert main(["run-file", "paper-triangle3", "--host-per-robot", "-o", str(path)]) == 0
    monkeypatch.delenv("ROS_DOMAIN_ID", raising=False)
    for host in ("ground", "r2"):
        args = build_parser().parse_args(["launch", str(path), "--host", host, "--out",
                                          str(tmp_path / host)])
        with pytest.raises(NoRun) as info:
            plan_of(args)
        assert info.value.message.startswith("network.domain_id: a run over several machines")
    monkeypatch.setenv("ROS_DOMAIN_ID", "42")
    args = build_parser().parse_args(["launch", str(path), "--host", "r2", "--out",
                                      str(tmp_path / "r2")])
    assert plan_of(args).domain == 42
    # the rehearsal (no --host) picks a free one, as a launch does
    args = build_parser().parse_args(["launch", str(path), "--out", str(tmp_path / "all")])
    monkeypatch.delenv("ROS_DOMAIN_ID")
    assert plan_of(args).domain is not None


def test_the_run_goes_to_the_other_hosts_over_the_graph_but_under_secure(tmp_path):
    from formation_ilc.cli.hostlaunch import description, over_graph

    plan = ground_plan(tmp_path)
    assert over_graph(plan)
    d = description(plan)
    assert d["run_id"] == plan.config.run_id and d["domain"] == plan.domain
    assert bytes.fromhex(d["key"]) == plan.key and d["status"] is None
