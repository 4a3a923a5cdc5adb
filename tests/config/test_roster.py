"""The roster against the answers the stack gave before it existed, frozen.

``data/roster_golden.json`` holds what the code at 88c1f6a answered (made by
``data/make_roster_golden.py`` on a checkout of it), before the roster replaced its three
separate rules: the leader's team (``config.team.Team.of``) for 1, 3 and
6 robots on every plant, links, monitor and recorder; every process of ``formation-ilc
launch`` (``plan.processes.node_specs`` through ``build_plan``: name, module, arguments, remaps,
parameters, restart policy, host) with the team, the awaited reporters and the plant's
kind, for every plant x links x record x live combination of paper-triangle3 and more
(containers, namespaces, drivers, fake drivers, physics bases); and the keystore's grants
(``config.enclaves.formation_grants``) of two scenarios in two namespaces for the
simulator and the Pioneer drivers. Each answer must stay what it was: keystores made before
stay valid, launches start the same processes with the same command lines. The one
difference is what the safety filter (added at 88c1f6a) reads and its grants never had:
every other robot's pose and the plant's ``team/poses`` (as main granted them from
77a8d24 on); and the clock exchanges (``protocol.timesync``, issue 29): a node's own
``clock/ping`` and ``clock/pong`` as the graph gives them, and the ones of the nodes it
asks or answers. Those permissions are added, and only those. And a run of physics bases
has the true state (issue 33): the bases publish their true poses and each bridge the
trial's true trajectory (``truth`` true in both nodes' parameters, ``_with_bases_truth``).
And two permissions are gone (issue 55: a member is exactly what its node does): the
monitor reads true trajectories only where some node writes them, not behind the Pioneer's
bridges, and a Pioneer driver's enclave no longer writes the fake driver's truth report,
which no launched driver makes (``_without_unwritten_truth``).
"""

from __future__ import annotations

import json
import socket
from importlib.metadata import entry_points
from pathlib import Path
from typing import Any

import pytest

from formation_ilc.cli.commands import build_parser
from formation_ilc.cli.runfile import plan_of
from formation_ilc.config.roster import ENTRY_SCRIPTS, Lineup, roster
from formation_ilc.config.safety import default_motion
from formation_ilc.config.scenario import load_scenario
from formation_ilc.core.names import (
    TEAM_POSES,
    absolute,
    applied_topic,
    pose_topic,
    whereabouts_topic,
)

GOLDEN = json.loads((Path(__file__).parent / "data" / "roster_golden.json").read_text())


#: plants whose robots have bodies, and the scenario their runs took (data/make_roster_golden)
BODIES = ("physics", "pioneer", "base")
BODY_SCENARIO = Path(__file__).parents[2] / "docs" / "examples" / "hexagon6-p3dx.yaml"


def _golden(part: str) -> dict[str, dict]:
    return {k.split("|", 1)[1]: v for k, v in GOLDEN.items() if k.startswith(part + "|")}


def _with_bases_truth(plan: dict) -> dict:
    """The golden ``plan`` as a run of physics bases is planned since they tell their
    bridges the true poses: ``truth`` true in the bases' and the bridges' parameters, and
    the run has the true state."""
    if not any(n["name"] == "physics_bases" for n in plan["nodes"]):
        return plan
    nodes = [{**n, "params": [*n["params"], ["truth", True]]}
             if n["name"] == "physics_bases" or n["name"].startswith("bridge_") else n
             for n in plan["nodes"]]
    return {**plan, "true_state": True, "nodes": nodes}


def _with_located_bridges(plan: dict) -> dict:
    """The golden ``plan`` of physics bases since their ground truth is the rehearsal's
    motion capture (issue 52, ``--pose truth``, the default): each bridge's ``pose_topic``
    names the bases' true pose after ``truth``; nothing else changed."""
    if not any(n["name"] == "physics_bases" for n in plan["nodes"]):
        return plan
    nodes = [{**n, "params": [*n["params"], ["pose_topic", "truth"]]}
             if n["name"].startswith("bridge_") else n for n in plan["nodes"]]
    return {**plan, "nodes": nodes}


def _with_bases_following_trials(plan: dict) -> dict:
    """The golden ``plan`` of physics bases as planned since they follow the trials (issue
    37: their contacts are counted per trial and return, and a contact asks the leader to
    abort its trial): a support member the leader waits for (after the bridges, before the
    passive nodes) and whose trial reports the launcher waits for (after the plants), with
    the contact parameters of the physics plant; nothing else changed."""
    if not any(n["name"] == "physics_bases" for n in plan["nodes"]):
        return plan
    name = "physics_bases"

    def expected(names: list[str]) -> list[str]:
        passive = [x for x in names if x in ("monitor", "recorder")]
        return [x for x in names if x not in passive] + [name] + passive

    team = dict(plan["team"])
    team["support"] = [*team["support"], name]
    team["expected"] = expected(team["expected"])
    reporters = list(plan["reporters"])
    plants = [r for r in reporters if r.startswith("bridge_")]
    reporters = plants + [name] + [r for r in reporters if r not in plants]
    nodes = []
    for n in plan["nodes"]:
        if n["name"] == name:
            n = {**n, "params": [*n["params"], ["on_contact", "stop"],
                                 ["contact_retries", 2], ["tilt_limit", 10.0]]}
        elif n["name"] == "virtual_leader":
            n = {**n, "params": [[k, expected(v) if k == "nodes_expected" else v]
                                 for k, v in n["params"]]}
        nodes.append(n)
    return {**plan, "team": team, "reporters": reporters, "nodes": nodes}


def _with_damped_learning(plan: dict) -> dict:
    """The golden ``plan`` with the safety filter's default learning on two wheels since
    it became ``damped`` (issue 37, docs/safety.md): the leader's ``safety`` parameter says
    so; nothing else of the plan changed."""
    text = json.dumps(plan).replace('\\"learning\\": \\"applied\\"',
                                    '\\"learning\\": \\"damped\\"')
    return json.loads(text)


def _with_robust_learning(plan: dict, pose_noise: bool) -> dict:
    """The golden ``plan`` since two-wheel teams learn ``robust`` through the filter when
    the scenario's poses are noisy (issue 52, docs/safety.md "Noise, and the limits"): the
    leader's ``safety`` parameter says so; nothing else of the plan changed."""
    if not pose_noise:
        return plan
    text = json.dumps(plan).replace('\\"learning\\": \\"damped\\"',
                                    '\\"learning\\": \\"robust\\"')
    return json.loads(text)


def _with_motion(plan: dict, motion: str) -> dict:
    """The golden ``plan`` since the safety settings say where a robot takes the other
    robots' speeds from (issue 52: ``motion``, by default 'commands' up to 12 robots): the
    leader's ``safety`` parameter carries it after ``sensing``; nothing else of the plan
    changed."""
    text = json.dumps(plan)
    for sensing in ("team", "peers"):
        text = text.replace(f'\\"sensing\\": \\"{sensing}\\"}}',
                            f'\\"sensing\\": \\"{sensing}\\", \\"motion\\": \\"{motion}\\"}}')
    return json.loads(text)


def _with_one_limits_table(plan: dict) -> dict:
    """The golden ``plan`` as the filter reads its limits since each base has one limits
    table (issue 37, ``config.bases``): the leader's ``safety`` parameter holds its body's
    row (a physics P3-DX drives within the Pioneer bridge's 0.75 m/s and 100 deg/s, no
    longer the datasheet's 1.2 m/s and 300 deg/s; TurtleBot 4 bases within their own
    preset's, no longer a P3-DX's) tightened by every bridge's limit parameters (m/s,
    deg/s, m/s^2, deg/s^2); nothing else of the plan changed."""
    import math

    from formation_ilc.config.bases import BASES

    def fixed(node: dict) -> dict:
        params = []
        for key, value in node["params"]:
            if key == "safety" and value:
                safety = json.loads(value)
                lim = list(BASES[safety["body"]].limits.as_tuple())
                for other in plan["nodes"]:
                    if other["name"].startswith("bridge_"):
                        given = dict(other["params"])
                        for k, name in enumerate(("v_max", "omega_max", "a_max", "alpha_max")):
                            x = float(given.get(name, 0.0))
                            x = math.radians(x) if name in ("omega_max", "alpha_max") else x
                            lim[k] = min(lim[k], x) if x > 0 else lim[k]
                value = json.dumps({**safety, "limits": lim})
            params.append([key, value])
        return {**node, "params": params}

    return {**plan, "nodes": [fixed(n) for n in plan["nodes"]]}


def _with_new_example(plan: dict) -> dict:
    """The golden ``plan`` of physics bases with the start poses (the desired poses at
    t = 0) of today's ``hexagon6-p3dx`` example, whose figure eight was halved to fit a
    P3-DX's 0.75 m/s (issue 37): the golden's poses must be the old example's
    (``data/hexagon6-p3dx-golden.yaml``) exactly, and only they are replaced."""
    def starts(path: Path) -> list[float]:
        sc = load_scenario(str(path)).with_options(headings="arc")  # as the launch plans it
        return [float(x) for x in sc.desired.eta[:, 0].ravel()]

    nodes = []
    for n in plan["nodes"]:
        if n["name"] == "physics_bases":
            given = dict(n["params"])
            assert given["poses"] == starts(Path(__file__).parent / "data"
                                            / "hexagon6-p3dx-golden.yaml")
            n = {**n, "params": [[k, starts(BODY_SCENARIO) if k == "poses" else v]
                                 for k, v in n["params"]]}
        nodes.append(n)
    return {**plan, "nodes": nodes}


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def test_the_golden_answers_are_all_there():
    assert GOLDEN["generated_from"] == "88c1f6a"
    assert len(_golden("teams")) == 120 and len(_golden("grants")) == 16
    assert len(_golden("plans")) == 48


@pytest.mark.parametrize("key", sorted(_golden("teams")))
def test_the_team_is_the_one_the_leader_waited_for(key):
    n, plant, links, monitor, recorder = key.split("|")
    r = roster(Lineup(int(n), plant=plant, links=links, monitor=monitor == "1",
                      record=recorder == "1", external=("ext_a", "ext_b")))
    team = r.team
    want = _golden("teams")[key]
    assert [list(team.robots), list(team.plants), list(team.support), list(team.passive),
            team.expected] == [want["robots"], want["plants"], want["support"],
                               want["passive"], want["expected"]]


def _take_own_and_peers(got: dict, suffix: str, prefix: str | None, topic: Any,
                        namespace: str, n: int) -> None:
    """Check and take out of the grants ``got`` the topics ending in ``/suffix``: node
    ``PREFIX``i publishes ``topic(i)`` and reads every other member's ``topic(j)``; no
    other node touches them (None: no node at all)."""
    for path, g in got.items():
        name = path.rsplit("/", 1)[1]
        pub = {t for t in g["publish"] if t.endswith(f"/{suffix}")}
        sub = {t for t in g["subscribe"] if t.endswith(f"/{suffix}")}
        tail = name[len(prefix):] if prefix is not None and name.startswith(prefix) else ""
        if tail.isdigit():
            i = int(tail)
            assert pub == {absolute(topic(i), namespace)}, name
            assert sub == {absolute(topic(j), namespace)
                           for j in range(1, n + 1) if j != i}, name
        else:
            assert not pub and not sub, name
        g["publish"] = [t for t in g["publish"] if t not in pub]
        g["subscribe"] = [t for t in g["subscribe"] if t not in sub]


@pytest.mark.parametrize("key", sorted(_golden("grants")))
def test_every_enclave_keeps_its_grant(key):
    scenario, namespace, plant, driver, driver_ns = key.split("|")
    sc = load_scenario(scenario)
    lineup = Lineup.of(sc.graph, plant=plant, driver=driver,
                       driver_ns=driver_ns if plant == "pioneer" else None).for_keystore()
    got = {path: {"enclave": g.enclave, "node": g.node, "node_namespace": g.node_namespace,
                  "publish": list(g.publish), "subscribe": list(g.subscribe),
                  "dds_publish": list(g.dds_publish), "dds_subscribe": list(g.dds_subscribe),
                  "service_node": g.service_node}
           for path, g in roster(lineup).grants(namespace).items()}
    # what the safety filter reads, granted now: the plant's team poses, or the peers' poses
    n = sc.n
    added: dict[str, tuple[set[str], set[str]]] = {}
    clocks = _clock_grants(sc, namespace, bridges=plant == "pioneer")
    for path, g in got.items():
        name = path.rsplit("/", 1)[1]
        # the clock exchanges (issue 29), granted now: exactly these, and only these
        cpub = {t for t in g["publish"] if "/clock/p" in t}
        csub = {t for t in g["subscribe"] if "/clock/p" in t}
        assert (cpub, csub) == clocks.get(name, (set(), set())), name
        g["publish"] = [t for t in g["publish"] if t not in cpub]
        g["subscribe"] = [t for t in g["subscribe"] if t not in csub]
        pub = {t for t in g["publish"] if t == absolute(TEAM_POSES, namespace)}
        sub = {t for t in g["subscribe"] if t == absolute(TEAM_POSES, namespace)}
        if name.startswith("robot_") and name[6:].isdigit():
            i = int(name[6:])
            sub |= {absolute(pose_topic(j), namespace) for j in range(1, n + 1) if j != i}
        g["publish"] = [t for t in g["publish"] if t not in pub]
        g["subscribe"] = [t for t in g["subscribe"] if t not in sub]
        if pub or sub:
            added[name] = (pub, sub)
    # the standard diagnostics stream (issue 30), granted now to every node that reports
    for g in got.values():
        reports = absolute("diagnostics", namespace) in g["publish"]
        assert ("/diagnostics" in g["publish"]) == reports, g
        g["publish"] = [t for t in g["publish"] if t != "/diagnostics"]
        g["dds_publish"] = [t for t in g["dds_publish"] if t != "rt/diagnostics"]
    # the nodes' reports, read by the leader (issue 32: its watchdog names the endpoints a
    # node still waits for at start-up), granted now
    diag = absolute("diagnostics", namespace)
    g = next(g for path, g in got.items() if path.endswith("/virtual_leader"))
    assert diag in g["subscribe"]
    g["subscribe"] = [t for t in g["subscribe"] if t != diag]
    # the returns' safety filter (issue 37): each bridge says where its robot is between
    # trials and reads every other bridge's, granted now; nobody else
    _take_own_and_peers(got, "whereabouts", "bridge_", whereabouts_topic, namespace, n)
    # the commands the robots tell each other for their filters (issue 52): each robot
    # publishes its own robot_i/applied and reads every other robot's, where the robots
    # have a filter to hear the others with; nobody else
    _take_own_and_peers(got, "applied", "robot_" if lineup.sensing is not None else None,
                        applied_topic, namespace, n)
    _take_stop_button(got, namespace)
    _take_frames(got, plant)
    assert got == _without_unwritten_truth(_golden("grants")[key], lineup)
    team = absolute(TEAM_POSES, namespace)
    robots = {f"robot_{i}" for i in range(1, n + 1)}
    peers = {r: {absolute(pose_topic(j), namespace) for j in range(1, n + 1)
                 if f"robot_{j}" != r} for r in robots}
    assert added == {**({"robot_sim": ({team}, set())} if plant == "sim" else {}),
                     **{r: (set(), {team} | peers[r]) for r in robots}}


def _without_unwritten_truth(want: dict[str, dict], lineup: Lineup) -> dict[str, dict]:
    """The golden grants without the monitor's reads of the true trajectories where no
    plant of ``lineup`` has a true state (the monitor makes no reader of them there), and
    without the drivers' writers of the fake driver's truth report (a test's, by hand)."""
    out = {path: dict(g) for path, g in want.items()}
    for path, g in out.items():
        if path.endswith("/monitor") and not lineup.true_state:
            g["subscribe"] = [t for t in g["subscribe"] if not t.endswith("/true_trajectory")]
        if "/driver_" in path:
            g["publish"] = [t for t in g["publish"] if not t.endswith("/fake_pioneer/truth")]
    return out


def _take_stop_button(got: dict[str, dict], namespace: str) -> None:
    """The stop button (issue 54), granted now, checked and taken out: the e-stop latched
    by the leader and the ground station's monitor, obeyed by every robot and bridge, read
    by the leader, the monitor, the recorder and the live view; the leader serves ``stop``
    and the monitor alone calls it."""
    estop = absolute("estop", namespace)
    rq, rr = f"rq{namespace}/stopRequest", f"rr{namespace}/stopReply"
    for path, g in got.items():
        name = path.rsplit("/", 1)[1]
        head, _, tail = name.rpartition("_")
        writes = name in ("virtual_leader", "monitor")
        reads = writes or name in ("recorder", "liveview") or (
            head in ("robot", "bridge") and tail.isdigit())
        assert (estop in g["publish"]) == writes, name
        assert (estop in g["subscribe"]) == reads, name
        g["publish"] = [t for t in g["publish"] if t != estop]
        g["subscribe"] = [t for t in g["subscribe"] if t != estop]
        pub, sub = {"virtual_leader": ([rr], [rq]), "monitor": ([rq], [rr])}.get(name, ([], []))
        assert [t for t in g["dds_publish"] if t in (rq, rr)] == pub, name
        assert [t for t in g["dds_subscribe"] if t in (rq, rr)] == sub, name
        g["dds_publish"] = [t for t in g["dds_publish"] if t not in (rq, rr)]
        g["dds_subscribe"] = [t for t in g["dds_subscribe"] if t not in (rq, rr)]


def _take_frames(got: dict[str, dict], plant: str) -> None:
    """The frames (issue 54), granted now, checked and taken out: /tf written by the leader
    (its reference frame) and the plant's nodes (the simulator, each bridge), which write
    /tf_static too; both read by the recorder and the live view; nobody else."""
    plants = {"robot_sim"} if plant == "sim" else {n for p in got for n in [p.rsplit("/", 1)[1]]
                                                   if n.startswith("bridge_")}
    for path, g in got.items():
        name = path.rsplit("/", 1)[1]
        pub = {t for t in g["publish"] if t in ("/tf", "/tf_static")}
        sub = {t for t in g["subscribe"] if t in ("/tf", "/tf_static")}
        assert pub == ({"/tf", "/tf_static"} if name in plants else
                       {"/tf"} if name == "virtual_leader" else set()), name
        assert sub == ({"/tf", "/tf_static"} if name in ("recorder", "liveview") else set()), name
        g["publish"] = [t for t in g["publish"] if t not in pub]
        g["subscribe"] = [t for t in g["subscribe"] if t not in sub]
        # the bodies: each robot's URDF from the plant that drives it (the simulator all,
        # bridge i its own), recorded and viewed
        desc = {t for t in g["publish"] if t.endswith("/robot_description")}
        want = ({t for t in desc} if name == "robot_sim" and len(desc) >= 3 else
                {t for t in desc if t.split("/")[-2] == f"robot_{name[7:]}"}
                if name.startswith("bridge_") and len(desc) == 1 else set())
        assert desc == want, (name, desc)
        g["publish"] = [t for t in g["publish"] if t not in desc]
        rd = {t for t in g["subscribe"] if t.endswith("/robot_description")}
        assert bool(rd) == (name in ("recorder", "liveview")), name
        g["subscribe"] = [t for t in g["subscribe"] if t not in rd]


def _clock_grants(sc, namespace: str, bridges: bool) -> dict[str, tuple[set[str], set[str]]]:
    """The clock exchanges' permissions by node, written out from the graph: every node
    publishes on topics of its own name only. Robot i publishes its questions (if it hears
    a robot, a_ij > 0, or the leader) and its answers (if a robot hears it) and reads the
    answers of the clocks it asks and the questions of the robots that ask it; the leader
    reads the questions of the robots that see it and of every bridge, and answers; a
    bridge asks the leader."""
    a, lead = sc.graph.adjacency, sc.graph.leader
    n = sc.n

    def t(name: str) -> str:
        return absolute(name, namespace)

    out: dict[str, tuple[set[str], set[str]]] = {}
    for i in range(n):
        me = f"robot_{i + 1}"
        asks = [f"robot_{j + 1}" for j in range(n) if a[i, j] > 0] + (
            ["leader"] if lead[i] > 0 else [])
        hearers = [f"robot_{k + 1}" for k in range(n) if a[k, i] > 0]
        pub = ({t(f"{me}/clock/ping")} if asks else set()) | (
            {t(f"{me}/clock/pong")} if hearers else set())
        sub = {t(f"{x}/clock/pong") for x in asks} | {t(f"{k}/clock/ping") for k in hearers}
        out[me] = (pub, sub)
    leader_sub = {t(f"robot_{i + 1}/clock/ping") for i in range(n) if lead[i] > 0}
    if bridges:
        leader_sub |= {t(f"bridge_{i + 1}/clock/ping") for i in range(n)}
        for i in range(n):
            out[f"bridge_{i + 1}"] = ({t(f"bridge_{i + 1}/clock/ping")},
                                      {t("leader/clock/pong")})
    out["virtual_leader"] = ({t("leader/clock/pong")}, leader_sub)
    return out


def _module(script: str) -> str:
    (ep,) = entry_points(group="console_scripts", name=script)
    return ep.value.split(":")[0]


def test_every_entry_script_is_installed():
    modules = {s: _module(s) for s in ENTRY_SCRIPTS}
    assert modules["formation-ilc-virtual-leader"] == "virtual_leader.node"


@pytest.mark.parametrize("key", sorted(_golden("plans")))
def test_a_launch_plans_the_processes_it_planned(tmp_path, key):
    scenario, plant, links, record, live, *extra = key.split("|")
    name = scenario
    if plant in BODIES:  # robots with bodies: a scenario within their limits
        name = str(tmp_path / "bodies.yaml")
        Path(name).write_text(BODY_SCENARIO.read_text())
    argv = ["launch", name, "--plant", plant, "--links", links, "--domain-id", "42",
            "--trials", "2", "--out", str(tmp_path / "run"), "--allow-contact", *extra]
    if plant in ("pioneer", "base"):
        argv += ["--v-max", "50", "--omega-max", "5000", "--a-max", "50", "--alpha-max",
                 "50000"]
    if record == "record":
        argv += ["--record", str(tmp_path / "run.mcap")]
    port = None
    if live == "live":
        port = _free_port()
        argv += ["--live", str(port)]
    if plant == "physics" or "--physics-bases" in extra:
        pytest.importorskip("pybullet")
    args = build_parser().parse_args(argv)
    args.run_id = "rgolden"
    plan = plan_of(args)

    def norm(x):
        text = json.dumps(x, default=str).replace(str(tmp_path), "<tmp>")
        text = text.replace(json.dumps(plan.nodes[0].python)[1:-1], "<python>")
        return json.loads(text if port is None else text.replace(str(port), "<port>"))

    got = norm({
        "team": {"robots": plan.team.robots, "plants": plan.team.plants,
                 "support": plan.team.support, "passive": plan.team.passive,
                 "expected": plan.team.expected},
        "reporters": plan.reporters, "true_state": plan.true_state, "bridged": plan.bridged,
        "nodes": [{"name": s.name, "module": s.module, "args": s.args, "remaps": s.remaps,
                   "params": s.params, "passive": s.passive, "optional": s.optional,
                   "host": s.host, "env": s.env,
                   "restart": [s.restart.max_restarts, s.restart.refused]}
                  for s in plan.nodes]})
    want = _with_robust_learning(_with_motion(_with_bases_following_trials(_with_new_example(
        _with_one_limits_table(_with_damped_learning(_with_located_bridges(
            _with_bases_truth(_golden("plans")[key])))))),
        default_motion(plan.scenario.n, bridged=plan.row.per_robot)),
        plan.scenario.uncertainty.pose_noise)
    assert got == want
    # the roster names the same processes, each started by its entry script
    sc = plan.scenario
    r = roster(Lineup.of(sc.graph, plant=plant, links=links, record=record == "record",
                         live=live == "live", external=tuple(plan.team.plants)
                         if plant == "external" else (),
                         driver=plan.bridge.driver if plan.bridge else "rosaria",
                         driver_ns=plan.bridge.driver_ns if plan.bridge else None,
                         base=plan.bridge.base if plan.bridge else None,
                         fake_drivers="--fake-drivers" in extra,
                         physics_bases="--physics-bases" in extra))
    if "--container" not in extra:
        assert [(m.name, _module(m.entry or "")) for m in r.processes] == [
            (n["name"], n["module"]) for n in want["nodes"]]
        assert [m.optional for m in r.processes] == [n["optional"] for n in want["nodes"]]
        assert [m.waits == "once" for m in r.processes] == [n["passive"]
                                                            for n in want["nodes"]]
    assert r.team.expected == want["team"]["expected"]
    assert list(r.reporters) == want["reporters"]
    assert r.lineup.true_state == want["true_state"]
    assert r.plant.per_robot == want["bridged"]


def test_contacts_come_from_the_members_that_watch_the_bodies():
    """The monitor takes a contact only from the physics plant or the physics bases (issue
    39): never from a robot, a kinematic simulator or a bridge."""
    assert roster(Lineup(3, plant="physics")).contact_watchers == ("physics_sim",)
    assert roster(Lineup(3, plant="base", physics_bases=True)).contact_watchers == (
        "physics_bases",)
    for lineup in (Lineup(3), Lineup(3, plant="pioneer"), Lineup(3, plant="base")):
        assert roster(lineup).contact_watchers == ()


def test_the_report_writers_are_the_members_that_report_in_the_formations_namespace():
    """The launcher's monitor takes a report only from the writer of the node it names,
    and says ready once the graph names these writers (issue 39): every member that
    publishes the formation's diagnostics, never the monitor itself (it reads them), the
    live view or a driver in a namespace of its own."""
    got = roster(Lineup(3, record=True, live=True)).report_writers
    assert got == ("recorder", "virtual_leader", "robot_sim", "link_emulator", "robot_1",
                   "robot_2", "robot_3")
    bridged = roster(Lineup(2, plant="pioneer", fake_drivers=True, links="direct"))
    assert bridged.report_writers == ("virtual_leader", "bridge_1", "bridge_2", "robot_1",
                                      "robot_2")
    assert "physics_bases" in roster(Lineup(2, plant="base", physics_bases=True)
                                     ).report_writers
    # an external plant's nodes are the user's: nothing is known of their writers
    assert roster(Lineup(2, plant="external", external=("x",))).report_writers == (
        "virtual_leader", "link_emulator", "robot_1", "robot_2")


def test_the_trajectory_writers_are_each_robot_and_its_plant():
    """The launcher's monitor makes metrics.csv from these topics, each from its writers
    only (issue 39): a robot's trajectory from the robot, its true trajectory from the
    plant that knows the truth (the simulator, or the robot's bridge over physics bases);
    a plant without the truth names no true-trajectory writer (nothing is taken there)."""
    got = roster(Lineup(2)).trajectory_writers()
    assert got == {"robot_1/trajectory": ("robot_1",), "robot_1/true_trajectory": ("robot_sim",),
                   "robot_2/trajectory": ("robot_2",), "robot_2/true_trajectory": ("robot_sim",)}
    bases = roster(Lineup(2, plant="base", physics_bases=True)).trajectory_writers()
    assert bases["robot_2/true_trajectory"] == ("bridge_2",)
    bridged = roster(Lineup(2, plant="pioneer", fake_drivers=True)).trajectory_writers()
    assert bridged == {"robot_1/trajectory": ("robot_1",), "robot_2/trajectory": ("robot_2",)}


@pytest.mark.parametrize(("mode", "links", "safety"), [
    ("lockstep", "emulated", None), ("lockstep", "direct", None),
    ("realtime", "direct", "team"), ("realtime", "emulated", "peers")])
def test_a_robot_s_member_follows_from_the_run_configuration_alone(mode, links, safety):
    """Each robot node builds its member from the configuration it runs
    (``Lineup.of_run``, nothing else): whatever else the run holds (the plant, its
    bridges, a recorder, a live view), a robot's member is the one the planner's roster
    gives it."""
    from dataclasses import replace

    from formation_ilc.config.runconfig import make_config
    from formation_ilc.config.safety import SafetySettings

    cfg = make_config("paper-hexagon6", mode=mode, links=links)
    if safety is not None:
        cfg = replace(cfg, safety=SafetySettings(sensing=safety, motion="commands"))
    own = roster(Lineup.of_run(cfg))
    for kw in ({"plant": "physics", "record": True, "live": True},
               {"plant": "pioneer", "fake_drivers": True, "monitor": False}):
        run = roster(Lineup.of_run(cfg, **kw))
        assert run.by_role("robot") == own.by_role("robot")
    robot_2 = own.member("robot_2")
    assert robot_2.robot == 2
    assert (applied_topic(2) in robot_2.publish) == (safety is not None)
    assert (TEAM_POSES in robot_2.subscribe) == (safety == "team")
    with pytest.raises(ValueError, match="no member 'robot_7'.*robot_6"):
        own.member("robot_7")
