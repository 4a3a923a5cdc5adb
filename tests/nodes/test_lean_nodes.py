"""Node processes hold no compiler (issue 32): every node module, and a whole team of the
cores the nodes wrap (plant, emulated links, robot learners), imports and runs with numba
and llvmlite made unimportable, and what that team computes equals the compiled batch
simulator bit for bit."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np

from formation_ilc.config.runconfig import make_config

ROOT = Path(__file__).resolve().parents[2]

#: every module a node process of the stack imports as its main module, and the launcher's
NODE_MODULES = ["formation_ilc.nodes.robot", "robot_sim.node", "robot_sim.link_emulator",
                "virtual_leader.node", "formation_ilc.nodes.recorder",
                "formation_ilc.nodes.monitor", "formation_ilc.nodes.pioneer_bridge",
                "formation_ilc.cli.launch"]

CHILD = """
import json, sys
for blocked in ("numba", "llvmlite"):
    sys.modules[blocked] = None  # any import of them raises ImportError
for m in {modules!r}:
    __import__(m)
from formation_ilc.config.runconfig import make_config
from tests.protocol.test_plant import run_team
plant, links, out = run_team(make_config({scenario!r}, seed=5), trials=2)
print(json.dumps([[xi.tobytes().hex(), u.tobytes().hex(), mem.tobytes().hex()]
                  for xi, u, mem in out]))
print(json.dumps(sorted(m for m in sys.modules if m.split(".")[0] in ("numba", "llvmlite")
                        and sys.modules[m] is not None)))
"""


def test_node_modules_and_their_cores_run_without_numba_and_equal_the_batch():
    scenario = "paper-hexagon6"
    code = CHILD.format(modules=NODE_MODULES, scenario=scenario)
    res = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True,
                         text=True, timeout=300)
    assert res.returncode == 0, res.stderr[-3000:]
    lines = res.stdout.strip().splitlines()
    trials, loaded = json.loads(lines[-2]), json.loads(lines[-1])
    assert loaded == []
    cfg = make_config(scenario, seed=5)
    sc = cfg.scenario
    from formation_ilc.model.simulate import Problem

    pb = Problem.from_scenario(sc)
    memory = np.zeros((pb.n, pb.samples, 2))
    assert len(trials) == 2
    for k, (xi_hex, u_hex, mem_hex) in enumerate(trials):
        shift, dist, noise = sc.uncertainty.draw_plant(sc.seed, k, pb.n, pb.samples)
        tau, tau0 = sc.uncertainty.draw_delays(sc.seed, k, pb.n, pb.src.shape[1], pb.samples)
        xi, _, u, memory = pb.trial(memory, pb.eta_d[:, 0] + shift, dist, noise, tau, tau0)
        assert bytes.fromhex(xi_hex) == xi.tobytes()
        assert bytes.fromhex(u_hex) == u.tobytes()
        assert bytes.fromhex(mem_hex) == memory.tobytes()
        assert np.abs(u).max() > 0.01  # the team commanded something
