"""One command per machine: ``formation-ilc launch RUN.yaml --host NAME``.

A run file's ``hosts:`` puts the run's members on machines. The launcher of the host with
the leader (the ground station) runs the pre-run checks for the whole team, its own
members, the monitor and the report; it writes ``OUT/hosts/ground.json`` (the run's
identity, ROS domain and run key, readable by its owner only) once no other formation
runs on its domain, and the final status there when the run ends. The launcher of every
other host waits for that file, then starts and supervises only its members (restarts,
logs and their state in ``OUT/hosts/NAME``), and stops them when the ground station's run
has ended. A host launcher that dies takes its members with it: the ground station names
the host whose members left the ROS graph, the leader re-runs the trial they were in when
they come back (their state is in the host's folder), and the run goes on.
"""

from __future__ import annotations

import json
import os
import signal
import sys
import time
from collections.abc import Collection
from pathlib import Path
from typing import Any

from formation_ilc.plan.build import HOSTS_DIR, with_ground
from formation_ilc.plan.specs import RunPlan

__all__ = ["GROUND_FILE", "write_ground", "run_member_host", "HostWatch"]

GROUND_FILE = "ground.json"


def ground_file(plan: RunPlan) -> Path:
    """The ground station's handshake file of ``plan`` (a ground's or a member host's)."""
    root = plan.out if plan.ground else plan.out.parent.parent
    return root / HOSTS_DIR / GROUND_FILE


def write_ground(plan: RunPlan, status: int | None = None) -> None:
    """The ground station's handshake: the run's identity, domain and key, and, once the run
    has ended, its status (owner-only: the key seals the leader's events)."""
    from formation_ilc.store.atomic import atomic_write_text

    path = ground_file(plan)
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(path, json.dumps({
        "run_id": plan.config.run_id, "domain": plan.domain, "namespace": plan.namespace,
        "key": (plan.key or b"").hex(), "pid": os.getpid(), "status": status}) + "\n")
    os.chmod(path, 0o600)


def _read_ground(path: Path) -> dict[str, Any] | None:
    try:
        d = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    return d if isinstance(d, dict) and "run_id" in d else None


def run_member_host(plan: RunPlan, poll: float = 0.2) -> int:
    """Run host ``plan.host``'s members (not the ground station's): wait for the ground
    station, start them, restart a member that dies (within its policy), stop them when the
    ground station's run has ended; the exit status (0: the run ended, 130: interrupted,
    else a member that failed for good)."""
    from formation_ilc.cli.launch import _node_env
    from formation_ilc.cli.supervisor import Supervisor

    host = plan.host or ""
    path = ground_file(plan)
    stop: list[int] = []

    def on_term(signum: int, frame: Any) -> None:
        stop.append(signum)

    signal.signal(signal.SIGTERM, on_term)
    signal.signal(signal.SIGINT, on_term)
    t0, said = time.monotonic(), -1.0
    ground = _read_ground(path)
    while ground is None or ground.get("status") is not None:
        if stop:
            return 130
        now = time.monotonic() - t0
        if now - said >= 1.0:
            said = now
            print(f"host {host}: waiting for the ground station's run ({path}) "
                  f"[{now:.0f} s]", flush=True)
        time.sleep(poll)
        ground = _read_ground(path)
    plan = with_ground(plan, str(ground["run_id"]), int(ground["domain"]),
                       bytes.fromhex(str(ground["key"])))
    supervisor = Supervisor(plan, _node_env(plan))
    supervisor.start()
    print(f"host {host}: started {', '.join(s.name for s in plan.nodes)} on ROS_DOMAIN_ID="
          f"{plan.domain} for run {plan.config.run_id} (logs and state in {plan.out})",
          flush=True)
    status = 0
    try:
        while not stop:
            failure = supervisor.watch()
            if failure is not None:
                status = supervisor.report(failure)
                break
            current = _read_ground(path)
            if current is None or current.get("run_id") != plan.config.run_id:
                print(f"host {host}: the ground station's run is gone: stopping", flush=True)
                break
            if current.get("status") is not None:
                print(f"host {host}: the ground station's run ended (status "
                      f"{current['status']}): stopping", flush=True)
                break
            time.sleep(poll)
        else:
            status = 130
    finally:
        supervisor.stop()
    return status


class HostWatch:
    """The ground station's view of the other hosts: which of them it has not heard from
    (none of their members in the ROS graph) while the run starts, and a host whose members
    left the graph during the run (its launcher died, or its machine dropped off the
    network) and came back; a row per host for the report."""

    def __init__(self, plan: RunPlan):
        self.plan = plan
        self.remote = {h: set(ms) for h, ms in plan.host_members if h != plan.host}
        self.heard: set[str] = set()
        self.gone: dict[str, float] = {}
        self.rows: dict[str, dict[str, Any]] = {
            h: {"members": sorted(ms), "left": 0, "away_s": 0.0} for h, ms in self.remote.items()}

    def silent(self, found: Collection[str]) -> list[str]:
        """The hosts none of whose members is in the graph yet (start-up)."""
        return [h for h, ms in self.remote.items() if not ms & set(found)]

    def update(self, now: float, found: Collection[str]) -> list[str]:
        """Lines to print: a host whose members all left the graph, or came back."""
        lines = []
        for h, ms in self.remote.items():
            present = ms <= set(found)
            if present:
                self.heard.add(h)
            if h not in self.heard:
                continue
            if not (ms & set(found)) and h not in self.gone:
                self.gone[h] = now
                self.rows[h]["left"] += 1
                lines.append(f"host {h}: its members ({', '.join(sorted(ms))}) left the ROS "
                             f"graph: its launcher died or its machine dropped off the "
                             f"network; the trial they were in runs again when they are back")
            elif present and h in self.gone:
                away = now - self.gone.pop(h)
                self.rows[h]["away_s"] += away
                lines.append(f"host {h}: back after {away:.1f} s")
        return lines

    def report(self) -> list[str]:
        """A row per host for the report."""
        rows = [f"  {self.plan.host:<10} (this launcher: the ground station) "
                f"{', '.join(self.plan.members_of(self.plan.host or ''))}"]
        for h, r in self.rows.items():
            rows.append(f"  {h:<10} {', '.join(r['members'])}: "
                        + ("never heard from" if h not in self.heard else
                           f"left {r['left']} time(s), away {r['away_s']:.1f} s"
                           if r["left"] else "present throughout"))
        return rows


def print_hosts(watch: HostWatch) -> None:
    print("hosts:", flush=True)
    for line in watch.report():
        print(line, flush=True)
    sys.stdout.flush()
