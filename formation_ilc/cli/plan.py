"""The plan of a ``formation-ilc launch``: everything decided from the options before any
process starts, built once and frozen.

``build_plan`` reads the options (and, with ``--resume DIR``, the run's own ``run.json``),
refuses what cannot run (``NoRun``: one line and the exit status, before anything starts)
and returns a ``RunPlan``: the validated run configuration, the team the leader waits for,
and one ``NodeSpec`` per process (name, command, parameters, restart policy, host). The
supervisor (``formation_ilc.cli.supervisor``) runs the plan, the report writer
(``formation_ilc.cli.report``) writes its outputs, and ``--hosts netns`` wraps its
execution (``formation_ilc.cli.hosts``). Nothing here needs ROS.
"""

from __future__ import annotations

import argparse
import os
import sys
import uuid
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from datetime import datetime
from pathlib import Path
from typing import Any

from formation_ilc.cli.options import OptionError
from formation_ilc.cli.secure import SecureRun
from formation_ilc.config.runconfig import RunConfig, make_config, param_text, scenario_reference
from formation_ilc.config.scenario import Scenario, ScenarioError
from formation_ilc.config.team import BRIDGED, Team
from formation_ilc.core.names import (
    BASES_NODE,
    LEADER_NODE,
    LINKS_NODE,
    LIVEVIEW_NODE,
    NAMESPACE,
    PHYSICS_NODE,
    RECORDER_NODE,
    SIM_NODE,
    bridge_name,
    fake_driver_name,
    namespace_remaps,
    robot_name,
    robots_process_name,
)
from formation_ilc.protocol.schedule import DONE
from formation_ilc.system.exits import NO_RESTART as EXIT_NO_RESTART
from formation_ilc.system.netns import LinkFaults

__all__ = ["RUN_FILE", "NO_RESTART", "NoRun", "BridgeOptions", "PhysicsOptions",
           "RestartPolicy", "NodeSpec",
           "HostsPlan", "RunPlan", "build_plan", "effective_options", "node_specs",
           "finished", "pick_domain", "resumed_part"]

#: the launch options a run is resumed with (DIR/run.json)
RUN_FILE = "run.json"
#: exit status of a node that refuses its configuration: restarting it cannot help
NO_RESTART = 2


class NoRun(Exception):
    """The options give no run: ``message`` (one line) and the launcher's exit status
    (2: refused, before anything started; 0: nothing left to do)."""

    def __init__(self, message: str, status: int = 2):
        super().__init__(message)
        self.message = message
        self.status = status

    def report(self) -> int:
        """Print the message (an error on stderr, else on stdout); the exit status."""
        if self.status:
            print(f"error: {self.message}", file=sys.stderr)
        else:
            print(self.message)
        return self.status


#: a Pioneer driver's usual namespace pattern; a base's (``--plant base``) is /base_{i}
PIONEER_NS = "/pioneer_{i}"
BASE_NS = "/base_{i}"


@dataclass(frozen=True)
class BridgeOptions:
    """How the bridges reach their drivers (``--plant pioneer`` or ``base``; the
    ``formation-ilc-bridge`` parameters of the same names).

    driver : 'rosaria', 'p2os2' or 'ros2aria' (a Pioneer's).
    driver_ns : robot i's driver namespace, ``{i}`` replaced by the robot number.
    cmd_type : 'twist' or 'twist_stamped' on the driver's cmd_vel (a Pioneer's; a base
        preset names its own).
    return_timeout : [s] how long a bridge drives its robot back between trials.
    fake_drivers : also start one fake driver per robot (``robot_sim.fake_pioneer``).
    base : the base preset (``--plant base``: ``formation_ilc.config.bases``), else None.
    limits : the limits given on the command line (``config.bases.LIMIT_KEYS``, in the
        bridge's units), only those given (not 0).
    params_file : a ROS 2 parameters file every bridge reads (``--params-file``).
    physics_bases : also start physics robots behind the bases' interface.
    """

    driver: str = "rosaria"
    driver_ns: str = PIONEER_NS
    cmd_type: str = "twist"
    return_timeout: float = 60.0
    fake_drivers: bool = False
    base: str | None = None
    limits: tuple[tuple[str, float], ...] = ()
    params_file: Path | None = None
    physics_bases: bool = False

    @classmethod
    def of(cls, opts: argparse.Namespace) -> BridgeOptions:
        from formation_ilc.config.bases import LIMIT_KEYS

        base = getattr(opts, "base", None) if opts.plant == "base" else None
        ns = opts.driver_ns
        if base is not None and ns == PIONEER_NS:
            ns = BASE_NS
        given = tuple((k, float(getattr(opts, k, 0.0) or 0.0)) for k in LIMIT_KEYS)
        pf = getattr(opts, "params_file", None)
        return cls(opts.driver, ns, opts.cmd_type, float(opts.return_timeout),
                   bool(opts.fake_drivers), base, tuple((k, v) for k, v in given if v != 0),
                   None if pf is None else Path(pf).resolve(),
                   bool(getattr(opts, "physics_bases", False)))

    def namespace(self, i: int) -> str:
        return self.driver_ns.replace("{i}", str(i))

    def params(self, i: int) -> tuple[tuple[str, Any], ...]:
        """Robot ``i``'s bridge parameters."""
        kind: tuple[tuple[str, Any], ...] = (
            (("base", self.base),) if self.base is not None
            else (("cmd_type", self.cmd_type), ("driver", self.driver)))
        return ((("robot_id", i), ("driver_ns", self.namespace(i))) + kind
                + (("return_timeout", self.return_timeout),) + self.limits)


@dataclass(frozen=True)
class PhysicsOptions:
    """The physics plant (``--plant physics``, and the bodies of ``--physics-bases``): the
    robot model ('p3dx', 'husky'), the measured pose's source ('truth', 'odometry'),
    whether robots collide, engine steps per second."""

    model: str = "p3dx"
    pose: str = "truth"
    collide: bool = True
    rate: float = 240.0

    @classmethod
    def of(cls, opts: argparse.Namespace) -> PhysicsOptions:
        return cls(getattr(opts, "robot_model", "p3dx"), getattr(opts, "pose", "truth"),
                   not getattr(opts, "pass_through", False),
                   float(getattr(opts, "physics_rate", 240.0)))


@dataclass(frozen=True)
class RestartPolicy:
    """A node process that dies is started again at most ``max_restarts`` times, unless it
    exited with ``refused`` (it refused its input) or another status a restart cannot help
    (``formation_ilc.system.exits.NO_RESTART``: the run is stuck, the disk is full)."""

    max_restarts: int = 3
    refused: int = NO_RESTART

    def allows(self, code: int, restarts: int) -> bool:
        """Whether a process that exited with ``code`` after ``restarts`` restarts is
        started again."""
        return (code != self.refused and code not in EXIT_NO_RESTART
                and restarts < self.max_restarts)


@dataclass(frozen=True)
class NodeSpec:
    """One process of the stack: ``python -m module args --ros-args remaps -p k:=v ...``.

    name : process name (its log is ``logs/NAME.log``; a single node's own name).
    params : ROS parameters, in order (written by ``param_text``).
    host : robot number whose network namespace the process runs in (``--hosts netns``);
        None: this machine's (the hub's).
    passive : a reader that says ready once for the run (the recorder): the leader is told
        at once when it dies, and its restart interrupts no trial.
    optional : no part of the run (the live view): the run never waits for it, its restart
        interrupts no trial, and once its restarts are used up the run goes on without it.
    env : environment variables of this process on top of the run's (``--secure``: its
        enclave).
    """

    name: str
    module: str
    args: tuple[str, ...] = ()
    remaps: tuple[str, ...] = ()
    params: tuple[tuple[str, Any], ...] = ()
    restart: RestartPolicy = field(default_factory=RestartPolicy)
    host: int | None = None
    passive: bool = False
    optional: bool = False
    python: str = sys.executable
    env: tuple[tuple[str, str], ...] = ()

    @property
    def command(self) -> list[str]:
        ros = [*self.remaps, *(a for k, v in self.params for a in ("-p", f"{k}:={param_text(v)}"))]
        return [self.python, "-m", self.module, *self.args, *(["--ros-args", *ros] if ros else [])]


@dataclass(frozen=True)
class HostsPlan:
    """``--hosts netns``: each robot process in a network namespace of its own, ``faults``
    on the links between robots, Fast DDS ``profile`` ('lossy' or 'none'); ``seed`` seeds
    the delayers."""

    faults: LinkFaults
    profile: str
    seed: int

    @property
    def profile_file(self) -> Path | None:
        """The Fast DDS profiles file every process of the run loads (None: Fast DDS's
        defaults, also when this machine's environment names one)."""
        from formation_ilc.system.netns import lossy_profile

        return lossy_profile() if self.profile == "lossy" else None


@dataclass(frozen=True)
class RunPlan:
    """A launch, decided: what runs, where, and what it writes.

    config : the run configuration every node shares (monitored, with this run's id).
    team : the nodes the leader waits for (``nodes_expected``).
    nodes : the processes, in start order.
    out : the output folder (absolute; it exists).
    resumed_at : iterations already learned (``--resume``); None for a new run.
    run_json : the options to write to ``out/run.json`` (None when resuming).
    final_wait : [s] after the last trial, the longest wait for the last reports.
    init_memory : ``--init-memory`` as given (the robots get its absolute path).
    record : the recording this launch writes (absolute), or None; ``record_root``: the
        run's first file (``analyze`` reads every part from it).
    bridge : how the bridges reach their drivers (``--plant pioneer`` or ``base``), or
        None.
    physics : the physics plant's options (``--plant physics``, ``--physics-bases``), or
        None.
    notes : lines to print before the run starts (a contact run allowed anyway).
    """

    config: RunConfig
    team: Team
    nodes: tuple[NodeSpec, ...]
    out: Path
    namespace: str
    domain: int
    discovery: str
    plant: str
    container: int
    max_restarts: int
    final_wait: float
    plots: bool
    resumed_at: int | None = None
    run_json: Mapping[str, Any] | None = None
    init_memory: Path | None = None
    record: Path | None = None
    bridge: BridgeOptions | None = None
    hosts: HostsPlan | None = None
    #: the run's first recording file (``record`` is the part this launch writes)
    record_root: Path | None = None
    #: every bound of the leader's liveness watchdog times this (``--watchdog-scale``)
    watchdog_scale: float = 1.0
    physics: PhysicsOptions | None = None
    notes: tuple[str, ...] = ()
    #: ``--secure``: the checked keystore every node runs in (its enclave is in its spec)
    secure: SecureRun | None = None
    #: ``--live``: the live view's (host, port), or None
    live: tuple[str, int] | None = None
    #: ``--live-rate``: messages a second per per-sample channel (None: the view's default)
    live_rate: float | None = None
    #: a team of more processes than localhost discovery reaches: the Fast DDS profiles
    #: file with every participant's discovery port (``system.discovery``), written by the
    #: launcher before anything starts and loaded by every process; None: the caller's
    peers_profile: Path | None = None
    #: the profiles file it builds on (the caller's FASTRTPS_DEFAULT_PROFILES_FILE), or None
    peers_base: Path | None = None

    @property
    def participants(self) -> int:
        """DDS participants of the run on this machine: its processes and the launcher's
        monitor (one per process; ``--hosts netns`` robots are on hosts of their own)."""
        return len(self.nodes) + 1

    def write_peers_profile(self) -> None:
        """Write ``peers_profile`` (when the plan has one)."""
        from formation_ilc.system.discovery import peers_profile

        if self.peers_profile is not None:
            self.peers_profile.write_text(peers_profile(self.peers_base, self.domain,
                                                        self.participants))

    @property
    def scenario(self) -> Scenario:
        return self.config.scenario

    @property
    def true_state(self) -> bool:
        """The plant publishes the robots' true state (the simulator, the physics plant)."""
        return self.plant in ("sim", "physics")

    @property
    def bridged(self) -> bool:
        """The plant is one bridge per robot (a Pioneer driver or a base behind each)."""
        return self.plant in BRIDGED

    @property
    def reporters(self) -> tuple[str, ...]:
        """Nodes besides the robots whose last trial's diagnostics the launcher waits for
        (timing, missed samples, injected delays, the bridges' returns, the recording)."""
        return ((self.team.plants if self.true_state or self.bridged else ())
                + self.team.support
                + ((RECORDER_NODE,) if self.record is not None else ()))

    def banner(self) -> str:
        sc = self.scenario
        layout = (f"container: {self.container} robots/process" if self.container
                  else "one process per robot")
        return (f"{sc.name}: {sc.n} robots, {sc.trials} trials of {sc.samples} samples "
                f"(dT {sc.dt} s), {self.config.mode}, {self.config.links} links, plant "
                f"{', '.join(self.team.plants)}, ROS_DOMAIN_ID={self.domain}, namespace "
                f"{self.namespace}, {layout}")


def finished(plan: RunPlan, diagnostics: Mapping[str, Mapping[str, Any]],
             events: Sequence[Mapping[str, Any]]) -> bool:
    """Whether a run whose trials are all in has nothing more to report: every robot's and
    reporter's diagnostics of the last trial, and the leader's ``done`` (it has saved the
    last trial as learned by all)."""
    last = plan.scenario.trials - 1
    nodes = plan.team.robots + plan.reporters
    return (all(diagnostics.get(n, {}).get("trial", -1) >= last for n in nodes)
            and any(e.get("event") == DONE for e in events))


# --------------------------------------------------------------------------- building

def build_plan(args: argparse.Namespace) -> RunPlan:
    """The plan of ``formation-ilc launch`` options (``args`` is not changed); NoRun with
    the refusal's one line and exit status; ScenarioError for a bad scenario."""
    opts = effective_options(args)
    faults = _hosts_faults(opts)
    mode, links = _mode_and_links(opts, hosts=faults is not None)
    try:
        cfg = make_config(opts.scenario, seed=opts.seed, noise=not opts.no_noise,
                          delay=not opts.no_delay, trials=opts.trials, law=opts.law,
                          memory=opts.memory, mode=mode, monitored=True,
                          timeout=opts.timeout, recorded=opts.record is not None,
                          links=links, run_id=opts.run_id,
                          headings=getattr(opts, "headings", None),
                          time_scale=getattr(opts, "time_scale", None))
    except ScenarioError:
        raise
    except ValueError as exc:
        # RunConfig owns its rules (e.g. wall-clock trials need direct links): a refusal
        # in one line, not a traceback
        raise NoRun(f"launch: {exc}") from None
    # 'auto' headings: arc on the plants that drive arcs and came with the option (physics,
    # base); chord for the kinematic simulator, and for the Pioneer bridges and external
    # plants as before them (their runs and learned memories keep their numbers)
    cfg = replace(cfg, scenario=cfg.scenario.for_plant(
        "arc" if opts.plant in ("physics", "base") else "euler"))
    namespace = opts.namespace or NAMESPACE
    if not namespace.startswith("/") or "//" in namespace:
        raise NoRun(f"--namespace {namespace!r}: an absolute ROS namespace like /team2 is "
                    f"required")
    sc = cfg.scenario
    if opts.init_memory is not None:
        _check_memory(opts.init_memory, sc)
    if sc.trials < 1:
        raise NoRun("--trials must be at least 1")
    # a formation too extreme for float64 is refused (ScenarioError) before anything is made
    _ = sc.desired
    out = _out_folder(opts.out, sc)
    resumed_at = _resumed_at(out, sc) if opts.resume is not None else None
    team = Team.of(sc.n, plant=opts.plant, links=links, external=opts.plant_nodes,
                   monitor=True, recorder=opts.record is not None)
    record = opts.record.resolve() if opts.record is not None else None
    root = getattr(opts, "record_root_", None) or record
    domain = opts.domain_id if opts.domain_id is not None else caller_domain()
    if domain is None:
        domain = pick_domain()
    bridge = BridgeOptions.of(opts) if opts.plant in BRIDGED else None
    physics = (PhysicsOptions.of(opts) if opts.plant == "physics"
               or (bridge is not None and bridge.physics_bases) else None)
    notes = _check_plant(opts, sc, namespace, bridge, physics)
    plan = RunPlan(
        config=cfg, team=team, nodes=(), out=out, namespace=namespace, domain=domain,
        discovery=opts.discovery, plant=opts.plant, container=opts.container,
        max_restarts=opts.max_restarts,
        # bridges drive their robots back after the last trial too
        final_wait=3.0 + (bridge.return_timeout + 2.0 if bridge is not None else 0.0),
        plots=not opts.no_plots, resumed_at=resumed_at,
        run_json=None if resumed_at is not None else _run_json(opts, mode, links, out),
        init_memory=opts.init_memory, record=record, bridge=bridge,
        record_root=root.resolve() if root is not None else None,
        watchdog_scale=float(getattr(opts, "watchdog_scale", 1.0)),
        physics=physics, notes=notes,
        live=_live(opts), live_rate=_live_rate(opts),
        hosts=None if faults is None else HostsPlan(faults, opts.dds_profile or "lossy",
                                                    sc.seed))
    # the processes follow from the rest of the plan
    plan = _with_peers(replace(plan, nodes=node_specs(plan, scenario_reference(opts.scenario))))
    return _secured(plan, getattr(opts, "secure", None))


def _user_profile() -> Path | None:
    """The caller's FASTRTPS_DEFAULT_PROFILES_FILE, or None."""
    value = os.environ.get("FASTRTPS_DEFAULT_PROFILES_FILE")
    return Path(value) if value else None


def _with_peers(plan: RunPlan) -> RunPlan:
    """``plan`` with a discovery profile when its processes are more than localhost
    discovery reaches on its own (``system.discovery``); NoRun when the caller's
    FASTRTPS_DEFAULT_PROFILES_FILE cannot be built on."""
    from formation_ilc.system.discovery import needs_peers, peers_profile

    if (plan.discovery != "localhost" or plan.hosts is not None
            or not needs_peers(plan.participants)):
        return plan
    base = _user_profile()
    try:
        peers_profile(base, plan.domain, plan.participants)
    except ValueError as exc:
        raise NoRun(f"FASTRTPS_DEFAULT_PROFILES_FILE {exc}") from None
    return replace(plan, peers_profile=plan.out / "fastdds-discovery.xml", peers_base=base)


def _secured(plan: RunPlan, keystore: Path | str | None) -> RunPlan:
    """``plan`` with every process in its enclave of ``keystore`` (``--secure``), checked
    before anything starts: NoRun if the keystore or the loaded Fast DDS cannot run it."""
    from formation_ilc.cli.secure import SECURE_PLANTS, prepare

    if keystore is not None and plan.plant not in SECURE_PLANTS:
        raise NoRun(f"--secure: the keystore's permissions cover the plants "
                    f"{', '.join(SECURE_PLANTS)}, not --plant {plan.plant} (run it without "
                    f"--secure, on a network you trust)")
    # the handshake retries go into the profile the processes would load anyway: the
    # lossy-links one on netns hosts, else the user's own (with the discovery peers of a
    # large team, which are written next to it: checked here on the user's own)
    base = plan.hosts.profile_file if plan.hosts is not None else _user_profile()
    try:
        sec = prepare(keystore, [s.name for s in plan.nodes], plan.namespace,
                      container=plan.container, profile=plan.out / "fastdds-secure.xml",
                      base_profile=base)
    except OptionError as exc:
        raise NoRun(str(exc)) from None
    if sec is None:
        return plan
    if plan.peers_profile is not None:
        sec = replace(sec, base_profile=plan.peers_profile)
    if not sec.handshake_applies:
        from formation_ilc.system.securedds import BUILD_COMMAND

        plan = replace(plan, notes=(*plan.notes, (
            "note: this venv's rmw_fastrtps drops the authentication handshake's retry "
            "settings (built before they were kept): a large secure team may not start; "
            f"rebuild it: {BUILD_COMMAND}")))
    return replace(plan, secure=sec, nodes=tuple(
        replace(s, env=tuple(sec.variables(s.name).items())) for s in plan.nodes))


def effective_options(args: argparse.Namespace) -> argparse.Namespace:
    """The options a run goes with, as a copy: with ``--resume DIR`` the run's own (its
    run.json), and a new run id when there is none; NoRun for what no run can have."""
    if args.resume is not None:
        opts = _resume_options(args)
    elif args.scenario is None:
        raise NoRun("a SCENARIO is required (or --resume DIR)")
    else:
        opts = argparse.Namespace(**vars(args))
    if opts.max_restarts < 0:
        raise NoRun("--max-restarts must be >= 0")
    if getattr(opts, "run_id", None) is None:
        # a letter first: an all-digit id would reach the leader as an integer parameter
        opts.run_id = "r" + uuid.uuid4().hex[:12]
    return opts


def _resume_options(args: argparse.Namespace) -> argparse.Namespace:
    """The options of the run in ``args.resume``: its run.json (read bounded and checked;
    every path that pointed into the run's folder re-rooted in the folder being resumed,
    so a copied folder resumes into itself: ``formation_ilc.store.runfile``), with this
    call's output folder and --max-restarts, and where the resumed launch records."""
    from formation_ilc.store.runfile import RunFileError, load_run, require

    out = args.resume
    try:
        d = load_run(out)
    except RunFileError as exc:
        raise NoRun(f"--resume {exc}") from None
    if d is None:
        raise NoRun(f"--resume {out}: no {RUN_FILE} there (not the output folder of a "
                    f"`formation-ilc launch` run)")
    if args.scenario is not None:
        raise NoRun("--resume takes the run's own scenario and options: give no SCENARIO")
    try:
        require(d, out)
    except RunFileError as exc:
        raise NoRun(f"--resume {exc}") from None
    ns = argparse.Namespace(**vars(args))
    for k, v in d.items():
        setattr(ns, k, v)
    for k in ("out", "init_memory", "record", "params_file"):
        if getattr(ns, k, None) is not None:
            setattr(ns, k, Path(getattr(ns, k)))
    ns.out = out
    ns.resume = out
    ns.max_restarts = args.max_restarts
    ns.watchdog_scale = getattr(args, "watchdog_scale", 1.0)
    if ns.record is not None:
        ns.record_root_ = ns.record
        ns.record = resumed_part(ns.record)
    return ns


def resumed_part(root: Path) -> Path:
    """Where a resumed launch records: the run's first file when no part of its recording
    exists yet (a launch killed before its recorder wrote it), else the next free
    ``RUN.resumedN.mcap`` (every part stays as it was written)."""
    from formation_ilc.recordings.recording import recording_parts

    if not any(p.exists() for p in recording_parts(root)):
        return root
    stem = root.with_suffix("")
    n = 1
    while Path(f"{stem}.resumed{n}.mcap").exists() or any(
            stem.parent.glob(f"{stem.name}.resumed{n}.part*.mcap")):
        n += 1
    return Path(f"{stem}.resumed{n}.mcap")


def _hosts_faults(opts: argparse.Namespace) -> LinkFaults | None:
    """``--hosts netns``: the faults on the links between robots, once the options and this
    machine allow it (None: every process on this machine's network)."""
    from formation_ilc.system import netns

    net = bool(opts.net_delay_ms or opts.net_jitter_ms or opts.net_loss
               or opts.dds_profile is not None)
    if opts.hosts != "netns" and not net:
        return None
    if opts.hosts != "netns":
        raise NoRun("--net-delay-ms, --net-jitter-ms, --net-loss and --dds-profile go with "
                    "--hosts netns")
    try:
        faults = netns.LinkFaults(opts.net_delay_ms, opts.net_jitter_ms, opts.net_loss)
    except netns.NetnsError as exc:
        raise NoRun(str(exc)) from None
    if opts.container or opts.plant != "sim" or opts.links == "emulated":
        raise NoRun("--hosts netns runs one process per robot (no --container), the "
                    "simulator as plant (--plant sim) and direct links (the links between "
                    "robots are the network's; no --links emulated)")
    problem = netns.support_problem()
    if problem:
        raise NoRun(f"--hosts netns: {problem}")
    return faults


def _mode_and_links(opts: argparse.Namespace, hosts: bool) -> tuple[str, str]:
    """The run's mode and links: refuses what a plant cannot do, fills in the defaults."""
    pioneer = opts.plant in BRIDGED
    links = "direct" if hosts else opts.links
    if pioneer and (opts.mode not in (None, "wallclock") or links not in (None, "direct")):
        raise NoRun(f"--plant {opts.plant} runs --mode wallclock with --links direct (real "
                    f"robots have no simulated clock and no link emulator), got --mode "
                    f"{opts.mode} --links {links}")
    if opts.mode == "wallclock" and not pioneer and opts.plant != "external":
        raise NoRun("--mode wallclock is for real robots: use it with --plant pioneer (or an "
                    "external plant that samples on the wall clock); the simulator runs "
                    "lockstep or realtime")
    if opts.fake_drivers and opts.plant != "pioneer":
        raise NoRun("--fake-drivers goes with --plant pioneer")
    if getattr(opts, "physics_bases", False) and opts.plant != "base":
        raise NoRun("--physics-bases goes with --plant base")
    if opts.fake_drivers and opts.driver == "p2os2":
        raise NoRun("--fake-drivers speak rosaria or ros2aria, not p2os2 (its p2os_msgs are "
                    "not on PyPI)")
    mode = opts.mode or ("wallclock" if pioneer else "lockstep")
    return mode, links or ("direct" if pioneer or mode == "wallclock" else "emulated")


def _check_plant(opts: argparse.Namespace, sc: Scenario, namespace: str,
                 bridge: BridgeOptions | None, physics: PhysicsOptions | None
                 ) -> tuple[str, ...]:
    """Refuse a run the plant cannot do, before anything starts: no PyBullet for a physics
    plant; desired speeds or accelerations beyond the bridges' limits (with the
    ``--time-scale`` that fits); robots with bodies whose footprints the batch simulator
    predicts to overlap (unless ``--allow-contact``: then the warning is the plan's note)."""
    if physics is not None:
        from formation_ilc.protocol.physics_plant import physics_available

        missing = physics_available()
        if missing is not None:
            raise NoRun(missing)
    if bridge is not None:
        line = _limits_line(bridge, sc, namespace)
        if line is not None:
            raise NoRun(line)
    # fake drivers are unicycles without bodies: nothing to crash in a rehearsal
    if physics is None and (bridge is None or bridge.fake_drivers):
        return ()
    line = _contact_line(opts, sc, bridge, physics)
    if line is None:
        return ()
    if getattr(opts, "allow_contact", False):
        return (f"warning: {line}; running anyway (--allow-contact)",)
    raise NoRun(f"{line}; start from a learned memory (--init-memory, see docs/physics.md), "
                f"widen the formation's offsets, or --allow-contact")


def _limits_line(bridge: BridgeOptions, sc: Scenario, namespace: str) -> str | None:
    """None if the scenario's desired speeds and accelerations fit every bridge's limits
    (as the bridges will read them: ``protocol.bridge.bridge_limits``, the params file,
    the command line); else the one line that says where they do not, and the time scale
    that fits."""
    import yaml

    from formation_ilc.config.bases import fit_limits, limits_from_params
    from formation_ilc.protocol.bridge import bridge_limits

    params = None
    if bridge.params_file is not None:
        try:
            params = yaml.safe_load(bridge.params_file.read_text())
        except (OSError, yaml.YAMLError) as exc:
            return f"--params-file {bridge.params_file}: cannot read: {exc}"
        if not isinstance(params, dict):
            return f"--params-file {bridge.params_file}: expected a mapping of node names"
    try:
        limits = limits_from_params(bridge_limits(bridge.base), sc.n, params,
                                    dict(bridge.limits), namespace)
    except ValueError as exc:
        return str(exc)
    return fit_limits(sc, limits)


def _contact_line(opts: argparse.Namespace, sc: Scenario, bridge: BridgeOptions | None,
                  physics: PhysicsOptions | None) -> str | None:
    """The batch simulator's prediction of a run on robots with bodies (noise-free, the arc
    plant, from the initial memory): None, or the line saying where two footprints first
    overlap."""
    from formation_ilc.model.footprint import first_overlap, footprint_of, predict_clearance
    from formation_ilc.store.memoryfile import load_memory

    body = (physics.model if physics is not None
            else bridge.base if bridge is not None and bridge.base is not None else "p3dx")
    fp = footprint_of(body)
    memory = None if opts.init_memory is None else load_memory(opts.init_memory, sc)
    hit = first_overlap(predict_clearance(sc, fp, sc.trials, memory=memory))
    if hit is None:
        return None
    start = "warm start" if memory is not None else "cold start (u_0 = 0)"
    return (f"the batch simulator predicts contact from this {start}: {hit.line(sc.dt)} "
            f"(footprint {fp.length} x {fp.width} m)")


def _check_memory(path: Path, sc: Scenario) -> None:
    """Refuse an --init-memory file that is not a memory for this run."""
    from formation_ilc.store.memoryfile import MemoryFileError, load_memory

    try:
        load_memory(path, sc)
    except MemoryFileError as exc:
        raise NoRun(f"--init-memory {exc}") from None


def _out_folder(out: Path | None, sc: Scenario) -> Path:
    """The output folder (made; absolute): ``out`` or runs/SCENARIO-launch-TIME."""
    out = out or Path("runs") / f"{sc.name}-launch-{datetime.now():%Y%m%d-%H%M%S}"
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise NoRun(f"--out {out}: cannot create the folder: {exc.strerror}") from None
    return out.resolve()


def _resumed_at(out: Path, sc: Scenario) -> int:
    """Iterations every robot has learned in the run in ``out``, decided before anything
    of it changes: the leader's state and every robot's, read bounded, validated and
    cross-checked (``formation_ilc.protocol.resume``), and its metrics.csv readable. NoRun
    naming the file when they are damaged or disagree; with status 0 when every trial is
    done."""
    from formation_ilc.core.metrics import read_metrics
    from formation_ilc.protocol.resume import ResumeError, resume_point
    from formation_ilc.store.bounded import StateFileError, open_regular

    try:
        done = resume_point(out / "state", sc).committed
    except ResumeError as exc:
        raise NoRun(f"--resume: {exc}") from None
    if done >= sc.trials:
        raise NoRun(f"{out}: all {sc.trials} trials are done; nothing to resume", status=0)
    path = out / "metrics.csv"
    try:
        # a few hundred bytes a row; a FIFO or a device is refused unread
        with open_regular(path, 1024 * sc.trials + (1 << 20), "a metrics.csv") as fh:
            present = fh is not None
        if present:
            read_metrics(path)
    except (StateFileError, OSError, ValueError) as exc:
        raise NoRun(f"--resume: {exc} (the run's metrics rows: restore the file, or move it "
                    f"away to resume without them)") from None
    return done


def _run_json(opts: argparse.Namespace, mode: str, links: str, out: Path) -> dict[str, Any]:
    """The options ``--resume`` takes the run back with (paths as strings)."""
    d = {k: (str(v) if isinstance(v, Path) else v) for k, v in vars(opts).items()
         if k not in ("func", "command", "resume") and not k.endswith("_")}
    d.update(mode=mode, links=links, out=str(out))
    return d


def _live(opts: argparse.Namespace) -> tuple[str, int] | None:
    """``--live [PORT]`` on ``--live-host``: refused (NoRun) when the port is taken."""
    import socket

    port = getattr(opts, "live", None)
    if port is None:
        return None
    host = getattr(opts, "live_host", None) or "127.0.0.1"
    try:
        with socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET) as s:
            s.bind((host, int(port)))
    except OSError as exc:
        raise NoRun(f"--live {port}: cannot serve on {host}:{port}: {exc.strerror}") from None
    return host, int(port)


def _live_rate(opts: argparse.Namespace) -> float | None:
    """``--live-rate HZ``: a rate >= 0 (NoRun otherwise, or without ``--live``)."""
    rate = getattr(opts, "live_rate", None)
    if rate is None:
        return None
    if getattr(opts, "live", None) is None:
        raise NoRun("--live-rate: only with --live")
    if not rate >= 0:
        raise NoRun(f"--live-rate {rate}: a rate >= 0 messages a second is required")
    return float(rate)


def caller_domain() -> int | None:
    """The caller's ``ROS_DOMAIN_ID`` (the launcher honours it), None when it is not set;
    NoRun when it is not a domain id."""
    text = os.environ.get("ROS_DOMAIN_ID", "").strip()
    if not text:
        return None
    if not text.isdigit() or int(text) > 232:
        raise NoRun(f"ROS_DOMAIN_ID={text[:20]!r}: a domain id 0..232 is required")
    return int(text)


def pick_domain() -> int:
    """A ROS_DOMAIN_ID in 30..100, distinct per launcher process. The shared-memory locks
    of Fast DDS name the domain port, so ids whose port files are held (another run on
    this machine) are avoided."""
    base = os.getpid() % 71
    for off in range(71):
        d = 30 + (base + off) % 71
        port = 7400 + 250 * d
        if not any(Path("/dev/shm").glob(f"fastrtps_port{port}*")):
            return d
    return 30 + base


def node_specs(plan: RunPlan, scenario: str) -> tuple[NodeSpec, ...]:
    """Every process of ``plan``, in start order: the recorder (it listens before the run
    starts), the leader, the plant, the link emulator, the robots. ``scenario`` is what
    the leader loads (``scenario_reference``)."""
    cfg, n = plan.config, plan.scenario.n
    state_dir = str(plan.out / "state")
    nsa = tuple(namespace_remaps(plan.namespace))
    policy = RestartPolicy(plan.max_restarts)

    def spec(name: str, module: str, **kw: Any) -> NodeSpec:
        return NodeSpec(name, module, restart=policy, **kw)

    specs: list[NodeSpec] = []
    if plan.record is not None:
        specs.append(spec(RECORDER_NODE, "formation_ilc.nodes.recorder",
                          args=("--output", str(plan.record)), remaps=nsa, passive=True))
    if plan.live is not None:
        # the view topics come from the recorder; without one the bridge makes them
        specs.append(spec(LIVEVIEW_NODE, "formation_ilc.nodes.liveview",
                          args=("--host", plan.live[0], "--port", str(plan.live[1]),
                                *(("--observe",) if plan.record is None else ()),
                                # the simulator and the physics plant publish a preview
                                *(("--preview",) if plan.true_state else ()),
                                *(("--rate", repr(plan.live_rate))
                                  if plan.live_rate is not None else ())),
                          remaps=nsa, optional=True))
    leader = {**cfg.to_params(scenario), "state_dir": state_dir,
              "nodes_expected": plan.team.expected}
    if plan.watchdog_scale != 1.0:
        leader["watchdog_scale"] = float(plan.watchdog_scale)
    specs.append(spec(LEADER_NODE, "virtual_leader.node", remaps=nsa,
                      params=tuple(leader.items())))
    if plan.plant == "sim":
        specs.append(spec(SIM_NODE, "robot_sim.node", remaps=nsa,
                          params=(("timeout", float(cfg.timeout)),)))
    phys = plan.physics
    if plan.plant == "physics" and phys is not None:
        specs.append(spec(PHYSICS_NODE, "robot_sim.physics_node", remaps=nsa,
                          params=(("timeout", float(cfg.timeout)), ("model", phys.model),
                                  ("pose", phys.pose), ("collide", phys.collide),
                                  ("rate", float(phys.rate)))))
    if plan.bridge is not None:
        specs.extend(_bridge_specs(plan, plan.bridge, nsa, spec))
    if cfg.links == "emulated":
        specs.append(spec(LINKS_NODE, "robot_sim.link_emulator", remaps=nsa))
    robot: tuple[tuple[str, Any], ...] = (
        ((("init_memory", str(plan.init_memory.resolve())),) if plan.init_memory else ())
        + (("state_dir", state_dir),))
    ids = list(range(1, n + 1))
    if plan.container > 0:
        for c in range(0, n, plan.container):
            grp = ids[c:c + plan.container]
            specs.append(spec(robots_process_name(grp[0], grp[-1]), "formation_ilc.nodes.robot",
                              args=("--robots", *map(str, grp)), remaps=nsa, params=robot))
    else:
        for i in ids:
            specs.append(spec(robot_name(i), "formation_ilc.nodes.robot", remaps=nsa,
                              params=(("robot_id", i), *robot),
                              host=i if plan.hosts is not None else None))
    return tuple(specs)


def _bridge_specs(plan: RunPlan, bridge: BridgeOptions, nsa: tuple[str, ...],
                  spec: Any) -> list[NodeSpec]:
    """The bridges (after the physics bases or fake drivers they drive, if any)."""
    specs: list[NodeSpec] = []
    n = plan.scenario.n
    if bridge.physics_bases and bridge.base is not None and plan.physics is not None:
        from formation_ilc.config.bases import base_preset

        preset = base_preset(bridge.base)
        starts = [float(x) for x in plan.scenario.desired.eta[:, 0].ravel()]
        specs.append(spec(BASES_NODE, "robot_sim.physics_base", remaps=nsa,
                          params=(("robots", n), ("poses", starts),
                                  ("ns_pattern", bridge.driver_ns),
                                  ("cmd_type", preset.cmd_type),
                                  ("odom_topic", preset.odom_topic),
                                  ("model", plan.physics.model),
                                  ("collide", plan.physics.collide))))
    # a params file goes with the ROS arguments, before the -p parameters (which win)
    pf = () if bridge.params_file is None else ("--params-file", str(bridge.params_file))
    for i in range(1, n + 1):
        if bridge.fake_drivers:
            specs.append(spec(fake_driver_name(i), "robot_sim.fake_pioneer",
                              remaps=("-r", f"__ns:={bridge.namespace(i)}"),
                              params=(("seed", i), ("cmd_type", bridge.cmd_type),
                                      ("driver", bridge.driver))))
        specs.append(spec(bridge_name(i), "formation_ilc.nodes.pioneer_bridge",
                          remaps=nsa + pf, params=bridge.params(i)))
    return specs
