"""The ground station's view of the other hosts (formation_ilc.cli.hostlaunch.HostWatch),
without ROS: which hosts a stuck run waits for, said cause first with the command that
starts each, and the host rows of the report."""

from __future__ import annotations

from formation_ilc.cli.commands import build_parser, main
from formation_ilc.cli.hostlaunch import HostWatch, host_command
from formation_ilc.cli.runfile import plan_of


def ground_plan(tmp_path):
    path = tmp_path / "team.yaml"
    assert main(["run-file", "paper-triangle3", "--host-per-robot", "-o", str(path)]) == 0
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
