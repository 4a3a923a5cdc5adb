"""``decide(options, machine)`` is pure and ``prepare(plan)`` makes what it names.

``decide`` plans from a ``LaunchOptions`` value and a ``Machine`` value: what it knows of the
machine comes from that value alone (a held domain, a missing extra, the clock), it gives
the same plan for the same two values, and it writes nothing: run in a process whose every
write, bind and process start is refused (Python's audit hooks), it plans the runs below and
leaves no file behind."""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
from datetime import datetime
from pathlib import Path

import pytest

from formation_ilc.plan.build import decide, prepare
from formation_ilc.plan.machine import DOMAINS, Machine
from formation_ilc.plan.options import LaunchOptions
from formation_ilc.plan.specs import NoRun

ROOT = Path(__file__).resolve().parents[2]
TRIANGLE = (ROOT / "formation_ilc" / "config" / "scenarios" / "paper-triangle3.yaml")

MACHINE = Machine(pid=7, now=datetime(2026, 12, 7, 12, 0, 0), time_ns=123,
                  token=bytes(range(16)))


def opts(tmp_path: Path, **kw) -> LaunchOptions:
    return LaunchOptions(**{"scenario": "paper-triangle3", "out": tmp_path / "run", **kw})


def test_what_decide_knows_of_the_machine_is_the_machine_value(tmp_path):
    plan = decide(opts(tmp_path), MACHINE)
    assert plan.config.run_id == "r000102030405"  # the machine's token
    assert plan.domain == MACHINE.free_domain() and plan.domain in DOMAINS
    held = Machine(**{**MACHINE.__dict__, "held_domains": frozenset({plan.domain})})
    assert decide(opts(tmp_path), held).domain != plan.domain  # another run holds it
    caller = Machine(**{**MACHINE.__dict__, "ros_domain_id": "55"})
    assert decide(opts(tmp_path), caller).domain == 55  # the caller's ROS_DOMAIN_ID
    bad = Machine(**{**MACHINE.__dict__, "ros_domain_id": "x1"})
    with pytest.raises(NoRun, match=r"ROS_DOMAIN_ID='x1': a domain id 0..232"):
        decide(opts(tmp_path), bad)
    bare = Machine(**{**MACHINE.__dict__, "has_foxglove": False})
    with pytest.raises(NoRun, match="argument --live: needs foxglove-sdk"):
        decide(opts(tmp_path, live=8765), bare)
    # a run with no --out is named by the machine's clock, and nothing is made
    named = decide(opts(tmp_path, out=None), MACHINE)
    assert named.out.name == "paper-triangle3-launch-20261207-120000"
    assert not named.out.exists() and not (tmp_path / "run").exists()


def test_the_same_options_and_machine_give_the_same_plan(tmp_path):
    a, b = (decide(opts(tmp_path, plant="pioneer", fake_drivers=True, allow_contact=True),
                   MACHINE) for _ in range(2))
    assert a.nodes == b.nodes and a.roster == b.roster and a.notes == b.notes
    assert (a.config.run_id, a.domain, a.out, a.key) == (b.config.run_id, b.domain, b.out, None)


def test_prepare_makes_the_folder_the_scenario_file_and_a_new_key(tmp_path):
    text = TRIANGLE.read_text()
    plan = decide(opts(tmp_path, scenario=None, scenario_text=text), MACHINE)
    where = Path(plan.config.scenario_param)
    assert where == tmp_path / "run" / "scenario.yaml" and not where.exists()
    leader = next(s for s in plan.nodes if s.name == "virtual_leader")
    assert ("scenario", str(where)) in leader.params  # what the nodes will load
    ready = prepare(plan)
    assert where.read_text() == text and ready.out.is_dir()
    assert ready.key is not None and len(ready.key) >= 16
    assert prepare(plan).key != ready.key  # each launch its own


def test_prepare_refuses_a_live_port_taken(tmp_path):
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        port = s.getsockname()[1]
        plan = decide(opts(tmp_path, live=port), MACHINE)  # the plan says where, not whether
        with pytest.raises(NoRun, match=f"--live {port}: cannot serve on 127.0.0.1:{port}"):
            prepare(plan)


READ_ONLY = r"""
import json, os, sys
from pathlib import Path
from formation_ilc.plan.build import decide
from formation_ilc.plan.machine import Machine
from formation_ilc.plan.options import LaunchOptions
from formation_ilc.plan.specs import NoRun

cases = json.loads(sys.argv[1])
machine = Machine.probe()
refused = []
WRITE = os.O_WRONLY | os.O_RDWR | os.O_CREAT | os.O_TRUNC | os.O_APPEND
EFFECTS = {"os.mkdir", "os.rename", "os.replace", "os.remove", "os.rmdir", "os.symlink",
           "os.link", "os.truncate", "os.chmod", "os.chown", "os.utime", "shutil.copyfile",
           "shutil.rmtree", "shutil.move", "socket.bind", "socket.connect", "subprocess.Popen",
           "os.system", "os.exec", "os.fork", "os.posix_spawn", "os.spawn", "os.kill",
           "os.putenv", "os.unsetenv"}

def hook(event, args):
    if event == "open":
        path, mode, flags = args
        if (mode and any(c in str(mode) for c in "wax+")) or (flags or 0) & WRITE:
            refused.append(f"open {path} {mode} {flags}")
            raise PermissionError(f"read-only: open {path!r} for writing")
    elif event in EFFECTS:
        refused.append(f"{event} {args[:2]}")
        raise PermissionError(f"read-only: {event}")

sys.addaudithook(hook)
out = []
for kw in cases:
    o = LaunchOptions().with_fields(kw)
    try:
        plan = decide(o, machine)
        out.append([len(plan.nodes), str(plan.out)])
    except NoRun as stop:
        out.append(["refused", stop.message])
print(json.dumps({"plans": out, "refused": refused}))
"""


def test_decide_writes_binds_and_starts_nothing(tmp_path):
    """Every case planned in a process where any write, folder, bind, connection or process
    start is refused by an audit hook (Python bytecode not written either): each plans, no
    effect was tried, and no file is left."""
    out = str(tmp_path / "run")
    text = TRIANGLE.read_text()
    cases = [
        {"scenario": "paper-triangle3", "out": out},
        {"scenario": str(TRIANGLE), "out": out, "trials": 3, "mode": "realtime",
         "links": "direct", "clock_offset_ms": 5.0},
        {"scenario_text": text, "out": out},
        {"scenario": "paper-triangle3", "out": out, "plant": "pioneer", "fake_drivers": True,
         "allow_contact": True},
        {"scenario": "paper-triangle3", "out": out, "live": 8765, "record": out + "/rec"},
        {"scenario": "paper-hexagon6", "out": out, "container": 2},
        {"scenario": "paper-triangle3", "out": out, "namespace": "team2"},  # refused
    ]
    res = subprocess.run([sys.executable, "-B", "-c", READ_ONLY, json.dumps(cases)],
                         capture_output=True, text=True, timeout=300, cwd=tmp_path,
                         env={**os.environ, "PYTHONDONTWRITEBYTECODE": "1",
                              "NUMBA_DISABLE_JIT": "1", "PYTHONPATH": str(ROOT)})
    assert res.returncode == 0, res.stderr[-3000:]
    got = json.loads(res.stdout.strip().splitlines()[-1])
    assert got["refused"] == [], got["refused"]
    plans = got["plans"]
    # leader, simulator, link emulator, 3 robots; no emulator on direct links; 3 bridges and
    # 3 fake drivers; a recorder and a live view; 6 robots in 3 containers
    assert [p[0] for p in plans[:-1]] == [6, 5, 6, 10, 8, 6], plans
    assert plans[-1][0] == "refused" and "an absolute ROS namespace" in plans[-1][1]
    assert all(p[1] == out for p in plans[:-1]), plans
    assert list(tmp_path.iterdir()) == [], list(tmp_path.iterdir())
