"""The supervisor of a launch: runs a plan's node processes.

It starts every process of a ``RunPlan`` (``formation_ilc.plan.specs``), one log each in
``DIR/logs/``; when one dies it starts it again with the same command line, within the
node's restart policy (a recorder goes on into a new file part), and tells whoever follows
the run that a passive node went down; it stops them all (SIGINT, then SIGTERM, SIGKILL).
What the processes do, and when the run is over, is the launcher's business. No ROS here.
"""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
import time
import uuid
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any

from formation_ilc.plan.specs import NodeSpec, RunPlan
from formation_ilc.system.exits import DISK_FULL, DISK_FULL_TAG, NO_RESTART, STOPPED, STUCK
from formation_ilc.system.heartbeat import BEAT_ENV, Board, Frozen
from formation_ilc.system.lifetime import GATE_ENV, RUNNER, early_argv

#: [s] a frozen process, continued and terminated, has this long to end before SIGKILL
FROZEN_GRACE = 3.0
#: what ``Supervisor.unseen`` says a process it stops did
UNSEEN = "spinning, not in the graph"

__all__ = ["Stack", "Supervisor", "Failure", "exit_status", "metrics_rows", "resume_hint",
           "disk_full_line", "trial_ranges"]


def _a_child_exited() -> bool:
    """Whether a child of this process has exited and waits to be reaped (left for its
    owner to reap: ``WNOWAIT``). True when it cannot be told (no children at all)."""
    try:
        return os.waitid(os.P_ALL, 0, os.WEXITED | os.WNOHANG | os.WNOWAIT) is not None
    except ChildProcessError:
        return True


class Stack:
    """The processes of one run; ``stop()`` ends them (SIGINT, then SIGTERM, SIGKILL)."""

    def __init__(self, env: dict[str, str], log_dir: Path):
        self.env = env
        self.log_dir = log_dir
        #: subprocess.Popen, or nodes.forkserver.ForkedProcess (the same calls)
        self.procs: dict[str, Any] = {}
        self.logs: dict[str, IO[bytes]] = {}
        self.argv: dict[str, list[str]] = {}
        self.extra: dict[str, dict[str, str]] = {}
        self.restarts: dict[str, int] = {}
        #: the gate's pipe (read end, write end) while it is shut (``shut_gate``)
        self.gate: tuple[int, int] | None = None
        #: every process's heartbeat (``system.heartbeat``): who froze
        self.board = Board(log_dir / "heartbeats")
        #: the processes killed as frozen, until they are seen dead (name: finding)
        self.frozen: dict[str, Frozen] = {}
        #: when each process stopped as frozen gets SIGKILL if it still lives
        self._kill_at: dict[str, float] = {}
        #: the fork server (``start_forker``), or None: each process imports on its own
        self.forker: Any = None

    def shut_gate(self) -> None:
        """Processes started from now on wait at the gate (``system.lifetime``) until
        ``open_gate``: their stdin is a pipe that stays open until then."""
        if self.gate is None:
            self.gate = os.pipe()
            self.board.hold(True)

    def open_gate(self) -> None:
        """Let every process waiting at the gate go on (idempotent)."""
        if self.gate is not None:
            for fd in self.gate:
                os.close(fd)
            self.gate = None
            self.board.hold(False)

    def start(self, name: str, argv: list[str], extra: dict[str, str] | None = None) -> None:
        """Start process ``name``: ``argv`` in the run's environment plus ``extra`` (kept
        for its restarts)."""
        self.log_dir.mkdir(parents=True, exist_ok=True)
        again = name in self.logs
        if again:
            self.logs[name].close()
        fh = (self.log_dir / f"{name}.log").open("ab" if again else "wb")
        if again:
            fh.write(f"\n--- restarted ({self.restarts.get(name, 0)}) ---\n".encode())
            fh.flush()
        self.logs[name] = fh
        self.argv[name] = argv
        if extra is not None:
            self.extra[name] = extra
        env = {**self.env, **self.extra.get(name, {})}
        if self.gate is not None:
            env[GATE_ENV] = "stdin"
        env[BEAT_ENV] = self.board.slot(name)
        # through the runner that sets the parent-death signal before the node's imports:
        # a launcher killed while its nodes start takes them with it
        command = early_argv(argv)
        # a restart is an interpreter of its own, not forked: a recorder forked again
        # mid-run (SIGKILLed at trial 3) was never discovered by one robot's participant
        # and recorded none of its topics (1 suite run of 2, 2026-12-07; never in the
        # runs that restarted interpreters), as a robot forked again mid-run never joined
        # before (docs/distributed-stack.md, "the fork server")
        proc = None if again else self._fork(name, command, env, fh)
        self.procs[name] = proc if proc is not None else subprocess.Popen(
            command, env=env, stdout=fh, stderr=subprocess.STDOUT,
            stdin=subprocess.DEVNULL if self.gate is None else self.gate[0])
        # a node of ours beats from its first line (the runner's); another command is
        # watched only once it beats
        self.board.started(name, self.procs[name].pid, watch=RUNNER in command)

    def forked(self) -> int:
        """How many of the processes the fork server made."""
        from formation_ilc.nodes.forkserver import ForkedProcess

        return sum(isinstance(p, ForkedProcess) for p in self.procs.values())

    def start_forker(self, modules: list[str]) -> None:
        """From now on, fork the node processes from a server that imported ``modules``
        once (``nodes.forkserver``); without one (it cannot start) as before."""
        from formation_ilc.nodes.forkserver import ForkRefused, ForkServer

        try:
            self.forker = ForkServer(self.env, modules, self.log_dir / "forkserver.log")
        except (ForkRefused, OSError) as exc:
            print(f"warning: no fork server ({exc}): each node process imports on its own",
                  flush=True)

    def _fork(self, name: str, command: list[str], env: dict[str, str],
              fh: IO[bytes]) -> Any:
        """Process ``name`` forked by the fork server, or None (no server, a command it
        cannot fork, or a server that refuses: then none for the rest of the run)."""
        from formation_ilc.nodes.forkserver import ForkRefused, forkable

        if self.forker is None or not forkable(command):
            return None
        try:
            return self.forker.spawn(command, env, fh.fileno(),
                                     None if self.gate is None else self.gate[0])
        except ForkRefused as exc:
            print(f"warning: the fork server refused {name} ({exc}): each node process "
                  f"imports on its own from now on", flush=True)
            self.forker.close()
            self.forker = None
            return None

    def kill_frozen(self, grace: float = FROZEN_GRACE) -> list[Frozen]:
        """The processes that stopped beating (``system.heartbeat``), stopped: SIGCONT and
        SIGTERM at once, SIGKILL ``grace`` seconds later if they still live. The
        supervisor's watch then sees them dead and starts them again like a crashed one.

        Why not SIGKILL at once: a process stopped by a signal (SIGSTOP, a debugger) may
        be stopped holding a Fast DDS shared-memory port's lock, which nobody could take
        again after a SIGKILL (every process that writes to that port then waits for
        ever: the launcher was seen so); continued and terminated it ends cleanly (its
        stop is bounded: ``system.lifetime``). A deadlocked one ends only by the SIGKILL."""
        now = time.monotonic()
        for name in self.frozen:
            p = self.procs.get(name)
            if p is not None and p.poll() is None and now >= self._kill_at.get(name, now):
                with contextlib.suppress(ProcessLookupError):
                    p.send_signal(signal.SIGKILL)
        alive = {n: p.pid for n, p in self.procs.items()
                 if p.returncode is None and n not in self.frozen}
        found = self.board.frozen(alive)
        return [f for f in found if self.stop_frozen(f.name, f, now, grace)]

    def stop_frozen(self, name: str, f: Frozen, now: float,
                    grace: float = FROZEN_GRACE) -> bool:
        """Stop process ``name`` as frozen (``kill_frozen``); False if it is gone."""
        try:
            os.kill(f.pid, signal.SIGCONT)
            os.kill(f.pid, signal.SIGTERM)
        except ProcessLookupError:
            return False
        self.frozen[name] = f
        self._kill_at[name] = now + grace
        return True

    def restart(self, name: str) -> str:
        """Start ``name`` again with the same command line (a recorder into a new file
        part, ``RUN.partN.mcap``: the first part stays as it was written). Returns a note
        for the user."""
        n = self.restarts[name] = self.restarts.get(name, 0) + 1
        argv = list(self.argv[name])
        note = ""
        if "--output" in argv:
            i = argv.index("--output") + 1
            first = Path(self.argv.get(f"{name}#first", argv)[i])
            argv[i] = str(first.with_suffix(f".part{n}.mcap"))
            self.argv.setdefault(f"{name}#first", self.argv[name])
            note = f"; the recording goes on in {argv[i]}"
        if "--port" in argv:  # a server (the live view): on a port it can bind
            i = argv.index("--port") + 1
            host = argv[argv.index("--host") + 1] if "--host" in argv else "127.0.0.1"
            port = int(argv[i])
            if not bindable(host, port):
                free = free_port(host)
                if free is not None:
                    argv[i] = str(free)
                    note = f"; serving on port {free} now ({host}:{port} is taken)"
        self.start(name, argv)
        return note

    def dead(self) -> list[tuple[str, int]]:
        """The processes that exited, with their status. The launcher asks after every
        callback it spins: one ``waitid`` (is any child waiting to be reaped?) instead of a
        ``waitpid`` per process, which was a fifth of the launcher's CPU at 50 robots."""
        if (not any(p.returncode is not None for p in self.procs.values())
                and not _a_child_exited()):
            return []
        return [(n, p.returncode) for n, p in self.procs.items() if p.poll() is not None]

    def log_tail(self, name: str, lines: int = 15) -> str:
        try:
            text = (self.log_dir / f"{name}.log").read_text(errors="replace")
        except OSError:
            return ""
        return "\n".join(text.splitlines()[-lines:])

    def stop(self, grace: float = 5.0) -> None:
        for sig, wait in ((signal.SIGINT, grace), (signal.SIGTERM, 2.0), (signal.SIGKILL, 2.0)):
            alive = [p for p in self.procs.values() if p.poll() is None]
            if not alive:
                break
            for p in alive:
                try:
                    p.send_signal(sig)
                except ProcessLookupError:
                    pass
            deadline = time.monotonic() + wait
            for p in alive:
                try:
                    p.wait(timeout=max(0.0, deadline - time.monotonic()))
                except subprocess.TimeoutExpired:
                    pass
        for fh in self.logs.values():
            fh.close()
        self.open_gate()  # after the signals: nothing stopped at the gate goes on
        self.board.close()
        if self.forker is not None:
            self.forker.close()
            self.forker = None


def bindable(host: str, port: int) -> bool:
    """Whether a server could listen on ``host``:``port`` now (as servers bind: with
    SO_REUSEADDR, so that connections of a killed predecessor do not hold it)."""
    import socket

    try:
        with socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET) as s:
            s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            s.bind((host, port))
    except OSError:
        return False
    return True


def free_port(host: str) -> int | None:
    """A port free on ``host`` now (the system's pick), or None."""
    import socket

    try:
        with socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET) as s:
            s.bind((host, 0))
            return int(s.getsockname()[1])
    except OSError:
        return None


def exit_status(code: int) -> str:
    """How a process ended, for the user: 'status N' or 'signal SIGKILL'."""
    if code < 0:
        try:
            return f"signal {signal.Signals(-code).name}"
        except ValueError:
            return f"signal {-code}"
    return f"status {code}"


@dataclass(frozen=True)
class Failure:
    """A node process that died for good: its exit ``code`` and the policy it had."""

    spec: NodeSpec
    code: int

    @property
    def status(self) -> int:
        """The launcher's exit status: 2 when the node refused (bad input, or another
        formation here), the node's own when it is one a restart cannot help (4 stuck, 5
        disk full: ``formation_ilc.system.exits``), else 1."""
        if self.code == self.spec.restart.refused:
            return 2
        return self.code if self.code in NO_RESTART else 1


class Supervisor:
    """Runs the processes of ``plan``.

    place : the command line of a process (``--hosts netns``: inside its robot's network
        namespace); default its own.
    on_down : called with (name, pid) when a process died and is started again (before
        it is).
    """

    def __init__(self, plan: RunPlan, env: dict[str, str],
                 place: Callable[[NodeSpec], list[str]] | None = None,
                 on_down: Callable[[str, int], None] | None = None):
        self.plan = plan
        self.stack = Stack(env, plan.out / "logs")
        self.specs = {s.name: s for s in plan.nodes}
        self.place = place or (lambda spec: spec.command)
        self.on_down = on_down
        #: the processes that are a node the leader waits for (``unseen``)
        self.team = set(plan.team.expected) & set(self.specs)

    @property
    def restarts(self) -> dict[str, int]:
        return self.stack.restarts

    def start(self, gated: bool = False) -> None:
        """Start every process of the plan, in its order; ``gated``: they wait at the
        gate until ``open_gate``."""
        if gated:
            self.stack.shut_gate()
        from formation_ilc.nodes.forkserver import wanted

        if wanted(self.stack.env, len(self.plan.nodes)) and self.stack.forker is None:
            self.stack.start_forker(sorted({s.module for s in self.plan.nodes}))
        for spec in self.plan.nodes:
            self.stack.start(spec.name, self.place(spec), dict(spec.env))

    def open_gate(self) -> None:
        self.stack.open_gate()

    def watch(self) -> Failure | None:
        """Start again each process that died, within its policy; the first that may not
        be started again, or None. A process that stopped beating is named and killed
        first (``Stack.kill_frozen``), then started again as one that died."""
        for f in self.stack.kill_frozen():
            print(f"{f.line()}: stopping it", flush=True)
            log = self.stack.logs[f.name]
            log.write(f"\n--- {f.line()}: stopped by the launcher ---\n".encode())
            log.flush()
        for name, silent, doing in self.stack.board.late:
            print(f"{name} beats again after {silent:.0f} s without a heartbeat, working "
                  f"meanwhile (now: {doing})", flush=True)
        self.stack.board.late.clear()
        for name, code in self.stack.dead():
            froze = self.stack.frozen.pop(name, None)
            self.stack._kill_at.pop(name, None)
            spec = self.specs[name]
            n = self.stack.restarts.get(name, 0)
            if not spec.restart.allows(code, n):
                if spec.optional:  # a viewer: the run goes on without it
                    self.stack.procs.pop(name)
                    said = self.last_word(name)
                    print(f"{name} exited with {exit_status(code)}"
                          f"{f' after {n} restarts' if n else ''}"
                          f"{f' ({said})' if said else ''}: the run goes on without it "
                          f"(log: {self.stack.log_dir / (name + '.log')})", flush=True)
                    continue
                return Failure(spec, code)
            if self.on_down is not None:
                # a passive node's death is not seen otherwise until it is back; every
                # node's name is free for its successor's participant (protocol.writers)
                self.on_down(name, self.stack.procs[name].pid)
            note = self.stack.restart(name)
            what = ("" if spec.passive or spec.optional
                    else "; the trial it interrupted runs again")
            how = (f"exited with {exit_status(code)}" if froze is None
                   else f"was not in the graph (pid {froze.pid})" if froze.doing == UNSEEN
                   else f"froze (pid {froze.pid})")
            print(f"{name} {how}: starting it again "
                  f"({n + 1}/{spec.restart.max_restarts}){what}{note}", flush=True)
        return None

    def unseen(self, seen: set[str], bound: float, now: float | None = None) -> list[str]:
        """Start-up: the processes of the team that have spun (their node built, their
        executor running: ``system.heartbeat``) for ``bound`` seconds while the graph
        does not show their node (not in ``seen``: a participant nobody discovered), named
        and stopped; the next ``watch`` starts them again. Their names."""
        now = time.monotonic() if now is None else now
        out = []
        for name, p in self.stack.procs.items():
            if name not in self.team or name in seen or name in self.stack.frozen \
                    or p.poll() is not None:
                continue
            since = self.stack.board.spinning_since(name, now)
            if since is None or now - since < bound:
                continue
            line = (f"{name} (pid {p.pid}) has spun {now - since:.0f} s and is not in the "
                    f"ROS graph (no node of the team has discovered it): stopping it")
            print(line, flush=True)
            log = self.stack.logs[name]
            log.write(f"\n--- {line} (the launcher) ---\n".encode())
            log.flush()
            self.stack.stop_frozen(name, Frozen(name, p.pid, UNSEEN, now - since, False), now)
            out.append(name)
        return out

    def report(self, failure: Failure) -> int:
        """Say which process failed and why: the one line the node said, when it stopped on
        purpose (bad input, a stuck run, a full disk, with what to do next), else its
        log's tail; the exit status."""
        name, code, policy = failure.spec.name, failure.code, failure.spec.restart
        log = self.stack.log_dir / (name + ".log")
        said = self.last_word(name)
        out = self.plan.out
        if code == DISK_FULL:
            file = (said.split(f"{DISK_FULL_TAG}: cannot write ", 1)[-1].split(" (")[0]
                    if said and DISK_FULL_TAG in said else None)
            print(f"error: {disk_full_line(name, file, out)}", file=sys.stderr)
            return failure.status
        if code == STOPPED and said is not None:  # the stop button: no error of the run
            print(f"stopped: {said} (log: {log}); the finished trials are in metrics.csv",
                  file=sys.stderr)
            return failure.status
        if (code == policy.refused or code in NO_RESTART) and said is not None:
            hint = (f"; {len(metrics_rows(out))} trials are in metrics.csv; after fixing the "
                    f"cause: {resume_hint(out)}" if code == STUCK else "")
            print(f"error: {said} (log: {log}){hint}", file=sys.stderr)
            return failure.status
        again = ("" if code == policy.refused or code in NO_RESTART or not policy.max_restarts
                 else f" after {policy.max_restarts} restarts")
        print(f"error: node process {name} exited with {exit_status(code)}{again} "
              f"(log: {self.stack.log_dir / (name + '.log')})", file=sys.stderr)
        tail = self.stack.log_tail(name)
        if tail:
            print(tail, file=sys.stderr)
        return failure.status

    def last_word(self, name: str) -> str | None:
        """The one line a node said last about why it stopped (``NAME: ...`` on stderr,
        or its entry script's ``formation-ilc-...: ...``), from its log."""
        for line in reversed(self.stack.log_tail(name, 40).splitlines()):
            if line.startswith((f"{name}:", "formation-ilc-")):
                return line
        return None

    def stop(self) -> None:
        self.stack.stop()


def metrics_rows(out: Path) -> list[str]:
    """The trial rows in ``out``/metrics.csv, as text (what the user has of the run)."""
    try:
        lines = (out / "metrics.csv").read_text().splitlines()[1:]
    except OSError:
        return []
    return [ln for ln in lines if ln.strip()]


def trial_ranges(ks: list[int]) -> str:
    """'trials 0-2, 5, 7-9' for [0, 1, 2, 5, 7, 8, 9]; 'trial 4' for [4]."""
    out: list[str] = []
    for k in sorted(ks):
        if out and out[-1].split("-")[-1] == str(k - 1):
            out[-1] = f"{out[-1].split('-')[0]}-{k}"
        else:
            out.append(str(k))
    return "trial " + ", ".join(out) if len(ks) == 1 else "trials " + ", ".join(out)


def resume_hint(out: Path) -> str:
    return f"formation-ilc launch --resume {out}"


def disk_full_line(who: str, filename: str | None, out: Path) -> str:
    """The one line of a run stopped by a full disk: the file, what was kept, what next."""
    return (f"the disk is full: {who} could not write {filename or 'its file'}; kept: "
            f"{out / 'metrics.csv'} with {len(metrics_rows(out))} trials and the state of "
            f"every trial learned ({out / 'state'}); free some space, then: "
            f"{resume_hint(out)}")


#: this launcher's identity, in every node's ``boot`` (``protocol.schedule.boot_id``): new
#: for each launcher process
LAUNCHER_ID = uuid.uuid4().hex[:8]


def node_env(plan: RunPlan) -> dict[str, str]:
    """The environment of every node process of ``plan`` (``plan.specs.RunPlan``): this
    one's, on the plan's domain, bound to this launcher and to the run."""
    from formation_ilc.nodes.common import KEY_ENV, LAUNCHER_ENV, RUN_ENV
    from formation_ilc.system.lifetime import PARENT_ENV

    env = dict(os.environ)
    env["ROS_DOMAIN_ID"] = str(plan.domain)
    if plan.discovery in ("localhost", "server"):  # (the server's address: execute)
        # with the server, rmw's LOCALHOST range would add shared memory, whose ports the
        # clients took twice at this scale: the profile's one transport, UDP bound to
        # 127.0.0.1, keeps every datagram on the loopback instead
        # (system.discovery.server_profile)
        env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = ("LOCALHOST" if plan.discovery == "localhost"
                                                else "SYSTEM_DEFAULT")
        env.pop("ROS_DISCOVERY_SERVER", None)  # a server of the caller's may be elsewhere
    if plan.peers_profile is not None:  # a secure run's profile, built on it, comes later
        env["FASTRTPS_DEFAULT_PROFILES_FILE"] = str(plan.peers_profile)
    env["PYTHONUNBUFFERED"] = "1"
    env[PARENT_ENV] = str(os.getpid())  # every node ends with this launcher
    env[RUN_ENV] = plan.config.run_id  # and takes only this run's configuration
    env[LAUNCHER_ENV] = LAUNCHER_ID  # its readies name this launcher (a host's restart)
    env.pop(KEY_ENV, None)
    if plan.key is not None:  # and only the events this run's leader sealed
        env[KEY_ENV] = plan.key.hex()
    return env
