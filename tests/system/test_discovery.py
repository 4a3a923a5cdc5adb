"""Localhost discovery for large teams (formation_ilc/system/discovery.py): the profile that
lists every participant's discovery port, built on the user's profiles, and the launch
plans that use it (a team beyond what rmw_fastrtps's 32 localhost peers reach)."""

from __future__ import annotations

import contextlib
import os
import signal
import socket
import xml.etree.ElementTree as ET

import pytest

from formation_ilc.cli.commands import build_parser
from formation_ilc.cli.runfile import plan_of
from formation_ilc.plan.specs import NoRun
from formation_ilc.system.ddsxml import PROFILES_NS
from formation_ilc.system.discovery import (
    MARGIN,
    MAX_IDS,
    RMW_PEER_IDS,
    SERVER_FROM,
    DiscoveryServer,
    discovery_port,
    mutation_tries,
    needs_peers,
    peer_ids,
    peers_profile,
    server_profile,
)

NS = {"p": PROFILES_NS}


def peers(text: str) -> list[tuple[str, int]]:
    root = ET.fromstring(text.split("\n", 2)[2])  # after the declaration and the comment
    part = [p for p in root.iter(f"{{{PROFILES_NS}}}participant")
            if p.get("is_default_profile") == "true"]
    assert len(part) == 1
    return [(loc.findtext("p:udpv4/p:address", namespaces=NS),
             int(loc.findtext("p:udpv4/p:port", namespaces=NS) or 0))
            for loc in part[0].findall("p:rtps/p:builtin/p:initialPeersList/p:locator", NS)]


def test_the_rtps_port_of_a_participant():
    # RTPS 9.6.1.1 with Fast DDS's defaults: 7400 + 250 d + 10 + 2 id
    assert discovery_port(0, 0) == 7410
    assert discovery_port(21, 0) == 12660 and discovery_port(21, 31) == 12722
    assert discovery_port(101, 119) == 7400 + 25250 + 10 + 238


def test_every_id_a_team_may_take_is_a_peer_on_the_loopback():
    got = peers(peers_profile(None, 21, 54))
    assert got == [("127.0.0.1", discovery_port(21, i)) for i in range(54 + MARGIN)]
    assert peer_ids(54) == 54 + MARGIN and peer_ids(500) == MAX_IDS


def test_needed_only_beyond_what_the_rmw_reaches():
    assert not needs_peers(RMW_PEER_IDS - MARGIN)
    assert needs_peers(RMW_PEER_IDS - MARGIN + 1)


def test_the_users_profiles_are_kept(tmp_path):
    own = tmp_path / "own.xml"
    own.write_text(f"""<dds><profiles xmlns="{PROFILES_NS}">
      <participant profile_name="mine" is_default_profile="true"><rtps>
        <builtin><initialPeersList><locator><udpv4><address>10.0.0.7</address></udpv4>
        </locator></initialPeersList></builtin>
        <name>kept</name></rtps></participant>
      <data_writer profile_name="w" is_default_profile="true"><topic><resourceLimitsQos>
        <allocated_samples>7</allocated_samples></resourceLimitsQos></topic></data_writer>
    </profiles></dds>""")
    text = peers_profile(own, 3, 20)
    got = peers(text)
    assert got[0] == ("10.0.0.7", 0)  # the user's peer first, as it was
    assert got[1:] == [("127.0.0.1", discovery_port(3, i)) for i in range(20 + MARGIN)]
    root = ET.fromstring(text.split("\n", 2)[2])
    assert root.find(".//p:participant/p:rtps/p:name", NS).text == "kept"
    assert root.find(".//p:data_writer", NS).get("profile_name") == "w"
    assert root.find(".//p:data_writer/p:topic/p:resourceLimitsQos/p:allocated_samples",
                     NS).text == "7"
    bad = tmp_path / "bad.xml"
    bad.write_text("<not-xml")
    with pytest.raises(ValueError, match="not a readable Fast DDS profiles file"):
        peers_profile(bad, 3, 20)


def plan(tmp_path, *argv: str):
    args = build_parser().parse_args(["launch", *argv, "--out", str(tmp_path / "run"),
                                      "--domain-id", "21"])
    return plan_of(args)


def test_a_50_robot_launch_lists_every_participant_and_a_6_robot_one_does_not(
        tmp_path, monkeypatch):
    monkeypatch.delenv("FASTRTPS_DEFAULT_PROFILES_FILE", raising=False)
    small = plan(tmp_path, "paper-hexagon6")
    assert small.peers_profile is None
    big = plan(tmp_path, "team50", "--links", "direct")
    assert big.participants == len(big.nodes) + 1 == 50 + 3  # robots, leader, sim, monitor
    assert big.peers_profile == big.out / "fastdds-discovery.xml" and big.peers_base is None
    big.write_peers_profile()
    assert len(peers(big.peers_profile.read_text())) == 53 + MARGIN
    from formation_ilc.cli.supervisor import node_env

    env = node_env(big)
    assert env["FASTRTPS_DEFAULT_PROFILES_FILE"] == str(big.peers_profile)
    assert env["ROS_AUTOMATIC_DISCOVERY_RANGE"] == "LOCALHOST"
    # container mode: few processes, nothing to add; --discovery inherit: the caller's
    assert plan(tmp_path, "team50", "--container", "10").peers_profile is None
    assert plan(tmp_path, "team50", "--discovery", "inherit").peers_profile is None


def test_built_on_the_callers_profile_or_refused_when_it_is_none(tmp_path, monkeypatch):
    own = tmp_path / "own.xml"
    own.write_text(f'<profiles xmlns="{PROFILES_NS}"/>')
    monkeypatch.setenv("FASTRTPS_DEFAULT_PROFILES_FILE", str(own))
    assert plan(tmp_path, "team50").peers_base == own
    monkeypatch.setenv("FASTRTPS_DEFAULT_PROFILES_FILE", str(tmp_path / "missing.xml"))
    with pytest.raises(NoRun) as info:
        plan(tmp_path, "team50")
    assert "FASTRTPS_DEFAULT_PROFILES_FILE" in str(info.value)


def _builtin(text: str, tag: str) -> str | None:
    root = ET.fromstring(text.split("\n", 2)[2])
    part = [p for p in root.iter(f"{{{PROFILES_NS}}}participant")
            if p.get("is_default_profile") == "true"]
    return part[0].findtext(f"p:rtps/p:builtin/p:{tag}", namespaces=NS)


def test_a_participant_tries_an_id_for_every_process_of_a_large_team():
    """Fast DDS tries 100 ids beyond its first by default: a 102nd participant on one host
    had no discovery port and was never found."""
    assert mutation_tries(20) == 100
    assert mutation_tries(103) == 103 + MARGIN
    assert _builtin(peers_profile(None, 21, 103), "mutation_tries") == str(103 + MARGIN)
    text = server_profile(None, 203)
    assert _builtin(text, "mutation_tries") == str(203 + MARGIN)
    assert peers(text) == []  # the server's clients list no peers


def test_from_64_processes_the_launch_goes_through_a_discovery_server(tmp_path, monkeypatch):
    monkeypatch.delenv("FASTRTPS_DEFAULT_PROFILES_FILE", raising=False)
    monkeypatch.setenv("ROS_DISCOVERY_SERVER", "10.1.2.3:11811")  # a caller's, elsewhere
    from formation_ilc.cli.supervisor import node_env

    fifty = plan(tmp_path, "team50", "--links", "direct")
    assert fifty.discovery == "localhost" and fifty.participants < SERVER_FROM
    assert "ROS_DISCOVERY_SERVER" not in node_env(fifty)  # localhost means this machine
    from formation_ilc.config.generate import team_yaml

    (tmp_path / "team100.yaml").write_text(team_yaml(100))
    hundred = plan(tmp_path, str(tmp_path / "team100.yaml"), "--links", "direct")
    assert hundred.participants == 103 >= SERVER_FROM
    assert hundred.discovery == "server"
    hundred.write_peers_profile()
    text = hundred.peers_profile.read_text()
    assert peers(text) == [] and _builtin(text, "mutation_tries") == str(103 + MARGIN)
    env = node_env(hundred)
    assert env["FASTRTPS_DEFAULT_PROFILES_FILE"] == str(hundred.peers_profile)
    # no shared memory (rmw's LOCALHOST would add it): UDP bound to the loopback
    assert env["ROS_AUTOMATIC_DISCOVERY_RANGE"] == "SYSTEM_DEFAULT"
    root = ET.fromstring(text.split("\n", 2)[2])
    desc = root.find("p:transport_descriptors/p:transport_descriptor", NS)
    assert desc.findtext("p:type", namespaces=NS) == "UDPv4"
    assert [a.text for a in desc.findall("p:interfaceWhiteList/p:address", NS)] == ["127.0.0.1"]
    assert _builtin(text, "mutation_tries") and "useBuiltinTransports>false" in text
    assert "ROS_DISCOVERY_SERVER" not in env  # the launcher's own server's, once started
    # asked for on a small team
    assert plan(tmp_path, "paper-triangle3", "--discovery", "server").discovery == "server"


def whitelist(text: str) -> list[str | None]:
    root = ET.fromstring(text.split("\n", 2)[2])
    desc = root.findall("p:transport_descriptors/p:transport_descriptor", NS)
    assert len(desc) == 1 and desc[0].findtext("p:type", namespaces=NS) == "UDPv4"
    return [a.text for a in desc[0].findall("p:interfaceWhiteList/p:address", NS)]


def test_a_client_on_a_host_of_its_own_binds_its_own_address():
    assert whitelist(server_profile(None, 9)) == ["127.0.0.1"]
    text = server_profile(None, 9, "10.77.0.12")
    assert whitelist(text) == ["10.77.0.12"]
    assert peers(text) == [] and "useBuiltinTransports>false" in text


def test_robots_on_hosts_of_their_own_go_through_the_server_in_the_hub(
        tmp_path, monkeypatch, netns_support):
    """``--hosts netns --discovery server``: every process a client of the server in the
    hub, each robot's bound to its namespace's address, the hub's to the hub's; the
    default from SERVER_FROM participants as on one host; refused with --secure and over
    several machines."""
    from dataclasses import replace

    from formation_ilc.cli.supervisor import node_env
    from formation_ilc.config.generate import team_yaml
    from formation_ilc.plan.build import _with_peers
    from formation_ilc.system.netns import Hosts, LinkFaults, lossy_profile

    # the caller's profile is not the run's on hosts of their own (HostsPlan.profile_file)
    monkeypatch.setenv("FASTRTPS_DEFAULT_PROFILES_FILE", str(tmp_path / "missing.xml"))
    small = plan(tmp_path, "paper-triangle3", "--hosts", "netns")
    assert small.discovery == "localhost" and small.peers_profile is None
    assert all(not s.env for s in small.nodes)  # unicast to every host, as before
    run = plan(tmp_path, "paper-triangle3", "--hosts", "netns", "--discovery", "server",
               "--dds-profile", "lossy")
    assert run.discovery == "server" and run.server_host == "10.77.0.1"
    assert run.peers_base == lossy_profile() and run.hosts.profile == "lossy"
    robots = {s.host: dict(s.env) for s in run.nodes if s.host is not None}
    assert sorted(robots) == [1, 2, 3]
    for i, env in robots.items():
        assert env == {"FASTRTPS_DEFAULT_PROFILES_FILE": str(run.robot_profile(i))}
    assert all(not s.env for s in run.nodes if s.host is None)  # the hub's: the run's
    run.write_peers_profile()
    assert whitelist(run.peers_profile.read_text()) == ["10.77.0.1"]
    for i in robots:
        text = run.robot_profile(i).read_text()
        assert whitelist(text) == [f"10.77.0.{10 + i}"]
        assert "heartbeatPeriod" in text  # built on the lossy-links profile
    env = node_env(run)
    assert env["FASTRTPS_DEFAULT_PROFILES_FILE"] == str(run.peers_profile)
    assert env["ROS_AUTOMATIC_DISCOVERY_RANGE"] == "SYSTEM_DEFAULT"
    hosts = Hosts(3, LinkFaults())
    assert "ROS_STATIC_PEERS" not in hosts.ros_env(server=True)
    assert "ROS_AUTOMATIC_DISCOVERY_RANGE" not in hosts.ros_env(server=True)
    assert hosts.ros_env()["ROS_STATIC_PEERS"].split(";")[:2] == ["10.77.0.1", "10.77.0.11"]
    # the default from SERVER_FROM participants on hosts too
    (tmp_path / "big.yaml").write_text(team_yaml(SERVER_FROM - 3))
    big = plan(tmp_path, str(tmp_path / "big.yaml"), "--hosts", "netns")
    assert big.participants == SERVER_FROM and big.discovery == "server"
    # without loss to repair, Fast DDS's defaults: the lossy profile's 50 ms heartbeat kept
    # 100 robots from starting; with --net-loss, or asked for, the lossy one
    assert big.hosts.profile == "none" and big.peers_base is None
    assert plan(tmp_path, str(tmp_path / "big.yaml"), "--hosts", "netns", "--net-loss",
                "0.01").peers_base == lossy_profile()
    assert small.hosts.profile == "lossy"  # not through the server: as before
    assert sum(dict(s.env).get("FASTRTPS_DEFAULT_PROFILES_FILE") == str(big.robot_profile(s.host))
               for s in big.nodes if s.host is not None) == SERVER_FROM - 3
    # refused where it cannot serve: a secure run stays on unicast to every host
    unplanned = replace(big, discovery="localhost", peers_profile=None, peers_base=None)
    assert _with_peers(unplanned, None, secure=True).discovery == "localhost"
    with pytest.raises(NoRun, match="--discovery server: not with --secure"):
        _with_peers(replace(unplanned, discovery="server"), None, secure=True)
    with pytest.raises(NoRun, match="--discovery server: not with a run over several"):
        _with_peers(replace(unplanned, discovery="server"), None, one_host=False)


def held(pid: int, where: list[str]) -> list[str]:
    """The local addresses of the UDP sockets process ``pid`` holds (``ss`` run with the
    command prefix ``where``: in a network namespace)."""
    import subprocess

    ss = subprocess.run([*where, "ss", "-ulpnH"], capture_output=True, text=True).stdout
    return [ln.split()[3] for ln in ss.splitlines() if f"pid={pid}," in ln]


def test_the_discovery_server_listens_on_the_loopback_and_stops(tmp_path):
    server = DiscoveryServer(tmp_path / "server.log")
    address = server.start()
    try:
        host, port = address.split(":")
        assert host == "127.0.0.1"
        assert server.proc is not None
        # on the loopback alone: Fast DDS binds 0.0.0.0 (every interface) unless told
        assert address in held(server.proc.pid, [])
        assert f"0.0.0.0:{port}" not in held(server.proc.pid, [])
        assert "SERVER" in server.profile.read_text()
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            with pytest.raises(OSError):
                s.bind(("127.0.0.1", int(port)))  # the server holds it
        assert server.proc is not None and server.proc.poll() is None
    finally:
        server.stop()
    assert server.proc.returncode is not None  # stopped, not left behind
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", int(port)))  # and its port is free again


def test_the_discovery_server_listens_in_the_hub_on_its_bridge_address(tmp_path,
                                                                      netns_support):

    from formation_ilc.system.discovery import ServerError
    from formation_ilc.system.netns import Hosts, LinkFaults

    with pytest.raises(ServerError, match="no UDP port free on 192.0.2.1"):
        DiscoveryServer(tmp_path / "none.log", "192.0.2.1").start()  # none of this machine's
    with Hosts(1, LinkFaults(), log_dir=tmp_path / "hosts") as hosts:
        with hosts.entered_hub():
            server = DiscoveryServer(tmp_path / "server.log", hosts.hub_address)
            address = server.start()
        try:
            assert address.startswith("10.77.0.1:")
            assert server.proc is not None
            # in the hub, on its address alone (Fast DDS binds 0.0.0.0 unless told)
            assert f"{address}" in held(server.proc.pid, hosts.exec_argv(hosts.hub, []))
            assert "0.0.0.0:" + address.split(":")[1] not in held(
                server.proc.pid, hosts.exec_argv(hosts.hub, []))
        finally:
            server.stop()
    assert server.proc.returncode is not None


def test_the_discovery_server_ends_with_a_launcher_killed_outright(tmp_path):
    """A launcher that dies by SIGKILL cannot stop its server: the server ends with it
    (PR_SET_PDEATHSIG), as every node does."""
    import subprocess
    import sys
    import time

    code = ("import sys, time; from pathlib import Path; "
            "from formation_ilc.system.discovery import DiscoveryServer; "
            "s = DiscoveryServer(Path(sys.argv[1])); s.start(); "
            "print(s.proc.pid, flush=True); time.sleep(60)")
    launcher = subprocess.Popen([sys.executable, "-c", code, str(tmp_path / "server.log")],
                                stdout=subprocess.PIPE, text=True)
    pid = None
    try:
        pid = int(launcher.stdout.readline())
        launcher.kill()
        launcher.wait()
        def alive() -> bool:  # neither reaped nor a zombie waiting for its new parent
            try:
                return open(f"/proc/{pid}/stat").read().split()[2] != "Z"
            except FileNotFoundError:  # reaped (between any two looks, too)
                return False

        deadline = time.monotonic() + 20
        while alive() and time.monotonic() < deadline:
            time.sleep(0.05)
        assert not alive(), f"the server {pid} outlived its launcher"
    finally:
        launcher.kill()
        launcher.wait()
        if pid is not None:  # a server that outlived it is stopped here all the same
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)
