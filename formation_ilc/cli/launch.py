"""Run the distributed ROS 2 stack on this machine: one OS process per node.

Starts the virtual leader, the plant (the kinematic simulator, unless --plant external),
the link emulator (with --links emulated), and one process per robot (or, with
--container N, N robot nodes per process), all on localhost discovery and on a
ROS_DOMAIN_ID of their own, in one namespace (--namespace). Prints per-trial progress,
writes DIR/metrics.csv (the columns of `formation-ilc simulate`), DIR/delays.csv (per-link
delay histograms: measured by the robots with eq. 11, injected by the emulated links, and
the model's), DIR/diagnostics.json, DIR/summary.json, DIR/errors.png and one log per
process in DIR/logs/. Stops every process on Ctrl-C, or when a node fails for good, and
then exits non-zero naming it.

Faults: a node process that dies during the run is started again with the same
parameters (at most --max-restarts times each); the robots and the leader keep their state
in DIR/state/ (written atomically at every trial), the interrupted trial is aborted and run
again, and no learned trial is lost. No node outlives the launcher, whatever signal ends
it; `launch --resume DIR` continues an interrupted run. Before anything starts, the
launcher refuses to join a ROS domain and namespace where another formation already runs
(docs/reliability.md).

Node entry points (also `ros2 run formation_ilc <exe>` on a full ROS 2 install):
  formation-ilc-leader  virtual leader: --ros-args -p scenario:=NAME [-p trials:=K ...]
  formation-ilc-sim     kinematic simulator, the plant (config from the config topic)
  formation-ilc-links   link emulator, for emulated links (config from the config topic)
  formation-ilc-robot   one robot: --ros-args -p robot_id:=I; container: --robots 1 2 3
  formation-ilc-bridge  a Pioneer 3-DX behind the plant contract: --ros-args -p robot_id:=I
                        -p driver:=rosaria (docs/real-robots.md)

--plant pioneer: one bridge per robot instead of the simulator (with --fake-drivers one
fake RosAria driver per robot too), wall-clock trials, direct links; --init-memory FILE:
every robot starts from its row of a memory learned by `formation-ilc simulate`.

--secure DIR: every node in its SROS2 enclave of the keystore DIR (`formation-ilc keystore
create DIR SCENARIO`), DDS-Security enforced; refused before anything starts if the
keystore or the loaded Fast DDS cannot run it (docs/security.md).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from datetime import datetime
from pathlib import Path
from typing import IO, Any

import numpy as np

from formation_ilc.cli.options import (
    OptionError,
    int_range,
    nonneg_int,
    out_dir_arg,
    output_file_arg,
    positive_float,
    positive_int,
)

__all__ = ["add_arguments", "run", "Stack", "node_commands"]


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("scenario", metavar="SCENARIO", nargs="?",
                   help="built-in scenario name (formation-ilc scenarios) or a YAML file "
                        "(not with --resume)")
    p.add_argument("--trials", type=positive_int, metavar="K",
                   help="number of trials (default: 20)", default=20)
    p.add_argument("--law", type=int, choices=(9, 22, 23))
    p.add_argument("--memory", choices=("feedforward", "literal"))
    p.add_argument("--seed", type=nonneg_int, help="random seed, >= 0 (default: the "
                   "scenario's)")
    p.add_argument("--no-noise", action="store_true",
                   help="no initial shifts, disturbances or measurement noise")
    p.add_argument("--no-delay", action="store_true", help="no communication delays")
    p.add_argument("--mode", choices=("lockstep", "realtime", "wallclock"), default=None,
                   help="lockstep (default with the simulator): the simulator waits for every "
                        "robot (as fast as the processes allow, deterministic); realtime: the "
                        "simulator ticks on the wall clock at dT; wallclock (default and "
                        "required with --plant pioneer): no /clock, the trials run on the "
                        "machines' synchronised wall clocks")
    p.add_argument("--links", choices=("emulated", "direct"), default=None,
                   help="emulated (default): a link emulator process puts the scenario's "
                        "delays on the robot-to-robot links, in simulated time (a lockstep "
                        "run equals `simulate`); direct: each robot subscribes to its "
                        "neighbours, as on robots, and the delays are the network's (a "
                        "lockstep run equals `simulate --no-delay`; the default and required "
                        "with --plant pioneer)")
    p.add_argument("--plant", choices=("sim", "external", "pioneer"), default="sim",
                   help="sim (default): start the kinematic simulator; external: another "
                        "process speaks the plant contract (docs/distributed-stack.md) and "
                        "says ready as one of --plant-nodes; pioneer: one Pioneer bridge per "
                        "robot (formation-ilc-bridge, docs/real-robots.md) in front of a "
                        "driver (--driver), wall-clock trials, direct links")
    p.add_argument("--driver", choices=("rosaria", "p2os2", "ros2aria"), default="rosaria",
                   help="with --plant pioneer: the robots' driver (default rosaria)")
    p.add_argument("--driver-ns", default="/pioneer_{i}", metavar="PATTERN",
                   help="with --plant pioneer: robot i's driver namespace, {i} replaced by "
                        "the robot number (default /pioneer_{i})")
    p.add_argument("--cmd-type", choices=("twist", "twist_stamped"), default="twist",
                   help="with --plant pioneer: Twist (default) or TwistStamped "
                        "(diff_drive_controller) on the driver's cmd_vel")
    p.add_argument("--fake-drivers", action="store_true",
                   help="with --plant pioneer: also start one fake RosAria driver per robot "
                        "(robot_sim.fake_pioneer: a unicycle in wall time with odometry "
                        "drift and noise), for a run without robots")
    p.add_argument("--return-timeout", type=positive_float, default=60.0, metavar="S",
                   help="with --plant pioneer: how long a bridge drives its robot back to the "
                        "initial pose between trials before it reports a timeout")
    p.add_argument("--init-memory", type=Path, metavar="MEMORY.npz",
                   help="every robot starts from its row of this memory file (written by "
                        "`formation-ilc simulate`): the sim-to-real carry-over")
    p.add_argument("--plant-nodes", nargs="+", default=["plant"], metavar="NAME",
                   help="with --plant external: the node names the schedule waits for "
                        "(default: plant)")
    p.add_argument("--namespace", default=None, metavar="NS",
                   help="ROS namespace of the whole formation (default /formation); two "
                        "formations in different namespaces share a ROS domain without "
                        "crosstalk (/clock is remapped into the namespace)")
    p.add_argument("--container", type=int_range(0, 1024), default=0, metavar="N",
                   help="N robot nodes per process on one executor (0: one process per "
                        "robot, the default)")
    p.add_argument("--out", type=out_dir_arg, metavar="DIR",
                   help="output folder (default: runs/SCENARIO-launch-TIME)")
    p.add_argument("--domain-id", type=int_range(0, 232), metavar="ID",
                   help="ROS_DOMAIN_ID (default: a free-looking one in 30..100)")
    p.add_argument("--discovery", choices=("localhost", "inherit"), default="localhost",
                   help="localhost (default): ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST; "
                        "inherit: keep the caller's discovery settings (multi-host runs)")
    p.add_argument("--timeout", type=positive_float, default=30.0, metavar="S",
                   help="lockstep: give up when a robot has not commanded for S seconds")
    p.add_argument("--no-plots", action="store_true", help="write no figures")
    p.add_argument("--resume", type=Path, metavar="DIR",
                   help="continue the interrupted run whose output folder is DIR, with its "
                        "options: the robots reload their memory from DIR/state/, the trial "
                        "that was running is run again, and metrics.csv goes on")
    p.add_argument("--max-restarts", type=int, default=3, metavar="N",
                   help="restart a node process that dies at most N times (default 3; 0: "
                        "a dead node ends the run)")
    p.add_argument("--record", type=output_file_arg, metavar="RUN.mcap",
                   help="record every formation topic to this MCAP file (its own recorder "
                        "process; the run starts once it listens); analyse it with "
                        "`formation-ilc analyze RUN.mcap`")
    add_host_arguments(p)
    from formation_ilc.cli import secure

    secure.add_arguments(p)


def _pick_domain() -> int:
    # distinct per launcher process; the shared-memory locks of Fast DDS name the domain
    # port, so avoid ids whose port files are held (another run on this machine)
    base = os.getpid() % 71
    for off in range(71):
        d = 30 + (base + off) % 71
        port = 7400 + 250 * d
        if not any(Path("/dev/shm").glob(f"fastrtps_port{port}*")):
            return d
    return 30 + base


def ros_args(namespace: str | None) -> list[str]:
    """ROS arguments that put a node into ``namespace`` (nothing for the default one)."""
    import msgs_schema as ms

    if namespace is None or namespace == ms.NAMESPACE:
        return []
    return ["-r", f"__ns:={namespace}", "-r", f"{ms.CLOCK}:={namespace}{ms.CLOCK}"]


def node_commands(cfg_args: dict[str, Any], n: int, container: int, *, links: str = "emulated",
                  plant: str = "sim", namespace: str | None = None,
                  robot_params: dict[str, Any] | None = None,
                  bridge_params: dict[str, Any] | None = None, driver_ns: str = "/pioneer_{i}",
                  fake_drivers: bool = False, cmd_type: str = "twist"
                  ) -> list[tuple[str, list[str]]]:
    """(name, argv) of every process of the stack (sys.executable -m ...)."""
    py = sys.executable
    nsa = ros_args(namespace)
    rp: list[str] = []
    for k, v in (robot_params or {}).items():
        rp += ["-p", f"{k}:={v}"]
    leader = [py, "-m", "virtual_leader.node", "--ros-args", *nsa]
    for k, v in cfg_args.items():
        leader += ["-p", f"{k}:={v}"]
    procs = [("virtual_leader", leader)]
    if plant == "sim":
        procs.append(("robot_sim", [py, "-m", "robot_sim.node", "--ros-args", *nsa, "-p",
                                    f"timeout:={float(cfg_args['timeout'])}"]))
    if plant == "pioneer":
        for i in range(1, n + 1):
            dns = driver_ns.replace("{i}", str(i))
            if fake_drivers:
                driver = (bridge_params or {}).get("driver", "rosaria")
                procs.append((f"fake_pioneer_{i}", [py, "-m", "robot_sim.fake_pioneer",
                                                    "--ros-args", "-r", f"__ns:={dns}", "-p",
                                                    f"seed:={i}", "-p", f"cmd_type:={cmd_type}",
                                                    "-p", f"driver:={driver}"]))
            bp = [f"robot_id:={i}", f"driver_ns:={dns}", f"cmd_type:={cmd_type}"]
            bp += [f"{k}:={v}" for k, v in (bridge_params or {}).items()]
            procs.append((f"bridge_{i}", [py, "-m", "formation_ilc.nodes.pioneer_bridge",
                                          "--ros-args", *nsa,
                                          *[a for b in bp for a in ("-p", b)]]))
    if links == "emulated":
        procs.append(("link_emulator", [py, "-m", "robot_sim.link_emulator", "--ros-args",
                                        *nsa]))
    ids = list(range(1, n + 1))
    if container > 0:
        for c in range(0, n, container):
            grp = ids[c:c + container]
            procs.append((f"robots_{grp[0]}-{grp[-1]}",
                          [py, "-m", "formation_ilc.nodes.robot", "--robots", *map(str, grp),
                           *(["--ros-args", *nsa, *rp] if nsa or rp else [])]))
    else:
        for i in ids:
            procs.append((f"robot_{i}", [py, "-m", "formation_ilc.nodes.robot", "--ros-args",
                                         *nsa, "-p", f"robot_id:={i}", *rp]))
    return procs


class Stack:
    """The processes of one run; ``stop()`` ends them (SIGINT, then SIGTERM, SIGKILL)."""

    def __init__(self, env: dict[str, str], log_dir: Path,
                 env_for: Callable[[dict[str, str], str], dict[str, str]] | None = None):
        self.env = env
        self.env_for = env_for  # a process's own environment (--secure: its enclave)
        self.log_dir = log_dir
        self.procs: dict[str, subprocess.Popen[bytes]] = {}
        self.logs: dict[str, IO[bytes]] = {}
        self.argv: dict[str, list[str]] = {}
        self.restarts: dict[str, int] = {}

    def start(self, name: str, argv: list[str]) -> None:
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
        env = self.env_for(self.env, name) if self.env_for else self.env
        self.procs[name] = subprocess.Popen(argv, env=env, stdout=fh,
                                            stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL)

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
        self.start(name, argv)
        return note

    def dead(self) -> list[tuple[str, int]]:
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


#: the launch options a run is resumed with (DIR/run.json)
RUN_FILE = "run.json"
#: exit status of a node that refuses its configuration: restarting it cannot help
NO_RESTART = 2


def _save_run(out: Path, args: argparse.Namespace) -> None:
    from formation_ilc.store.atomic import atomic_write_text

    d = {k: (str(v) if isinstance(v, Path) else v) for k, v in vars(args).items()
         if k not in ("func", "command", "resume") and not k.endswith("_")}
    atomic_write_text(out / RUN_FILE, json.dumps(d, indent=2) + "\n")


def _resume_args(args: argparse.Namespace) -> argparse.Namespace | str:
    """The options of the run in ``args.resume`` (an error message if there is none)."""
    out = args.resume
    try:
        d = json.loads((out / RUN_FILE).read_text())
    except FileNotFoundError:
        return (f"--resume {out}: no {RUN_FILE} there (not the output folder of a "
                f"`formation-ilc launch` run)")
    except (OSError, ValueError) as exc:
        return f"--resume {out}/{RUN_FILE}: unreadable: {exc}"
    if args.scenario is not None:
        return "--resume takes the run's own scenario and options: give no SCENARIO"
    ns = argparse.Namespace(**vars(args))
    for k, v in d.items():
        setattr(ns, k, v)
    for k in ("out", "init_memory", "record"):
        if getattr(ns, k, None) is not None:
            setattr(ns, k, Path(getattr(ns, k)))
    ns.out = out
    ns.resume = out
    ns.max_restarts = args.max_restarts
    if ns.record is not None:
        # the first recording is closed; the resumed part goes next to it
        stem = ns.record.with_suffix("")
        n = 1
        while Path(f"{stem}.resumed{n}.mcap").exists():
            n += 1
        ns.record = Path(f"{stem}.resumed{n}.mcap")
    return ns


def _foreign(node: Any, namespace: str, wait: float, allowed: set[str]) -> list[str]:
    """Nodes of another formation in ``namespace`` on this domain (other than ``allowed``:
    an external plant's), after giving discovery ``wait`` seconds."""
    import msgs_schema as ms

    deadline = time.monotonic() + wait
    while time.monotonic() < deadline:
        time.sleep(0.05)
    found = [f"{ns.rstrip('/')}/{name}" for name, ns in node.get_node_names_and_namespaces()
             if ns == namespace and name != node.get_name() and name not in allowed]
    if node.count_publishers(ms.absolute(ms.CONFIG, namespace)) and not found:
        found.append(ms.absolute(ms.CONFIG, namespace))
    return found


def run(args: argparse.Namespace) -> int:
    """Run the stack; return the exit status (0 ok, 1 a node failed, 130 interrupted)."""
    import uuid

    import msgs_schema as ms
    from formation_ilc.config.runconfig import make_config
    from formation_ilc.core.links import delay_rows, link_histograms, write_delays
    from formation_ilc.core.metrics import MetricsWriter
    from formation_ilc.model.simulate import Problem
    from formation_ilc.nodes.common import warm_up
    from formation_ilc.protocol.schedule import Ready, Schedule
    from formation_ilc.system.shm import clean_leftovers, fastdds_files

    if getattr(args, "resume", None) is not None and not getattr(args, "resumed_", False):
        resumed = _resume_args(args)
        if isinstance(resumed, str):
            print(f"error: {resumed}", file=sys.stderr)
            return 2
        args = resumed
        args.resumed_ = True
    elif args.scenario is None:
        print("error: a SCENARIO is required (or --resume DIR)", file=sys.stderr)
        return 2
    if args.max_restarts < 0:
        print("error: --max-restarts must be >= 0", file=sys.stderr)
        return 2
    if getattr(args, "run_id", None) is None:
        # a letter first: an all-digit id would reach the leader as an integer parameter
        args.run_id = "r" + uuid.uuid4().hex[:12]
    if getattr(args, "hosts_", None) is None and (args.hosts == "netns" or _net_options(args)):
        return run_on_hosts(args)
    pioneer = args.plant == "pioneer"
    if pioneer and (args.mode not in (None, "wallclock") or args.links not in (None, "direct")):
        print(f"error: --plant pioneer runs --mode wallclock with --links direct (real robots "
              f"have no simulated clock and no link emulator), got --mode {args.mode} "
              f"--links {args.links}", file=sys.stderr)
        return 2
    if args.mode == "wallclock" and not pioneer and args.plant != "external":
        print("error: --mode wallclock is for real robots: use it with --plant pioneer (or an "
              "external plant that samples on the wall clock); the simulator runs lockstep "
              "or realtime", file=sys.stderr)
        return 2
    if args.fake_drivers and not pioneer:
        print("error: --fake-drivers goes with --plant pioneer", file=sys.stderr)
        return 2
    if args.fake_drivers and args.driver == "p2os2":
        print("error: --fake-drivers speak rosaria or ros2aria, not p2os2 (its p2os_msgs "
              "are not on PyPI)", file=sys.stderr)
        return 2
    args.mode = args.mode or ("wallclock" if pioneer else "lockstep")
    args.links = args.links or ("direct" if pioneer or args.mode == "wallclock" else "emulated")
    cfg = make_config(args.scenario, seed=args.seed, noise=not args.no_noise,
                      delay=not args.no_delay, trials=args.trials, law=args.law,
                      memory=args.memory, mode=args.mode, monitored=True,
                      timeout=args.timeout, links=args.links, run_id=args.run_id)
    namespace = args.namespace or ms.NAMESPACE
    if not namespace.startswith("/") or "//" in namespace:
        print(f"error: --namespace {namespace!r}: an absolute ROS namespace like /team2 is "
              f"required", file=sys.stderr)
        return 2
    sc = cfg.scenario
    robot_params: dict[str, Any] = {}
    if args.init_memory is not None:
        from formation_ilc.store.memoryfile import MemoryFileError, load_memory

        try:
            load_memory(args.init_memory, sc)  # refuse before any process starts
        except MemoryFileError as exc:
            print(f"error: --init-memory {exc}", file=sys.stderr)
            return 2
        robot_params["init_memory"] = str(args.init_memory.resolve())
    if sc.trials < 1:
        print("error: --trials must be at least 1", file=sys.stderr)
        return 2
    from formation_ilc.cli import secure

    try:  # --secure: keystore and Fast DDS checked before anything starts
        sec = secure.prepare(getattr(args, "secure", None), [name for name, _ in node_commands(
            {"timeout": 0}, sc.n, args.container, links=args.links, plant=args.plant,
            fake_drivers=args.fake_drivers)] + (["recorder"] if args.record else []),
            namespace, container=args.container)
    except OptionError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    out = args.out or Path("runs") / f"{sc.name}-launch-{datetime.now():%Y%m%d-%H%M%S}"
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        print(f"error: --out {out}: cannot create the folder: {exc.strerror}", file=sys.stderr)
        return 2
    out = out.resolve()
    args.out = out
    state_dir = out / "state"
    done = 0   # iterations every robot has learned (a resumed run)
    if args.resume is not None:
        probe = Schedule([], set(), sc.trials)
        try:
            probe.restore(state_dir / "leader.json")
        except Exception as exc:  # noqa: BLE001 - a ScheduleError naming the file
            print(f"error: --resume: {exc}", file=sys.stderr)
            return 2
        done = probe.committed
        if done >= sc.trials:
            print(f"{out}: all {sc.trials} trials are done; nothing to resume")
            return 0
    else:
        _save_run(out, args)
    robot_params["state_dir"] = str(state_dir)
    domain = args.domain_id if args.domain_id is not None else _pick_domain()
    env = dict(os.environ)
    env["ROS_DOMAIN_ID"] = str(domain)
    if args.discovery == "localhost":
        env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    env["PYTHONUNBUFFERED"] = "1"
    from formation_ilc.system.lifetime import PARENT_ENV

    env[PARENT_ENV] = str(os.getpid())  # every node ends with this launcher
    from formation_ilc.nodes.common import RUN_ENV

    env[RUN_ENV] = args.run_id  # and takes only this run's configuration
    # Fast DDS files that nodes killed earlier left behind (held by no process)
    stale = clean_leftovers(min_age=2.0)
    if stale:
        print(f"removed {len(stale)} Fast DDS shared-memory files of dead processes")
    shm_before = fastdds_files()
    # our own monitor node joins the same domain: set before rclpy initialises
    os.environ["ROS_DOMAIN_ID"] = env["ROS_DOMAIN_ID"]
    if "ROS_AUTOMATIC_DISCOVERY_RANGE" in env:
        os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = env["ROS_AUTOMATIC_DISCOVERY_RANGE"]
    pb = Problem.from_scenario(sc)

    scen = args.scenario
    if Path(scen).exists():
        scen = str(Path(scen).resolve())
    leader_params: dict[str, Any] = {
        "scenario": scen, "seed": sc.seed, "trials": sc.trials, "law": sc.law.kind,
        "memory": sc.law.memory, "noise": str(not args.no_noise).lower(),
        "delay": str(not args.no_delay).lower(), "mode": args.mode, "monitored": "true",
        "timeout": float(args.timeout), "links": args.links, "state_dir": str(state_dir),
        "run_id": args.run_id}
    # the schedule waits for every node, the launcher's monitor and the recorder included,
    # so that none of them misses a trial
    plants = (["robot_sim"] if args.plant == "sim"
              else [ms.bridge_name(i + 1) for i in range(sc.n)] if pioneer
              else list(args.plant_nodes))
    support = (["link_emulator"] if args.links == "emulated" else [])
    expected = [ms.robot_name(i + 1) for i in range(sc.n)] + plants + support + ["monitor"]
    if args.record is not None:
        expected.append("recorder")
        args.record = args.record.resolve()
    leader_params["nodes_expected"] = "[" + ",".join(expected) + "]"
    layout = (f"container: {args.container} robots/process" if args.container
              else "one process per robot")
    print(f"{sc.name}: {sc.n} robots, {sc.trials} trials of {sc.samples} samples "
          f"(dT {sc.dt} s), {args.mode}, {args.links} links, plant {', '.join(plants)}, "
          f"ROS_DOMAIN_ID={domain}, namespace {namespace}, {layout}", flush=True)

    import rclpy
    from rclpy.experimental import EventsExecutor
    from rclpy.signals import SignalHandlerOptions
    from std_msgs.msg import String

    from formation_ilc.nodes.monitor import MonitorNode

    if done:
        from formation_ilc.core.metrics import read_metrics

        try:
            kept = [r for r in read_metrics(out / "metrics.csv") if int(r[0]) < done]
        except (OSError, ValueError):
            kept = []
        writer = MetricsWriter(out / "metrics.csv")
        for r in kept:
            writer.write(np.asarray(r, dtype=float))
        print(f"resuming {out}: {done} of {sc.trials} trials learned; run {args.run_id}",
              flush=True)
    else:
        writer = MetricsWriter(out / "metrics.csv")
    t_start = time.monotonic()
    trial_wall: list[float] = []
    true_state = args.plant == "sim"

    from formation_ilc.core.metrics import METRIC_COLUMNS, TRUE_COLUMNS

    # without a true state the true_ columns are nan by design
    finite_cols = [i for i, c in enumerate(METRIC_COLUMNS)
                   if i > 0 and (true_state or c not in TRUE_COLUMNS)]

    def on_trial(k: int, row: np.ndarray) -> None:
        writer.write(row)
        now = time.monotonic()
        trial_wall.append(now)
        if not np.isfinite(row[finite_cols]).all():
            raise Diverged(k)
        print(f"trial {k + 1}/{sc.trials}  max position {row[1]:.4g} m  max heading "
              f"{row[2]:.4g} rad  [{now - t_start:.1f} s]", flush=True)

    def on_term(signum: int, frame: Any) -> None:
        raise KeyboardInterrupt

    signal.signal(signal.SIGTERM, on_term)
    if sec is not None:
        sec.enter_launcher()
    rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
    stack = Stack(env, out / "logs", env_for=sec.env if sec is not None else None)
    status = 0
    monitor = None
    try:
        monitor = MonitorNode(cfg, on_trial, true_state=true_state, namespace=namespace,
                              first=done)
        down_pub = monitor.create_publisher(String, ms.READY, ms.LATCHED_QOS)
        ex = EventsExecutor()
        ex.add_node(monitor)
        # discovery runs while the kernels compile; then look for another formation here
        t_node = time.monotonic()
        warm_up(pb)  # compile the kernels once, into the numba cache every node then loads
        others = _foreign(monitor, namespace, max(0.0, 1.5 - (time.monotonic() - t_node)),
                          set(plants) if args.plant == "external" else set())
        if others:
            print(f"error: another formation runs on ROS_DOMAIN_ID={domain} in namespace "
                  f"{namespace} ({', '.join(sorted(others)[:6])}"
                  f"{', ...' if len(others) > 6 else ''}): refusing to start a second one "
                  f"there (it would corrupt both); use --namespace or --domain-id",
                  file=sys.stderr)
            status = 2
            raise _Refused
        if args.record is not None:
            stack.start("recorder", [sys.executable, "-m", "formation_ilc.nodes.recorder",
                                     "--output", str(args.record),
                                     *(["--ros-args", *ros_args(namespace)]
                                       if ros_args(namespace) else [])])
        for name, argv in node_commands(
                leader_params, sc.n, args.container, links=args.links, plant=args.plant,
                namespace=namespace, robot_params=robot_params,
                bridge_params={"driver": args.driver,
                               "return_timeout": float(args.return_timeout)},
                driver_ns=args.driver_ns, fake_drivers=args.fake_drivers,
                cmd_type=args.cmd_type):
            stack.start(name, host_argv(args, name, argv))
        final_deadline: float | None = None
        while True:
            ex.spin_once(timeout_sec=0.05)
            if len(monitor.rows) == sc.trials - done:
                # the last diagnostics come right after the last trajectories
                if final_deadline is None:
                    # bridges drive their robots back after the last trial too
                    final_deadline = time.monotonic() + 3.0 + (
                        args.return_timeout + 2.0 if pioneer else 0.0)
                robots = {ms.robot_name(i + 1) for i in range(sc.n)}
                got = [d.get("trial", -1) for n, d in monitor.diagnostics.items()
                       if n in robots]
                recorded = (args.record is None or monitor.diagnostics.get(
                    "recorder", {}).get("trial", -1) >= sc.trials - 1)
                # the simulator's and link emulator's last reports (timing, missed
                # samples, injected delays) too
                recorded = recorded and all(
                    monitor.diagnostics.get(node, {}).get("trial", -1) >= sc.trials - 1
                    for node in (["robot_sim"] if true_state else []) + support
                    + (plants if pioneer else []))
                # and the leader's "done": it has saved the last trial as learned by all
                done_seen = any(e.get("event") == ms.DONE for e in monitor.events)
                if (len(got) == sc.n and min(got) >= sc.trials - 1 and recorded
                        and done_seen) or time.monotonic() > final_deadline:
                    break
            failed = None
            for name, code in stack.dead():
                n = stack.restarts.get(name, 0)
                if code == NO_RESTART or n >= args.max_restarts:
                    failed = (name, code)
                    break
                if name == "recorder":
                    # tell the leader at once, so that no trial starts without a recorder
                    # (a passive node's death is not seen otherwise until it is back)
                    down_pub.publish(ms.json_to_msg(Ready(
                        name, sc.trials, str(stack.procs[name].pid), passive=True,
                        run=args.run_id, down=True).to_json()))
                note = stack.restart(name)
                what = ("" if name in ("recorder",)
                        else "; the trial it interrupted runs again")
                print(f"{name} exited with {_status(code)}: starting it again "
                      f"({n + 1}/{args.max_restarts}){what}{note}", flush=True)
            if failed is not None:
                name, code = failed
                again = ("" if code == NO_RESTART or not args.max_restarts
                         else f" after {args.max_restarts} restarts")
                print(f"error: node process {name} exited with {_status(code)}{again} "
                      f"(log: {out / 'logs' / (name + '.log')})", file=sys.stderr)
                tail = stack.log_tail(name)
                if tail:
                    print(tail, file=sys.stderr)
                # status 2: the node refused (bad input, or another formation here)
                status = 2 if code == NO_RESTART else 1
                break
    except _Refused:
        pass
    except Diverged as exc:
        print(f"error: trial {exc.trial + 1}: the errors are no longer finite (the learning "
              f"diverged; check the gains with `formation-ilc check`): stopping; the finished "
              f"trials are in metrics.csv", file=sys.stderr)
        status = 1
    except KeyboardInterrupt:
        print("\ninterrupted: stopping every node; finished trials are in metrics.csv",
              file=sys.stderr)
        status = 130
    finally:
        stack.stop()
        writer.close()
        diagnostics = dict(monitor.diagnostics) if monitor is not None else {}
        if monitor is not None:
            monitor.destroy_node()
        rclpy.try_shutdown()
        # the shared-memory files of nodes killed during the run, and older leftovers
        clean_leftovers(fastdds_files() - shm_before)
        clean_leftovers(min_age=2.0)
    elapsed = time.monotonic() - t_start
    rows = ([r for r in kept] if done else []) + (
        [monitor.rows[k] for k in sorted(monitor.rows)] if monitor is not None else [])
    (out / "diagnostics.json").write_text(json.dumps(diagnostics, indent=2) + "\n")
    measured, injected = link_histograms(diagnostics)
    emulated = args.links == "emulated"
    dtab = delay_rows(measured, injected if emulated else None,
                      sc.uncertainty.delay.pmf() if emulated else None)
    write_delays(out / "delays.csv", dtab)
    sim_diag = diagnostics.get("robot_sim", {})
    summary = {"scenario": sc.name, "robots": sc.n, "trials_done": len(rows),
               "trials": sc.trials, "mode": args.mode, "links": args.links,
               "plant": plants, "true_state": true_state, "namespace": namespace,
               "container": args.container, "domain_id": domain, "seconds": elapsed,
               "run_id": args.run_id, "resumed_at": done if args.resume is not None else None,
               "restarts": dict(stack.restarts),
               "timing": sim_diag.get("timing", {}), "missed": sim_diag.get("missed", {}),
               "dropped": {n: d.get("dropped", {}) for n, d in diagnostics.items()}}
    if pioneer:
        summary["bridges"] = {
            b: {key: diagnostics.get(b, {}).get(key) for key in
                ("initial_shifts", "returns", "return_timeouts", "missed", "clipped",
                 "watchdog_zero", "stale_odometry")} for b in plants}
    if args.init_memory is not None:
        summary["init_memory"] = str(args.init_memory)
    (out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    if status:
        return status
    files = ["metrics.csv", "delays.csv", "diagnostics.json", "summary.json"]
    m = np.array(rows)
    if not args.no_plots and len(rows):
        from formation_ilc.recordings.plots import plot_errors

        plot_errors(m[:, 0], m[:, 1], m[:, 2], out / "errors.png",
                    f"{sc.name}: distributed stack, {sc.n} robot nodes, {args.mode}")
        files.append("errors.png")
    _print_report(sc, m, dtab, summary)
    print(f"results in {out}/ ({', '.join(files)}; logs/)")
    if args.record is not None:
        print(f"recording: {args.record} (formation-ilc analyze {args.record})")
    return 0


class _Refused(Exception):
    """The run was refused before any node started (the message is printed)."""


class Diverged(Exception):
    """A trial's errors are not finite."""

    def __init__(self, trial: int):
        super().__init__(trial)
        self.trial = trial


def _status(code: int) -> str:
    if code < 0:
        try:
            return f"signal {signal.Signals(-code).name}"
        except ValueError:
            return f"signal {-code}"
    return f"status {code}"


def _print_report(sc: Any, m: np.ndarray, dtab: list[list[Any]], summary: dict[str, Any]
                  ) -> None:
    k = len(m)
    show = range(k) if k <= 20 else sorted({0, 1, 2, k // 4, k // 2, 3 * k // 4, k - 1})
    print(f"{'trial':>6s} {'max pos [m]':>12s} {'max head [rad]':>15s} {'rms pos [m]':>12s}")
    for i in show:
        print(f"{int(m[i, 0]):6d} {m[i, 1]:12.4g} {m[i, 2]:15.4g} {m[i, 5]:12.4g}")
    tim = summary.get("timing") or {}
    nan = float("nan")
    if tim and summary.get("mode") == "realtime":
        print(f"realtime: {tim.get('missed_total', 0)} missed of "
              f"{tim.get('commands', 0) + tim.get('missed_total', 0)} robot-samples; command "
              f"arrival after the tick p50 {tim.get('p50_ms', nan):.2f} ms, "
              f"p99 {tim.get('p99_ms', nan):.2f} ms (dT {1000 * sc.dt:.0f} ms)")
    elif tim:
        print(f"lockstep: {tim.get('samples_per_s', nan):.0f} samples/s, per-sample "
              f"latency p50 {tim.get('p50_ms', nan):.2f} ms, "
              f"p99 {tim.get('p99_ms', nan):.2f} ms")
    for b, d in (summary.get("bridges") or {}).items():
        shifts = d.get("initial_shifts") or {}
        worst = max((math.hypot(s[0], s[1]) for s in shifts.values()), default=float("nan"))
        print(f"{b}: {len(shifts)} starts, largest initial shift {worst:.3f} m, return "
              f"timeouts {d.get('return_timeouts')}, missed samples {d.get('missed')}, "
              f"clipped commands {d.get('clipped')}")
    if not summary.get("true_state", True):
        print("true state: the plant publishes none; the true_ columns of metrics.csv are nan")
    if dtab:
        direct = summary.get("links") == "direct"
        agg: dict[int, list[float]] = {}
        for _link, tau, meas, inj, _, p in dtab:
            a = agg.setdefault(tau, [0, 0, 0 if direct else p])
            a[0] += meas
            a[1] += 0 if direct else inj
        tot = sum(a[0] for a in agg.values()) or 1
        if direct:
            print("delays measured by the robots (eq. 11, all links): tau  measured")
        else:
            print("delays (all links): tau  measured  injected  model")
        for tau, (meas, inj, p) in sorted(agg.items()):
            rest = "" if direct else f" {inj / tot:9.3f} {p:6.3f}"
            print(f"  {tau:4d} {meas / tot:9.3f}{rest}")
    drops = {n: sum(d.values()) for n, d in summary["dropped"].items() if sum(d.values())}
    if drops:
        print(f"dropped messages: {drops}")


# --------------------------------------------------------------------------- separate hosts
def add_host_arguments(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("robots on separate hosts, one machine (root; "
                             "docs/lossy-links.md)")
    g.add_argument("--hosts", choices=("local", "netns"), default="local",
                   help="local (default): every process on this machine's network; netns: "
                        "each robot process in a network namespace of its own, joined by "
                        "veth links to a hub namespace (leader, simulator, this launcher), "
                        "DDS over UDP, unicast discovery; direct links. Needs root, iproute2 "
                        "and iptables with NFQUEUE")
    g.add_argument("--net-delay-ms", type=float, default=0.0, metavar="MS",
                   help="with --hosts netns: mean delay of every link between robots, per "
                        "direction (default 0)")
    g.add_argument("--net-jitter-ms", type=float, default=0.0, metavar="MS",
                   help="with --hosts netns: delays uniform in delay +- jitter (default 0)")
    g.add_argument("--net-loss", type=float, default=0.0, metavar="P",
                   help="with --hosts netns: fraction of the packets between robots "
                        "dropped, per direction (default 0)")
    g.add_argument("--dds-profile", choices=("lossy", "none"), default=None,
                   help="with --hosts netns: lossy (default): the package's Fast DDS profile "
                        "for lossy links (50 ms writer heartbeat: a lost sample is repaired "
                        "within about a round trip); none: Fast DDS defaults (3 s)")


def host_argv(args: argparse.Namespace, name: str, argv: list[str]) -> list[str]:
    """``argv`` of process ``name``, inside its robot's namespace with --hosts netns."""
    import re

    hosts = getattr(args, "hosts_", None)
    m = re.fullmatch(r"robot_(\d+)", name)
    if hosts is None or m is None:
        return argv
    return hosts.exec_argv(hosts.robot_ns(int(m.group(1))), argv)


def _net_options(args: argparse.Namespace) -> bool:
    return bool(args.net_delay_ms or args.net_jitter_ms or args.net_loss
                or args.dds_profile is not None)


def run_on_hosts(args: argparse.Namespace) -> int:
    """``run`` with each robot process in a network namespace of its own (--hosts netns);
    the namespaces, rules and delayers are removed whatever happens."""
    from formation_ilc.config.scenario import load_scenario
    from formation_ilc.core.links import robot_name
    from formation_ilc.system import netns

    def usage(msg: str) -> int:
        print(f"error: {msg}", file=sys.stderr)
        return 2

    if args.hosts != "netns":
        return usage("--net-delay-ms, --net-jitter-ms, --net-loss and --dds-profile go with "
                     "--hosts netns")
    try:
        faults = netns.LinkFaults(args.net_delay_ms, args.net_jitter_ms, args.net_loss)
    except netns.NetnsError as exc:
        return usage(str(exc))
    if args.container or args.plant != "sim" or args.links == "emulated":
        return usage("--hosts netns runs one process per robot (no --container), the "
                     "simulator as plant (--plant sim) and direct links (the links between "
                     "robots are the network's; no --links emulated)")
    problem = netns.support_problem()
    if problem:
        return usage(f"--hosts netns: {problem}")
    orphans = netns.remove_orphans()
    if orphans:
        print(f"removed {len(orphans)} network namespaces of dead launchers", flush=True)
    args.links = "direct"
    sc = load_scenario(args.scenario)
    args.out = args.out or Path("runs") / f"{sc.name}-launch-{datetime.now():%Y%m%d-%H%M%S}"
    profile = args.dds_profile or "lossy"
    hosts = netns.Hosts(sc.n, faults, seed=sc.seed if args.seed is None else args.seed,
                        log_dir=args.out / "hosts")
    saved = dict(os.environ)
    status = 1
    try:
        with hosts:
            os.environ.update(hosts.ros_env())
            os.environ.pop("FASTRTPS_DEFAULT_PROFILES_FILE", None)
            if profile == "lossy":
                os.environ["FASTRTPS_DEFAULT_PROFILES_FILE"] = str(netns.lossy_profile())
            print(f"hosts: robot i in network namespace {hosts.robot_ns(1)[:-1]}i "
                  f"({netns.SUBNET}.{netns.ROBOT_HOST0}+i), the rest in {hosts.hub} "
                  f"({hosts.hub_address}); links between robots: {faults.describe()}; "
                  f"Fast DDS profile {profile}", flush=True)
            args.hosts_ = hosts
            with hosts.entered_hub():
                status = run(args)
            stats = hosts.stop_delayers()
    except netns.NetnsError as exc:
        print(f"error: --hosts netns: {exc}", file=sys.stderr)
        return 1
    finally:
        args.hosts_ = None
        os.environ.clear()
        os.environ.update(saved)
    report: dict[str, Any] = {"namespaces": hosts.namespaces(), "hub": hosts.hub_address,
                              "faults": vars(faults), "dds_profile": profile,
                              "delayers": {robot_name(i): s for i, s in stats.items()}}
    for robot, s in report["delayers"].items():
        lo, p50, p99, hi = netns.hold_quantiles(s.get("hold_ms", {}))
        n = s.get("packets", 0)
        print(f"{robot} -> other robots: {n} packets, {s.get('dropped', 0)} dropped "
              f"({100 * s.get('dropped', 0) / max(n, 1):.1f} %), held {lo:.0f} / {p50:.0f} / "
              f"{p99:.0f} / {hi:.0f} ms (min / p50 / p99 / max)")
    path = args.out / "summary.json"
    if path.exists():
        summary = json.loads(path.read_text())
        summary["hosts"] = report
        path.write_text(json.dumps(summary, indent=2) + "\n")
    return status
