"""ROS environment fixtures: a private ROS_DOMAIN_ID per test, localhost discovery, and
clean-up of the Fast DDS shared-memory files that processes killed by a test leave."""

from __future__ import annotations

import itertools
import os
from collections.abc import Iterator

import pytest

from formation_ilc.system.shm import clean_leftovers, fastdds_files

_counter = itertools.count()


def _domains() -> range:
    """The domain ids the tests use: 30-100, or ``FORMATION_ILC_TEST_DOMAINS=LO-HI`` (two
    test runs side by side on one machine, each with a range of its own, never meet)."""
    text = os.environ.get("FORMATION_ILC_TEST_DOMAINS", "30-100")
    try:
        lo, hi = (int(v) for v in text.split("-"))
    except ValueError:
        raise pytest.UsageError(f"FORMATION_ILC_TEST_DOMAINS={text!r}: expected LO-HI, "
                                "e.g. 101-170 (ROS domain ids, 0-232)") from None
    if not 0 <= lo < hi <= 232:
        raise pytest.UsageError(f"FORMATION_ILC_TEST_DOMAINS={text!r}: LO < HI within "
                                "0-232 (ROS domain ids)")
    return range(lo, hi + 1)


#: the free range of domain ids the tests use
DOMAINS = _domains()


def next_domain_id() -> int:
    """Distinct per test in this run, within DOMAINS. Tests run in parallel (pytest-xdist,
    one network namespace for all) each take ids from a share of the range of their own
    (worker k of W: the k-th of W slices), so two tests running at once never meet."""
    worker = os.environ.get("PYTEST_XDIST_WORKER", "")
    count = int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1") or 1)
    if not worker.startswith("gw") or count <= 1:
        return DOMAINS[(os.getpid() * 13 + next(_counter)) % len(DOMAINS)]
    span = len(DOMAINS) // count
    return DOMAINS[int(worker[2:]) * span + next(_counter) % span]


def clean_shm(before: set[str]) -> list[str]:
    """Remove fastrtps_* files created since ``before`` that no live process holds."""
    return clean_leftovers(fastdds_files() - before)


@pytest.fixture
def ros_env(monkeypatch: pytest.MonkeyPatch) -> Iterator[dict[str, str]]:
    """Environment for ROS processes of one test: own domain, localhost discovery.

    Also applied to this process (for a test-side node) and undone afterwards; new
    Fast DDS shared-memory files that no process holds any more are removed at the end.
    """
    domain = next_domain_id()
    monkeypatch.setenv("ROS_DOMAIN_ID", str(domain))
    monkeypatch.setenv("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    before = fastdds_files()
    env = dict(os.environ)
    yield env
    clean_shm(before)


@pytest.fixture
def netns_support() -> None:
    """Robots in network namespaces can run here (root, ip, iptables): skips saying what is
    missing, or fails where they are required (FORMATION_ILC_REQUIRE_NETNS=1: CI)."""
    from formation_ilc.system.netns import support_problem

    problem = support_problem()
    if problem and os.environ.get("FORMATION_ILC_REQUIRE_NETNS") == "1":
        pytest.fail(f"robots in network namespaces: {problem} (required here: CI)")
    if problem:
        pytest.skip(f"robots in network namespaces: {problem}")


@pytest.fixture
def context(ros_env):
    """A private rclpy Context for an in-process node test, shut down afterwards."""
    import rclpy
    from rclpy.context import Context

    ctx = Context()
    rclpy.init(context=ctx)
    yield ctx
    rclpy.try_shutdown(context=ctx)


@pytest.fixture
def executor(context):
    """An executor in ``context`` and a list of nodes destroyed with it afterwards."""
    from rclpy.executors import SingleThreadedExecutor

    ex = SingleThreadedExecutor(context=context)
    nodes: list = []
    yield ex, nodes
    ex.shutdown()
    for n in nodes:
        n.destroy_node()


#: stack tests that mostly wait on the wall clock (wall-clock and realtime trials, a
#: watchdog's bounds): with the suite side by side (pytest-xdist) they run one after
#: another in one test process, the ``clock`` lane, while the other stack tests (lockstep
#: runs that take all the CPU they get) run one after another in another, the ``lockstep``
#: lane (``pytest_xdist_make_scheduler``); the tests that wait for a bound run in a third,
#: the ``waits`` lane (WAIT_TESTS); in-process tests fill in beside them. One lockstep lane
#: and one clock lane, not more: two lockstep runs at once on two cores only slow each
#: other, and a realtime run needs the cores a third lockstep stack would take. Tests in
#: one lane run in file order, so runs shared through tests/stack/shared.py are made before
#: they are read.
CLOCK_FILES = ("test_pioneer.py", "test_realtime.py", "test_base_physics.py",
               "test_diagnostics.py", "test_clocks.py")
# (Loaded by two other sessions, the lockstep lane was the critical path, 1,582 s of a
# 1,624 s suite against the clock lane's 1,034 s, and test_faults.py here evened them:
# 1,309 s. On a quiet machine the clock lane's waits do not shrink while the lockstep
# runs do: a fresh-clone CI took 1,218 s with it here against 1,103 s before. 2026-12-07.)
CLOCK_TESTS = ("test_secure_pioneer_bridges_and_fake_drivers",
               "test_secure_bases_with_physics_bases_equal_the_insecure_run",
               "test_lossy_links_across_namespaces")
#: the stack tests that mostly wait for a bound to pass (a freeze's, a start-up's, a host
#: that never comes or comes back), the ``waits`` lane: they take little CPU, so they run
#: beside both other lanes. (A quiet full run, 2026-12-07, forked starts: the lockstep lane
#: 911 s of a 931 s suite, the clock lane 845 s; these were 102 s of the one, 71 of the
#: other.)
WAIT_TESTS = ("test_robots_frozen_in_start_up_and_in_trial_1_are_named_and_restarted",
              "test_a_host_that_never_starts_is_named_first_with_the_command_that_starts_it",
              "test_a_start_up_that_cannot_complete_names_the_unmatched_endpoints",
              "test_a_run_waiting_for_a_node_that_never_comes_stops_naming_it",
              # a short lockstep run, most of its 22 s waiting for a host to come back
              "test_four_host_launchers_run_the_team_and_a_killed_host_rejoins")


def lane(nodeid: str) -> str | None:
    """The lane of a test (``clock``, ``waits`` or ``lockstep``), or None: what is not a
    stack test runs wherever a test process is free."""
    path, _, name = nodeid.partition("::")
    if not path.startswith("tests/stack/"):
        return None
    base = name.split("[", 1)[0]
    if base in WAIT_TESTS:
        return "waits"
    return "clock" if path.rsplit("/", 1)[1] in CLOCK_FILES or base in CLOCK_TESTS \
        else "lockstep"


#: the longest tests outside the lanes (seconds in a loaded run, 2026-12-07): handed out
#: first, before the short ones (longest first), so that none is left to run alone at the
#: end while the other test processes have finished
LONG_FIRST = ("test_tune_hexagon_meets_issue_targets",  # 424
              "test_a_sample_of_the_families_on_the_physics_plant_never_touches",  # 260
              "test_edit_of_a_called_module_is_compiled_and_an_unchanged_tree_loads_the_cache",
              "test_a_hundred_generated_formations_never_overlap_through_the_filter",  # 95
              "test_dask_cluster_table_equals_local_pool",  # 37
              "test_sigkill_midway_then_resume_gives_the_same_table",  # 32
              "test_pool_table_equals_serial_table",  # 27
              "test_any_64_bytes_of_the_first_chunk_overwritten_keep_every_other_trial",
              "test_the_chords_errors_bound_the_carry_from_both_sides_and_no_more")


def pytest_sessionstart(session):
    """With test processes side by side (pytest-xdist), the batch simulator's kernels are
    compiled once here before they start, not by every first test of each at once (a
    cold cache, as in a fresh clone: 43 s alone, and the lanes' first tests, a tuning's
    pool and the studies would each compile the same kernels on two cores); a warm cache
    loads in a second."""
    import subprocess
    import sys

    if hasattr(session.config, "workerinput") or not session.config.getoption(
            "numprocesses", None) or os.environ.get("NUMBA_DISABLE_JIT") == "1":
        return
    code = ("from formation_ilc.config.scenario import load_scenario\n"
            "from formation_ilc.model.simulate import simulate\n"
            "simulate(load_scenario('paper-triangle3'), 1)\n")
    subprocess.run([sys.executable, "-c", code], timeout=1800, check=False)


def pytest_collection_modifyitems(session, config, items):
    """The tests outside the lanes in LONG_FIRST's order ahead of the rest (a stable
    sort: the lanes keep their file order, which the runs they share depend on)."""
    def rank(item) -> int:
        if lane(item.nodeid) is not None:
            return -1
        name = item.name.split("[", 1)[0]
        return LONG_FIRST.index(name) if name in LONG_FIRST else len(LONG_FIRST)

    items.sort(key=rank)


def pytest_xdist_make_scheduler(config, log):
    """pytest-xdist's scheduler with the lanes as units of work: every test of a lane goes
    to one test process, in file order; every other test is a unit of its own."""
    from xdist.scheduler import LoadScopeScheduling

    class Lanes(LoadScopeScheduling):
        def _split_scope(self, nodeid: str) -> str:
            return lane(nodeid) or nodeid

    return Lanes(config, log)
