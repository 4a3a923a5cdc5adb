"""Run files (formation_ilc.cli.runfile, formation_ilc.plan.options), without ROS: a run
file written by ``run-file`` plans the run its options plan; a launch option beside it
overrides its key; a misspelt key or a bad value is refused in one line naming the key;
the resolved run file a launch keeps resumes the run, and so does a run.json of before."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
import yaml

from formation_ilc.cli.commands import build_parser, main
from formation_ilc.cli.launch import _save_run
from formation_ilc.cli.runfile import RUN_YAML, launch_options, plan_of
from formation_ilc.plan.options import FIELD_KEYS, LaunchOptions, option_fields
from formation_ilc.plan.specs import NoRun
from formation_ilc.store.runfile import save_run


def options(*argv: str):
    return build_parser().parse_args(["launch", *argv])


def write_run_file(tmp_path, *argv: str, name: str = "run.yaml"):
    path = tmp_path / name
    assert main(["run-file", *argv, "-o", str(path)]) == 0
    return path


def same_run(a, b) -> None:
    """Two plans of one run: the same configuration (but the run id) and processes."""
    ja, jb = a.config.to_json(), b.config.to_json()
    ja.pop("run_id"), jb.pop("run_id")
    assert ja == jb
    strip = {"run_id", "state_dir"}

    def specs(plan):  # (the recording's path is the run folder's)
        return [(s.name, s.module, s.args if s.name != "recorder" else (),
                 tuple((k, v) for k, v in s.params if k not in strip)) for s in plan.nodes]

    assert specs(a) == specs(b)


def test_every_launch_option_is_a_field_with_the_parsers_declared_default():
    from formation_ilc.cli.launchargs import add_arguments
    from formation_ilc.cli.options import OneLineParser

    p = OneLineParser(add_help=False)
    add_arguments(p)
    defaults = LaunchOptions()
    for action in p._actions:
        assert action.dest in option_fields(), action.dest
        want = getattr(defaults, action.dest)
        got = action.default
        assert (tuple(got) if isinstance(got, list) else got) == want, action.dest
    # every field but the --resume folder, the hosts and this launcher's host has a key
    assert set(option_fields()) - set(FIELD_KEYS) == {"resume", "host_members", "host",
                                                      "scenario_text"}


def test_a_written_run_file_plans_the_run_its_options_plan(tmp_path):
    argv = ("paper-triangle3", "--trials", "3", "--seed", "5", "--links", "direct",
            "--record", str(tmp_path / "rec.mcap"))
    path = write_run_file(tmp_path, *argv)
    text = path.read_text()
    assert "# --seed: random seed" in text and "  seed: 5\n" in text
    assert "record: rec.mcap" in text  # relative to the run file's folder
    direct = plan_of(options(*argv, "--out", str(tmp_path / "a")))
    from_file = plan_of(options(str(path), "--out", str(tmp_path / "b")))
    same_run(direct, from_file)
    assert from_file.record == (tmp_path / "rec.mcap").resolve()
    # an option given beside the run file overrides its key
    seven = launch_options(options(str(path), "--seed", "7"))
    assert seven.seed == 7 and seven.trials == 3 and seven.links == "direct"


def test_host_per_robot_puts_each_robot_on_its_host_and_the_rest_on_ground(tmp_path):
    path = write_run_file(tmp_path, "paper-triangle3", "--host-per-robot")
    hosts = yaml.safe_load(path.read_text())["hosts"]
    assert hosts == {"ground": ["monitor", "virtual_leader", "robot_sim", "link_emulator"],
                     "r1": ["robot_1"], "r2": ["robot_2"], "r3": ["robot_3"]}
    plan = plan_of(options(str(path), "--out", str(tmp_path / "run")))
    assert dict(plan.host_members)["r2"] == ("robot_2",)
    # bridges and fake drivers go with their robot
    path = write_run_file(tmp_path, "paper-triangle3", "--plant", "pioneer", "--fake-drivers",
                          "--allow-contact", "--host-per-robot", name="p.yaml")
    hosts = yaml.safe_load(path.read_text())["hosts"]
    assert hosts["ground"] == ["monitor", "virtual_leader"]
    assert hosts["r1"] == ["fake_pioneer_1", "bridge_1", "robot_1"]


def test_a_run_file_for_the_robots_is_rehearsed_with_its_stand_ins_beside_them(tmp_path):
    # written for the robots (no fake drivers), rehearsed on one machine with them: each
    # fake driver goes on its robot's host by itself (it was "fake_pioneer_1, ... on no
    # host"), and a launch of one host starts its robot's fake driver with it
    path = write_run_file(tmp_path, "paper-triangle3", "--plant", "pioneer", "--allow-contact",
                          "--host-per-robot", "--domain-id", "7")
    assert "fake_pioneer" not in yaml.safe_load(path.read_text())["hosts"]["r1"]
    plan = plan_of(options(str(path), "--fake-drivers", "--out", str(tmp_path / "run")))
    assert plan.host is None and plan.ground
    assert dict(plan.host_members)["r2"] == ("bridge_2", "robot_2", "fake_pioneer_2")
    assert {s.name for s in plan.nodes} >= {"fake_pioneer_1", "fake_pioneer_2",
                                            "fake_pioneer_3", "bridge_1", "robot_1"}
    r2 = plan_of(options(str(path), "--fake-drivers", "--host", "r2", "--out",
                         str(tmp_path / "run2")))
    assert sorted(s.name for s in r2.nodes) == ["bridge_2", "fake_pioneer_2", "robot_2"]
    # a rehearsal's file (fake drivers on the robots' hosts) runs the real drivers too
    path = write_run_file(tmp_path, "paper-triangle3", "--plant", "pioneer", "--fake-drivers",
                          "--allow-contact", "--host-per-robot", name="f.yaml")
    d = yaml.safe_load(path.read_text())
    d["plant"]["fake_drivers"] = False
    path.write_text(yaml.safe_dump(d))
    real = plan_of(options(str(path), "--out", str(tmp_path / "run3")))
    assert dict(real.host_members)["r1"] == ("bridge_1", "robot_1")
    # the physics bases go beside the leader
    path = write_run_file(tmp_path, "paper-triangle3", "--plant", "base", "--time-scale",
                          "1.85", "--allow-contact", "--host-per-robot", name="b.yaml")
    bases = plan_of(options(str(path), "--physics-bases", "--out", str(tmp_path / "run4")))
    assert "physics_bases" in dict(bases.host_members)["ground"]


@pytest.mark.parametrize("edit, line", [
    (lambda d: d.update(safety={**(d.get("safety") or {}), "margn": 0.2}),
     "safety.margn: unknown key (did you mean 'margin'?)"),
    (lambda d: d.update(trails=3), "trails: unknown key (did you mean 'trials'?)"),
    (lambda d: d.update(safty={}), "safty: unknown key (did you mean 'safety'?)"),
    (lambda d: d.update(safety={**(d.get("safety") or {}), "margin": -1}),
     "safety.margin: must be a finite number >= 0, got -1"),
    (lambda d: d["plant"].update(kind="simm"),
     "plant.kind: invalid choice: 'simm' (choose from sim, physics, external, pioneer, base)"
     " (did you mean 'sim'?)"),
    (lambda d: d["run"].update(noise="no"), "run.noise: expected true or false, got 'no'"),
    (lambda d: d["plant"].update(kind="pioneer", base="jackal"),
     "plant.base: --plant pioneer does not use it (it goes with --plant base)"),
    (lambda d: d.update(hosts={"ground": ["virtual_leader", "robot_sim", "link_emulator",
                                          "robot_1", "robot_2", "robot_3"]}),
     "hosts: monitor on no host (every member of the run on one)"),
    (lambda d: d.update(hosts={"ground": ["monitor", "virtual_leader", "robot_sim",
                                          "link_emulator", "robot_1", "robot_2", "robot_3",
                                          "robot_4"]}),
     "hosts: ground: 'robot_4' is no member of this run"),
])
def test_a_bad_run_file_is_refused_in_one_line_naming_the_key(tmp_path, capsys, edit, line):
    path = write_run_file(tmp_path, "paper-triangle3")
    d = yaml.safe_load(path.read_text())
    edit(d)
    path.write_text(yaml.safe_dump(d))
    capsys.readouterr()
    assert main(["launch", str(path), "--out", str(tmp_path / "run")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("error: ") and line in err, err
    assert not (tmp_path / "run" / "logs").exists()  # nothing started


def test_the_resolved_run_file_resumes_and_relaunches_the_run(tmp_path):
    first = plan_of(options("paper-triangle3", "--trials", "4", "--seed", "2", "--out",
                            str(tmp_path / "a"), "--record", str(tmp_path / "a" / "r.mcap")))
    _save_run(first.out, first.run_json, first)
    stored = first.out / RUN_YAML
    text = stored.read_text()
    assert "record: '@run/r.mcap'" in text and f"id: {first.config.run_id}" in text
    assert "mode: lockstep" in text  # resolved: every default filled in
    resumed = plan_of(options("--resume", str(first.out)))
    assert resumed.config.to_json() == first.config.to_json()  # the same run id too
    # launched as a run file: the same run, a new one (its own id, its own recording)
    again = plan_of(options(str(stored), "--out", str(tmp_path / "b")))
    same_run(first, again)
    assert again.config.run_id != first.config.run_id
    assert again.record == (tmp_path / "b" / "r.mcap").resolve()
    # one stored description: run.yaml, no run.json beside it
    assert not (first.out / "run.json").exists()
    # a run.json of a launch before run files resumes it as well
    save_run(first.out, first.run_json)
    stored.unlink()
    legacy = plan_of(options("--resume", str(first.out)))
    assert legacy.config.to_json() == first.config.to_json()


@pytest.mark.parametrize("argv", [
    ("paper-triangle3", "--trials", "3"),
    ("paper-triangle3", "--plant", "pioneer", "--fake-drivers", "--allow-contact"),
    ("paper-triangle3", "--plant", "base", "--base", "turtlebot3", "--time-scale", "2.3",
     "--physics-bases", "--allow-contact", "--alpha-max", "150"),
    ("paper-triangle3", "--plant", "physics", "--allow-contact", "--safety-margin", "0.05"),
    ("paper-triangle3", "--safety", "--time-scale", "1.25", "--mode", "realtime"),
])
def test_a_stored_run_file_holds_every_key_with_its_value_and_plans_the_same_run(
        tmp_path, argv):
    first = plan_of(options(*argv, "--out", str(tmp_path / "a")))
    _save_run(first.out, first.run_json, first)
    text = (first.out / RUN_YAML).read_text()
    d = yaml.safe_load(text)

    def leaves(x, path=""):
        if isinstance(x, dict):
            for k, v in x.items():
                yield from leaves(v, f"{path}.{k}" if path else str(k))
        else:
            yield path, x

    values = dict(leaves({k: v for k, v in d.items() if k != "hosts"}))
    assert [k for k, v in values.items() if v is None] == [], text
    # no 0 standing for "the preset's" or "the scenario's"
    assert [k for k, v in values.items() if type(v) in (int, float) and v == 0
            and k.startswith(("plant.", "run."))] == []
    assert values["run.seed"] == first.config.scenario.seed and values["out"] == "."
    assert values["network.domain_id"] == first.domain
    assert values["network.namespace"] == first.namespace
    # launched again elsewhere: the same run
    again = plan_of(options(str(first.out / RUN_YAML), "--out", str(tmp_path / "b")))
    same_run(first, again)
    assert again.config.safety == first.config.safety
    if first.config.safety is not None:  # where the speeds came from, as the run took it
        assert values["safety.motion"] == first.config.safety.motion


def test_a_stored_run_files_paths_are_its_own_wherever_it_was_launched_from(
        tmp_path, monkeypatch):
    # given relative to the caller's folder, they were written so, and read relative to the
    # stored file: a launch of OUT/run.yaml recorded into OUT/runs/a/...
    (tmp_path / "work").mkdir()
    monkeypatch.chdir(tmp_path / "work")
    memory = tmp_path / "work" / "sim" / "memory.npz"
    from formation_ilc.cli.commands import main as cli

    assert cli(["simulate", "paper-triangle3", "--trials", "1", "--no-plots", "--out",
                "sim"]) == 0
    assert memory.is_file()
    first = plan_of(options("paper-triangle3", "--trials", "2", "--out", "runs/a",
                            "--record", "runs/a/run.mcap", "--init-memory", "sim/memory.npz"))
    _save_run(first.out, first.run_json, first)
    d = yaml.safe_load((first.out / RUN_YAML).read_text())
    assert d["recording"]["record"] == "@run/run.mcap"
    assert d["run"]["init_memory"] == "../../sim/memory.npz"  # relative to the file
    monkeypatch.chdir(tmp_path)
    before = sorted(p.relative_to(first.out) for p in first.out.rglob("*"))
    again = plan_of(options(str(first.out / RUN_YAML), "--out", "new"))
    assert again.out == (tmp_path / "new").resolve()
    assert again.record == (tmp_path / "new" / "run.mcap").resolve()
    assert again.init_memory is not None and again.init_memory.resolve() == memory.resolve()
    assert sorted(p.relative_to(first.out) for p in first.out.rglob("*")) == before
    resumed = plan_of(options("--resume", str(first.out)))
    assert resumed.record == first.record and resumed.init_memory.resolve() == memory
    # launched again without --out: its folder is the run's, which is taken
    with pytest.raises(NoRun, match="holds another run"):
        plan_of(options(str(first.out / RUN_YAML)))


def test_the_options_value_is_frozen_and_typed():
    opts = launch_options(options("paper-triangle3", "--plant-nodes", "a", "b",
                                  "--init-memory", "m.npz"))
    assert opts.plant_nodes == ("a", "b") and opts.init_memory is not None
    with pytest.raises(dataclasses.FrozenInstanceError):
        opts.seed = 3  # type: ignore[misc]
    with pytest.raises(NoRun, match="no run.yaml or run.json there"):
        plan_of(options("--resume", "/nonexistent-run-folder-38"))


@pytest.mark.parametrize("argv, line", [
    (("--params-file", "p.yaml"), "argument --params-file: --plant sim does not use it (it "
                                  "goes with --plant pioneer or base)"),
    (("--base", "jackal"), "argument --base: --plant sim does not use it (it goes with "
                           "--plant base)"),
    (("--v-max", "0.5"), "argument --v-max: --plant sim does not use it"),
    (("--tilt-limit", "5"), "argument --tilt-limit: --plant sim does not use it (it goes "
                            "with --plant physics or --physics-bases: their bodies tilt)"),
    (("--on-contact", "abort"), "argument --on-contact: --plant sim does not use it"),
])
def test_an_option_the_plant_does_not_use_is_refused(tmp_path, argv, line):
    with pytest.raises(NoRun) as info:
        plan_of(options("paper-triangle3", *argv, "--out", str(tmp_path / "run")))
    assert info.value.status == 2 and info.value.message.startswith(line)


def full_paths(prefixes: dict[str, bytes]) -> list[str]:
    """The enclave folders (``formation/robot_1``) of ``enclave_prefixes``' names."""
    return [name.strip("/") for name in prefixes]


def test_keystore_create_of_a_run_file_writes_one_bundle_per_host(tmp_path):
    pytest.importorskip("cryptography")
    from formation_ilc.store.keystore import verify

    path = write_run_file(tmp_path, "paper-triangle3", "--host-per-robot", "--domain-id", "7")
    ks = tmp_path / "keys"
    assert main(["keystore", "create", str(ks), str(path), "--days", "2"]) == 0
    held = {h: sorted(str(p.relative_to(ks / "bundles" / h / "enclaves"))
                      for p in (ks / "bundles" / h / "enclaves").glob("*/*"))
            for h in ("ground", "r1", "r2", "r3")}
    assert held["r2"] == ["formation/robot_2"]
    assert held["ground"] == ["formation/link_emulator", "formation/monitor",
                              "formation/robot_sim", "formation/virtual_leader"]
    for h in held:  # the CA's certificate, never its key
        assert (ks / "bundles" / h / "public" / "ca.cert.pem").is_file()
        assert not (ks / "bundles" / h / "private").exists()
    verify(ks / "bundles" / "r2", ["/formation/robot_2"])
    # every host pins every member's name to its enclave: the other members' certificates
    # (never a key) ride in its bundle's public part
    from formation_ilc.store.keystore import MEMBER_CERTS, enclave_prefixes

    full = enclave_prefixes(ks, "/formation")
    for h in held:
        public = ks / "bundles" / h / MEMBER_CERTS
        assert not list(public.rglob("key.pem"))
        assert sorted(str(p.parent.relative_to(public)) for p in public.rglob("cert.pem")) \
            == sorted(set(full_paths(full)) - set(held[h]))
        assert enclave_prefixes(ks / "bundles" / h, "/formation") == full
    # a certificate of another CA, or one filed under another enclave, is not taken
    other = tmp_path / "other"
    assert main(["keystore", "create", str(other), str(path), "--days", "2"]) == 0
    public = ks / "bundles" / "r2" / MEMBER_CERTS / "formation"
    (public / "robot_1" / "cert.pem").write_bytes(
        (other / "enclaves" / "formation" / "robot_1" / "cert.pem").read_bytes())
    (public / "robot_3" / "cert.pem").write_bytes(
        (public / "virtual_leader" / "cert.pem").read_bytes())
    got = enclave_prefixes(ks / "bundles" / "r2", "/formation")
    assert set(full) - set(got) == {"/formation/robot_1", "/formation/robot_3"}
    # a host launcher refuses a member whose enclave its bundle does not hold, naming it
    with pytest.raises(NoRun, match=r"--secure: .*formation/robot_2: missing: no enclave "
                                    r"for node /formation/robot_2"):
        plan_of(options(str(path), "--host", "r2", "--secure", str(ks / "bundles" / "r1")))


def test_a_scenario_written_in_the_run_file_is_kept_in_the_runs_folder(tmp_path):
    from formation_ilc.config.scenario import load_scenario

    path = write_run_file(tmp_path, "paper-triangle3", "--trials", "2")
    d = yaml.safe_load(path.read_text())
    d["scenario"] = yaml.safe_load(load_scenario("paper-triangle3").text)
    path.write_text(yaml.safe_dump(d))
    inline = plan_of(options(str(path), "--out", str(tmp_path / "a")))
    named = plan_of(options("paper-triangle3", "--trials", "2", "--out", str(tmp_path / "b")))
    assert inline.scenario.name == "paper-triangle3" and inline.scenario.trials == 2
    assert np.array_equal(inline.scenario.desired.eta, named.scenario.desired.eta)
    kept = tmp_path / "a" / "scenario.yaml"
    assert kept.is_file() and dict(params(inline, "virtual_leader"))["scenario"] == str(kept)
    # a bad one is refused as a scenario file is
    d["scenario"]["robots"] = 0
    path.write_text(yaml.safe_dump(d))
    assert main(["launch", str(path), "--out", str(tmp_path / "c")]) == 2


def params(plan, name):
    return next(s.params for s in plan.nodes if s.name == name)


@pytest.mark.parametrize("value", ["1e9", "0", "nan"])
def test_a_tilt_limit_no_plant_takes_is_refused_before_any_node_starts(capsys, value):
    """``--tilt-limit`` is checked by the launcher against the range the physics plant
    and the physics bases take (issue 39: it used to start every process, then the
    physics node refused it and the launch exited 1)."""
    with pytest.raises(SystemExit) as info:
        build_parser().parse_args(["launch", "paper-triangle3", "--plant", "physics",
                                   "--tilt-limit", value])
    assert info.value.code == 2
    err = capsys.readouterr().err.strip()
    assert f"argument --tilt-limit: must be a number in 0.1..180 deg, got {value}" in err


def test_a_keystore_where_none_can_be_made_is_refused_in_one_line(tmp_path, capsys):
    """``keystore create`` into a folder that cannot be made (in /proc, a folder whose
    files are the kernel's, root or not): status 2 and one line naming the path (it used
    to exit 1)."""
    pytest.importorskip("cryptography")
    where = "/proc/formation-ilc-keys"
    assert main(["keystore", "create", where, "paper-triangle3"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"error: {where}: cannot make the keystore "
                                               f"there: ")


def test_a_run_file_changes_a_scenarios_gains_without_copying_it(tmp_path, capsys):
    """``scenario: {from: NAME, ...}``: the named scenario with only the keys written here
    changed (a mapping key by key); a bad name is refused naming ``scenario.from``."""
    path = tmp_path / "run.yaml"
    path.write_text("scenario: {from: paper-triangle3, law: {gain: 0.05}, trials: 4}\n")
    plan = plan_of(options(str(path), "--out", str(tmp_path / "run")))
    base = plan_of(options("paper-triangle3", "--out", str(tmp_path / "base")))
    assert plan.scenario.law.gain == (0.05,) * 3 and base.scenario.law.gain == (0.08,) * 3
    assert plan.scenario.law.gain_prime == base.scenario.law.gain_prime
    assert plan.scenario.n == 3 and plan.scenario.dt == base.scenario.dt
    path.write_text("scenario: {from: paper-triangel3}\n")
    assert main(["launch", str(path), "--out", str(tmp_path / "bad")]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"error: {path}: scenario.from: ") and "paper-triangle3" in err, err


def test_a_refusal_of_a_value_from_a_run_file_names_its_key(tmp_path, capsys):
    """The planner's refusals name flags; for a value the run file set they name its key
    (issue 53: ``argument --base`` for a file's plant.base)."""
    path = tmp_path / "run.yaml"
    path.write_text("scenario: paper-triangle3\nplant: {kind: physics, physics_rate: 3}\n")
    assert main(["launch", str(path), "--out", str(tmp_path / "a")]) == 2
    assert capsys.readouterr().err.startswith(f"error: {path}: plant.physics_rate: 3: ")
    path.write_text("scenario: paper-triangle3\nsafety: {enabled: true, margin: 0.5}\n")
    assert main(["launch", str(path), "--out", str(tmp_path / "b")]) == 2
    assert f"lower safety.margin in {path}," in capsys.readouterr().err
    # given on the command line, the flag is named
    assert main(["launch", str(path), "--safety-margin", "0.6", "--out",
                 str(tmp_path / "c")]) == 2
    assert "lower --safety-margin," in capsys.readouterr().err


def test_a_run_files_robots_give_one_robot_its_host_driver_and_start(tmp_path, capsys):
    """``robots: {I: {host, driver_ns, start}}``: what robot I does not share with the
    team; its host places its node and bridge (the rest on 'ground'), its driver namespace
    and start pose go to its bridge only. A robot the scenario has not, or a misspelt key,
    is refused naming it."""
    path = tmp_path / "run.yaml"
    path.write_text("scenario: paper-triangle3\nplant: {kind: pioneer, allow_contact: true}\n"
                    "robots: {2: {host: r2, driver_ns: /RosAria, start: [0.5, 1.0, 5 deg]}}\n")
    plan = plan_of(options(str(path), "--out", str(tmp_path / "run")))
    hosts = dict(plan.host_members)
    assert sorted(hosts["r2"]) == ["bridge_2", "robot_2"]
    assert {"virtual_leader", "monitor", "robot_1", "bridge_3"} <= set(hosts["ground"])
    params = {s.name: dict(s.params) for s in plan.nodes}
    assert params["bridge_2"]["driver_ns"] == "/RosAria"
    assert params["bridge_2"]["initial_pose"] == pytest.approx([0.5, 1.0, math.radians(5)])
    assert params["bridge_1"]["driver_ns"] == "/pioneer_1"
    assert "initial_pose" not in params["bridge_1"]
    # the written file keeps the section, and reads back the same
    out = write_run_file(tmp_path, str(path), "--allow-contact", name="again.yaml")
    again = plan_of(options(str(out), "--out", str(tmp_path / "again")))
    assert dict(again.host_members)["r2"] == hosts["r2"]
    for text, line in (("{7: {host: r7}}", "robots: 7: no such robot (robots are 1..3)"),
                       ("{2: {hots: r2}}", f"{path}: robots.2.hots: unknown key"),
                       ("{2: {start: [1, 2]}}", f"{path}: robots.2.start: expected [x, y, theta]")):
        path.write_text("scenario: paper-triangle3\nplant: {kind: pioneer, allow_contact: "
                        f"true}}\nrobots: {text}\n")
        assert main(["launch", str(path), "--out", str(tmp_path / "bad")]) == 2
        assert line in capsys.readouterr().err
