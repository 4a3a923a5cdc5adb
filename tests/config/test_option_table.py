"""The option table declares every launch option once; everything else derives from it.

Each test compares one place that uses an option's default (the parser, ``LaunchOptions``,
the run file's comments, the plant option classes, the physics nodes' parameters) with the
table, so that a default written a second time is caught; and one follows
``safety.margin`` from a run file to the safety filter's spec."""

from __future__ import annotations

import math
from dataclasses import fields

import pytest

from formation_ilc.config.option_table import BY_FIELD, OPTIONS, SECTIONS, default, option
from formation_ilc.plan.options import FIELD_KEYS, PLANT_USES, RUN_KEYS, LaunchOptions


def _parser():
    from formation_ilc.cli.launchargs import add_arguments
    from formation_ilc.cli.options import OneLineParser

    p = OneLineParser(add_help=False)
    add_arguments(p)
    return p


def test_every_field_of_the_options_is_one_row_of_the_table():
    assert [f.name for f in fields(LaunchOptions)] == [o.field for o in OPTIONS]
    assert len(BY_FIELD) == len(OPTIONS)
    keys = [o.key for o in OPTIONS if o.key is not None]
    assert len(keys) == len(set(keys))
    assert {o.section for o in OPTIONS if o.key is not None} <= set(SECTIONS)


def test_launch_options_start_from_the_tables_defaults():
    opts = LaunchOptions()
    for o in OPTIONS:
        assert getattr(opts, o.field) == o.default, o.field


def test_the_parser_is_the_table():
    """Each argument: the row's flag, default, choices and help (with its default)."""
    actions = {a.dest: a for a in _parser()._actions}
    assert set(actions) == {o.field for o in OPTIONS if o.flag is not None}
    for name, a in actions.items():
        o = option(name)
        got = tuple(a.default) if isinstance(a.default, list) else a.default
        assert got == o.default, name
        assert (a.option_strings[0] if a.option_strings else a.dest) == (
            o.flag if o.flag.startswith("-") else o.field)
        assert a.choices == o.choices if o.choices is not None else True
        assert a.help == o.help_text().replace("%", "%%"), name


def test_help_names_each_default_as_the_table_holds_it():
    for o in OPTIONS:
        if o.flag is None or o.kind in ("bool",):
            continue
        text = o.help_text()
        if o.default_text:
            assert f"(default: {o.default_text})" in text, o.field
        elif o.default is not None:
            shown = (f"{o.default:g}" if isinstance(o.default, float)
                     else " ".join(o.default) if isinstance(o.default, tuple)
                     else str(o.default))
            assert f"(default {shown}" in text, o.field


def test_run_file_keys_and_the_plants_that_use_an_option_are_the_tables():
    assert {k.field: (k.path, k.negated) for k in RUN_KEYS} == {
        o.field: (o.key, o.negated) for o in OPTIONS if o.key is not None}
    assert set(FIELD_KEYS) == {o.field for o in OPTIONS if o.key is not None}
    assert PLANT_USES == {o.field: o.uses for o in OPTIONS if o.uses is not None}


def test_a_written_run_files_comment_is_the_tables_help(tmp_path):
    from formation_ilc.cli.runfile import run_file_text

    every = {o.field: "x" for o in OPTIONS}  # a value for every key, each plant's too
    text = " ".join(line.strip().lstrip("# ") for line in run_file_text(
        LaunchOptions(scenario="paper-triangle3"), effective=every).splitlines())
    for o in OPTIONS:
        if o.key is not None and o.kind != "stored":
            assert " ".join(o.help_text().split()) in text, o.field


def test_the_plant_option_classes_start_from_the_tables_defaults():
    from formation_ilc.plan.specs import BridgeOptions, PhysicsOptions, RestartPolicy

    phys = PhysicsOptions()
    assert (phys.model, phys.pose, phys.collide, phys.rate, phys.on_contact,
            phys.contact_retries, phys.tilt_limit) == (
        default("robot_model"), default("pose"), not default("pass_through"),
        default("physics_rate"), default("on_contact"), default("contact_retries"),
        default("tilt_limit"))
    assert PhysicsOptions.of(LaunchOptions()) == phys
    bridge = BridgeOptions()
    assert (bridge.driver, bridge.driver_ns, bridge.cmd_type, bridge.return_timeout,
            bridge.fake_drivers, bridge.physics_bases, bridge.lifecycle) == (
        default("driver"), default("driver_ns"), default("cmd_type"),
        default("return_timeout"), default("fake_drivers"), default("physics_bases"),
        default("lifecycle"))
    assert RestartPolicy().max_restarts == default("max_restarts")


def test_the_physics_nodes_contact_parameters_are_the_tables():
    from formation_ilc.model.physics import DEFAULT_RATE
    from formation_ilc.protocol.physics_plant import CONTACT_PARAMS, ContactWatch

    assert {p.name: p.default for p in CONTACT_PARAMS} == {
        "on_contact": default("on_contact"), "contact_retries": default("contact_retries"),
        "tilt_limit": default("tilt_limit")}
    watch = ContactWatch()
    assert (watch.on_contact, watch.retries, watch.tilt_limit) == (
        default("on_contact"), default("contact_retries"), math.radians(default("tilt_limit")))
    assert DEFAULT_RATE == default("physics_rate")


@pytest.mark.parametrize("field, text, want", [
    ("tilt_limit", "10", 10.0), ("tilt_limit", "0.5 rad", math.degrees(0.5)),
    ("omega_max", "100 deg/s", 100.0), ("omega_max", "1.5 rad/s", math.degrees(1.5)),
    ("alpha_max", "2rad/s^2", math.degrees(2.0)), ("safety_margin", "0.3", 0.3),
])
def test_an_angle_is_taken_with_its_unit(field, text, want):
    assert option(field).parse(text) == pytest.approx(want)


@pytest.mark.parametrize("field, text, why", [
    ("tilt_limit", "10 m", "unit 'm': expected deg or rad"),
    ("tilt_limit", "200", "must be a number in 0.1..180 deg, got 200"),
    ("trials", "0", "must be an integer >= 1, got 0"),
    ("plant", "pionier", "invalid choice: 'pionier'"),
])
def test_a_bad_value_is_refused_with_the_reason(field, text, why):
    with pytest.raises(ValueError, match=why.replace("^", r"\^").replace(".", r"\.")):
        option(field).parse(text)


def test_a_run_files_angle_with_its_unit_is_read(tmp_path):
    from formation_ilc.cli.runfile import load_run_file

    path = tmp_path / "run.yaml"
    path.write_text("scenario: paper-triangle3\nplant: {kind: physics}\n"
                    "safety: {tilt_limit: 0.2 rad}\n")
    assert load_run_file(path)["tilt_limit"] == pytest.approx(math.degrees(0.2))
    path.write_text("scenario: paper-triangle3\nsafety: {tilt_limit: 3 parsecs}\n")
    from formation_ilc.cli.options import OptionError

    with pytest.raises(OptionError, match=r"run\.yaml: safety\.tilt_limit: "):
        load_run_file(path)


def test_safety_margin_reaches_the_filter_unchanged(tmp_path):
    """A run file's ``safety.margin`` is the margin of the filter every robot runs: read
    by its row (1), a field of the options (2), the plan's safety settings (3), the leader's
    parameter (4) and the configuration it publishes to the robots (5), the robot's filter
    spec (6)."""
    from formation_ilc.cli.runfile import load_run_file
    from formation_ilc.config.runconfig import RunConfig
    from formation_ilc.model.footprint import footprint_of
    from formation_ilc.model.safety import spec_for, spec_of
    from formation_ilc.plan.build import build_plan

    path = tmp_path / "run.yaml"
    path.write_text("scenario: paper-triangle3\nsafety: {enabled: true, margin: 0.17}\n"
                    f"out: {tmp_path / 'out'}\n")
    opts = LaunchOptions().with_fields(load_run_file(path))                   # 1, 2
    assert opts.safety_margin == 0.17
    plan = build_plan(opts)
    assert plan.config.safety.margin == 0.17                                  # 3
    leader = RunConfig.from_params(plan.config.to_params("paper-triangle3"))  # 4
    robot = RunConfig.from_json(leader.to_json())                             # 5
    spec = spec_of(robot.safety, robot.scenario.dt, robot.scenario.uncertainty)  # 6
    error, _ = robot.scenario.uncertainty.pose_bounds()
    fp = footprint_of(robot.safety.body)
    want = spec_for(fp, robot.safety.limits, robot.scenario.dt, margin=0.17,
                    pose_error=error)
    assert spec.distance == pytest.approx(want.distance)
    assert spec.distance - spec_for(fp, robot.safety.limits, robot.scenario.dt,
                                    margin=0.0, pose_error=error).distance == (
        pytest.approx(0.17))
