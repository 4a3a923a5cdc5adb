"""A run's clock settings (``config.clocks``): the emulated clocks each node reads, their
truth, and how they travel in the run configuration and the leader's parameters."""

from __future__ import annotations

import json

import pytest

from formation_ilc.config.clocks import ClockSettings
from formation_ilc.config.runconfig import RunConfig, clocks_param, make_config
from formation_ilc.core.clock import Rejected
from formation_ilc.core.clocksync import EmulatedClock

ORIGIN = 1_795_000_000 * 10**9


def test_each_robot_reads_its_own_seeded_clock_and_the_leader_the_machines():
    cs = ClockSettings(offset_ms=300.0, drift_ppm=100.0, origin_ns=ORIGIN)
    truth = cs.truth(seed=5, n=3)
    assert truth is not None and set(truth) == {"leader", "robot_1", "robot_2", "robot_3",
                                                "bridge_1", "bridge_2", "bridge_3"}
    assert truth["leader"].read(ORIGIN + 7) == ORIGIN + 7
    for i in (1, 2, 3):
        c = truth[f"robot_{i}"]
        assert c == cs.robot_clock(5, i) == EmulatedClock.seeded(5, i, 300.0, 100.0, ORIGIN)
        assert truth[f"bridge_{i}"] == c  # one robot, one machine, one clock
        assert abs(c.offset_ns) <= 300_000_000 and abs(c.drift) <= 100e-6
    assert len({truth[f"robot_{i}"].offset_ns for i in (1, 2, 3)}) == 3
    assert truth["robot_1"] != ClockSettings(offset_ms=300.0, drift_ppm=100.0,
                                             origin_ns=ORIGIN).truth(6, 3)["robot_1"]
    plain = ClockSettings()
    assert not plain.emulated and plain.truth(5, 3) is None and plain.robot_clock(5, 1) is None


@pytest.mark.parametrize("bad", [dict(fallback="guess"), dict(offset_ms=-1.0),
                                 dict(drift_ppm=float("nan")), dict(drift_ppm=1e4)])
def test_settings_out_of_range_are_refused(bad):
    with pytest.raises(ValueError):
        ClockSettings(**bad)


def test_settings_travel_in_the_configuration_and_the_leaders_parameter():
    cs = ClockSettings(sync=False, fallback="own", offset_ms=250.0, drift_ppm=50.0,
                       origin_ns=ORIGIN)
    cfg = make_config("paper-triangle3", mode="realtime", links="direct", clocks=cs)
    back = RunConfig.from_json(json.loads(json.dumps(cfg.to_json())))
    assert back.clocks == cs and back.to_json() == cfg.to_json()
    assert clocks_param(json.dumps(cs.to_json())) == cs and clocks_param("") == ClockSettings()
    # a configuration without clocks (an older recording's) takes the defaults
    old = cfg.to_json()
    del old["clocks"]
    assert RunConfig.from_json(old).clocks == ClockSettings()
    with pytest.raises(Rejected, match="clock settings"):
        RunConfig.from_json({**cfg.to_json(), "clocks": {"sync": "yes"}})
    with pytest.raises(ValueError, match="parameter clocks: JSON of the clock settings"):
        clocks_param('{"offset_ms": -3}')


def test_emulated_clocks_need_a_mode_that_reads_clocks():
    cs = ClockSettings(offset_ms=10.0)
    with pytest.raises(ValueError, match="emulated clocks need mode realtime or wallclock"):
        make_config("paper-triangle3", clocks=cs)
    assert make_config("paper-triangle3", mode="realtime", clocks=cs).clock_exchanges
    # lockstep exchanges nothing: no node reads a clock there
    assert not make_config("paper-triangle3").clock_exchanges
