"""The plan of a ``formation-ilc launch``, decided and frozen: ``RunPlan`` (the validated run
configuration, the roster of the run, one ``NodeSpec`` per process the roster names:
command, parameters, restart policy, host), the options of the bridges and of the physics
plant it holds, and ``NoRun``, the refusal of options that give no run (one line and the
exit status, before anything starts). ``formation_ilc.plan.build`` builds it; the
supervisor (``formation_ilc.cli.supervisor``) runs it, the report writer
(``formation_ilc.cli.report``) writes its outputs. Nothing here needs ROS."""

from __future__ import annotations

import contextlib
import sys
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from formation_ilc.config.option_table import RobotEntry, default
from formation_ilc.config.plants import Plant, plant
from formation_ilc.config.roster import DRIVER_NS, Roster, Team
from formation_ilc.config.runconfig import (
    RunConfig,
    param_text,
)
from formation_ilc.config.scenario import Scenario
from formation_ilc.core.names import LEADER_NODE
from formation_ilc.plan.options import LaunchOptions
from formation_ilc.plan.secure import SecureRun
from formation_ilc.protocol.schedule import DONE
from formation_ilc.system.exits import NO_RESTART as EXIT_NO_RESTART
from formation_ilc.system.netns import LinkFaults

__all__ = ["NO_RESTART", "NoRun", "BridgeOptions", "PhysicsOptions",
           "RestartPolicy", "NodeSpec", "HostsPlan", "RunPlan", "finished", "PIONEER_NS",
           "BASE_NS"]


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
PIONEER_NS: str = default("driver_ns")
BASE_NS = DRIVER_NS["base"]


def _is_default(base: str | None, key: str, value: float) -> bool:
    """Whether limit ``key`` given as ``value`` (its option's units) is the one the bridge
    holds without it: a stored run file writes every limit the run went with, and a launch
    of it is the same run (the same parameters) as the launch that wrote it."""
    from formation_ilc.config.bases import with_given
    from formation_ilc.protocol.bridge import bridge_limits

    try:
        default = bridge_limits(base)
        return bool(getattr(with_given(default, {key: value}), key) == getattr(default, key))
    except ValueError:
        return False  # refused where the limits are read, in its words


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
    lifecycle : the bridges are managed nodes, brought up by the launcher (``--lifecycle``).
    """

    driver: str = default("driver")
    driver_ns: str = default("driver_ns")
    cmd_type: str | None = default("cmd_type")
    return_timeout: float = default("return_timeout")
    fake_drivers: bool = default("fake_drivers")
    base: str | None = None
    limits: tuple[tuple[str, float], ...] = ()
    params_file: Path | None = None
    physics_bases: bool = default("physics_bases")
    lifecycle: bool = default("lifecycle")
    #: what single robots do not share with the team (a run file's robots:): their driver
    #: namespace and start pose
    robots: tuple[RobotEntry, ...] = default("robots")

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
        given = tuple((k, v) for k, v in given if v != 0 and not _is_default(base, k, v))
        pf = opts.params_file
        cmd_type = opts.cmd_type
        if base is not None and cmd_type is not None:
            from formation_ilc.config.bases import base_preset

            with contextlib.suppress(ValueError):  # (an unknown preset: refused in its words)
                if base_preset(base).cmd_type == cmd_type:
                    cmd_type = None  # the preset's own: the same run as without it
        return cls(opts.driver, ns, cmd_type,
                   float(opts.return_timeout),
                   bool(opts.fake_drivers), base, given,
                   None if pf is None else Path(pf).resolve(),
                   bool(opts.physics_bases), bool(opts.lifecycle),
                   robots=tuple(e for e in opts.robots
                                if e.driver_ns is not None or e.start is not None))

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
        own = self._own(i)
        pattern = own.driver_ns if own is not None and own.driver_ns else self.driver_ns
        return pattern.replace("{i}", str(i))

    def _own(self, i: int) -> RobotEntry | None:
        return next((e for e in self.robots if e.robot == i), None)

    def params(self, i: int) -> tuple[tuple[str, Any], ...]:
        """Robot ``i``'s bridge parameters."""
        kind: tuple[tuple[str, Any], ...] = (
            (("base", self.base),) if self.base is not None
            else (("cmd_type", self.sent_type), ("driver", self.driver)))
        if self.base is not None and self.cmd_type is not None:  # the preset's, overridden
            kind += (("cmd_type", self.cmd_type),)
        return ((("robot_id", i), ("driver_ns", self.namespace(i))) + kind
                + (("return_timeout", self.return_timeout),) + self.limits
                + ((("lifecycle", True),) if self.lifecycle else ())
                + self._start(i))

    def _start(self, i: int) -> tuple[tuple[str, Any], ...]:
        own = self._own(i)
        if own is None or own.start is None:
            return ()  # the bridge takes the scenario's desired start
        return (("initial_pose", [float(x) for x in own.start]),)


@dataclass(frozen=True)
class PhysicsOptions:
    """The physics plant (``--plant physics``, and the bodies of ``--physics-bases``): the
    robot model ('p3dx', 'husky'), the measured pose's source ('truth', 'odometry'),
    whether robots collide, engine steps per second."""

    model: str = default("robot_model")
    pose: str = default("pose")
    collide: bool = not default("pass_through")
    rate: float = default("physics_rate")
    #: what the plant does when robots touch (``config.option_table.ON_CONTACT``), how
    #: often one trial runs again after one, and the tilt [deg] that counts as one
    on_contact: str = default("on_contact")
    contact_retries: int = default("contact_retries")
    tilt_limit: float = default("tilt_limit")

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

    max_restarts: int = default("max_restarts")
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
    out : the output folder (absolute; ``prepare`` makes it).
    resumed_at : iterations already learned (``--resume``); None for a new run.
    run_json : the options to keep in ``out/run.yaml`` (None when resuming).
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
    #: file with every participant's discovery port, or (``discovery`` "server") the
    #: settings of the discovery server's clients (``system.discovery``), written by the
    #: launcher before anything starts and loaded by every process; None: the caller's
    peers_profile: Path | None = None
    #: the profiles file it builds on (the caller's FASTRTPS_DEFAULT_PROFILES_FILE), or None
    peers_base: Path | None = None
    #: the batch simulator predicted no contact in this run's trials (a plant with bodies):
    #: the report warns if the plant saw one all the same
    predicted_clear: bool = False
    #: a run file's ``hosts:``: which host runs which members (empty: all on this one)
    host_members: tuple[tuple[str, tuple[str, ...]], ...] = ()
    #: the host this launcher runs (``--host``), or None: every member here
    host: str | None = None
    #: the run key the leader seals its events with (``protocol.schedule.seal``), given to
    #: every process this launch starts; a new one for each launch (``prepare``'s), kept
    #: nowhere
    key: bytes | None = None
    #: a run file's own scenario: (the file the nodes load, in the run's folder; its
    #: text), which ``prepare`` writes; or None
    scenario_file: tuple[str, str] | None = None

    @property
    def ground(self) -> bool:
        """This launcher runs the leader: the checks, the monitor and the report are its
        (with ``--host``: the host the leader is on; without: the only launcher)."""
        return self.host is None or LEADER_NODE in self.members_of(self.host)

    def members_of(self, host: str) -> tuple[str, ...]:
        """The members a run file's ``hosts:`` puts on ``host``."""
        return dict(self.host_members).get(host, ())

    def host_of(self, member: str) -> str | None:
        """The host a member runs on, or None (no ``hosts:``)."""
        return next((h for h, ms in self.host_members if member in ms), None)

    @property
    def participants(self) -> int:
        """DDS participants of the run on this machine: its processes and the launcher's
        monitor (one per process; ``--hosts netns`` robots are on hosts of their own)."""
        return len(self.nodes) + 1

    @property
    def server_host(self) -> str:
        """Where the launcher's discovery server (``discovery`` "server") listens and its
        clients here bind: 127.0.0.1, or with ``--hosts netns`` the hub's address on the
        namespaces' bridge."""
        from formation_ilc.system.discovery import LOOPBACK
        from formation_ilc.system.netns import hub_address

        return LOOPBACK if self.hosts is None else hub_address()

    def robot_profile(self, robot: int) -> Path:
        """``--hosts netns`` through the discovery server: the profiles file of robot
        ``robot``'s processes, its UDP bound to its namespace's address."""
        return self.out / "hosts" / f"fastdds-discovery-r{robot}.xml"

    def write_peers_profile(self) -> None:
        """Write ``peers_profile`` (when the plan has one), and with ``--hosts netns``
        through the discovery server each robot namespace's (``robot_profile``)."""
        from formation_ilc.system.discovery import peers_profile, server_profile
        from formation_ilc.system.netns import robot_address

        if self.peers_profile is None:
            return
        if self.discovery != "server":
            self.peers_profile.write_text(
                peers_profile(self.peers_base, self.domain, self.participants))
            return
        self.peers_profile.write_text(
            server_profile(self.peers_base, self.participants, self.server_host))
        for robot in sorted({s.host for s in self.nodes if s.host is not None}):
            path = self.robot_profile(robot)
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_text(server_profile(self.peers_base, self.participants,
                                           robot_address(robot)))

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
