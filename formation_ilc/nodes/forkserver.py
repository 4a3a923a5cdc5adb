"""One import, many robots: a fork server for the node processes of a launch.

Every node process imports Python, numpy, rclpy, the message types and this package on
its own: about 1.7 s of CPU each before it does anything (issue 56), and the same pages
held once per process. The fork server imports all of that once (the entry modules of the
plan's nodes), with no rclpy context and no DDS thread, then forks each node process,
which only then initialises rclpy with its own name and parameters (as Android's zygote
does for its apps). The children share the server's pages until they write them
(``gc.freeze`` keeps the collector from writing every object it visits).

How a child is made (``spawn``): the launcher sends the server the command line, the
environment and the child's log and stdin (file descriptors over a Unix socket); the
server forks an intermediate process, which forks the child and exits at once. The
launcher is a child subreaper (``PR_SET_CHILD_SUBREAPER``), so the orphaned child becomes
the launcher's own child: the supervisor waits for it, signals it and restarts it as it
does a process it started itself (a restarted one starts as an interpreter of its own:
``cli.supervisor.Stack.start``), and the parent-death
signal the child sets (``system.lifetime``) is bound to the launcher. The child then runs
exactly what ``python -m formation_ilc.system.lifetime -m MODULE ARGS`` runs, so the
``ros2 run``-style entry points are unchanged.

The guard (``fork_problem``): the server forks only when no thread of its own exists but
those the shared libraries start as they load (LTTng-UST's two listener threads, linked
into the rmw of the locked wheels: counted once after the imports, they wait on a futex
and hold nothing a child needs; a child has none of them) and no rclpy context is
initialised. A server that finds another thread refuses to fork, and the launcher starts
its processes as before (``Stack.start``). Fast DDS is not fork-safe: a child of a process
that had a participant would inherit its locks and sockets half-held.
"""

from __future__ import annotations

import gc
import importlib
import json
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import IO, Any

__all__ = ["FORK_ENV", "ForkServer", "ForkedProcess", "ForkRefused", "forkable",
           "fork_problem", "subreaper", "wanted"]

#: environment variable of the launcher: "1" starts the node processes through a fork
#: server, "0" as separate interpreters; unset: ``wanted``'s default
FORK_ENV = "FORMATION_ILC_FORKSERVER"
#: the most node processes a launcher forks by default. A launch of a 3- or 6-robot team
#: forked used a quarter less CPU than one interpreter per node (tests/stack/test_stack.py,
#: 13 runs: 222 against 296 CPU seconds, 2026-12-07); 50 robots forked started no faster
#: and twice did not finish starting (docs/distributed-stack.md, "the fork server"): every
#: child joins the domain at once, so a large team stays as before until it is admitted
#: in waves
FORK_DEFAULT_MAX = 16
_PR_SET_CHILD_SUBREAPER = 36
#: [s] the longest a spawn waits for the server (its imports come first, once)
SPAWN_WAIT = 300.0
#: [s] the longest a forked child waits for its intermediate process to exit (at once)
ADOPT_WAIT = 10.0
#: the server's last argument: room for its children's command lines (``_retitle``)
_PAD = "--pad=" + "." * 4090


def wanted(env: dict[str, str] | None = None, processes: int = 0) -> bool:
    """Whether a launcher of ``processes`` node processes forks them: ``FORK_ENV`` "1" or
    "0" says so; unset, up to ``FORK_DEFAULT_MAX`` processes."""
    value = (env if env is not None else os.environ).get(FORK_ENV, "")
    if value in ("0", "1"):
        return value == "1"
    return processes <= FORK_DEFAULT_MAX


class ForkRefused(RuntimeError):
    """The server cannot fork (it has a thread it must not have, or it is gone)."""


def subreaper() -> bool:
    """Make this process the child subreaper of its descendants; whether it is."""
    try:
        import ctypes

        libc = ctypes.CDLL(None, use_errno=True)
        return libc.prctl(_PR_SET_CHILD_SUBREAPER, 1, 0, 0, 0) == 0
    except (OSError, AttributeError):
        return False


def forkable(command: list[str]) -> bool:
    """Whether ``command`` is a node run through the lifetime runner by this interpreter
    (``python -m RUNNER -m MODULE ...``): what the server can fork. Anything else (a
    command in a network namespace, another interpreter) is started as before."""
    from formation_ilc.system.lifetime import RUNNER

    return (len(command) >= 5 and command[0] == sys.executable
            and command[1:3] == ["-m", RUNNER] and command[3] == "-m")


class ForkedProcess:
    """A node process the server forked, now this launcher's child: what the supervisor
    uses of ``subprocess.Popen``."""

    def __init__(self, pid: int, args: list[str]):
        self.pid = pid
        self.args = args
        self.returncode: int | None = None

    def poll(self) -> int | None:
        if self.returncode is None:
            try:
                pid, status = os.waitpid(self.pid, os.WNOHANG)
            except ChildProcessError:  # reaped by someone else: it ended, how is unknown
                self.returncode = -int(signal.SIGKILL)
                return self.returncode
            if pid:
                self.returncode = os.waitstatus_to_exitcode(status)
        return self.returncode

    def wait(self, timeout: float | None = None) -> int:
        deadline = None if timeout is None else time.monotonic() + timeout
        while self.poll() is None:
            if deadline is not None and time.monotonic() >= deadline:
                raise subprocess.TimeoutExpired(self.args, timeout or 0.0)
            time.sleep(0.01)  # a child of ours, not of a Popen: polled, up to the timeout
        assert self.returncode is not None
        return self.returncode

    def send_signal(self, sig: int) -> None:
        if self.poll() is None:
            os.kill(self.pid, sig)

    def kill(self) -> None:
        self.send_signal(signal.SIGKILL)


class ForkServer:
    """The launcher's side: the server process and its socket."""

    def __init__(self, env: dict[str, str], modules: list[str], log: Path):
        if not subreaper():
            raise ForkRefused("this launcher cannot adopt forked processes "
                              "(PR_SET_CHILD_SUBREAPER failed)")
        self.sock, theirs = socket.socketpair(socket.AF_UNIX, socket.SOCK_SEQPACKET)
        log.parent.mkdir(parents=True, exist_ok=True)
        self.log: IO[bytes] = log.open("wb")
        try:
            self.proc = subprocess.Popen(
                [sys.executable, "-m", __name__, str(theirs.fileno()), *modules, _PAD],
                env=env, pass_fds=[theirs.fileno()], stdin=subprocess.DEVNULL,
                stdout=self.log, stderr=subprocess.STDOUT)
        finally:
            theirs.close()
        self.modules = modules
        #: what the server said at its last fork: its threads, and those it allows
        self.last: dict[str, Any] = {}

    def spawn(self, command: list[str], env: dict[str, str], out: int,
              stdin: int | None) -> ForkedProcess:
        """Fork ``command`` (``forkable``) with ``env``, stdout and stderr into ``out``,
        stdin from ``stdin`` (None: /dev/null). Raises ForkRefused when the server will
        not or cannot."""
        request = json.dumps({"argv": command[3:], "env": env, "cwd": os.getcwd()}).encode()
        fds = [out] if stdin is None else [out, stdin]
        self.sock.settimeout(SPAWN_WAIT)
        try:
            socket.send_fds(self.sock, [request], fds)
            reply = self.sock.recv(65536)
        except OSError as exc:
            raise ForkRefused(f"the fork server is gone ({exc})") from exc
        if not reply:
            raise ForkRefused(f"the fork server is gone ({self.tail()})")
        answer = json.loads(reply)
        self.last = answer
        if "error" in answer:
            raise ForkRefused(str(answer["error"]))
        return ForkedProcess(int(answer["pid"]), command)

    def tail(self) -> str:
        self.log.flush()
        try:
            text = Path(self.log.name).read_text(errors="replace")
        except OSError:
            return ""
        return " / ".join(text.strip().splitlines()[-3:])

    def close(self) -> None:
        """End the server (its children are the launcher's now and go on)."""
        self.sock.close()  # the server reads its end and exits
        try:
            self.proc.wait(timeout=5)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
        self.log.close()


# ---- the server ---------------------------------------------------------------------

def _tasks() -> set[int]:
    return {int(t) for t in os.listdir("/proc/self/task")}


def fork_problem(allowed: int) -> str | None:
    """Why this process must not fork now, or None: a Python thread besides the main one,
    more native threads than ``allowed`` (those the libraries started as they loaded),
    or an rclpy context that is initialised (its participant's threads)."""
    if threading.active_count() > 1:
        names = [t.name for t in threading.enumerate() if t is not threading.main_thread()]
        return f"the fork server has Python threads: {', '.join(names)}"
    tasks = len(_tasks())
    if tasks > allowed:
        return (f"the fork server has {tasks} threads, {allowed} allowed (the libraries' "
                f"own): a DDS participant or another thread was started before the fork")
    rclpy = sys.modules.get("rclpy")
    if rclpy is not None and rclpy.ok():
        return "the fork server has an initialised rclpy context"
    return None


def _serve(sock: socket.socket, modules: list[str]) -> None:
    """Import ``modules``, then fork a child for each request until the launcher closes
    the socket. Returns in the server; in a child it never returns (SystemExit)."""
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # no BLAS thread pool to fork
    # the threads the shared libraries start as they load (LTTng-UST's listeners, in the
    # locked wheels' rmw): counted before anything else is imported; any thread more at a
    # fork (a participant's, a module's) is refused
    import rclpy  # noqa: F401 - its libraries' constructors

    allowed = len(_tasks())
    failed = []
    for m in modules:
        try:
            importlib.import_module(m)
        except Exception as exc:  # noqa: BLE001 - the child imports it again and says why
            failed.append(f"{m}: {exc}")
    if failed:
        print(f"fork server: not preloaded: {'; '.join(failed)}", file=sys.stderr, flush=True)
    gc.collect()
    gc.freeze()
    print(f"fork server: {len(sys.modules)} modules imported, {allowed} threads",
          flush=True)
    while True:
        try:
            msg, fds, _, _ = socket.recv_fds(sock, 1 << 20, 2)
        except ConnectionError:
            return
        if not msg:
            return
        problem = fork_problem(allowed)
        if problem:
            for fd in fds:
                os.close(fd)
            sock.send(json.dumps({"error": problem}).encode())
            continue
        request = json.loads(msg)
        tasks = len(_tasks())
        r, w = os.pipe()
        sys.stdout.flush()
        sys.stderr.flush()
        middle = os.fork()
        if middle == 0:  # the intermediate process
            os.close(r)
            # its own pid, taken before the fork: the child's os.getppid() may already be
            # the launcher's (the intermediate gone first), and a child that waited for
            # that to change waited its whole bound: 10 s at the start of one process in
            # two launches of a small team (2026-12-07)
            me = os.getpid()
            try:
                child = os.fork()
            except OSError:
                os._exit(1)
            if child == 0:
                os.close(w)
                _become(sock, request, fds, me)  # never returns
            os.write(w, str(child).encode())
            os._exit(0)
        os.close(w)
        got = b""
        while chunk := os.read(r, 64):
            got += chunk
        os.close(r)
        os.waitpid(middle, 0)  # gone: its child is the launcher's now
        for fd in fds:
            os.close(fd)
        reply: dict[str, Any] = ({"pid": int(got), "threads": tasks, "allowed": allowed}
                                 if got else {"error": "the fork failed"})
        sock.send(json.dumps(reply).encode())


def _become(sock: socket.socket, request: dict[str, Any], fds: list[int],
            middle: int) -> None:
    """In the forked child: wait to be the launcher's (``middle``: the intermediate
    process's pid, its parent until that exits), take the log and stdin, the environment
    and the command line, and run the node as the lifetime runner does."""
    launcher = os.environ.get("FORMATION_ILC_PARENT")
    deadline = time.monotonic() + ADOPT_WAIT
    while os.getppid() == middle and time.monotonic() < deadline:
        time.sleep(0.001)  # the intermediate exits at once
    late = os.getppid() == middle
    sock.close()
    out, stdin = fds[0], (fds[1] if len(fds) > 1 else os.open(os.devnull, os.O_RDONLY))
    os.dup2(stdin, 0)
    os.dup2(out, 1)
    os.dup2(out, 2)
    for fd in {out, stdin}:
        if fd > 2:
            os.close(fd)
    os.chdir(request["cwd"])
    os.environ.clear()
    os.environ.update(request["env"])
    signal.signal(signal.SIGINT, signal.default_int_handler)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    if late:
        print(f"forked by the fork server, but its intermediate process {middle} was still "
              f"its parent after {ADOPT_WAIT:.0f} s", file=sys.stderr, flush=True)
    if launcher and str(os.getppid()) != launcher:
        print(f"forked by the fork server, but launcher {launcher} did not adopt it "
              f"(parent {os.getppid()})", file=sys.stderr, flush=True)
    from formation_ilc.system.heartbeat import beat
    from formation_ilc.system.lifetime import _run, die_with_parent

    argv = list(request["argv"])  # -m MODULE ARGS
    module = sys.modules.get(argv[1]) if len(argv) > 1 else None
    if module is None or not callable(getattr(module, "main", None)):
        _run(argv)  # not preloaded: imported here, run as python -m runs it
        raise SystemExit(0)
    # preloaded: its main, as its `if __name__ == "__main__": sys.exit(main())` calls it
    # (runpy would execute the module a second time, beside the shared copy)
    die_with_parent()
    beat("forked")
    _retitle([sys.executable, "-m", "formation_ilc.system.lifetime", *argv])
    sys.argv = [module.__file__ or argv[1], *argv[2:]]
    raise SystemExit(module.main())


def _retitle(argv: list[str]) -> None:
    """Make ``/proc/PID/cmdline`` say ``argv`` (what ps, the tests and the benchmarks read
    to tell a node process: its robot id, its module), written over the server's own
    command line (which ``_PAD`` made long enough; a longer one is cut)."""
    import ctypes

    try:
        with open("/proc/self/stat", "rb") as fh:
            fields = fh.read().rsplit(b")", 1)[1].split()
        start, end = int(fields[45]), int(fields[46])  # arg_start, arg_end (48, 49)
    except (OSError, IndexError, ValueError):
        return
    size = end - start
    text = "\0".join(argv).encode()[: size - 1]
    ctypes.memmove(start, text.ljust(size, b"\0"), size)


def main(argv: list[str]) -> int:
    from formation_ilc.system.lifetime import die_with_parent

    die_with_parent()
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the launcher ends it (closes its socket)
    sock = socket.socket(fileno=int(argv[0]))
    _serve(sock, [a for a in argv[1:] if not a.startswith("--pad=")])
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
