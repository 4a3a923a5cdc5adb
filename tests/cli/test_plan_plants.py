"""The launch plan of the physics plant and of the bridges in front of any base: their
node specs, the options that reach the nodes through the plan and RunConfig.to_params, and
the refusals made before anything starts (limits, predicted contact). No ROS here."""

from __future__ import annotations

import pytest

from formation_ilc.cli.commands import build_parser
from formation_ilc.cli.runfile import plan_of as plan_of_args
from formation_ilc.config.bases import BASES
from formation_ilc.config.runconfig import RunConfig
from formation_ilc.config.scenario import load_scenario
from formation_ilc.plan.specs import NoRun, RunPlan


def plan_of(tmp_path, *argv: str) -> RunPlan:
    return plan_of_args(build_parser().parse_args(["launch", *argv, "--out",
                                                 str(tmp_path / "run")]))


def short(tmp_path) -> str:
    """paper-triangle3 cut to 40 samples (8 s)."""
    scen = tmp_path / "short.yaml"
    scen.write_text(load_scenario("paper-triangle3").text.replace("samples: 140",
                                                                  "samples: 40"))
    return str(scen)


def test_the_kinematic_simulator_keeps_chord_headings_and_its_numbers(tmp_path):
    plan = plan_of(tmp_path, "paper-triangle3", "--trials", "2")
    sc = plan.scenario
    assert sc.headings == "chord" and sc.time_scale == 1.0
    base = load_scenario("paper-triangle3")
    assert (sc.desired.u == base.desired.u).all() and (sc.desired.eta == base.desired.eta).all()
    leader = dict(plan.nodes[0].params)
    assert leader["headings"] == "chord" and leader["time_scale"] == 1.0
    # the one mapping back: the leader's configuration is the plan's
    assert RunConfig.from_params(leader).to_json() == plan.config.to_json()


def test_physics_plant_is_a_node_spec_with_its_options_and_arc_headings(tmp_path):
    pytest.importorskip("pybullet")
    # the Husky's body at the paper's spacing: no room for the safety filter (refused with
    # it, tested below), so without it
    plan = plan_of(tmp_path, "paper-triangle3", "--plant", "physics", "--robot-model",
                   "husky", "--pose", "odometry", "--physics-rate", "480", "--pass-through",
                   "--allow-contact", "--time-scale", "1.5", "--trials", "2", "--no-safety",
                   "--on-contact", "continue", "--contact-retries", "5", "--tilt-limit", "20")
    names = [s.name for s in plan.nodes]
    assert names == ["virtual_leader", "physics_sim", "link_emulator", "robot_1", "robot_2",
                     "robot_3"]
    assert dict(plan.nodes[1].params) == {"timeout": 30.0, "model": "husky",
                                          "pose": "odometry", "collide": False, "rate": 480.0,
                                          "on_contact": "continue", "contact_retries": 5,
                                          "tilt_limit": 20.0}
    assert plan.config.safety is None
    assert plan.nodes[1].module == "robot_sim.physics_node"
    assert plan.team.plants == ("physics_sim",) and plan.true_state
    assert plan.reporters == ("physics_sim", "link_emulator")
    leader = dict(plan.nodes[0].params)
    assert leader["headings"] == "arc" and leader["time_scale"] == 1.5
    assert RunConfig.from_params(leader).to_json() == plan.config.to_json()
    assert plan.scenario.samples == 210  # 140 samples stretched 1.5 times
    # the contact the batch simulator predicts is said before the run, not hidden
    assert len(plan.notes) == 1 and plan.notes[0].startswith(
        "warning: the batch simulator predicts contact from this cold start (u_0 = 0): ")


def test_a_colliding_cold_start_is_refused_with_one_line(tmp_path):
    pytest.importorskip("pybullet")
    with pytest.raises(NoRun) as info:
        plan_of(tmp_path, "paper-triangle3", "--plant", "physics", "--no-safety")
    exc = info.value
    assert exc.status == 2 and "\n" not in exc.message
    assert exc.message.startswith("the batch simulator predicts contact from this cold start")
    assert "robots 2 and 3 overlap" in exc.message and "--allow-contact" in exc.message
    assert "--safety" in exc.message


def test_the_safety_filter_is_on_with_bodies_and_lets_the_cold_start_run(tmp_path):
    pytest.importorskip("pybullet")
    plan = plan_of(tmp_path, "paper-triangle3", "--plant", "physics", "--trials", "30")
    sf = plan.config.safety
    assert sf is not None and sf.body == "p3dx" and sf.sensing == "team"
    # the p3dx row of the one limits table, which the physics model enforces and a
    # Pioneer bridge holds: 0.75 m/s, not the datasheet's 1.2 m/s
    from formation_ilc.config.bases import BASES
    from formation_ilc.model.physics import MODELS

    assert sf.limits == BASES["p3dx"].limits == MODELS["p3dx"].limits
    assert sf.limits.v_max == 0.75 and sf.limits.a_max == 0.3
    # the prediction went through the filter and says what it covered
    assert plan.notes[-1].startswith("the batch simulator predicts no contact in the 30 "
                                     "trials of this run through the safety filter")
    # the robots read it from the leader's configuration
    leader = dict(plan.nodes[0].params)
    assert RunConfig.from_params(leader).safety == sf
    # off on the kinematic simulator unless asked for
    assert plan_of(tmp_path / "s", "paper-triangle3").config.safety is None
    # the physics plant's poses are its own (motion capture's stand-in): no word on them
    assert not [x for x in plan.notes if "odometry" in x]
    # a skid-steer body keeps a wider margin by default: the paper's spacing has no room
    with pytest.raises(NoRun, match="jackal bodies \\+ 0.25 m margin"):
        plan_of(tmp_path / "t", "paper-triangle3", "--safety", "--body", "jackal")
    # with 0.1 m and exact poses it fits (the paper's noise widens the distance the filter
    # keeps by 7 cm: two robots' measured positions may be that far off each other)
    on = plan_of(tmp_path / "t", "paper-triangle3", "--safety", "--body", "jackal",
                 "--safety-margin", "0.1", "--no-noise")
    assert on.config.safety is not None and on.config.safety.body == "jackal"
    assert sf.margin == 0.1 and on.config.safety.margin == 0.1
    # how the memory learns through the filter: by body and by the poses' noise, as
    # measured (docs/safety.md): the paper's noisy triangle ``robust``, exact ``damped``
    assert sf.learning == "robust" and on.config.safety.learning == "split"
    exact = plan_of(tmp_path / "v", "paper-triangle3", "--plant", "physics", "--no-noise")
    assert exact.config.safety is not None and exact.config.safety.learning == "damped"
    told = plan_of(tmp_path / "u", "paper-triangle3", "--safety", "--safety-learning",
                   "freeze")
    assert told.config.safety is not None and told.config.safety.learning == "freeze"


def test_behind_bridges_the_plan_says_which_poses_the_filter_trusts(tmp_path):
    """A rehearsal behind bridges puts the filter on the drivers' wheel odometry, which
    drifts: said in one line before the run, not found out by a contact."""
    plan = plan_of(tmp_path, "paper-triangle3", "--plant", "pioneer", "--fake-drivers",
                   "--trials", "2")
    assert plan.config.safety is not None and plan.config.safety.sensing == "peers"
    (note,) = [x for x in plan.notes if "odometry" in x]
    assert note.startswith("note: the safety filter keeps the robots apart where their "
                           "bridges say they are: each driver's wheel odometry")
    assert "\n" not in note
    bare = plan_of(tmp_path / "n", "paper-triangle3", "--plant", "pioneer", "--fake-drivers",
                   "--trials", "2", "--no-safety")
    assert not [x for x in bare.notes if "odometry" in x]


@pytest.mark.parametrize(("args", "says"), [
    (("--plant", "physics", "--robot-model", "husky"),
     "the desired formation brings robots 1 and 3 to 0.559 m"),
    (("--plant", "physics", "--scenario", "paper-hexagon6"),
     "robot 2: desired acceleration 31.2 m/s^2 at t = 0.0 s exceeds its limit 0.3 m/s^2; "
     "no time scale up to 20 fits (p3dx robots' limits: p3dx: 0.75 m/s, 100 deg/s"),
    (("--plant", "external", "--safety"), "--safety: with --plant external"),
    (("--plant", "physics", "--body", "husky"), "--body goes with --plant sim"),
])
def test_what_the_bodies_or_the_filter_cannot_do_is_refused(tmp_path, args, says):
    pytest.importorskip("pybullet")
    name = "paper-triangle3"
    if "--scenario" in args:
        i = args.index("--scenario")
        name, args = args[i + 1], args[:i] + args[i + 2:]
    with pytest.raises(NoRun) as info:
        plan_of(tmp_path, name, *args)
    assert info.value.status == 2 and says in info.value.message
    assert "\n" not in info.value.message


def test_base_bridges_refuse_a_scenario_beyond_the_preset_then_plan_it_stretched(tmp_path):
    pytest.importorskip("pybullet")
    scen = short(tmp_path)
    args = [scen, "--plant", "base", "--base", "turtlebot4", "--physics-bases", "--no-noise",
            "--trials", "3"]
    with pytest.raises(NoRun) as info:
        plan_of(tmp_path, *args)
    line = info.value.message
    assert line.startswith("robot ") and "exceeds its limit 0.306 m/s; --time-scale " in line
    scale = line.rsplit("--time-scale ", 1)[1].split()[0]
    plan = plan_of(tmp_path, *args, "--time-scale", scale, "--a-max", "2.0")
    assert plan.config.mode == "wallclock" and plan.config.links == "direct"
    names = [s.name for s in plan.nodes]
    assert names == ["virtual_leader", "physics_bases", "bridge_1", "bridge_2", "bridge_3",
                     "robot_1", "robot_2", "robot_3"]
    bases = dict(plan.nodes[1].params)
    assert bases["robots"] == 3 and len(bases["poses"]) == 9
    assert bases["ns_pattern"] == "/base_{i}" and bases["cmd_type"] == "twist_stamped"
    # the physics bases tell each bridge their true pose: the metrics' true columns, and
    # (--pose truth, the default) the pose the bridge samples and returns on, as motion
    # capture would give it in a lab
    assert bases["truth"] is True and plan.true_state
    assert dict(plan.nodes[3].params) == {"robot_id": 2, "driver_ns": "/base_2",
                                          "base": "turtlebot4", "return_timeout": 60.0,
                                          "a_max": 2.0, "truth": True, "pose_topic": "truth"}
    odometry = plan_of(tmp_path, *args, "--time-scale", scale, "--a-max", "2.0", "--pose",
                       "odometry", "--no-safety")
    assert "pose_topic" not in dict(odometry.nodes[3].params)
    assert plan.bridged
    # the physics bases follow the trials and report each (their contacts, issue 37)
    assert plan.reporters == ("bridge_1", "bridge_2", "bridge_3", "physics_bases")
    assert dict(plan.nodes[0].params)["headings"] == "arc"
    assert BASES["turtlebot4"].limits.v_max == 0.306


@pytest.mark.parametrize("argv, message", [
    (["--plant", "sim", "--physics-bases"], "--physics-bases goes with --plant base"),
    (["--plant", "base", "--mode", "lockstep"], "--plant base runs --mode wallclock"),
    (["--plant", "base", "--v-max", "-1"], "--v-max: a limit >= 0 is required"),
])
def test_plant_refusals(tmp_path, argv, message):
    with pytest.raises(NoRun) as info:
        plan_of(tmp_path, "paper-triangle3", *argv)
    assert message in info.value.message and info.value.status == 2


def test_a_memory_past_the_limits_is_held_by_the_filter_or_refused(tmp_path):
    """A warm memory whose commands leave the robots' limits: with the filter the run says
    so (the filter holds them inside); without it the run is refused: never sent."""
    pytest.importorskip("pybullet")
    import numpy as np

    from formation_ilc.store.memoryfile import save_memory

    plan = plan_of(tmp_path / "a", "paper-triangle3", "--plant", "physics", "--trials", "2")
    sc = plan.scenario
    fast = np.zeros((sc.n, sc.samples, 2))
    fast[1, 40:, 0] = 3.0  # robot 2 asked for 3 m/s from t = 8 s: past 0.75 m/s, and a step
    mem = save_memory(tmp_path / "fast.npz", fast, sc)
    plan = plan_of(tmp_path / "b", "paper-triangle3", "--plant", "physics", "--trials", "2",
                   "--init-memory", str(mem), "--allow-contact")
    (note,) = [x for x in plan.notes if x.startswith("note: --init-memory")]
    assert "robot 2: the memory's" in note and "exceeds its limit" in note
    assert "the safety filter holds those commands inside the limits" in note
    with pytest.raises(NoRun) as info:
        plan_of(tmp_path / "c", "paper-triangle3", "--plant", "physics", "--trials", "2",
                "--init-memory", str(mem), "--no-safety", "--allow-contact")
    assert info.value.status == 2 and "would be sent past the robots' limits" \
        in info.value.message
    assert "robot 2" in info.value.message


def test_a_wrong_contact_prediction_is_said():
    import numpy as np

    from formation_ilc.cli.report import contact_warning

    rows = np.zeros((3, 9))
    rows[:, 0] = [0, 1, 2]
    assert contact_warning(True, rows) is None  # predicted none, none happened
    rows[2, 8] = 1
    line = contact_warning(True, rows)
    assert line is not None and "predicted no contact, but robots touched in trial(s) 2" in line
    assert contact_warning(False, rows) is None  # it was predicted (or not predicted at all)
