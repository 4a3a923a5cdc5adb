"""The fork server (formation_ilc.nodes.forkserver): a node process forked from it is
this launcher's child, runs its entry point with its own argv and environment, and joins
the domain only after the fork; a server with a DDS thread (an rclpy context) refuses to
fork: the guard of issue 56."""

from __future__ import annotations

import json
import os
import sys

import pytest

from formation_ilc.nodes.forkserver import (
    FORK_DEFAULT_MAX,
    FORK_ENV,
    ForkedProcess,
    ForkRefused,
    ForkServer,
    forkable,
    wanted,
)
from formation_ilc.system.lifetime import PARENT_ENV, RUNNER, early_argv

pytestmark = [pytest.mark.ros]

PROBE = "tests.nodes.fork_probe"


def _env(ros_env: dict[str, str]) -> dict[str, str]:
    return {**ros_env, PARENT_ENV: str(os.getpid()), "PYTHONPATH": os.getcwd() + os.pathsep
            + ros_env.get("PYTHONPATH", "")}


def test_a_forked_node_is_ours_and_joins_the_domain_only_after_the_fork(ros_env, tmp_path):
    env = _env(ros_env)
    server = ForkServer(env, ["formation_ilc.nodes.robot", PROBE], tmp_path / "server.log")
    try:
        command = early_argv([sys.executable, "-m", PROBE, "--flag", "x"])
        assert forkable(command) and command[1:3] == ["-m", RUNNER]
        outs = []
        for i in range(2):  # a second child: forked again, as a restart is
            out = tmp_path / f"child{i}.log"
            with out.open("wb") as fh:
                child = server.spawn(command, {**env, "PROBE": f"p{i}"}, fh.fileno(), None)
            assert isinstance(child, ForkedProcess)
            assert child.wait(timeout=120) == 7, out.read_text()
            # the guard: at the fork the server had no thread but the libraries' own
            assert server.last["threads"] <= server.last["allowed"], server.last
            outs.append(json.loads(out.read_text().strip().splitlines()[-1]))
    finally:
        server.close()
    for i, said in enumerate(outs):
        assert said["ppid"] == os.getpid()  # adopted by the launcher (a subreaper)
        assert said["before"] == 1  # no thread before rclpy.init: none came with the fork
        assert said["after"] > 1  # its DDS participant's threads, its own
        assert said["argv"] == ["--flag", "x"] and said["probe"] == f"p{i}"
        assert said["name"] == "fork_probe"
        # ps, the tests and the benchmarks tell a node by its command line
        assert said["cmdline"] == " ".join(command), said["cmdline"]
    assert "modules imported" in (tmp_path / "server.log").read_text()


def test_children_forked_in_a_row_go_on_as_soon_as_the_launcher_adopts_them(ros_env,
                                                                             tmp_path):
    """A child took its parent once forked for the intermediate process; when that had
    already exited, the parent was the launcher, and the child waited out its whole bound
    for it to change (10 s at the start of one process in two launches of a team)."""
    env = _env(ros_env)
    server = ForkServer(env, [PROBE], tmp_path / "server.log")
    said = []
    try:
        command = early_argv([sys.executable, "-m", PROBE])
        for i in range(12):
            out = tmp_path / f"child{i}.log"
            with out.open("wb") as fh:
                child = server.spawn(command, env, fh.fileno(), None)
            assert child.wait(timeout=120) == 7, out.read_text()
            said.append(out.read_text())
    finally:
        server.close()
    late = [text for text in said if "was still its parent" in text]
    assert not late, late
    assert all(json.loads(t.strip().splitlines()[-1])["ppid"] == os.getpid() for t in said)


def test_a_server_with_a_dds_thread_refuses_to_fork(ros_env, tmp_path):
    env = _env(ros_env)
    server = ForkServer(env, ["tests.nodes.fork_dds"], tmp_path / "server.log")
    try:
        command = early_argv([sys.executable, "-m", PROBE])
        with (tmp_path / "child.log").open("wb") as fh, pytest.raises(ForkRefused) as exc:
            server.spawn(command, env, fh.fileno(), None)
        # its participant's threads are what the server counts (before its context)
        assert "threads, " in str(exc.value) and "allowed" in str(exc.value), exc.value
    finally:
        server.close()
    assert not (tmp_path / "child.log").read_text()  # nothing ran


def test_a_small_team_is_forked_by_default_and_the_environment_decides_when_set():
    assert wanted({}, FORK_DEFAULT_MAX) and not wanted({}, FORK_DEFAULT_MAX + 1)
    assert wanted({FORK_ENV: "1"}, 200) and not wanted({FORK_ENV: "0"}, 3)
