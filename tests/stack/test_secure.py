"""A formation secure by construction: ``launch --secure`` with SROS2 enclaves from the graph.

With the Fast DDS of scripts/build_secure_dds.sh in the venv (skipped otherwise, saying why;
failed instead where FORMATION_ILC_REQUIRE_SECURE=1, as in CI):

* a secure lockstep run equals the batch simulator to 1e-9, like an insecure one;
* during a secure run, on its domain: an unsecured participant receives nothing and its
  forged ``cmd_vel`` changes nothing; a participant holding robot 3's identity gets robot
  3's pose but cannot create a writer of ``robot_2/cmd_vel`` or of the trial events; a
  participant whose certificate is another CA's receives nothing;
* no pose, trajectory or configuration leaves a process in clear: every UDP datagram of
  a run (``FASTDDS_BUILTIN_TRANSPORTS=UDPv4``, captured on ``lo`` in a network namespace of
  its own) and every shared-memory segment (default transports) is searched, and the same
  search finds them in an insecure run.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from formation_ilc.config.scenario import load_scenario
from formation_ilc.core.metrics import read_metrics
from formation_ilc.model.simulate import simulate

from ..procs import end_forger, stop_group
from .shared import RUNS
from .test_stack import TOL, launch, start_launch

pytestmark = [pytest.mark.ros, pytest.mark.multiprocess]

HERE = Path(__file__).parent
REQUIRE = "FORMATION_ILC_REQUIRE_SECURE"
SECURITY_VARS = ("ROS_SECURITY_KEYSTORE", "ROS_SECURITY_ENABLE", "ROS_SECURITY_STRATEGY",
                 "ROS_SECURITY_ENCLAVE_OVERRIDE")
#: in clear on the wire only without security: a frame id "map" as CDR encodes it (every
#: pose, shared pose and trajectory carries one) and a key of the run's JSON configuration
MAP_CDR = b"\x04\x00\x00\x00map\x00"
RUN_ID_KEY = b'"run_id"'


def secure_problem() -> str | None:
    out = subprocess.run([sys.executable, "-m", "formation_ilc.system.securedds"],
                         capture_output=True, text=True)
    return None if out.returncode == 0 else out.stderr.strip().removeprefix("error: ")


@pytest.fixture(scope="module")
def secure_dds():
    problem = secure_problem()
    if problem and os.environ.get(REQUIRE) == "1":
        pytest.fail(f"DDS-Security: {problem} (required here: CI)")
    if problem:
        pytest.skip(f"DDS-Security: {problem}")


def make_keystore(path: Path, scenario: str = "paper-triangle3") -> Path:
    res = subprocess.run([sys.executable, "-m", "formation_ilc.cli", "keystore", "create",
                          str(path), scenario], capture_output=True, text=True)
    assert res.returncode == 0, res.stderr
    return path


@pytest.fixture(scope="module")
def keystore(tmp_path_factory, secure_dds):
    return make_keystore(tmp_path_factory.mktemp("secure") / "ks")


def plain(env: dict[str, str]) -> dict[str, str]:
    return {k: v for k, v in env.items() if k not in SECURITY_VARS}


def identity(env: dict[str, str], ks: Path, enclave: str) -> dict[str, str]:
    return {**plain(env), "ROS_SECURITY_KEYSTORE": str(ks), "ROS_SECURITY_ENABLE": "true",
            "ROS_SECURITY_STRATEGY": "Enforce", "ROS_SECURITY_ENCLAVE_OVERRIDE": enclave}


GRANT_CASES = {"emulated": ["--links", "emulated"], "direct": ["--links", "direct"],
               "pioneer": ["--plant", "pioneer", "--fake-drivers", "--no-noise"]}


def node_topics(node, ex, expected: set[tuple[str, str]], deadline: float
                ) -> dict[tuple[str, str], tuple[set[str], set[str]]]:
    """(publishers, subscriptions) of each (name, namespace) in ``expected``, from the ROS
    graph. Endpoints are discovered one by one: gather until every node is seen and
    nothing new came for 20 polls."""
    from rclpy.node import NodeNameNonExistentError
    seen: dict[tuple[str, str], tuple[set[str], set[str]]] = {}
    stable = 0
    while time.monotonic() < deadline and stable < 20:
        ex.spin_once(timeout_sec=0.1)  # the graph cache fills meanwhile
        before = {k: (set(p), set(q)) for k, (p, q) in seen.items()}
        for key in node.get_node_names_and_namespaces():
            if key in expected:
                try:
                    pubs = node.get_publisher_names_and_types_by_node(*key)
                    subs = node.get_subscriber_names_and_types_by_node(*key)
                except NodeNameNonExistentError:  # gone since the names were read
                    continue
                pub, sub = seen.setdefault(key, (set(), set()))
                pub |= {t for t, _ in pubs}
                sub |= {t for t, _ in subs}
        stable = stable + 1 if set(seen) == expected and seen == before else 0
    return seen


def _run_roster(case: str, tmp_path: Path):
    """The roster of a GRANT_CASES run and its namespace, as the planner decides them."""
    from formation_ilc.plan.build import decide
    from formation_ilc.plan.machine import Machine
    from formation_ilc.plan.options import LaunchOptions

    kw = ({"plant": "pioneer", "fake_drivers": True, "no_noise": True} if case == "pioneer"
          else {"links": case, "record": tmp_path / "run.mcap"})
    plan = decide(LaunchOptions(scenario="paper-triangle3", trials=100,
                                out=tmp_path / "planned", **kw), Machine())
    return plan.roster, plan.namespace


def _node_key(m, namespace: str) -> tuple[str, str]:
    """(node name, namespace) of member ``m``'s node in the graph: a fake driver's node is
    the driver's own in the driver's namespace."""
    if m.role == "driver":
        from formation_ilc.core.names import FAKE_DRIVER_NODE
        return FAKE_DRIVER_NODE, m.node_namespace
    return m.name, namespace


@pytest.mark.parametrize("case", list(GRANT_CASES))
def test_grants_cover_what_the_nodes_do(ros_env, tmp_path, case):
    """Every topic a node of a real (insecure) run publishes or reads is in its grant: a
    secure run refuses anything else, so a gap would stop the node; and every node of the
    run's roster publishes and reads exactly its member's topics, read from the live graph
    (the grants are the members': none wider than what its node does). Needs no secure
    build."""
    import rclpy
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor
    from std_msgs.msg import String

    import msgs_schema as ms
    from formation_ilc.cli.keystore import grants_for

    pioneer = case == "pioneer"
    # the recorder's grant is checked with the simulator (its run records every topic)
    record = [] if pioneer else ["--record", str(tmp_path / "run.mcap")]
    # trials enough to outlast the look at the graph (a run that ended took its nodes
    # with it while they were read: CI stop 25); the run is stopped after it
    proc = start_launch(ros_env, tmp_path, "paper-triangle3", "--trials", "100",
                        *GRANT_CASES[case], *record)
    grants = grants_for(load_scenario("paper-triangle3"), ms.NAMESPACE,
                        plant="pioneer" if pioneer else "sim")
    f = ms.NAMESPACE
    # every node of the run's roster: its processes and the launcher's monitor (not the
    # operator: a stop button's client of its own, in the monitor's enclave)
    run, run_ns = _run_roster(case, tmp_path)
    members = {_node_key(m, run_ns): m for m in run.members
               if m.entry is not None or m.role == "monitor"}
    expected = set(members)
    robots = {(f"robot_{i}", f) for i in (1, 2, 3)}
    assert robots | {("virtual_leader", f), ("monitor", f)} <= expected, sorted(expected)
    if pioneer:  # a bridge per robot and its driver: enclave driver_i, node fake_pioneer
        assert {("fake_pioneer", f"/pioneer_{i}") for i in (1, 2, 3)} <= expected
    ctx = Context()
    rclpy.init(context=ctx)
    node = None
    try:
        # outside the formation's namespace (the launcher refuses to join one in use)
        node = rclpy.create_node("grant_probe", context=ctx)
        ex = SingleThreadedExecutor(context=ctx)
        ex.add_node(node)
        events: list[str] = []
        node.create_subscription(String, ms.absolute(ms.TRIAL_EVENTS), lambda m:
                                 events.append(m.data), ms.SAMPLE_QOS)
        deadline = time.monotonic() + 400
        while not any('"start"' in e for e in events):
            assert proc.poll() is None, proc.communicate()[0]
            if time.monotonic() > deadline:
                stop_group(proc)
                raise AssertionError(f"the stack did not start trial 1: {events}\n"
                                     f"{proc.communicate()[0][-2000:]}")
            ex.spin_once(timeout_sec=0.05)
        # the leader starts once every node said ready: all have made what they will make
        seen = node_topics(node, ex, expected, deadline)
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown(context=ctx)
        stop_group(proc)
    assert set(seen) == expected, sorted(seen)
    housekeeping = {"/rosout", "/parameter_events"}
    for (name, ns), (pub, sub) in seen.items():
        enclave = f"driver_{ns.rsplit('_', 1)[1]}" if name == "fake_pioneer" else name
        g = grants[f"{f}/{enclave}"]
        assert pub - housekeeping <= set(g.publish), (name, sorted(pub - set(g.publish)))
        assert sub - housekeeping <= set(g.subscribe), (name, sorted(sub - set(g.subscribe)))
    # and every node does what its member of the run's own roster says, no more, no less
    # (the keystore's grants above cover every run of the scenario: a superset)
    differ = {}
    for key, (pub, sub) in seen.items():
        got = (pub - housekeeping, sub - housekeeping)
        want = tuple(set(t) for t in run.topics(members[key], run_ns))
        if got != want:
            differ[f"{key[1].rstrip('/')}/{key[0]}"] = {
                "publishes, not in the roster": sorted(got[0] - want[0]),
                "in the roster, not published": sorted(want[0] - got[0]),
                "reads, not in the roster": sorted(got[1] - want[1]),
                "in the roster, not read": sorted(want[1] - got[1])}
    assert not differ, json.dumps(differ, indent=1)
    # and the check has teeth: the robots do publish their commands, the plant reads them
    plant = ("bridge_2", f) if pioneer else ("robot_sim", f)
    assert f"{f}/robot_2/cmd_vel" in seen[("robot_2", f)][0]
    assert f"{f}/robot_2/cmd_vel" in seen[plant][1]


@pytest.mark.slow
def test_secure_lockstep_equals_batch_simulator(ros_env, tmp_path, keystore):
    """A secure lockstep run equals the batch simulator, while an insider holding robot 3's
    enclave forges what it can (tests/stack/forger.py): a ready in robot_1's name with
    another seed (from its own node, and from a node it names robot_1 in the formation's
    namespace: refused at once, by its enclave) and reports in the plant's name (a contact
    slot that is text, a line of terminal escapes, contacts in a run without bodies) are
    refused by their writer and counted by sender; a burst of trial events and forged
    ``team/poses`` are refused by its permissions when it creates their writers."""
    trials = 12
    forger = subprocess.Popen(
        [sys.executable, str(HERE / "forger.py"), "--ready-as", "3", "--bad-report", "3",
         "--burst-at", "2", "--team-poses", "2", "--impostor", "robot_1"],
        env=identity(ros_env, keystore, "/formation/robot_3"), stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT, text=True, start_new_session=True)
    try:
        res = launch(ros_env, tmp_path, "paper-triangle3", "--trials", str(trials), "--seed",
                     "5", "--secure", str(keystore))
        said = end_forger(forger)
    finally:
        stop_group(forger)
    assert res.returncode == 0, res.stdout
    got = read_metrics(tmp_path / "metrics.csv")
    ref = simulate(load_scenario("paper-triangle3").with_options(seed=5), trials=trials).metrics
    assert got.shape == ref.shape
    np.testing.assert_allclose(got[:, 1:], ref[:, 1:], rtol=0, atol=TOL)
    lines = [json.loads(ln) for ln in said.splitlines() if ln.startswith("{")]
    # robot 3's permissions grant it no writer of the leader's events nor of the plant's
    # poses, nor a reader of the readies
    refused = {d["refused"] for d in lines if "refused" in d}
    assert {"/formation/leader/trial_events", "/formation/team/poses",
            "/formation/ready"} <= refused, said
    assert sorted(d["forged"] for d in lines if "forged" in d) == ["ready", "ready_as_node",
                                                                   "report"], said
    # its ready and its reports in other nodes' names went out and were refused by writer
    forged = json.loads((tmp_path / "summary.json").read_text())["forged"]
    assert forged["virtual_leader"]["/formation/ready"]["/forger/forger"] >= 1, forged
    assert forged["monitor"]["/formation/ready"]["/forger/forger"] >= 1, forged
    assert forged["monitor"]["/formation/diagnostics"]["/forger/forger"] >= 1, forged
    # its node named robot_1: authenticated in robot 3's enclave, not robot_1's, which the
    # GID of its writer says from its first message (no wait for robot_1 to speak again)
    impostor = "/formation/robot_1 (second participant)"
    assert forged["virtual_leader"]["/formation/ready"][impostor] >= 1, forged
    assert forged["monitor"]["/formation/ready"][impostor] >= 1, forged
    log = (tmp_path / "logs" / "virtual_leader.log").read_text()
    assert "named /formation/robot_1" in log and "not authenticated in its enclave" in log
    assert "\x1b" not in res.stdout


def probe(env: dict[str, str], seconds: float, name: str, *ops: str) -> subprocess.Popen[str]:
    return subprocess.Popen([sys.executable, str(HERE / "secure_probe.py"), str(seconds), name,
                             *ops], env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, start_new_session=True)


def result(p: subprocess.Popen[str]) -> dict:
    try:
        out, err = p.communicate(timeout=120)
    finally:
        stop_group(p)
    assert p.returncode == 0, err
    return json.loads(out.strip().splitlines()[-1])


@pytest.mark.slow
def test_outsiders_during_a_secure_run(ros_env, tmp_path, keystore):
    """Three outsiders try their luck while a secure formation learns (robot 3's identity
    may neither call the stop button nor latch the e-stop); then an operator with the
    ground station's identity calls /formation/stop, which ends the run with status 7. Its
    finished trials must equal the batch simulator's."""
    trials = 400
    foreign = make_keystore(tmp_path / "foreign")
    proc = start_launch(ros_env, tmp_path / "run", "paper-triangle3", "--trials", str(trials),
                        "--secure", str(keystore))
    probes = {}
    metrics = tmp_path / "run" / "metrics.csv"
    try:
        deadline = time.monotonic() + 480  # a hang guard: secure start-up is slow under load
        while not (metrics.exists() and len(metrics.read_text().splitlines()) >= 2):
            assert proc.poll() is None, proc.communicate()[0]
            assert time.monotonic() < deadline, "the secure stack did not get to trial 1"
            time.sleep(0.05)
        seconds = 6.0
        probes["plain"] = probe(plain(ros_env), seconds, "intruder",
                                "listen:robot_1/pose:PoseStamped", "listen:config:String",
                                "publish:robot_2/cmd_vel:Twist")
        probes["robot_3"] = probe(identity(ros_env, keystore, "/formation/robot_3"), seconds,
                                  "robot_3", "listen:robot_3/pose:PoseStamped",
                                  "publish:robot_2/cmd_vel:Twist",
                                  "publish:leader/trial_events:String",
                                  # the stop button is the ground station's alone
                                  "call:stop:Trigger", "publish:estop:Bool")
        probes["foreign"] = probe(identity(ros_env, foreign, "/formation/robot_3"), seconds,
                                  "robot_3", "listen:robot_3/pose:PoseStamped",
                                  "listen:robot_1/shared_pose:PoseStamped")
        got = {k: result(p) for k, p in probes.items()}
        # the probes ran while the formation did (else they would prove nothing)
        assert proc.poll() is None, proc.communicate()[0]
        done_while_probed = len(metrics.read_text().splitlines()) - 1
        # the ground station's identity may press the stop button: the run ends, status 7
        got["operator"] = result(probe(identity(ros_env, keystore, "/formation/monitor"),
                                       seconds, "operator", "call:stop:Trigger"))
        stdout = proc.communicate(timeout=120)[0]
    finally:
        for p in probes.values():
            stop_group(p)
        stop_group(proc)  # SIGINT: the finished trials stay in metrics.csv
    ops = got["plain"]["ops"]
    # nothing refuses its readers and writers locally, and no one lets it in
    assert all(o["created"] for o in ops.values()), ops
    assert all(o["received"] == 0 and o["matched"] == 0 for o in ops.values()), ops
    ops = got["robot_3"]["ops"]
    assert ops["listen:robot_3/pose:PoseStamped"]["received"] > 0, ops  # it is authenticated
    for op in ("publish:robot_2/cmd_vel:Twist", "publish:leader/trial_events:String",
               "call:stop:Trigger", "publish:estop:Bool"):
        assert not ops[op]["created"], ops  # refused at creation, by its own permissions
        assert "error" in ops[op]
    ops = got["foreign"]["ops"]
    assert all(o["received"] == 0 and o["matched"] == 0 for o in ops.values()), ops
    ops = got["operator"]["ops"]
    assert ops["call:stop:Trigger"]["created"] and ops["call:stop:Trigger"]["received"] >= 1
    assert proc.returncode == 7, stdout
    assert "stopped by /formation/stop called by /formation/operator" in stdout, stdout
    # the forged commands changed nothing: the trials equal the batch simulator's
    got_m = read_metrics(metrics)
    assert len(got_m) >= max(done_while_probed, 2)
    ref = simulate(load_scenario("paper-triangle3"), trials=len(got_m)).metrics
    np.testing.assert_allclose(got_m[:, 1:], ref[:, 1:], rtol=0, atol=TOL)


@pytest.mark.slow
def test_secure_pioneer_bridges_and_fake_drivers(ros_env, tmp_path, secure_dds):
    """Bridges and (fake) drivers run in their enclaves: the bridge's driver topics and
    motor service, and the driver's own services, are in the derived permissions."""
    from .test_pioneer import pioneer_args

    res = subprocess.run([sys.executable, "-m", "formation_ilc.cli", "keystore", "create",
                          str(tmp_path / "ks"), "paper-triangle3", "--plant", "pioneer"],
                         capture_output=True, text=True)
    assert res.returncode == 0, res.stderr
    out = tmp_path / "run"
    res = launch(ros_env, out, *pioneer_args("--trials", "1", "--secure",
                                             str(tmp_path / "ks")), timeout=400)
    assert res.returncode == 0, res.stdout
    got = read_metrics(out / "metrics.csv")
    assert got.shape[0] == 1 and np.isfinite(got[:, [1, 2]]).all()
    assert "return timeouts 0" in res.stdout  # every bridge drove its robot back


@pytest.mark.slow
def test_secure_robots_on_separate_hosts(netns_support, ros_env, tmp_path, secure_dds):
    """Robots in network namespaces of their own (--hosts netns), each in its enclave."""
    from .test_realtime import short_scenario

    scen = short_scenario(tmp_path)
    ks = make_keystore(tmp_path / "ks", str(scen))
    trials = 2
    res = launch(ros_env, tmp_path / "run", str(scen), "--trials", str(trials), "--hosts",
                 "netns", "--secure", str(ks), timeout=300)
    assert res.returncode == 0, res.stdout
    got = read_metrics(tmp_path / "run" / "metrics.csv")
    assert got.shape[0] == trials and np.isfinite(got[:, 1:3]).all()
    summary = json.loads((tmp_path / "run" / "summary.json").read_text())
    assert len(summary["hosts"]["namespaces"]) >= 3  # the robots were on hosts of their own


def capture_problem() -> str | None:
    if os.geteuid() != 0:
        return "capturing in a network namespace of its own needs root"
    for tool in ("unshare", "ip"):
        if shutil.which(tool) is None:
            return f"{tool}: not found"
    return None


def captured_run(env: dict[str, str], out: Path, udp_only: bool, keystore: Path | None
                 ) -> dict:
    """A 3-trial run in a private network namespace; what its processes sent in clear."""
    cmd = [sys.executable, "-m", "formation_ilc.cli", "launch", "paper-triangle3",
           "--trials", "3", "--out", str(out), "--domain-id", env["ROS_DOMAIN_ID"],
           "--no-plots", "--timeout", "20"]
    if keystore is not None:
        cmd += ["--secure", str(keystore)]
    run_env = dict(plain(env))
    if udp_only:
        # localhost discovery makes rmw choose its transports (shared memory first); in a
        # namespace whose only interface is lo, Fast DDS's own discovery is as contained
        # and honours FASTDDS_BUILTIN_TRANSPORTS
        cmd += ["--discovery", "inherit"]
        run_env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "SUBNET"
        run_env["FASTDDS_BUILTIN_TRANSPORTS"] = "UDPv4"
    markers = ",".join(m.hex() for m in (MAP_CDR, RUN_ID_KEY))
    p = subprocess.Popen(["unshare", "-n", sys.executable, str(HERE / "secure_capture.py"),
                          markers, "--", *cmd], env=run_env, stdout=subprocess.PIPE,
                         stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        stdout, stderr = p.communicate(timeout=400)
    finally:
        stop_group(p)
    assert p.returncode == 0, stderr
    rep = json.loads(stdout.strip().splitlines()[-1])
    assert rep["status"] == 0, rep["output"]
    # a capture that lost datagrams proves nothing either way (a busy machine dropped 40 %
    # of them from a default-sized buffer, and with them every configuration message)
    assert rep["udp_dropped"] == 0, {k: v for k, v in rep.items() if k != "output"}
    return rep


@pytest.mark.slow
@pytest.mark.parametrize("udp_only", [True, False], ids=["udp", "shared-memory"])
def test_no_plaintext_leaves_a_process(ros_env, tmp_path, keystore, udp_only):
    problem = capture_problem()
    if problem and os.environ.get(REQUIRE) == "1":
        pytest.fail(f"capture: {problem} (required here: CI)")
    if problem:
        pytest.skip(f"capture: {problem}")
    where = "udp_hits" if udp_only else "shm_hits"
    insecure = captured_run(ros_env, tmp_path / "insecure", udp_only, None)
    # the search works: without security the poses and the configuration are in clear
    assert insecure[where][0] > 0 and insecure[where][1] > 0, insecure
    secure = captured_run(ros_env, tmp_path / "secure", udp_only, keystore)
    if udp_only:
        assert secure["udp_packets"] > 1000, secure  # the run's traffic was captured
    else:
        assert secure["shm_segments"] > 0 and secure["shm_reads"] > 0, secure
    assert secure[where] == [0, 0], secure


def _secure_run_probed(env: dict[str, str], out: Path, ks: Path, args: list[str],
                       first_rows: int = 1, seconds: float = 5.0,
                       also: Callable[[], bool] = lambda: True) -> tuple[dict, str, bool]:
    """A secure launch of ``args`` (long enough to outlast the probe), an unsecured
    participant listening to it once ``first_rows`` trials are in (and ``also`` holds),
    then the launch stopped (SIGINT: the finished trials stay in metrics.csv). (probe
    result, the launcher's output, whether the run was still going when the probe was
    done)."""
    proc = start_launch(env, out, *args, "--secure", str(ks))
    metrics = out / "metrics.csv"
    p = None
    try:
        deadline = time.monotonic() + 600  # a hang guard: secure start-up is slow under load
        while not (metrics.exists() and len(metrics.read_text().splitlines()) > first_rows
                   and also()):
            assert proc.poll() is None, proc.communicate()[0]
            assert time.monotonic() < deadline, "the secure run did not get to its trials"
            time.sleep(0.05)
        p = probe(plain(env), seconds, "intruder", "listen:robot_1/pose:PoseStamped",
                  "listen:config:String", "listen:leader/trial_events:String")
        got = result(p)
        alive = proc.poll() is None
    finally:
        if p is not None:
            stop_group(p)
        stop_group(proc)
    return got, proc.communicate()[0], alive


def _nothing_received(got: dict) -> None:
    ops = got["ops"]
    assert all(o["created"] for o in ops.values()), ops  # nothing refuses it locally
    assert all(o["received"] == 0 and o["matched"] == 0 for o in ops.values()), ops


def _keystore(path: Path, scenario: str, *extra: str) -> Path:
    res = subprocess.run([sys.executable, "-m", "formation_ilc.cli", "keystore", "create",
                          str(path), scenario, *extra], capture_output=True, text=True)
    assert res.returncode == 0, res.stderr
    return path


@pytest.mark.slow
def test_secure_physics_plant_equals_the_insecure_run(ros_env, tmp_path, secure_dds):
    """``launch --secure --plant physics``: the physics plant in its enclave (its grants
    from the roster: the simulator's topics), lockstep, equal to the same run insecure to
    round-off (the engine is deterministic), an unsecured participant receiving nothing."""
    pytest.importorskip("pybullet")
    from .test_physics_stack import short_triangle

    scen = str(short_triangle(tmp_path / "short.yaml"))
    ks = _keystore(tmp_path / "ks", scen, "--plant", "physics")
    common = [scen, "--plant", "physics", "--no-noise", "--no-delay", "--links", "direct"]
    got, out, alive = _secure_run_probed(ros_env, tmp_path / "secure", ks,
                                         [*common, "--trials", "60"])
    assert alive, out  # the probe listened while the formation ran
    _nothing_received(got)
    secure = read_metrics(tmp_path / "secure" / "metrics.csv")
    assert len(secure) >= 2, out
    # the insecure run of the same options: test_physics_stack's (3 trials), else our own
    insecure = RUNS.get(("physics", (Path(scen).read_text(),)))
    if insecure is None:
        res = launch(ros_env, tmp_path / "insecure", *common, "--trials", "3", timeout=600)
        assert res.returncode == 0, res.stdout
        insecure = read_metrics(tmp_path / "insecure" / "metrics.csv")
    k = min(len(secure), len(insecure))
    np.testing.assert_allclose(secure[:k], insecure[:k], rtol=0, atol=TOL)


@pytest.mark.slow
def test_secure_bases_with_physics_bases_equal_the_insecure_run(ros_env, tmp_path, secure_dds):
    """``launch --secure --plant base --physics-bases``: each bridge and the physics bases
    in their enclaves (the bases' cmd_vel and odometry granted from the roster). Wall-clock
    trials against physics in wall time are not repeatable to round-off: the secure run's
    first trial (nothing learned yet: what the secured data path delivers) equals the
    insecure run's within 15 % of its error (or BATCH_ATOL), both runs learn, and an
    unsecured participant receives nothing. (What a secured robot learns is checked to
    round-off by the lockstep secure runs; a wall-clock learned trial also carries where
    the return left each robot.) (The run is stopped once the probe is done:
    its report, written after the bridges' last return, is not waited for.) An insider
    holding robot 3's enclave tries to send every base's true pose 1 km away (forger.py
    ``--truth``): its permissions refuse it each writer at creation."""
    pytest.importorskip("pybullet")
    from .test_base_physics import base_key
    from .test_pioneer import BATCH_ATOL

    scen = tmp_path / "short.yaml"
    scen.write_text(load_scenario("paper-triangle3").text.replace("samples: 140",
                                                                  "samples: 40"))
    ks = _keystore(tmp_path / "ks", str(scen), "--plant", "base", "--base", "turtlebot4",
                   "--physics-bases")
    common = [str(scen), "--plant", "base", "--base", "turtlebot4", "--physics-bases",
              "--no-noise", "--return-timeout", "40"]
    # the time scale that fits the base's limits, as the refusal names it (no process runs)
    refused = launch(ros_env, tmp_path / "refused", *common, "--trials", "2", timeout=120.0)
    assert refused.returncode == 2, refused.stdout
    scale = refused.stdout.rsplit("--time-scale ", 1)[1].split()[0]
    common += ["--time-scale", scale]
    said_file = tmp_path / "forger.out"

    def tried_every_truth() -> bool:
        # the run goes on until the insider has found all three truth topics (a secure
        # graph lists a participant's writers one by one: a run stopped after its second
        # trial once left the insider with two of three, 2026-12-07); an insider that
        # ended is not waited for (what it said is asserted below)
        return forger.poll() is not None or said_file.read_text().count('/truth"') >= 3

    with said_file.open("w") as fh:
        forger = subprocess.Popen(
            [sys.executable, str(HERE / "forger.py"), "--truth", "0", "--timeout", "600"],
            env=identity(ros_env, ks, "/formation/robot_3"), stdout=fh,
            stderr=subprocess.STDOUT, text=True, start_new_session=True)
    try:
        got, out, alive = _secure_run_probed(ros_env, tmp_path / "secure", ks,
                                             [*common, "--trials", "30"], first_rows=2,
                                             also=tried_every_truth)
        end_forger(forger)
        said = said_file.read_text()
    finally:
        stop_group(forger)
    assert alive, out
    _nothing_received(got)
    # it found every base's truth topic and was refused a writer on each
    lines = [json.loads(ln) for ln in said.splitlines() if ln.startswith("{")]
    refused = {d["refused"] for d in lines if "refused" in d}
    assert len({t for t in refused if t.endswith("/truth")}) == 3, said
    assert not any("forged" in d for d in lines), said
    assert forger.returncode == 0, said
    secure = read_metrics(tmp_path / "secure" / "metrics.csv")
    assert len(secure) >= 2, out
    # the insecure run of the same options: test_base_physics's (3 trials), else our own
    insecure = RUNS.get(base_key(scen.read_text(), scale))
    if insecure is None:
        res = launch(ros_env, tmp_path / "insecure", *common, "--trials", "2", timeout=900)
        assert res.returncode == 0, res.stdout
        insecure = read_metrics(tmp_path / "insecure" / "metrics.csv")
    k = min(len(secure), len(insecure))
    assert k >= 2 and insecure[k - 1, 1] < insecure[0, 1] and secure[k - 1, 1] < secure[0, 1]
    # trial 0 (nothing learned yet) within what two wall-clock runs of a physics in wall time
    # differ by: 0.27 m on 2.45 m (11 %) in a fresh-clone CI (2026-12-07). A learned trial is
    # not compared: it carries the previous trial's timing and where the return stopped each
    # robot (within the return's tolerance) into its memory: the two runs' trial 1 differed
    # by 11 %, 18 % and 27 % (0.53 m on 1.92 m) in three pairs of runs on 2026-12-07, their
    # trial 0 within 11 % each time, so it measures the return and the load, not the
    # security; what a secured robot learns equals the insecure to round-off in
    # test_secure_physics_plant_equals_the_insecure_run and the lockstep tests
    assert (np.abs(secure[0, 1:3] - insecure[0, 1:3])
            <= np.maximum(BATCH_ATOL, 0.15 * np.abs(insecure[0, 1:3]))).all(), (
        secure[0, 1:3], insecure[0, 1:3])


@pytest.mark.slow
def test_secure_host_launchers_each_with_its_bundle(ros_env, tmp_path, secure_dds):
    """One command per machine under --secure, four machines on one: ``keystore create DIR
    RUN.yaml`` makes a bundle per host, and each host's launcher runs with its own bundle
    only (``--secure DIR/bundles/HOST``). The run equals the batch simulator. An insider
    holding robot 3's bundle names a node robot_1 and says ready from it: the ground
    station's leader knows robot_1's certificate from its bundle's public part alone, and
    refuses the ready at once as not of robot_1's enclave."""
    from formation_ilc.cli.commands import main

    from .test_host_launchers import launcher

    trials = 4
    run_file, out, ks = tmp_path / "run.yaml", tmp_path / "run", tmp_path / "keys"
    assert main(["run-file", "paper-triangle3", "--trials", str(trials), "--seed", "5",
                 "--no-plots", "--domain-id", ros_env["ROS_DOMAIN_ID"], "--out", str(out),
                 "--host-per-robot", "-o", str(run_file)]) == 0
    assert main(["keystore", "create", str(ks), str(run_file)]) == 0
    hosts = ("r1", "r2", "r3", "ground")
    forger = subprocess.Popen(
        [sys.executable, str(HERE / "forger.py"), "--ready-as", "1", "--impostor", "robot_1"],
        env=identity(ros_env, ks / "bundles" / "r3", "/formation/robot_3"),
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, start_new_session=True)
    procs: dict[str, subprocess.Popen] = {}
    try:
        for h in hosts:
            procs[h] = launcher(ros_env, run_file, h, tmp_path / f"{h}.log",
                                "--secure", str(ks / "bundles" / h))
        assert procs["ground"].wait(timeout=300) == 0, (tmp_path / "ground.log").read_text()
        for h in hosts[:3]:
            assert procs[h].wait(timeout=30) == 0, (tmp_path / f"{h}.log").read_text()
        said = end_forger(forger)
    finally:
        for p in [forger, *procs.values()]:
            stop_group(p)
    got = read_metrics(out / "metrics.csv")
    ref = simulate(load_scenario("paper-triangle3").with_options(seed=5), trials=trials).metrics
    np.testing.assert_allclose(got[:, 1:7], ref[:, 1:7], rtol=0, atol=TOL)
    assert any(json.loads(ln).get("forged") == "ready_as_node"
               for ln in said.splitlines() if ln.startswith("{")), said
    forged = json.loads((out / "summary.json").read_text())["forged"]
    impostor = "/formation/robot_1 (second participant)"
    assert forged["virtual_leader"]["/formation/ready"][impostor] >= 1, forged
    log = (out / "logs" / "virtual_leader.log").read_text()
    assert "named /formation/robot_1" in log and "not authenticated in its enclave" in log
