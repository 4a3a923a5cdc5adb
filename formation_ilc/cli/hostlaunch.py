"""One command per machine: ``formation-ilc launch RUN.yaml --host NAME``.

A run file's ``hosts:`` puts the run's members on machines. The launcher of the host with
the leader (the ground station) runs the pre-run checks for the whole team, its own
members, the monitor and the report; once no other formation runs on its domain it
publishes the run's description on the ROS graph (``nodes.hostlink``: the run's identity,
ROS domain and run key; under ``--secure``, whose enclaves grant no such topic yet, it
writes ``OUT/hosts/ground.json``, readable by its owner only, in a folder the hosts share),
and the final status there when the run ends. The launcher of every other host waits for
it, then starts and supervises only its members (restarts, logs and their state in
``OUT/hosts/NAME`` on its own disk), and stops them when the ground station's run has
ended. A host launcher that dies takes its members with it: the ground station names
the host whose members left the ROS graph, the leader re-runs the trial they were in when
they come back (their state is in the host's folder), and the run goes on.
"""

from __future__ import annotations

import json
import os
import signal
import sys
import time
from collections.abc import Collection, Mapping
from pathlib import Path
from typing import Any

from formation_ilc.plan.build import HOSTS_DIR, with_ground
from formation_ilc.plan.specs import RunPlan

__all__ = ["GROUND_FILE", "STARTING", "write_ground", "run_member_host", "HostWatch"]

GROUND_FILE = "ground.json"
#: the status of a ground station's run that is starting (the hosts wait for none)
STARTING = "starting"


def ground_file(plan: RunPlan) -> Path:
    """The ground station's handshake file of ``plan`` (a ground's or a member host's)."""
    root = plan.out if plan.ground else plan.out.parent.parent
    return root / HOSTS_DIR / GROUND_FILE


def write_ground(plan: RunPlan, status: int | str | None = None) -> None:
    """The ground station's handshake: the run's identity, domain and key, and, once the run
    has ended, its status (owner-only: the key seals the leader's events)."""
    from formation_ilc.store.atomic import atomic_write_text

    path = ground_file(plan)
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(path, json.dumps(description(plan, status)) + "\n")
    os.chmod(path, 0o600)


def over_graph(plan: RunPlan) -> bool:
    """Whether the hosts of ``plan`` hand the run over the ROS graph (``nodes.hostlink``),
    or, under ``--secure`` (whose enclaves grant no such topic yet), through
    ``OUT/hosts/ground.json`` in a folder they share."""
    return plan.secure is None


def description(plan: RunPlan, status: int | str | None = None) -> dict[str, Any]:
    """The ground station's run as the other hosts take it (its identity, domain, namespace
    and key; ``status``: None while it goes on, STARTING, or its exit status)."""
    return {"run_id": plan.config.run_id, "domain": plan.domain, "namespace": plan.namespace,
            "key": (plan.key or b"").hex(), "pid": os.getpid(), "status": status}


def describe(plan: RunPlan, host: Any, status: int | str | None = None) -> None:
    """Tell the other hosts where the ground station's run is (``status`` as in
    :func:`description`): on the graph through the launcher's ROS host ``host``
    (``nodes.host.LauncherHost``), or in the handshake file under ``--secure``."""
    if not over_graph(plan):
        write_ground(plan, status)
    elif host is not None and host.monitor is not None:
        host.describe(description(plan, status))


def _read_ground(path: Path) -> dict[str, Any] | None:
    try:
        d = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    return d if isinstance(d, dict) and "run_id" in d else None


def run_member_host(plan: RunPlan, poll: float = 0.2) -> int:
    """Run host ``plan.host``'s members (not the ground station's): wait for the ground
    station's run, start them, restart a member that dies (within its policy), stop them
    when the ground station's run has ended (then return 0), or wait for the next run when
    another replaces it (a ground station started again); 130 when interrupted, else the
    status of a member that failed for good."""
    stop: list[int] = []

    def on_term(signum: int, frame: Any) -> None:
        stop.append(signum)

    signal.signal(signal.SIGTERM, on_term)
    signal.signal(signal.SIGINT, on_term)
    source = _Source(plan)
    try:
        while True:
            ground = _wait_ground(plan, source, stop, poll)
            status = 130 if ground is None else _run_members(plan, ground, source, stop, poll)
            if status == 130:
                print(f"host {plan.host}: interrupted: its members stopped; to rejoin the "
                      f"run: {host_command(plan.host or '')}", file=sys.stderr, flush=True)
            if status is not None:
                return status
    finally:
        source.close()


class _Source:
    """Where a host's launcher reads the ground station's run: the graph (a node of its
    own, ``nodes.hostlink.RunListener``, on the run's domain) or, under ``--secure``, the
    handshake file in the shared folder."""

    def __init__(self, plan: RunPlan):
        self.listener: Any = None
        self.path = ground_file(plan)
        if over_graph(plan):
            from formation_ilc.cli.supervisor import node_env
            from formation_ilc.nodes.hostlink import RunListener

            env = node_env(plan)
            for name in ("ROS_DOMAIN_ID", "ROS_AUTOMATIC_DISCOVERY_RANGE",
                         "FASTRTPS_DEFAULT_PROFILES_FILE"):
                if name in env:
                    os.environ[name] = env[name]
            self.listener = RunListener(plan.host or "", plan.namespace)

    @property
    def where(self) -> str:
        if self.listener is not None:
            return f"on {self.listener.topic}, ROS_DOMAIN_ID={os.environ.get('ROS_DOMAIN_ID')}"
        return str(self.path)

    def read(self, timeout: float) -> dict[str, Any] | None:
        if self.listener is not None:
            return self.listener.read(timeout)  # type: ignore[no-any-return]
        time.sleep(timeout)
        return _read_ground(self.path)

    def close(self) -> None:
        if self.listener is not None:
            self.listener.close()
            self.listener = None


def _wait_ground(plan: RunPlan, source: _Source, stop: list[int], poll: float
                 ) -> dict[str, Any] | None:
    """The ground station's run going on, said each second while it is waited for; None
    when interrupted."""
    host = plan.host or ""
    t0, said = time.monotonic(), -1.0
    while True:
        ground = source.read(poll)
        if ground is not None and ground.get("status") is None:
            return ground
        if stop:
            return None
        now = time.monotonic() - t0
        if now - said >= 1.0:
            said = now
            print(f"host {host}: waiting for the ground station's run ({source.where}) "
                  f"[{now:.0f} s]", flush=True)


def _run_members(plan: RunPlan, ground: dict[str, Any], source: _Source, stop: list[int],
                 poll: float) -> int | None:
    """Run this host's members in the ground station's run ``ground`` until it ends (0),
    a member fails for good (its status), this launcher is interrupted (130), or another
    run replaces it (None)."""
    from formation_ilc.cli.supervisor import Supervisor, node_env

    host = plan.host or ""
    plan = with_ground(plan, str(ground["run_id"]), int(ground["domain"]),
                       bytes.fromhex(str(ground["key"])))
    if plan.secure is not None:
        plan.secure.write_profile()
    supervisor = Supervisor(plan, node_env(plan))
    supervisor.start()
    print(f"host {host}: started {', '.join(s.name for s in plan.nodes)} on ROS_DOMAIN_ID="
          f"{plan.domain} for run {plan.config.run_id} (logs and state in {plan.out})",
          flush=True)
    try:
        while not stop:
            failure = supervisor.watch()
            if failure is not None:
                return supervisor.report(failure)
            current = source.read(poll)
            if current is None or current.get("run_id") != plan.config.run_id:
                print(f"host {host}: the ground station's run {plan.config.run_id} is gone: "
                      f"stopping its members", flush=True)
                return None
            if current.get("status") == STARTING:  # the ground station starts again
                print(f"host {host}: the ground station starts its run again: stopping its "
                      f"members", flush=True)
                return None
            if current.get("status") is not None:
                print(f"host {host}: the ground station's run ended (status "
                      f"{current['status']}): stopping", flush=True)
                return 0
        return 130
    finally:
        supervisor.stop()


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
        #: the launcher each host's members last said ready from (``boot_launcher``)
        self.launcher: dict[str, str] = {}
        #: hosts whose departure the graph showed, their new launcher not yet heard
        self.returning: set[str] = set()
        self.rows: dict[str, dict[str, Any]] = {
            h: {"members": sorted(ms), "left": 0, "away_s": 0.0, "quick_returns": 0}
            for h, ms in self.remote.items()}

    def silent(self, found: Collection[str]) -> list[str]:
        """The hosts none of whose members is in the graph yet (start-up)."""
        return [h for h, ms in self.remote.items() if not ms & set(found)]

    def update(self, now: float, found: Collection[str],
               readies: Mapping[str, Any] | None = None) -> list[str]:
        """Lines to print: a host whose members all left the graph, or came back; a host
        whose members say ready from a new launcher (``readies``: the last ready of each
        node, ``protocol.schedule.Ready``) although the graph never showed them gone: its
        launcher was started again within the DDS lease (the old members' participants
        still in the graph), which counts as a departure and a return too."""
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
                self.returning.add(h)
                lines.append(f"host {h}: its members ({', '.join(sorted(ms))}) left the ROS "
                             f"graph: its launcher died or its machine dropped off the "
                             f"network; the trial they were in runs again when they are back")
            elif present and h in self.gone:
                away = now - self.gone.pop(h)
                self.rows[h]["away_s"] += away
                lines.append(f"host {h}: back after {away:.1f} s")
            lines += self._launcher(h, ms, readies or {})
        return lines

    def _launcher(self, h: str, ms: Collection[str], readies: Mapping[str, Any]) -> list[str]:
        """The launcher host ``h``'s members said ready from last; a line when it is a new
        one the graph did not show coming (its members' new participants took over the
        names of the old ones before their lease ran out)."""
        from formation_ilc.protocol.schedule import boot_launcher

        tags = {t for m in ms if (r := readies.get(m)) is not None and not r.down
                and (t := boot_launcher(str(r.boot))) is not None}
        known = self.launcher.get(h)
        if not tags or known in tags:
            return []
        tag = sorted(tags)[0]
        self.launcher[h] = tag
        if known is None:
            return []
        if h in self.returning:  # the graph showed it go: counted then
            self.returning.discard(h)
            return []
        self.rows[h]["left"] += 1
        self.rows[h]["quick_returns"] += 1
        return [f"host {h}: its launcher was started again (its members, "
                f"{', '.join(sorted(ms))}, said ready from a new one) before the ROS graph "
                f"saw it go: it left and came back; the trial they were in runs again"]

    def cause(self, found: Collection[str], now: float) -> str | None:
        """What a stuck run waits for, cause first and what to do: the hosts never heard
        from, or gone, with the command that starts each; None when every host is here."""
        found = set(found)
        never = [h for h, ms in self.remote.items() if h not in self.heard and not ms & found]
        gone = [h for h in self.remote if h in self.gone]
        parts = []
        for h in never:
            parts.append(f"host {h} ({', '.join(sorted(self.remote[h]))}) never joined: "
                         f"start `{host_command(h)}` on it (on the run's ROS domain "
                         f"{self.plan.domain}, its discovery reaching this machine)")
        for h in gone:
            parts.append(f"host {h} ({', '.join(sorted(self.remote[h]))}) left "
                         f"{now - self.gone[h]:.0f} s ago: start `{host_command(h)}` on it "
                         f"again (its robot goes on from its state)")
        return "; ".join(parts) or None

    def save(self, summary: Path) -> None:
        """Add a row per host to the run's summary.json (``hosts``)."""
        try:
            d = json.loads(summary.read_text())
        except (OSError, ValueError):
            return
        hosts: dict[str, dict[str, Any]] = {self.plan.host or "": {
            "members": list(self.plan.members_of(self.plan.host or "")), "ground": True}}
        for h, r in self.rows.items():
            hosts[h] = {**r, "heard": h in self.heard}
        d["hosts"] = hosts
        summary.write_text(json.dumps(d, indent=2) + "\n")

    def report(self) -> list[str]:
        """A row per host for the report."""
        rows = [f"  {self.plan.host:<10} (this launcher: the ground station) "
                f"{', '.join(self.plan.members_of(self.plan.host or ''))}"]
        for h, r in self.rows.items():
            quick = r["quick_returns"]
            seen = (f", away {r['away_s']:.1f} s" if r["left"] > quick else "")
            rows.append(f"  {h:<10} {', '.join(r['members'])}: "
                        + ("never heard from" if h not in self.heard else
                           f"left {r['left']} time(s){seen}"
                           + (f" ({quick} of them back before the ROS graph saw it go: "
                              f"its launcher started again within the DDS lease)"
                              if quick else "")
                           if r["left"] else "present throughout"))
        return rows


def host_command(host: str, argv: list[str] | None = None) -> str:
    """The command that starts host ``host``'s launcher: this launcher's own (``argv``,
    default ``sys.argv``) with ``--host`` naming ``host``."""
    import shlex

    args = list(sys.argv[1:] if argv is None else argv)
    for i, a in enumerate(args):
        if a == "--host" and i + 1 < len(args):
            args[i + 1] = host
            break
        if a.startswith("--host="):
            args[i] = f"--host={host}"
            break
    else:
        args = [*args, "--host", host]
    return shlex.join(["formation-ilc", *args])


def print_hosts(watch: HostWatch) -> None:
    print("hosts:", flush=True)
    for line in watch.report():
        print(line, flush=True)
    sys.stdout.flush()
