"""The planner of a ``formation-ilc launch``: ``decide(options, machine)`` turns the run's
options (``formation_ilc.plan.options.LaunchOptions``: from the command line, a run file, a
stored run or a launch file's arguments) and the machine it runs on
(``formation_ilc.plan.machine.Machine``, probed once) into its ``RunPlan``
(``formation_ilc.plan.specs``), refusing what cannot run (``NoRun``: one line and the exit
status, before anything starts); with ``--resume DIR`` the run's state decides where it goes
on. ``decide`` is pure: it reads the files the options name and writes nothing, binds
nothing, draws nothing (``run-file`` and ``keystore create`` call it and nothing else).
``prepare(plan)`` then makes what the plan names: the run's folder, a run file's scenario in
it, the live view's port checked free, the run's key. ``build_plan`` is the two for this
machine, now. The pre-run checks of the plant, the limits and the safety filter are in
``formation_ilc.plan.checks``, the processes in ``formation_ilc.plan.processes``. No parser,
no ROS."""

from __future__ import annotations

import secrets
from collections.abc import Mapping, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

from formation_ilc.config.clocks import ClockSettings
from formation_ilc.config.plants import Plant, plant
from formation_ilc.config.roster import Lineup, roster
from formation_ilc.config.runconfig import (
    WALL_MODES,
    RunConfig,
    make_config,
    scenario_reference,
)
from formation_ilc.config.scenario import Scenario, ScenarioError
from formation_ilc.core.names import (
    BASES_NODE,
    LEADER_NODE,
    MONITOR_NODE,
    NAMESPACE,
    driver_ns_problem,
    fake_driver_name,
    robot_name,
)
from formation_ilc.plan.checks import check_memory, check_plant, safety_settings
from formation_ilc.plan.machine import Machine
from formation_ilc.plan.options import PATH_FIELDS, LaunchOptions, OptionError, unused_option
from formation_ilc.plan.processes import node_specs
from formation_ilc.plan.specs import (
    BridgeOptions,
    HostsPlan,
    NoRun,
    PhysicsOptions,
    RunPlan,
)
from formation_ilc.protocol.schedule import KEY_BYTES
from formation_ilc.store.runfile import used_folder_line
from formation_ilc.system.netns import LinkFaults

__all__ = ["build_plan", "decide", "prepare", "effective_options", "hosted_members",
           "placed_members", "HOSTS_DIR", "with_ground", "caller_domain", "unmade_folder"]


# --------------------------------------------------------------------------- building

def build_plan(options: LaunchOptions) -> RunPlan:
    """The plan of a launch's options on this machine, now, prepared (``decide`` then
    ``prepare``); NoRun with the refusal's one line and exit status; ScenarioError for a
    bad scenario."""
    return prepare(decide(options, Machine.probe()))


def decide(options: LaunchOptions, machine: Machine) -> RunPlan:
    """The plan of a launch's options on ``machine``; NoRun with the refusal's one line and
    exit status; ScenarioError for a bad scenario. Pure: reads the files the options name,
    writes nothing (``prepare`` makes the folder, files, port and key)."""
    opts = effective_options(options, machine)
    text = None
    if opts.scenario_text is not None:
        opts, text = _inline_scenario(opts, machine)
    assert opts.scenario is not None and opts.run_id is not None
    unused = unused_option(opts, plant(opts.plant))
    if unused is not None:  # before, run and said nothing
        raise NoRun(unused)
    faults = _hosts_faults(opts)
    mode, links = _mode_and_links(opts, hosts=faults is not None)
    clocks = _clocks(opts, mode, machine)
    try:
        cfg = make_config(opts.scenario, text=text, seed=opts.seed, noise=not opts.no_noise,
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
    _check_robots(opts, cfg.scenario.n)
    # 'auto' headings: arc on the plants that drive arcs and came with the option (physics,
    # base); chord for the kinematic simulator, and for the Pioneer bridges and external
    # plants as before them (their runs and learned memories keep their numbers)
    row = plant(opts.plant)
    cfg = replace(cfg, scenario=cfg.scenario.for_plant(row.headings))
    namespace = _namespace(opts)
    sc = cfg.scenario
    _check_scenario(opts, sc)
    out = _out_folder(opts.out, sc, machine)
    if opts.resume is None and _is_ground(opts) and (used := used_folder_line(out)):
        raise NoRun(used)  # one run, one folder
    resumed_at = _resumed_at(out, sc) if opts.resume is not None else None
    record = _in_run(opts.record, out)
    root = opts.record_root or record
    domain = _domain(opts, machine)
    bridge = _bridge(opts, row)
    physics = (PhysicsOptions.of(opts) if row.physics
               or (bridge is not None and bridge.physics_bases) else None)
    safety = safety_settings(opts, row, sc, namespace, bridge, physics)
    cfg = replace(cfg, safety=safety)
    notes = check_plant(opts, row, sc, namespace, bridge, physics, safety)
    live = _live(opts, machine)
    lineup = _lineup(opts, cfg, row, bridge, live is not None)
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
        scenario_file=None if text is None else (opts.scenario, text))
    return _with_processes(plan, opts, machine)


def unmade_folder(machine: Machine) -> Path:
    """An output folder for a plan that is never prepared (``run-file``, ``keystore
    create``): a name no run has used, made of ``machine``'s token (relative: nothing
    is made, nothing read but that it is not there)."""
    return Path(f".formation-ilc-unmade-{machine.token.hex()}")


def _lineup(opts: LaunchOptions, cfg: RunConfig, row: Plant, bridge: BridgeOptions | None,
            live: bool) -> Lineup:
    """What the run's roster is built from: the configuration's part (``Lineup.of_run``:
    the part each robot node builds its own member from), its plant and bridges, what it
    records and serves."""
    return Lineup.of_run(cfg, plant=row.name, record=opts.record is not None, live=live,
                         external=tuple(opts.plant_nodes),
                         **({} if bridge is None else dict(
                             driver=bridge.driver, driver_ns=bridge.driver_ns,
                             base=bridge.base, fake_drivers=bridge.fake_drivers,
                             physics_bases=bridge.physics_bases)))


def prepare(plan: RunPlan) -> RunPlan:
    """What ``plan`` names, made: its output folder (and a host's own under it), a run
    file's scenario written there, its live view's port checked free; the plan with its
    run key (new for each launch). NoRun, in one line, for what cannot be made."""
    from formation_ilc.store.atomic import atomic_write_text

    try:
        plan.out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise NoRun(f"--out {plan.out}: cannot create the folder: {exc.strerror}") from None
    if plan.scenario_file is not None:
        atomic_write_text(Path(plan.scenario_file[0]), plan.scenario_file[1])
    if plan.live is not None:
        _port_free(*plan.live)
    return replace(plan, key=secrets.token_bytes(KEY_BYTES))


def _port_free(host: str, port: int) -> None:
    """NoRun when ``--live PORT`` cannot be served on ``host``."""
    import socket

    try:
        with socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET) as s:
            s.bind((host, port))
    except OSError as exc:
        raise NoRun(f"--live {port}: cannot serve on {host}:{port}: {exc.strerror}") from None


def _with_processes(plan: RunPlan, opts: LaunchOptions, machine: Machine) -> RunPlan:
    """``plan`` with its processes, which follow from the rest of the plan, their peers,
    hosts and enclaves."""
    assert opts.scenario is not None
    plan = replace(plan, nodes=node_specs(plan, scenario_reference(opts.scenario)))
    plan = _with_peers(plan, machine.user_profile, secure=opts.secure is not None,
                       one_host=not (opts.host_members or _robot_hosts(opts))
                       and opts.host is None,
                       dds_profile=opts.dds_profile)
    plan = replace(plan, host_members=placed_members(plan, _hosts(plan, opts)))
    return _secured(_on_host(plan, opts.host), opts.secure, machine.user_profile)


def _check_scenario(opts: LaunchOptions, sc: Scenario) -> None:
    """NoRun (ScenarioError) for a scenario the run cannot take: an initial memory of
    another, no trial, a formation too extreme for float64, before anything is made."""
    if opts.init_memory is not None:
        check_memory(opts.init_memory, sc)
    if sc.trials < 1:
        raise NoRun("--trials must be at least 1")
    _ = sc.desired


def _check_robots(opts: LaunchOptions, n: int) -> None:
    """NoRun for a run file's ``robots:`` entry of a robot the scenario has not."""
    for entry in opts.robots:
        if not 1 <= entry.robot <= n:
            raise NoRun(f"robots: {entry.robot}: no such robot (robots are 1..{n})")


def _namespace(opts: LaunchOptions) -> str:
    namespace = opts.namespace or NAMESPACE
    if not namespace.startswith("/") or "//" in namespace:
        raise NoRun(f"--namespace {namespace!r}: an absolute ROS namespace like /team2 is "
                    f"required")
    return namespace


def _domain(opts: LaunchOptions, machine: Machine) -> int:
    """The run's ROS domain: the option's, the caller's, else a free-looking one; NoRun
    for a host launcher that knows none."""
    domain = (opts.domain_id if opts.domain_id is not None
              else caller_domain(machine.ros_domain_id))
    if domain is None and opts.host is not None:
        # the hosts find each other on the graph: one domain, known to every machine
        raise NoRun("network.domain_id: a run over several machines needs its ROS domain "
                    "on every one: write it in the run file (formation-ilc run-file ... "
                    "--domain-id N) or set ROS_DOMAIN_ID on each machine")
    return machine.free_domain() if domain is None else domain


def _bridge(opts: LaunchOptions, row: Plant) -> BridgeOptions | None:
    """The bridges' options of a plant of one bridge per robot (None for another); NoRun
    for a driver namespace or a lifecycle they cannot take."""
    bridge = BridgeOptions.of(opts) if row.per_robot else None
    if bridge is not None:
        why = driver_ns_problem(bridge.driver_ns)
        if why is not None:  # before, the bridges started with an invalid namespace
            raise NoRun(f"argument --driver-ns: {bridge.driver_ns!r}: {why}")
    if opts.lifecycle and opts.secure is not None:  # (without bridges: PLANT_USES)
        raise NoRun("argument --lifecycle: not with --secure (the enclaves' permissions "
                    "grant no lifecycle services)")
    return bridge


#: where a host launcher keeps its logs and its members' state: OUT/hosts/NAME; the
#: ground station's handshake (the run's identity, domain and key) is OUT/hosts/ground.json
HOSTS_DIR = "hosts"


def _on_host(plan: RunPlan, host: str | None) -> RunPlan:
    """``plan`` for the launcher of ``host`` (``--host``): only its members' processes; a
    host without the leader keeps its logs and state in OUT/hosts/HOST. NoRun for a host
    the run file does not name."""
    if host is None:
        return plan
    if not plan.host_members:
        raise NoRun(f"argument --host: {host}: the run has no hosts: mapping (write one with "
                    f"formation-ilc run-file ... --host-per-robot)")
    names = [h for h, _ in plan.host_members]
    if host not in names:
        raise NoRun(f"argument --host: {host!r} is no host of this run (its hosts: "
                    f"{', '.join(names)})")
    if plan.hosts is not None:
        raise NoRun("argument --host: not with --hosts netns (that is one machine's hosts)")
    plan = replace(plan, host=host)
    if not plan.ground:
        plan = replace(plan, out=plan.out / HOSTS_DIR / host, record=None, run_json=None)
    mine = set(plan.members_of(host))
    # the other hosts' processes' parameters name their own folder (no leader among them)
    nodes = plan.nodes if plan.ground else node_specs(plan, plan.config.scenario_param)
    return replace(plan, nodes=tuple(s for s in nodes if s.name in mine))


def with_ground(plan: RunPlan, run_id: str, domain: int, key: bytes) -> RunPlan:
    """A host launcher's plan on the ground station's run: its identity, domain and key
    (``OUT/hosts/ground.json``), its processes' parameters made anew."""
    plan = replace(plan, config=replace(plan.config, run_id=run_id), domain=domain, key=key)
    mine = set(plan.members_of(plan.host or ""))
    nodes = tuple(s for s in node_specs(plan, plan.config.scenario_param) if s.name in mine)
    sec = plan.secure
    if sec is not None:  # each in its enclave, as _secured put them
        nodes = tuple(replace(s, env=tuple(sec.variables(_enclave(plan, s.name)).items()))
                      for s in nodes)
    return replace(plan, nodes=nodes)


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
    stand_ins = _stand_ins(plan)
    where: dict[str, str] = {}
    placed: dict[str, list[str]] = {h: [] for h in hosts}
    for host, members in hosts.items():
        for name in members:
            if name not in names:
                if _is_stand_in(name):  # a rehearsal's, in a run without it: real drivers
                    continue
                raise NoRun(f"hosts: {host}: {name!r} is no member of this run (its members: "
                            f"{', '.join(names)})")
            if name in where:
                raise NoRun(f"hosts: {name!r} is on {where[name]} and on {host}")
            where[name] = host
            placed[host].append(name)
    for name, beside in stand_ins.items():  # a rehearsal's stand-ins: beside their robot
        if name not in where and beside in where:
            where[name] = where[beside]
            placed[where[beside]].append(name)
    missing = [n for n in names if n not in where]
    if missing:
        raise NoRun(f"hosts: {', '.join(missing)} on no host (every member of the run on "
                    f"one)")
    if where[MONITOR_NODE] != where[LEADER_NODE]:
        raise NoRun(f"hosts: the monitor goes with the leader (on {where[LEADER_NODE]}): "
                    f"the ground station runs the checks and the report")
    return tuple((h, tuple(m)) for h, m in placed.items())


def _stand_ins(plan: RunPlan) -> dict[str, str]:
    """The run's stand-ins for the real world (a fake driver, the physics bases), each
    with the member it goes beside when a run file's ``hosts:`` does not place it: robot
    I's fake driver beside robot I's node, the physics bases beside the leader. A run file
    written for the robots is rehearsed with ``--fake-drivers`` or ``--physics-bases``."""
    out: dict[str, str] = {}
    for m in plan.roster.processes:
        if m.name == BASES_NODE:
            out[m.name] = LEADER_NODE
        elif m.role == "driver" and m.robot is not None:
            out[m.name] = robot_name(m.robot)
    return out


def _is_stand_in(name: str) -> bool:
    """Whether ``name`` is a stand-in's of some run (a fake driver, the physics bases)."""
    prefix = fake_driver_name(1)[:-1]
    return name == BASES_NODE or (name.startswith(prefix) and name[len(prefix):].isdigit())


def _in_run(path: Path | None, out: Path) -> Path | None:
    """``path`` absolute; ``@run/REL`` (a stored run file's recording, launched again) in
    the run's folder ``out``."""
    if path is None:
        return None
    if path.parts[:1] == ("@run",):
        return out.joinpath(*path.parts[1:])
    return path.resolve()


def _with_peers(plan: RunPlan, user_profile: Path | None, secure: bool = False,
                one_host: bool = True, dds_profile: str | None = None) -> RunPlan:
    """``plan`` with a discovery profile when its processes are more than localhost
    discovery reaches on its own (``system.discovery``), and through the launcher's
    discovery server from ``SERVER_FROM`` participants (or with ``--discovery server``) on
    one host, its robots on network namespaces of their own or not, without ``--secure``;
    NoRun when the caller's FASTRTPS_DEFAULT_PROFILES_FILE cannot be built on, or the
    server is asked for where it cannot serve. On ``--hosts netns`` the profiles build on
    the run's (``HostsPlan.profile_file``), and each robot's processes load their own,
    bound to their namespace's address (``RunPlan.robot_profile``). Through the server on
    hosts without ``--net-loss`` and without ``--dds-profile`` (``dds_profile``) the run's
    profile is Fast DDS's defaults, not the lossy-links one: its 50 ms heartbeat kept 100
    robots on hosts from starting (68 of 102 nodes found after 6 minutes, the server's
    socket dropping what it could not read; with the defaults they started in 138 s), and
    there is no injected loss to repair."""
    from formation_ilc.system.discovery import (
        SERVER_FROM,
        needs_peers,
        peers_profile,
        server_profile,
    )

    if plan.discovery == "server":
        why = ("--secure (the server would run outside every enclave, and a secure "
               "participant takes no discovery from it)" if secure else
               "a run over several machines (it listens on this machine only)" if not one_host
               else None)
        if why is not None:
            raise NoRun(f"argument --discovery server: not with {why}; leave --discovery "
                        f"out")
    elif plan.discovery != "localhost":
        return plan
    elif plan.participants >= SERVER_FROM and one_host and not secure:
        plan = replace(plan, discovery="server")
    elif plan.hosts is not None or not needs_peers(plan.participants):
        # (on hosts of their own the robots find their peers by unicast: ROS_STATIC_PEERS)
        return plan
    if (plan.discovery == "server" and plan.hosts is not None and dds_profile is None
            and plan.hosts.faults.loss == 0.0):
        plan = replace(plan, hosts=replace(plan.hosts, profile="none"))
    base = plan.hosts.profile_file if plan.hosts is not None else user_profile
    try:
        if plan.discovery == "server":
            server_profile(base, plan.participants)
        else:
            peers_profile(base, plan.domain, plan.participants)
    except ValueError as exc:
        raise NoRun(f"FASTRTPS_DEFAULT_PROFILES_FILE {exc}") from None
    plan = replace(plan, peers_profile=plan.out / "fastdds-discovery.xml", peers_base=base)
    if plan.hosts is None:
        return plan
    return replace(plan, nodes=tuple(
        s if s.host is None else replace(s, env=(*s.env, (
            "FASTRTPS_DEFAULT_PROFILES_FILE", str(plan.robot_profile(s.host)))))
        for s in plan.nodes))


def _secured(plan: RunPlan, keystore: Path | str | None, user_profile: Path | None
             ) -> RunPlan:
    """``plan`` with every process in its enclave of ``keystore`` (``--secure``), checked
    before anything starts: NoRun if the keystore or the loaded Fast DDS cannot run it."""
    from formation_ilc.config.plants import SECURE_PLANTS
    from formation_ilc.plan.secure import prepare as secure_run

    if keystore is not None and not plan.row.secure:
        raise NoRun(f"--secure: the keystore's permissions cover the plants "
                    f"{', '.join(SECURE_PLANTS)}, not --plant {plan.plant} (run it without "
                    f"--secure, on a network you trust)")
    # the handshake retries go into the profile the processes would load anyway: the
    # lossy-links one on netns hosts, else the user's own (with the discovery peers of a
    # large team, which are written next to it: checked here on the user's own)
    base = plan.hosts.profile_file if plan.hosts is not None else user_profile
    try:
        sec = secure_run(keystore, [_enclave(plan, s.name) for s in plan.nodes], plan.namespace,
                      container=plan.container, profile=plan.out / "fastdds-secure.xml",
                      base_profile=base, launcher=plan.ground,
                      grants=plan.roster.grants(plan.namespace))
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


def _inline_scenario(opts: LaunchOptions, machine: Machine) -> tuple[LaunchOptions, str]:
    """``opts`` naming its inline scenario by the file it goes to in the run's folder
    (``scenario.yaml``, what the nodes load; ``prepare`` writes it), and the text;
    ScenarioError for a bad one."""
    from formation_ilc.config.scenario import scenario_from_text

    text = opts.scenario_text or ""
    out = _out_folder(opts.out, scenario_from_text(text, "<the run file's scenario>"), machine)
    return replace(opts, scenario=str(out / "scenario.yaml"), scenario_text=None,
                   out=out), text


def effective_options(opts: LaunchOptions, machine: Machine) -> LaunchOptions:
    """The options a run goes with: a new run id when there is none (``machine``'s); NoRun
    for what no run can have."""
    if opts.scenario is None and opts.scenario_text is None:
        raise NoRun("a SCENARIO is required (or --resume DIR)")
    if opts.max_restarts < 0:
        raise NoRun("--max-restarts must be >= 0")
    if opts.run_id is None:
        return replace(opts, run_id=machine.run_id())
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


def _is_ground(opts: LaunchOptions) -> bool:
    """Whether this launcher runs the leader (``RunPlan.ground``, from the options): the
    run's folder is its own. A member host keeps its members' state in OUT/hosts/HOST and
    comes (back) into the ground station's run, whose folder holds its files."""
    if not opts.host_members and _robot_hosts(opts):
        return opts.host in (None, GROUND)
    return opts.host is None or LEADER_NODE in dict(opts.host_members).get(opts.host, ())


#: the host of the members a run file's robots: does not place on a robot's host
GROUND = "ground"


def _robot_hosts(opts: LaunchOptions) -> dict[int, str]:
    """The hosts a run file's ``robots:`` gives its robots: robot -> host."""
    return {e.robot: e.host for e in opts.robots if e.host is not None}


def _hosts(plan: RunPlan, opts: LaunchOptions) -> dict[str, list[str]]:
    """Which host runs which members: the run file's ``hosts:``, else its robots' hosts
    (robot I's node and bridge on its host, every other member on GROUND); NoRun for a
    file that gives both."""
    robots = _robot_hosts(opts)
    if not robots:
        return {h: list(m) for h, m in opts.host_members}
    if opts.host_members:
        raise NoRun("robots: a robot's host goes in hosts: when the run file has one (give "
                    "the hosts either in hosts: or in robots:)")
    hosts: dict[str, list[str]] = {GROUND: []}
    for name, robot in hosted_members(plan):
        hosts.setdefault(robots.get(robot, GROUND) if robot else GROUND, []).append(name)
    return hosts


def _out_folder(out: Path | None, sc: Scenario, machine: Machine) -> Path:
    """The output folder (absolute; ``prepare`` makes it): ``out`` or
    runs/SCENARIO-launch-TIME."""
    out = out or Path("runs") / f"{sc.name}-launch-{machine.now:%Y%m%d-%H%M%S}"
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
    for k in PATH_FIELDS:  # absolute: a path given relative to the caller's folder is
        v = d.get(k)       # not one relative to the run's (where run.yaml reads it from)
        if isinstance(v, str) and k not in ("out", "resume"):
            p = _in_run(Path(v), out)
            d[k] = str(p) if p is not None else v
    if clocks.emulated:
        d["clock_origin_ns"] = clocks.origin_ns
    return d


def _clocks(opts: LaunchOptions, mode: str, machine: Machine) -> ClockSettings:
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
                                 offset or drift) else (machine.time_ns if offset or drift
                                                        else 0))
    except ValueError as exc:
        raise NoRun(f"argument --clock-offset-ms/--clock-drift-ppm: {exc}") from None


def _live(opts: LaunchOptions, machine: Machine) -> tuple[str, int] | None:
    """``--live [PORT]`` on ``--live-host``: refused (NoRun) without foxglove-sdk
    (``prepare`` checks the port is free)."""
    port = opts.live
    if port is None:
        return None
    if not machine.has_foxglove:  # before anything starts, not 3 restarts
        raise NoRun("argument --live: needs foxglove-sdk, the 'live' extra: pip install -c "
                    "requirements.lock -e \".[live]\" (or pip install foxglove-sdk)")
    return opts.live_host or "127.0.0.1", int(port)


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


def caller_domain(text: str) -> int | None:
    """The caller's ``ROS_DOMAIN_ID`` as set (``text``; the launcher honours it), None when
    it is not set; NoRun when it is not a domain id."""
    text = text.strip()
    if not text:
        return None
    if not text.isdigit() or int(text) > 232:
        raise NoRun(f"ROS_DOMAIN_ID={text[:20]!r}: a domain id 0..232 is required")
    return int(text)
