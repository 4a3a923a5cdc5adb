"""``formation-ilc keystore create`` and ``launch --secure``'s refusals: one line, exit 2,
before any node starts."""

from __future__ import annotations

import shutil
import subprocess
import sys
from datetime import UTC, datetime, timedelta
from pathlib import Path

import pytest

import msgs_schema as ms
from formation_ilc.cli import keystore as ks_cli
from formation_ilc.config.roster import Lineup, roster
from formation_ilc.config.scenario import load_scenario
from formation_ilc.core.names import clock_topic
from formation_ilc.plan.secure import SecureRun
from formation_ilc.store.keystore import create, enclave_dir


def cli(*args: str, timeout: float = 120) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "formation_ilc.cli", *args],
                          capture_output=True, text=True, timeout=timeout)


def test_the_pure_names_are_msgs_schemas():
    # the grants' names (formation_ilc.core.names, no ROS) are what the nodes use
    assert (ms.CONFIG, ms.REFERENCE, ms.TRIAL_EVENTS, ms.READY, ms.DIAGNOSTICS,
            clock_topic(ms.NAMESPACE), ms.LEADER) == (
        "config", "leader/reference", "leader/trial_events", "ready", "diagnostics", "/clock",
        "leader")
    assert [f(7) for f in (ms.pose_topic, ms.cmd_vel_topic, ms.shared_pose_topic,
                           ms.trajectory_topic, ms.true_trajectory_topic)] == [
        f"robot_7/{t}" for t in ("pose", "cmd_vel", "shared_pose", "trajectory",
                                 "true_trajectory")]
    assert ms.link_topic(2, "leader") == "robot_2/links/leader"
    # the e-stop, the frames and each robot's body are recorded too (issue 54)
    assert ms.recorded_topics(3) == [t for t, _, _ in ms.topic_table(3)] == [
        "config", "leader/reference", "leader/trial_events", "ready", "diagnostics",
        "/clock", "estop", "/tf", "/tf_static"] + [
            f"robot_{i}/{t}" for i in range(1, 4)
            for t in ("pose", "cmd_vel", "trajectory", "true_trajectory",
                      "robot_description")]
    assert ms.view_topics(3) == [t for t, _, _ in ms.view_topic_table(3)]


def test_the_live_view_reads_everything_and_commands_nothing():
    sc = load_scenario("paper-triangle3")
    grants = ks_cli.grants_for(sc, ms.NAMESPACE)
    live, rec = grants["/formation/liveview"], grants["/formation/recorder"]
    view = {f"/formation/{t}" for t, _, _ in ms.view_topic_table(sc.n)}
    assert set(live.publish) == view and view <= set(rec.publish)
    assert set(rec.subscribe) <= set(live.subscribe)
    assert not any("cmd_vel" in t or "trial_events" in t for t in live.publish)


def test_clock_follows_the_launchers_remapping():
    from formation_ilc.core.names import namespace_remaps

    assert clock_topic(ms.NAMESPACE) == ms.CLOCK and namespace_remaps(ms.NAMESPACE) == []
    assert namespace_remaps("/team2")[-1] == f"{ms.CLOCK}:={clock_topic('/team2')}"


def test_every_process_of_a_launch_has_an_enclave(tmp_path):
    from tests.cli.test_plan import plan_of

    sc = load_scenario("paper-triangle3")
    for plant, extra in (("sim", ("--links", "emulated")), ("sim", ("--links", "direct")),
                         ("pioneer", ("--fake-drivers",))):
        grants = ks_cli.grants_for(sc, ms.NAMESPACE, plant=plant)
        plan = plan_of(tmp_path, "paper-triangle3", "--plant", plant, *extra, "--record",
                       str(tmp_path / "run.mcap"), out=f"{plant}-{extra[-1]}")
        names = [s.name for s in plan.nodes]
        assert "recorder" in names and len(names) > sc.n
        for name in [*names, "monitor"]:
            assert f"{ms.NAMESPACE}/{plan.roster.enclave_of(name)}" in grants, (plant, name)


def test_keystore_create_and_rerun(tmp_path):
    ks = tmp_path / "ks"
    first = cli("keystore", "create", str(ks), "paper-triangle3")
    assert first.returncode == 0, first.stderr
    assert f"{ks}: CA: created" in first.stdout
    assert f"{ks}: /formation/robot_2: new identity, permissions signed" in first.stdout
    assert (enclave_dir(ks, "/formation/robot_2") / "permissions.p7s").is_file()
    again = cli("keystore", "create", str(ks), "paper-triangle3")
    assert again.returncode == 0 and "CA: kept" in again.stdout
    assert "new identity" not in again.stdout and "signed" not in again.stdout


def test_keystore_create_bad_input(tmp_path):
    res = cli("keystore", "create", str(tmp_path / "ks"), "no-such-scenario")
    assert res.returncode == 2 and res.stderr.count("\n") == 1
    assert res.stderr.startswith("error: no-such-scenario: ")
    res = cli("keystore", "create", str(tmp_path / "ks"), "paper-triangle3", "--days", "0")
    assert res.returncode == 2 and "--days" in res.stderr
    res = cli("keystore", "create", str(tmp_path / "ks"), "paper-triangle3", "--namespace",
              "team")
    assert res.returncode == 2 and "--namespace" in res.stderr


def secure_launch(tmp_path: Path, ks: Path, *extra: str) -> subprocess.CompletedProcess[str]:
    out = tmp_path / "run"
    res = cli("launch", "paper-triangle3", "--trials", "2", "--out", str(out), "--no-plots",
              "--secure", str(ks), *extra)
    assert not (out / "logs").exists(), "a node was started"
    return res


def one_line_refusal(res: subprocess.CompletedProcess[str], *needles: str) -> None:
    assert res.returncode == 2, res.stdout + res.stderr
    assert res.stderr.count("\n") == 1 and res.stderr.startswith("error: --secure: ")
    for n in needles:
        assert n in res.stderr, res.stderr


def test_secure_launch_missing_keystore(tmp_path):
    one_line_refusal(secure_launch(tmp_path, tmp_path / "nope"), f"{tmp_path / 'nope'}: no "
                     "such keystore folder")


def test_secure_launch_missing_enclave(tmp_path):
    ks = tmp_path / "ks"
    assert cli("keystore", "create", str(ks), "paper-triangle3").returncode == 0
    shutil.rmtree(enclave_dir(ks, "/formation/robot_3"))
    one_line_refusal(secure_launch(tmp_path, ks), "formation/robot_3: missing: no enclave "
                     "for node /formation/robot_3")


def test_secure_launch_keystore_of_a_smaller_formation(tmp_path):
    ks = tmp_path / "ks"
    assert cli("keystore", "create", str(ks), "paper-triangle3").returncode == 0
    res = cli("launch", "paper-hexagon6", "--trials", "2", "--out", str(tmp_path / "run"),
              "--no-plots", "--secure", str(ks))
    one_line_refusal(res, "robot_4: missing: no enclave")


def test_secure_launch_keystore_of_another_scenario_names_a_missing_grant(tmp_path):
    """A paper-hexagon6 keystore has robots 1 to 3 too, with hexagon6's graph: a
    paper-triangle3 run is refused before anything starts, naming a grant it lacks
    (before, it started and the link emulator and robot_3 died three times each)."""
    ks = tmp_path / "ks"
    assert cli("keystore", "create", str(ks), "paper-hexagon6").returncode == 0
    res = secure_launch(tmp_path, ks)
    one_line_refusal(res, "needs what the permissions do not grant: ",
                     "keystore create")
    assert "publish rt/formation/" in res.stderr or "subscribe rt/formation/" in res.stderr


def test_secure_launch_expired_keystore(tmp_path):
    ks = tmp_path / "ks"
    sc = load_scenario("paper-triangle3")
    create(ks, ks_cli.grants_for(sc, ms.NAMESPACE), days=1,
           now=datetime.now(UTC) - timedelta(days=2))
    one_line_refusal(secure_launch(tmp_path, ks), "cert.pem: expired on ")


def test_secure_launch_foreign_ca(tmp_path):
    ks, other = tmp_path / "ks", tmp_path / "other"
    for k in (ks, other):
        assert cli("keystore", "create", str(k), "paper-triangle3").returncode == 0
    robot_3 = enclave_dir(ks, "/formation/robot_3")
    shutil.rmtree(robot_3)
    shutil.copytree(enclave_dir(other, "/formation/robot_3"), robot_3)
    one_line_refusal(secure_launch(tmp_path, ks), "robot_3/identity_ca.cert.pem: another CA "
                     "than the keystore's")


def test_secure_launch_refuses_containers(tmp_path):
    ks = tmp_path / "ks"
    assert cli("keystore", "create", str(ks), "paper-triangle3").returncode == 0
    one_line_refusal(secure_launch(tmp_path, ks, "--container", "2"), "one process per robot")


def test_secure_env_of_a_process(tmp_path):
    run = SecureRun(tmp_path, "/formation")
    # robot i's fake driver runs in the enclave of robot i's driver, as a real one would
    fake = roster(Lineup(3, plant="pioneer", fake_drivers=True)).enclave_of("fake_pioneer_2")
    env = run.env({"A": "1"}, fake)
    assert env["A"] == "1" and env["ROS_SECURITY_ENABLE"] == "true"
    assert env["ROS_SECURITY_STRATEGY"] == "Enforce"
    assert env["ROS_SECURITY_ENCLAVE_OVERRIDE"] == "/formation/driver_2"
    assert run.env({}, "robot_3")["ROS_SECURITY_ENCLAVE_OVERRIDE"] == "/formation/robot_3"


@pytest.mark.parametrize("cmd", [["keystore", "--help"], ["keystore", "create", "--help"]])
def test_help(cmd):
    res = cli(*cmd)
    assert res.returncode == 0 and "keystore" in res.stdout


def test_a_secure_plan_puts_every_process_in_its_enclave(tmp_path, monkeypatch):
    """The plan carries each process's enclave (what its restarts reuse); the loaded Fast DDS
    check is the one thing stubbed (the wheels' library has no security)."""
    import formation_ilc.system.securedds as securedds
    from tests.cli.test_plan import plan_of

    ks = tmp_path / "ks"
    assert cli("keystore", "create", str(ks), "paper-triangle3").returncode == 0
    monkeypatch.setattr(securedds, "check", lambda *a, **k: None)
    monkeypatch.setattr(securedds, "keeps_profile_properties", lambda libs: True)
    monkeypatch.delenv("FASTRTPS_DEFAULT_PROFILES_FILE", raising=False)
    plan = plan_of(tmp_path, "paper-triangle3", "--secure", str(ks), "--record",
                   str(tmp_path / "run.mcap"))
    assert plan.secure is not None and plan.secure.keystore == ks.resolve()
    profile = plan.out / "fastdds-secure.xml"
    for spec in plan.nodes:
        env = dict(spec.env)
        assert env["ROS_SECURITY_ENCLAVE_OVERRIDE"] == f"/formation/{spec.name}", spec.name
        assert env["ROS_SECURITY_STRATEGY"] == "Enforce"
        assert env["ROS_SECURITY_KEYSTORE"] == str(ks.resolve())
        # every process loads the profile with the handshake retries
        assert env["FASTRTPS_DEFAULT_PROFILES_FILE"] == str(profile), spec.name
    assert not any("handshake" in n for n in plan.notes)
    plan.secure.write_profile()
    assert "max_handshake_requests" in profile.read_text()
    insecure = plan_of(tmp_path, "paper-triangle3", out="plain")
    assert insecure.secure is None and all(not s.env for s in insecure.nodes)


def test_a_secure_plan_keeps_the_users_profile_and_warns_of_an_unpatched_rmw(
        tmp_path, monkeypatch):
    """The user's own Fast DDS profile is the base of the run's; an rmw that would drop the
    handshake settings is named in a note before the run (the run still goes: small teams
    start without them)."""
    import formation_ilc.system.securedds as securedds
    from tests.cli.test_plan import plan_of

    ks = tmp_path / "ks"
    assert cli("keystore", "create", str(ks), "paper-triangle3").returncode == 0
    own = tmp_path / "own.xml"
    own.write_text('<profiles xmlns="http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles">'
                   '<data_writer profile_name="mine" is_default_profile="true"/></profiles>')
    monkeypatch.setattr(securedds, "check", lambda *a, **k: None)
    monkeypatch.setattr(securedds, "keeps_profile_properties", lambda libs: False)
    monkeypatch.setenv("FASTRTPS_DEFAULT_PROFILES_FILE", str(own))
    plan = plan_of(tmp_path, "paper-triangle3", "--secure", str(ks))
    assert plan.secure is not None and plan.secure.base_profile == own
    assert any("handshake" in n and "build_secure_dds" in n for n in plan.notes)
    plan.secure.write_profile()
    text = (plan.out / "fastdds-secure.xml").read_text()
    assert 'profile_name="mine"' in text and "handshake_resend_period_gain" in text
    own.write_text("not xml")
    from formation_ilc.plan.specs import NoRun

    with pytest.raises(NoRun) as info:
        plan_of(tmp_path, "paper-triangle3", "--secure", str(ks), out="again")
    assert info.value.status == 2 and str(own) in info.value.message
    assert "\n" not in info.value.message


def test_a_plant_without_grants_is_refused_secure(tmp_path):
    """An external plant's nodes are not the formation's to grant: one line naming the plants
    that have grants (every other plant), before the keystore is even read."""
    from formation_ilc.plan.specs import NoRun
    from tests.cli.test_plan import plan_of

    with pytest.raises(NoRun) as info:
        plan_of(tmp_path, "paper-triangle3", "--plant", "external", "--secure",
                str(tmp_path / "no-keystore"))
    assert info.value.status == 2 and "--plant external" in info.value.message
    assert "sim, physics, pioneer, base" in info.value.message
    assert "\n" not in info.value.message


def test_keystore_create_on_a_file_or_for_an_invalid_driver_namespace(tmp_path):
    """Before: a file given as the keystore folder exited 1 ("afile/private: Not a
    directory"), and --driver-ns 'x{i}{j}' wrote permissions for an invalid name."""
    afile = tmp_path / "afile"
    afile.write_text("hi\n")
    res = cli("keystore", "create", str(afile), "paper-triangle3")
    assert res.returncode == 2 and res.stderr.count("\n") == 1, res.stderr
    assert f"{afile}: exists and is not a folder" in res.stderr
    res = cli("keystore", "create", str(tmp_path / "ks"), "paper-triangle3", "--plant",
              "pioneer", "--driver-ns", "x{i}{j}")
    assert res.returncode == 2 and res.stderr.count("\n") == 1, res.stderr
    assert res.stderr.startswith("error: argument --driver-ns: 'x{i}{j}': robot 1's namespace")
    assert not (tmp_path / "ks").exists()
