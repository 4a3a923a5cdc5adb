"""The plan of a ``formation-ilc launch``: everything decided from the options before any
process starts, built once and frozen.

``build_plan`` reads the options (and, with ``--resume DIR``, the run's own ``run.json``),
refuses what cannot run (``NoRun``: one line and the exit status, before anything starts)
and returns a ``RunPlan``: the validated run configuration, the roster of the run
(``formation_ilc.config.roster``: its members, the team the leader waits for, their
enclaves), and one ``NodeSpec`` per process the roster names (command, parameters, restart
policy, host). The
supervisor (``formation_ilc.cli.supervisor``) runs the plan, the report writer
(``formation_ilc.cli.report``) writes its outputs, and ``--hosts netns`` wraps its
execution (``formation_ilc.cli.hosts``). Nothing here needs ROS.
"""

from __future__ import annotations

import functools
import json
import os
import secrets
import sys
import time
import uuid
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from datetime import datetime
from pathlib import Path
from typing import Any

from formation_ilc.cli.options import OptionError
from formation_ilc.cli.secure import SecureRun
from formation_ilc.config.clocks import ClockSettings
from formation_ilc.config.plants import Plant, plant
from formation_ilc.config.roster import Lineup, Member, Roster, Team, roster
from formation_ilc.config.runconfig import (
    WALL_MODES,
    RunConfig,
    make_config,
    param_text,
    scenario_reference,
)
from formation_ilc.config.safety import SafetySettings, default_learning, default_margin
from formation_ilc.config.scenario import Scenario, ScenarioError
from formation_ilc.core.names import (
    LEADER_NODE,
    MONITOR_NODE,
    NAMESPACE,
    driver_ns_problem,
    namespace_remaps,
    robots_process_name,
)
from formation_ilc.plan.options import LaunchOptions, unused_option
from formation_ilc.protocol.schedule import DONE, KEY_BYTES
from formation_ilc.system.exits import NO_RESTART as EXIT_NO_RESTART
from formation_ilc.system.netns import LinkFaults

__all__ = ["RUN_FILE", "NO_RESTART", "NoRun", "BridgeOptions", "PhysicsOptions",
           "RestartPolicy", "NodeSpec",
           "HostsPlan", "RunPlan", "build_plan", "hosted_members", "placed_members",
           "effective_options", "node_specs",
           "finished", "pick_domain", "entry_module"]

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
    cmd_type : 'twist' or 'twist_stamped' on the driver's cmd_vel, or None: a base
        preset's own, Twist for a Pioneer's.
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
    cmd_type: str | None = None
    return_timeout: float = 60.0
    fake_drivers: bool = False
    base: str | None = None
    limits: tuple[tuple[str, float], ...] = ()
    params_file: Path | None = None
    physics_bases: bool = False

    @classmethod
    def of(cls, opts: LaunchOptions) -> BridgeOptions:
        from formation_ilc.config.bases import LIMIT_KEYS

        base = opts.base if plant(opts.plant).driver == "base" else None
        ns = opts.driver_ns
        if base is not None and ns == PIONEER_NS:
            ns = BASE_NS
        limits = {"v_max": opts.v_max, "omega_max": opts.omega_max, "a_max": opts.a_max,
                  "alpha_max": opts.alpha_max}
        given = tuple((k, float(limits[k] or 0.0)) for k in LIMIT_KEYS)
        pf = opts.params_file
        return cls(opts.driver, ns, opts.cmd_type,
                   float(opts.return_timeout),
                   bool(opts.fake_drivers), base, tuple((k, v) for k, v in given if v != 0),
                   None if pf is None else Path(pf).resolve(),
                   bool(opts.physics_bases))

    @property
    def sent_type(self) -> str:
        """The command type the bridges send: the one asked for, else a base preset's,
        else Twist."""
        if self.cmd_type is not None:
            return self.cmd_type
        if self.base is not None:
            from formation_ilc.config.bases import base_preset

            return base_preset(self.base).cmd_type
        return "twist"

    def namespace(self, i: int) -> str:
        return self.driver_ns.replace("{i}", str(i))

    def params(self, i: int) -> tuple[tuple[str, Any], ...]:
        """Robot ``i``'s bridge parameters."""
        kind: tuple[tuple[str, Any], ...] = (
            (("base", self.base),) if self.base is not None
            else (("cmd_type", self.sent_type), ("driver", self.driver)))
        if self.base is not None and self.cmd_type is not None:  # the preset's, overridden
            kind += (("cmd_type", self.cmd_type),)
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
    #: what the plant does when robots touch (``protocol.physics_plant.ON_CONTACT``), how
    #: often one trial runs again after one, and the tilt [deg] that counts as one
    on_contact: str = "stop"
    contact_retries: int = 2
    tilt_limit: float = 10.0

    @classmethod
    def of(cls, opts: LaunchOptions) -> PhysicsOptions:
        return cls(opts.robot_model, opts.pose,
                   not opts.pass_through,
                   float(opts.physics_rate),
                   opts.on_contact, int(opts.contact_retries),
                   float(opts.tilt_limit))


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
    roster : every member of the run (``config.roster``): the team the leader waits for
        (``nodes_expected``), the processes, the enclaves, the plant's row.
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
    roster: Roster
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
    #: the batch simulator predicted no contact in this run's trials (a plant with bodies):
    #: the report warns if the plant saw one all the same
    predicted_clear: bool = False
    #: a run file's ``hosts:``: which host runs which members (empty: all on this one)
    host_members: tuple[tuple[str, tuple[str, ...]], ...] = ()
    #: the run key the leader seals its events with (``protocol.schedule.seal``), given to
    #: every process this launch starts; a new one for each launch, kept nowhere
    key: bytes | None = None

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
    def team(self) -> Team:
        """The nodes the leader waits for (``nodes_expected``)."""
        return self.roster.team

    @property
    def row(self) -> Plant:
        """The plant's row of the plant table."""
        return self.roster.plant

    @property
    def true_state(self) -> bool:
        """The robots' true trajectories are published: by the plant (the simulator, the
        physics plant) or by the bridges of physics bases (``Lineup.true_state``)."""
        return self.roster.lineup.true_state

    @property
    def bridged(self) -> bool:
        """The plant is one bridge per robot (a Pioneer driver or a base behind each)."""
        return self.row.per_robot

    @property
    def reporters(self) -> tuple[str, ...]:
        """Nodes besides the robots whose last trial's diagnostics the launcher waits for
        (timing, missed samples, injected delays, the bridges' returns, the recording)."""
        return self.roster.reporters

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

def build_plan(options: LaunchOptions) -> RunPlan:
    """The plan of a launch's options; NoRun with the refusal's one line and exit status;
    ScenarioError for a bad scenario."""
    opts = effective_options(options)
    assert opts.scenario is not None and opts.run_id is not None
    unused = unused_option(opts, plant(opts.plant))
    if unused is not None:  # before, run and said nothing
        raise NoRun(unused)
    faults = _hosts_faults(opts)
    mode, links = _mode_and_links(opts, hosts=faults is not None)
    clocks = _clocks(opts, mode)
    try:
        cfg = make_config(opts.scenario, seed=opts.seed, noise=not opts.no_noise,
                          delay=not opts.no_delay, trials=opts.trials, law=opts.law,
                          memory=opts.memory, mode=mode, monitored=True,
                          timeout=opts.timeout, recorded=opts.record is not None,
                          links=links, run_id=opts.run_id,
                          headings=opts.headings,
                          time_scale=opts.time_scale, clocks=clocks)
    except ScenarioError:
        raise
    except ValueError as exc:
        # RunConfig owns its rules (e.g. wall-clock trials need direct links): a refusal
        # in one line, not a traceback
        raise NoRun(f"launch: {exc}") from None
    # 'auto' headings: arc on the plants that drive arcs and came with the option (physics,
    # base); chord for the kinematic simulator, and for the Pioneer bridges and external
    # plants as before them (their runs and learned memories keep their numbers)
    row = plant(opts.plant)
    cfg = replace(cfg, scenario=cfg.scenario.for_plant(row.headings))
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
    record = _in_run(opts.record, out)
    root = opts.record_root or record
    domain = opts.domain_id if opts.domain_id is not None else caller_domain()
    if domain is None:
        domain = pick_domain()
    bridge = BridgeOptions.of(opts) if row.per_robot else None
    if bridge is not None:
        why = driver_ns_problem(bridge.driver_ns)
        if why is not None:  # before, the bridges started with an invalid namespace
            raise NoRun(f"argument --driver-ns: {bridge.driver_ns!r}: {why}")
    physics = (PhysicsOptions.of(opts) if row.physics
               or (bridge is not None and bridge.physics_bases) else None)
    safety = _safety(opts, row, sc, namespace, bridge, physics)
    cfg = replace(cfg, safety=safety)
    notes = _check_plant(opts, row, sc, namespace, bridge, physics, safety)
    live = _live(opts)
    lineup = Lineup.of(sc.graph, plant=row.name, links=links, record=opts.record is not None,
                       live=live is not None, external=tuple(opts.plant_nodes),
                       **({} if bridge is None else dict(
                           driver=bridge.driver, driver_ns=bridge.driver_ns, base=bridge.base,
                           fake_drivers=bridge.fake_drivers,
                           physics_bases=bridge.physics_bases)),
                       sensing=None if safety is None else safety.sensing,
                       clocks=cfg.clock_exchanges)
    plan = RunPlan(
        config=cfg, roster=roster(lineup), nodes=(), out=out, namespace=namespace, domain=domain,
        discovery=opts.discovery, plant=opts.plant, container=opts.container,
        max_restarts=opts.max_restarts,
        # bridges drive their robots back after the last trial too
        final_wait=3.0 + (bridge.return_timeout + 2.0 if bridge is not None else 0.0),
        plots=not opts.no_plots, resumed_at=resumed_at,
        run_json=None if resumed_at is not None else _run_json(opts, mode, links, out,
                                                                clocks),
        init_memory=opts.init_memory, record=record, bridge=bridge,
        record_root=root.resolve() if root is not None else None,
        watchdog_scale=float(opts.watchdog_scale),
        physics=physics, notes=notes,
        live=live, live_rate=_live_rate(opts),
        hosts=None if faults is None else HostsPlan(faults, opts.dds_profile or "lossy",
                                                    sc.seed),
        predicted_clear=any(n.startswith("the batch simulator predicts no contact")
                            for n in notes),
        key=secrets.token_bytes(KEY_BYTES))
    # the processes follow from the rest of the plan
    plan = _with_peers(replace(plan, nodes=node_specs(plan, scenario_reference(opts.scenario))))
    plan = replace(plan, host_members=placed_members(plan, dict(opts.host_members)))
    return _secured(plan, opts.secure)


def hosted_members(plan: RunPlan) -> tuple[tuple[str, int | None], ...]:
    """(name, robot) of every member a host of the run runs: the launcher's processes and
    its monitor, in start order."""
    return ((MONITOR_NODE, None),) + tuple((m.name, m.robot) for m in plan.roster.processes)


def placed_members(plan: RunPlan, hosts: Mapping[str, Sequence[str]]
                   ) -> tuple[tuple[str, tuple[str, ...]], ...]:
    """A run file's ``hosts:`` checked against the plan: every member on exactly one host,
    the monitor with the leader; NoRun naming the first that is not."""
    if not hosts:
        return ()
    if plan.container:
        raise NoRun("hosts: robots on hosts of their own run one process per robot (no "
                    "processes.container)")
    names = [n for n, _ in hosted_members(plan)]
    where: dict[str, str] = {}
    for host, members in hosts.items():
        for name in members:
            if name not in names:
                raise NoRun(f"hosts: {host}: {name!r} is no member of this run (its members: "
                            f"{', '.join(names)})")
            if name in where:
                raise NoRun(f"hosts: {name!r} is on {where[name]} and on {host}")
            where[name] = host
    missing = [n for n in names if n not in where]
    if missing:
        raise NoRun(f"hosts: {', '.join(missing)} on no host (every member of the run on "
                    f"one)")
    if where[MONITOR_NODE] != where[LEADER_NODE]:
        raise NoRun(f"hosts: the monitor goes with the leader (on {where[LEADER_NODE]}): "
                    f"the ground station runs the checks and the report")
    return tuple((h, tuple(m)) for h, m in hosts.items())


def _in_run(path: Path | None, out: Path) -> Path | None:
    """``path`` absolute; ``@run/REL`` (a stored run file's recording, launched again) in
    the run's folder ``out``."""
    if path is None:
        return None
    if path.parts[:1] == ("@run",):
        return out.joinpath(*path.parts[1:])
    return path.resolve()


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
    from formation_ilc.cli.secure import prepare
    from formation_ilc.config.plants import SECURE_PLANTS

    if keystore is not None and not plan.row.secure:
        raise NoRun(f"--secure: the keystore's permissions cover the plants "
                    f"{', '.join(SECURE_PLANTS)}, not --plant {plan.plant} (run it without "
                    f"--secure, on a network you trust)")
    # the handshake retries go into the profile the processes would load anyway: the
    # lossy-links one on netns hosts, else the user's own (with the discovery peers of a
    # large team, which are written next to it: checked here on the user's own)
    base = plan.hosts.profile_file if plan.hosts is not None else _user_profile()
    try:
        sec = prepare(keystore, [_enclave(plan, s.name) for s in plan.nodes], plan.namespace,
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
        replace(s, env=tuple(sec.variables(_enclave(plan, s.name)).items()))
        for s in plan.nodes))


def _enclave(plan: RunPlan, process: str) -> str:
    """The enclave a process runs in: its member's (robot i's fake driver runs in
    ``driver_i``, as a real driver would)."""
    return plan.roster.enclave_of(process)


def effective_options(opts: LaunchOptions) -> LaunchOptions:
    """The options a run goes with: a new run id when there is none; NoRun for what no
    run can have."""
    if opts.scenario is None:
        raise NoRun("a SCENARIO is required (or --resume DIR)")
    if opts.max_restarts < 0:
        raise NoRun("--max-restarts must be >= 0")
    if opts.run_id is None:
        # a letter first: an all-digit id would reach the leader as an integer parameter
        return replace(opts, run_id="r" + uuid.uuid4().hex[:12])
    return opts


def _hosts_faults(opts: LaunchOptions) -> LinkFaults | None:
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
    if opts.container or not plant(opts.plant).hosts or opts.links == "emulated":
        raise NoRun("--hosts netns runs one process per robot (no --container), the "
                    "simulator as plant (--plant sim) and direct links (the links between "
                    "robots are the network's; no --links emulated)")
    problem = netns.support_problem()
    if problem:
        raise NoRun(f"--hosts netns: {problem}")
    return faults


def _mode_and_links(opts: LaunchOptions, hosts: bool) -> tuple[str, str]:
    """The run's mode and links: refuses what a plant cannot do, fills in the defaults."""
    row = plant(opts.plant)
    pioneer = row.per_robot
    links = "direct" if hosts else opts.links
    if pioneer and (opts.mode not in (None, "wallclock") or links not in (None, "direct")):
        raise NoRun(f"--plant {opts.plant} runs --mode wallclock with --links direct (real "
                    f"robots have no simulated clock and no link emulator), got --mode "
                    f"{opts.mode} --links {links}")
    if opts.mode == "wallclock" and row.clock:
        raise NoRun("--mode wallclock is for real robots: use it with --plant pioneer (or an "
                    "external plant that samples on the wall clock); the simulator runs "
                    "lockstep or realtime")
    if opts.fake_drivers and row.driver != "pioneer":
        raise NoRun("--fake-drivers goes with --plant pioneer")
    if opts.physics_bases and row.driver != "base":
        raise NoRun("--physics-bases goes with --plant base")
    if opts.fake_drivers and opts.driver == "p2os2":
        raise NoRun("--fake-drivers speak rosaria or ros2aria, not p2os2 (its p2os_msgs are "
                    "not on PyPI)")
    mode = opts.mode or ("wallclock" if pioneer else "lockstep")
    return mode, links or ("direct" if pioneer or mode == "wallclock" else "emulated")


def _safety(opts: LaunchOptions, row: Plant, sc: Scenario, namespace: str,
            bridge: BridgeOptions | None, physics: PhysicsOptions | None
            ) -> SafetySettings | None:
    """The run's safety filter (``--safety``; on by default with a plant whose robots have
    bodies: the plant table's ``bodies``): the body its robots have and the limits it
    keeps (the physics model's, the bridges' as they will read them, the base preset's),
    or None."""
    on = getattr(opts, "safety", None)
    if on is None:
        on = row.bodies
    if not on:
        return None
    from formation_ilc.config.bases import BASES, limits_from_params
    from formation_ilc.core.limits import Limits
    from formation_ilc.model.physics import MODELS
    from formation_ilc.protocol.bridge import bridge_limits

    body = getattr(opts, "body", None)
    if row.entry is None:  # an external plant
        raise NoRun("--safety: with --plant external the launcher knows neither the robots' "
                    "bodies nor their limits; run the filter on the plant's side")
    if body is not None and row.bodies:
        raise NoRun(f"--body goes with --plant sim; --plant {opts.plant} knows its robots' "
                    f"body")
    if physics is not None:  # the physics plant, or physics robots behind the bases
        body = physics.model
        limits = MODELS[body].limits
    else:
        body = body or "p3dx"
        limits = MODELS[body].limits if body in MODELS else BASES[body].limits
    if bridge is not None:
        # the bridges' limits, as they will read them; a Pioneer's acceleration is ARIA's
        base = bridge.base
        if base is None:
            body = "p3dx" if physics is None else body
            limits = limits.tighter(BASES["p3dx"].limits)
        elif physics is None:
            body = base
        try:
            held = limits_from_params(bridge_limits(base), sc.n, _params_file(bridge),
                                      dict(bridge.limits), namespace)
        except ValueError as exc:
            raise NoRun(str(exc)) from None
        for lim in held:
            limits = limits.tighter(lim)
    limits = limits.tighter(Limits())
    try:
        margin = getattr(opts, "safety_margin", None)
        return SafetySettings(body, limits,
                              default_margin(body) if margin is None else float(margin),
                              getattr(opts, "safety_learning", None)
                              or default_learning(body),
                              "peers" if row.per_robot else "team")
    except ValueError as exc:
        raise NoRun(f"--safety: {exc}") from None


def _params_file(bridge: BridgeOptions) -> Any:
    """The bridges' parameters file as YAML (None without one); NoRun if unreadable."""
    import yaml

    if bridge.params_file is None:
        return None
    try:
        params = yaml.safe_load(bridge.params_file.read_text())
    except (OSError, yaml.YAMLError) as exc:
        raise NoRun(f"--params-file {bridge.params_file}: cannot read: {exc}") from None
    if not isinstance(params, dict):
        raise NoRun(f"--params-file {bridge.params_file}: expected a mapping of node names")
    return params


def _check_plant(opts: LaunchOptions, row: Plant, sc: Scenario, namespace: str,
                 bridge: BridgeOptions | None, physics: PhysicsOptions | None,
                 safety: SafetySettings | None = None) -> tuple[str, ...]:
    """Refuse a run the plant cannot do, before anything starts: no PyBullet for a physics
    plant; desired speeds or accelerations beyond the bridges' or the physics robots'
    limits (with the ``--time-scale`` that fits); a formation tighter than the safety
    filter's distance; an initial memory past the limits without the filter; robots with
    bodies whose footprints the batch simulator predicts to overlap (unless
    ``--allow-contact``: then the warning is the plan's note). The notes say what the
    prediction covered."""
    notes: list[str] = []
    if physics is not None:
        from formation_ilc.model.physics import rate_problem
        from formation_ilc.protocol.physics_plant import physics_available

        why = rate_problem(physics.rate, sc.dt)
        if why is not None:  # before, refused by the node after every node had started
            raise NoRun(f"--physics-rate {physics.rate:g}: {why}")
        missing = physics_available()
        if missing is not None:
            raise NoRun(missing)
        line = _physics_limits_line(physics, sc)
        if line is not None:
            raise NoRun(line)
    if bridge is not None:
        line = _limits_line(bridge, sc, namespace)
        if line is not None:
            raise NoRun(line)
    if safety is not None:
        line = _formation_line(sc, safety)
        if line is not None:
            raise NoRun(line)
    memory_note = _memory_limits(opts, sc, physics, safety)
    if memory_note:
        notes.append(memory_note)
    # fake drivers are unicycles without bodies: nothing to crash in a rehearsal
    if not row.bodies or (bridge is not None and bridge.fake_drivers):
        return tuple(notes)
    line, covered = _contact_line(opts, sc, bridge, physics, safety)
    if line is None:
        return (*notes, covered)
    if getattr(opts, "allow_contact", False):
        return (*notes, f"warning: {line}; running anyway (--allow-contact)")
    raise NoRun(f"{line}; put the robots through the safety filter (--safety), start from "
                f"a learned memory (--init-memory, see docs/physics.md), widen the "
                f"formation's offsets, or --allow-contact")


def _physics_limits_line(physics: PhysicsOptions, sc: Scenario) -> str | None:
    """None if the scenario's desired motion fits the physics robots' limits (their
    makers'); else the line that says where not, and the ``--time-scale`` that fits."""
    from formation_ilc.config.bases import fit_limits
    from formation_ilc.model.physics import MODELS

    model = MODELS[physics.model]
    line = fit_limits(sc, [model.limits] * sc.n)
    if line is None:
        return None
    return f"{line} ({model.name} robots' limits: {model.limits_source})"


def _formation_line(sc: Scenario, safety: SafetySettings) -> str | None:
    """None if the desired formation keeps the robots' covering discs the filter's
    distance apart; else the line that says where it does not."""
    from formation_ilc.model.safety import desired_clearance, spec_of

    dc = desired_clearance(sc, spec_of(safety, sc.dt))
    if dc.fits:
        return None
    return (f"{dc.line(sc.dt)} ({safety.body} bodies + {safety.margin:g} m margin): the "
            f"filter would hold the robots off their own formation; widen the formation's "
            f"offsets, lower --safety-margin, or --no-safety")


def _memory_limits(opts: LaunchOptions, sc: Scenario, physics: PhysicsOptions | None,
                   safety: SafetySettings | None) -> str | None:
    """An initial memory whose commands leave the limits: refused without the filter on a
    plant with bodies (they would be sent); with it, a note (the filter holds them inside
    and the memory learns inside)."""
    if opts.init_memory is None:
        return None
    from formation_ilc.core.limits import check_inputs
    from formation_ilc.model.physics import MODELS
    from formation_ilc.store.memoryfile import load_memory

    if safety is not None:
        limits = safety.limits
    elif physics is not None:
        limits = MODELS[physics.model].limits
    else:
        return None
    memory = load_memory(opts.init_memory, sc)
    v = check_inputs(memory, sc.dt, [limits] * sc.n)
    if v is None:
        return None
    line = v.line(sc.dt).replace("desired", "the memory's")
    if safety is None:
        raise NoRun(f"--init-memory {opts.init_memory}: {line}: it would be sent past the "
                    f"robots' limits; run with the safety filter (--safety: it holds every "
                    f"command inside them and the memory learns inside)")
    return (f"note: --init-memory {opts.init_memory}: {line}; the safety filter holds those "
            f"commands inside the limits and the memory learns inside them")


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


def _contact_line(opts: LaunchOptions, sc: Scenario, bridge: BridgeOptions | None,
                  physics: PhysicsOptions | None, safety: SafetySettings | None = None
                  ) -> tuple[str | None, str]:
    """The batch simulator's prediction of a run on robots with bodies (noise-free, the arc
    plant, from the initial memory, through the run's safety filter): (None, or the line
    saying where two footprints first overlap; the note saying what it covered)."""
    from formation_ilc.model.footprint import first_overlap, footprint_of, predict_clearance
    from formation_ilc.model.safety import spec_of
    from formation_ilc.store.memoryfile import load_memory

    body = (physics.model if physics is not None
            else bridge.base if bridge is not None and bridge.base is not None else "p3dx")
    fp = footprint_of(body)
    memory = None if opts.init_memory is None else load_memory(opts.init_memory, sc)
    spec = None if safety is None else spec_of(safety, sc.dt)
    found = predict_clearance(sc, fp, sc.trials, memory=memory, safety=spec)
    hit = first_overlap(found)
    start = "warm start" if memory is not None else "cold start (u_0 = 0)"
    through = " through the safety filter" if spec is not None else ""
    if hit is None:
        least = min(found, key=lambda c: c.value)
        return None, (f"the batch simulator predicts no contact in the {len(found)} trials "
                      f"of this run{through} ({start}; least clearance "
                      f"{least.value:.3f} m, trial {least.trial}); it does not look past "
                      f"trial {sc.trials - 1}, and a plant with bodies reports what happens")
    return (f"the batch simulator predicts contact from this {start}{through}: "
            f"{hit.line(sc.dt)} (footprint {fp.length} x {fp.width} m)"), ""


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


def _run_json(opts: LaunchOptions, mode: str, links: str, out: Path,
              clocks: ClockSettings) -> dict[str, Any]:
    """The options ``--resume`` takes the run back with (paths as strings; the emulated
    clocks' origin, so that a resumed run's robots keep their clocks)."""
    d = {k: v for k, v in opts.stored().items() if k != "resume"}
    d.update(mode=mode, links=links, out=str(out))
    if clocks.emulated:
        d["clock_origin_ns"] = clocks.origin_ns
    return d


def _clocks(opts: LaunchOptions, mode: str) -> ClockSettings:
    """The run's clock settings (``--clock-offset-ms --clock-drift-ppm --no-clock-sync
    --clock-fallback``); NoRun for emulated clocks in lockstep, where no clock is read."""
    offset = float(opts.clock_offset_ms or 0.0)
    drift = float(opts.clock_drift_ppm or 0.0)
    if (offset or drift) and mode not in WALL_MODES:
        which = "--clock-offset-ms" if offset else "--clock-drift-ppm"
        raise NoRun(f"argument {which}: emulated clocks need --mode realtime or wallclock "
                    f"(in lockstep every node runs on the simulated clock and no robot's own "
                    f"clock is read)")
    origin = opts.clock_origin_ns
    try:
        return ClockSettings(sync=not opts.no_clock_sync,
                             fallback=opts.clock_fallback,
                             offset_ms=offset, drift_ppm=drift,
                             origin_ns=int(origin) if isinstance(origin, int) and (
                                 offset or drift) else (time.time_ns() if offset or drift
                                                        else 0))
    except ValueError as exc:
        raise NoRun(f"argument --clock-offset-ms/--clock-drift-ppm: {exc}") from None


def _live(opts: LaunchOptions) -> tuple[str, int] | None:
    """``--live [PORT]`` on ``--live-host``: refused (NoRun) without foxglove-sdk or when
    the port is taken."""
    import importlib.util
    import socket

    port = opts.live
    if port is None:
        return None
    if importlib.util.find_spec("foxglove") is None:  # before anything starts, not 3 restarts
        raise NoRun("argument --live: needs foxglove-sdk, the 'live' extra: pip install -c "
                    "requirements.lock -e \".[live]\" (or pip install foxglove-sdk)")
    host = opts.live_host or "127.0.0.1"
    try:
        with socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET) as s:
            s.bind((host, int(port)))
    except OSError as exc:
        raise NoRun(f"--live {port}: cannot serve on {host}:{port}: {exc.strerror}") from None
    return host, int(port)


def _live_rate(opts: LaunchOptions) -> float | None:
    """``--live-rate HZ``: a rate >= 0 (NoRun otherwise, or without ``--live``)."""
    rate = opts.live_rate
    if rate is None:
        return None
    if opts.live is None:
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
    """Every process of ``plan``: the roster's members that have an entry script, in its
    start order (the recorder, which listens before the run starts, the live view, the
    leader, the plant and what it drives, the link emulator, the robots), each with its
    launch parameters. ``scenario`` is what the leader loads (``scenario_reference``)."""
    nsa = tuple(namespace_remaps(plan.namespace))
    policy = RestartPolicy(plan.max_restarts)
    specs: list[NodeSpec] = []
    robots: list[Member] = []
    for m in plan.roster.processes:
        if m.role == "robot":
            robots.append(m)
            continue
        args, remaps, params = _launch(plan, m, scenario, nsa)
        specs.append(NodeSpec(m.name, entry_module(m.entry or ""), args=args, remaps=remaps,
                              params=params, restart=policy, passive=m.waits == "once",
                              optional=m.optional))
    state_dir = str(plan.out / "state")
    robot: tuple[tuple[str, Any], ...] = (
        ((("init_memory", str(plan.init_memory.resolve())),) if plan.init_memory else ())
        + (("state_dir", state_dir),))
    module = entry_module("formation-ilc-robot")
    if plan.container > 0:
        for c in range(0, len(robots), plan.container):
            grp = [m.robot or 0 for m in robots[c:c + plan.container]]
            specs.append(NodeSpec(robots_process_name(grp[0], grp[-1]), module,
                                  args=("--robots", *map(str, grp)), remaps=nsa, params=robot,
                                  restart=policy))
    else:
        for m in robots:
            specs.append(NodeSpec(m.name, module, remaps=nsa,
                                  params=(("robot_id", m.robot), *robot), restart=policy,
                                  host=m.robot if plan.hosts is not None else None))
    return tuple(specs)


Launch = tuple[tuple[str, ...], tuple[str, ...], tuple[tuple[str, Any], ...]]


def _launch(plan: RunPlan, m: Member, scenario: str, nsa: tuple[str, ...]) -> Launch:
    """(arguments, ROS remaps, ROS parameters) of member ``m``'s process, from the plan's
    options."""
    cfg = plan.config
    if m.role == "recorder":
        return ("--output", str(plan.record)), nsa, ()
    if m.role == "liveview":
        assert plan.live is not None
        # the view topics come from the recorder; without one the bridge makes them
        return (("--host", plan.live[0], "--port", str(plan.live[1]),
                 *(("--observe",) if plan.record is None else ()),
                 # the simulator and the physics plant publish a preview
                 *(("--preview",) if plan.row.true_state else ()),
                 *(("--rate", repr(plan.live_rate)) if plan.live_rate is not None else ())),
                nsa, ())
    if m.role == "leader":
        leader = {**cfg.to_params(scenario), "state_dir": str(plan.out / "state"),
                  "nodes_expected": plan.team.expected}
        if plan.watchdog_scale != 1.0:
            leader["watchdog_scale"] = float(plan.watchdog_scale)
        if cfg.clocks != ClockSettings():
            leader["clocks"] = json.dumps(cfg.clocks.to_json())
        return (), nsa, tuple(leader.items())
    if m.role == "support":
        return (), nsa, ()
    bridge, phys = plan.bridge, plan.physics
    if m.role == "plant" and m.robot is None:  # one node for the team
        params: tuple[tuple[str, Any], ...] = (("timeout", float(cfg.timeout)),)
        if plan.row.physics and phys is not None:
            params += (("model", phys.model), ("pose", phys.pose), ("collide", phys.collide),
                       ("rate", float(phys.rate)), ("on_contact", phys.on_contact),
                       ("contact_retries", phys.contact_retries),
                       ("tilt_limit", float(phys.tilt_limit)))
        return (), nsa, params
    if m.role == "plant":  # robot i's bridge
        assert bridge is not None and m.robot is not None
        # a params file goes with the ROS arguments, before the -p parameters (which win)
        pf = () if bridge.params_file is None else ("--params-file", str(bridge.params_file))
        truth = (("truth", True),) if plan.roster.lineup.bases_truth else ()
        return (), nsa + pf, bridge.params(m.robot) + truth
    if m.robot is not None:  # robot i's fake driver, in the driver's namespace
        assert bridge is not None
        return ((), ("-r", f"__ns:={bridge.namespace(m.robot)}"),
                (("seed", m.robot), ("cmd_type", bridge.sent_type), ("driver", bridge.driver)))
    # the physics bases: every robot's base in one world
    from formation_ilc.config.bases import base_preset

    assert bridge is not None and bridge.base is not None and phys is not None
    preset = base_preset(bridge.base)
    starts = [float(x) for x in plan.scenario.desired.eta[:, 0].ravel()]
    return (), nsa, (("robots", plan.scenario.n), ("poses", starts),
                     ("ns_pattern", bridge.driver_ns), ("cmd_type", bridge.sent_type),
                     ("odom_topic", preset.odom_topic), ("model", phys.model),
                     ("collide", phys.collide), ("truth", True))


def entry_module(script: str) -> str:
    """The module an entry script runs (``pyproject.toml``'s ``[project.scripts]``, as
    installed), started as ``python -m MODULE``; NoRun when it is not installed."""
    found = _entry_modules().get(script)
    if found is None:
        raise NoRun(f"the entry script {script!r} is not installed: install the package "
                    f"again (pip install -e .)")
    return found


@functools.cache
def _entry_modules() -> dict[str, str]:
    from importlib.metadata import entry_points

    return {ep.name: ep.value.split(":")[0]
            for ep in entry_points(group="console_scripts") if ep.name.startswith("formation-ilc")}


# --------------------------------------------------------------------------- ros2 launch

#: the ``ros2 run formation_ilc`` executable of each node's entry script (``ros2_run/``)
ROS2_RUN = {
    "formation-ilc-leader": "virtual_leader", "formation-ilc-sim": "robot_sim",
    "formation-ilc-physics": "physics_sim", "formation-ilc-links": "link_emulator",
    "formation-ilc-robot": "robot", "formation-ilc-record": "recorder",
    "formation-ilc-liveview": "liveview", "formation-ilc-bridge": "pioneer_bridge",
    "formation-ilc-fake-pioneer": "fake_pioneer", "formation-ilc-physics-bases": "physics_bases",
}


def ros2_executable(module: str) -> str:
    """The ``ros2 run formation_ilc`` executable that runs node module ``module``."""
    script = {m: s for s, m in _entry_modules().items()}[module]
    return ROS2_RUN[script]
