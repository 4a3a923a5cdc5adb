"""The pre-run checks of a launch: the safety filter a run gets, and the refusals of a run
the plant cannot do (limits, clearance, contact predicted by the batch simulator, a memory
that would command past the limits), before anything starts. Moved whole from the
launcher's plan; ``formation_ilc.plan.build`` calls them."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from formation_ilc.config.plants import Plant
from formation_ilc.config.safety import (
    SafetySettings,
    default_learning,
    default_margin,
    default_motion,
)
from formation_ilc.config.scenario import Scenario
from formation_ilc.plan.options import LaunchOptions
from formation_ilc.plan.specs import BridgeOptions, NoRun, PhysicsOptions

__all__ = ["safety_settings", "check_plant", "check_memory"]


def safety_settings(opts: LaunchOptions, row: Plant, sc: Scenario, namespace: str,
                    bridge: BridgeOptions | None, physics: PhysicsOptions | None
                    ) -> SafetySettings | None:
    """The run's safety filter (``--safety``; on by default with a plant whose robots have
    bodies: the plant table's ``bodies``): the body its robots have and the limits it
    keeps (the physics model's, the bridges' as they will read them, the base preset's),
    or None."""
    on = opts.safety
    if on is None:
        on = row.bodies
    if not on:
        return None
    from formation_ilc.config.bases import BASES, limits_from_params
    from formation_ilc.core.limits import Limits
    from formation_ilc.model.physics import MODELS
    from formation_ilc.protocol.bridge import bridge_limits

    body = opts.body
    if row.entry is None:  # an external plant
        raise NoRun("--safety: with --plant external the launcher knows neither the robots' "
                    "bodies nor their limits; run the filter on the plant's side")
    if body is not None and row.bodies:
        raise NoRun(f"--body goes with --plant sim; --plant {opts.plant} knows its robots' "
                    f"body")
    if physics is not None:  # the physics plant, or physics robots behind the bases
        if physics.pose == "odometry":
            raise NoRun("--pose odometry with the safety filter: wheel odometry drifts (1.4 m "
                        "off the truth in 8 trials, docs/safety.md) and the filter keeps its "
                        "distance only between poses it can trust; give the robots poses "
                        "from motion capture or a localiser (--pose truth), or --no-safety")
        body = physics.model
    elif bridge is not None and physics is None:
        # the bridges' base (a Pioneer driver's without a preset)
        body = bridge.base or "p3dx"
    else:
        body = body or "p3dx"
    # the one limits table (config.bases), which the physics models read too
    limits = MODELS[body].limits if body in MODELS else BASES[body].limits
    if bridge is not None:
        # the bridges' limits, as they will read them; a Pioneer's acceleration is ARIA's
        base = bridge.base
        if base is None:
            limits = limits.tighter(BASES["p3dx"].limits)
        try:
            held = limits_from_params(bridge_limits(base), sc.n, _params_file(bridge),
                                      dict(bridge.limits), namespace)
        except ValueError as exc:
            raise NoRun(str(exc)) from None
        for lim in held:
            limits = limits.tighter(lim)
    limits = limits.tighter(Limits())
    try:
        margin = opts.safety_margin
        return SafetySettings(body, limits,
                              default_margin(body) if margin is None else float(margin),
                              opts.safety_learning
                              or default_learning(body, sc.uncertainty.pose_noise),
                              "peers" if row.per_robot else "team",
                              opts.safety_motion
                              or default_motion(sc.n, bridged=row.per_robot))
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


def check_plant(opts: LaunchOptions, row: Plant, sc: Scenario, namespace: str,
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
    if safety is not None and bridge is not None:
        # the one pose source the filter has behind bridges, said before the run
        notes.append("note: the safety filter keeps the robots apart where their bridges "
                     "say they are: each driver's wheel odometry from its start pose, which "
                     "drifts without bound (1.4 m in 8 trials on the physics plant, "
                     "docs/safety.md); it holds only while that drift stays inside the "
                     "filter's margin")
    # fake drivers are unicycles without bodies: nothing to crash in a rehearsal
    if not row.bodies or (bridge is not None and bridge.fake_drivers):
        return tuple(notes)
    line, covered = _contact_line(opts, sc, bridge, physics, safety)
    if line is None:
        return (*notes, covered)
    if opts.allow_contact:
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

    dc = desired_clearance(sc, spec_of(safety, sc.dt, sc.uncertainty))
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
    """The batch simulator's prediction of a run on robots with bodies (the arc plant, from
    the initial memory, through the run's safety filter, with the run's own noise, delays
    and seed: every trial of it): (None, or the line saying where two footprints first
    overlap; the note saying what it covered)."""
    from formation_ilc.model.footprint import first_overlap, footprint_of, predict_clearance
    from formation_ilc.model.safety import spec_of
    from formation_ilc.store.memoryfile import load_memory

    body = (physics.model if physics is not None
            else bridge.base if bridge is not None and bridge.base is not None else "p3dx")
    fp = footprint_of(body)
    memory = None if opts.init_memory is None else load_memory(opts.init_memory, sc)
    spec = None if safety is None else spec_of(safety, sc.dt, sc.uncertainty)
    found = predict_clearance(sc, fp, sc.trials, memory=memory, safety=spec, as_run=True)
    hit = first_overlap(found)
    start = "warm start" if memory is not None else "cold start (u_0 = 0)"
    through = " through the safety filter" if spec is not None else ""
    drawn = ", ".join(w for w, on in (("noise", sc.uncertainty.noisy),
                                      ("delays", sc.uncertainty.delay.kind != "none")) if on)
    draws = (f"the run's {' and '.join(drawn.split(', '))}, seed {sc.seed}" if drawn
             else "no noise nor delay, as the run")
    if hit is None:
        least = min(found, key=lambda c: c.value)
        return None, (f"the batch simulator predicts no contact in the {len(found)} trials "
                      f"of this run{through} ({start}; {draws}; exact-arc kinematics; least "
                      f"clearance {least.value:.3f} m, trial {least.trial}); it does not look "
                      f"past trial {sc.trials - 1}, and a plant with bodies reports what "
                      f"happens")
    return (f"the batch simulator predicts contact from this {start}{through}: "
            f"{hit.line(sc.dt)} (footprint {fp.length} x {fp.width} m)"), ""


def check_memory(path: Path, sc: Scenario) -> None:
    """Refuse an --init-memory file that is not a memory for this run."""
    from formation_ilc.store.memoryfile import MemoryFileError, load_memory

    try:
        load_memory(path, sc)
    except MemoryFileError as exc:
        raise NoRun(f"--init-memory {exc}") from None
