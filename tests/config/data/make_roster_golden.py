"""Today's three answers (Team.of, node_specs through build_plan, formation_grants), frozen:

    PYTHONPATH=CHECKOUT_AT_0647a59 python tests/config/data/make_roster_golden.py \\
        tests/config/data/roster_golden.json 0647a59

It reads the code that the roster replaced, so it runs only on a checkout from before it.
"""
import json
import socket
import sys
import tempfile
from pathlib import Path

from formation_ilc.config.team import Team  # type: ignore[import-not-found]

from formation_ilc.cli.commands import build_parser
from formation_ilc.cli.keystore import grants_for
from formation_ilc.cli.runfile import plan_of
from formation_ilc.config.scenario import load_scenario


def free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]

#: plants whose robots have bodies (limits checked, the safety filter on by default), and
#: the scenario their runs take: one that fits a P3-DX's limits
BODIES = ("physics", "pioneer", "base")
BODY_SCENARIO = Path(__file__).parents[3] / "docs" / "examples" / "hexagon6-p3dx.yaml"


def combos():
    for plant in ("sim", "physics", "external", "pioneer", "base"):
        for links in (("direct",) if plant in ("pioneer", "base") else ("emulated", "direct")):
            for record in (False, True):
                for live in (False, True):
                    yield plant, links, record, live, ()
    yield "sim", "emulated", False, False, ("--container", "2")
    yield "sim", "direct", True, False, ("--namespace", "/team2")
    yield "sim", "emulated", False, False, ("--mode", "realtime")
    yield "external", "direct", False, False, ("--plant-nodes", "my_plant", "other")
    yield "pioneer", "direct", False, False, ("--fake-drivers",)
    yield "pioneer", "direct", True, True, ("--fake-drivers", "--driver", "ros2aria",
                                            "--driver-ns", "/p{i}")
    yield "base", "direct", False, False, ("--physics-bases",)
    yield "base", "direct", True, False, ("--physics-bases", "--base", "jackal")

def key(plant, links, record, live, extra):
    return "|".join([plant, links, "record" if record else "-", "live" if live else "-", *extra])

def plan_answers(tmp):
    out = {}
    for scen in ("paper-triangle3", "paper-hexagon6"):
        for plant, links, record, live, extra in combos():
            if scen == "paper-hexagon6" and (extra or not (record and live)):
                continue
            name = scen
            if plant in BODIES:  # robots with bodies: a scenario within their limits
                name = str(tmp / "bodies.yaml")
                Path(name).write_text(BODY_SCENARIO.read_text())
            argv = ["launch", name, "--plant", plant, "--links", links, "--domain-id", "42",
                    "--trials", "2", "--out", str(tmp / "run"), "--allow-contact", *extra]
            if plant in ("pioneer", "base"):
                argv += ["--v-max", "50", "--omega-max", "5000", "--a-max", "50",
                         "--alpha-max", "50000"]
            if record:
                argv += ["--record", str(tmp / "run.mcap")]
            port = None
            if live:
                port = free_port()
                argv += ["--live", str(port)]
            args = build_parser().parse_args(argv)
            args.run_id = "rgolden"
            plan = plan_of(args)
            def norm(x, port=port):
                s = json.dumps(x, default=str)
                s = s.replace(str(tmp), "<tmp>").replace(sys.executable, "<python>")
                if port is not None:
                    s = s.replace(str(port), "<port>")
                return json.loads(s)
            out[scen + "|" + key(plant, links, record, live, extra)] = norm({
                "team": {"robots": plan.team.robots, "plants": plan.team.plants,
                         "support": plan.team.support, "passive": plan.team.passive,
                         "expected": plan.team.expected},
                "reporters": plan.reporters, "true_state": plan.true_state,
                "bridged": plan.bridged,
                "nodes": [{"name": s.name, "module": s.module, "args": s.args,
                           "remaps": s.remaps, "params": s.params, "passive": s.passive,
                           "optional": s.optional, "host": s.host, "env": s.env,
                           "restart": [s.restart.max_restarts, s.restart.refused]}
                          for s in plan.nodes]})
    return out

def team_answers():
    out = {}
    for n in (1, 3, 6):
        for plant in ("sim", "physics", "external", "pioneer", "base"):
            for links in ("emulated", "direct"):
                for monitor in (False, True):
                    for recorder in (False, True):
                        t = Team.of(n, plant=plant, links=links, external=("ext_a", "ext_b"),
                                    monitor=monitor, recorder=recorder)
                        out[f"{n}|{plant}|{links}|{int(monitor)}|{int(recorder)}"] = {
                            "robots": t.robots, "plants": t.plants, "support": t.support,
                            "passive": t.passive, "expected": t.expected}
    return json.loads(json.dumps(out))

def grant_answers():
    out = {}
    for scen in ("paper-triangle3", "paper-hexagon6"):
        sc = load_scenario(scen)
        for ns in ("/formation", "/team2"):
            for plant, driver, dns in (("sim", "rosaria", "/pioneer_{i}"),
                                       ("pioneer", "rosaria", "/pioneer_{i}"),
                                       ("pioneer", "p2os2", "/pioneer_{i}"),
                                       ("pioneer", "ros2aria", "/p{i}")):
                g = grants_for(sc, ns, plant=plant, driver=driver, driver_ns=dns)
                out[f"{scen}|{ns}|{plant}|{driver}|{dns}"] = {
                    k: {"enclave": v.enclave, "node": v.node, "node_namespace": v.node_namespace,
                        "publish": v.publish, "subscribe": v.subscribe,
                        "dds_publish": v.dds_publish, "dds_subscribe": v.dds_subscribe,
                        "service_node": v.service_node} for k, v in g.items()}
    return json.loads(json.dumps(out))

if __name__ == "__main__":
    with tempfile.TemporaryDirectory() as d:
        golden = {"generated_from": sys.argv[2], "plans": plan_answers(Path(d)),
                  "teams": team_answers(), "grants": grant_answers()}
    lines = [json.dumps({"generated_from": golden["generated_from"]})[:-1]]
    for part in ("plans", "teams", "grants"):
        for k in sorted(golden[part]):
            lines.append(f', "{part}|{k}": ' + json.dumps(golden[part][k], sort_keys=True,
                                                         separators=(",", ":")))
    Path(sys.argv[1]).write_text("\n".join(lines) + "\n}\n")
    print(len(golden["plans"]), len(golden["teams"]), len(golden["grants"]))
