"""The bridge as a managed node (``lifecycle:=true``), driven through the standard
lifecycle services as a lab's lifecycle manager drives it: it starts unconfigured and
sends its driver nothing; configure fails while the driver is missing and succeeds once it
is there; activate lets commands through; deactivate sends one zero at once and nothing
after; each transition is one line of its log at INFO (private rclpy Context)."""

from __future__ import annotations

import time

import pytest

pytestmark = pytest.mark.ros

rclpy = pytest.importorskip("rclpy")
from geometry_msgs.msg import Twist  # noqa: E402
from lifecycle_msgs.msg import State, Transition  # noqa: E402
from lifecycle_msgs.srv import ChangeState, GetState  # noqa: E402
from rcl_interfaces.msg import Log  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402

import msgs_schema as ms  # noqa: E402

from ..procs import spin_until  # noqa: E402

#: the run's sample period [s] (paper-triangle3): deactivate stops the base within one
SAMPLE = 0.2


def test_a_managed_bridge_moves_its_base_only_while_active(context):
    from formation_ilc.nodes.pioneer_bridge import BridgeNode
    from robot_sim.fake_pioneer import FakePioneer

    bridge = BridgeNode(context=context, parameter_overrides=[
        Parameter("robot_id", value=1), Parameter("scenario", value="paper-triangle3"),
        Parameter("driver_ns", value="/pioneer_1"), Parameter("lifecycle", value=True)])
    manager = rclpy.create_node("manager", context=context)
    ex = SingleThreadedExecutor(context=context)
    ex.add_node(bridge)
    ex.add_node(manager)
    driver = None
    got: list[tuple[float, float, float]] = []  # (arrival, v, omega) on the driver's cmd_vel
    manager.create_subscription(Twist, "/pioneer_1/cmd_vel",
                                lambda m: got.append((time.monotonic(), m.linear.x,
                                                      m.angular.z)), ms.DRIVER_CMD_QOS)
    logs: list[Log] = []  # the bridge's lifecycle lines on /rosout
    manager.create_subscription(Log, "/rosout", lambda m: logs.append(m) if (
        "bridge_1" in m.name and "lifecycle:" in m.msg) else None, 100)
    change = manager.create_client(ChangeState, "/formation/bridge_1/change_state")
    get = manager.create_client(GetState, "/formation/bridge_1/get_state")

    def call(client, req):
        spin_until(ex, client.service_is_ready)
        fut = client.call_async(req)
        spin_until(ex, fut.done)
        return fut.result()

    def transition(tid: int) -> bool:
        return bool(call(change, ChangeState.Request(transition=Transition(id=tid))).success)

    def state() -> int:
        return int(call(get, GetState.Request()).current_state.id)

    def quiet(seconds: float) -> int:
        """Commands that reach the driver in ``seconds``."""
        n = len(got)
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            ex.spin_once(timeout_sec=0.01)
        return len(got) - n

    try:
        assert state() == State.PRIMARY_STATE_UNCONFIGURED
        assert quiet(0.5) == 0  # unconfigured: nothing to the driver
        assert not transition(Transition.TRANSITION_CONFIGURE)  # no driver yet
        assert state() == State.PRIMARY_STATE_UNCONFIGURED
        assert any("odom" in m or "pose" in m for m in bridge.driver_missing())

        driver = FakePioneer(context=context, namespace="/pioneer_1")
        ex.add_node(driver)
        spin_until(ex, lambda: not bridge.driver_missing())
        assert transition(Transition.TRANSITION_CONFIGURE)
        assert state() == State.PRIMARY_STATE_INACTIVE
        assert quiet(0.5) == 0  # inactive: still nothing
        assert not driver.motors

        assert transition(Transition.TRANSITION_ACTIVATE)
        assert state() == State.PRIMARY_STATE_ACTIVE
        spin_until(ex, lambda: len(got) >= 3)  # the bridge's commands flow (idle: zero)
        spin_until(ex, lambda: driver.motors)  # activate: the motors go on

        assert transition(Transition.TRANSITION_DEACTIVATE)
        t_off = time.monotonic()
        assert state() == State.PRIMARY_STATE_INACTIVE
        assert quiet(1.0) <= 1  # at most the zero sent on deactivating, none after
        last = got[-1]
        assert last[1:] == (0.0, 0.0) and last[0] - t_off < SAMPLE

        assert transition(Transition.TRANSITION_ACTIVATE)  # and back
        spin_until(ex, lambda: got[-1][0] > t_off + 1.0)
        assert transition(Transition.TRANSITION_ACTIVE_SHUTDOWN)
        assert state() == State.PRIMARY_STATE_FINALIZED
        n = len(got)
        assert quiet(0.5) <= 1 and got[-1][1:] == (0.0, 0.0) and len(got) >= n
        # one INFO line a transition, as nav2's lifecycle nodes log them
        said = ["configure from unconfigured failed (failure)",
                "configure: unconfigured -> inactive", "activate: inactive -> active",
                "deactivate: active -> inactive", "activate: inactive -> active",
                "shutdown: active -> finalized"]
        spin_until(ex, lambda: len(logs) >= len(said))
        assert [m.msg.split("lifecycle: ", 1)[1] for m in logs] == said
        assert {m.level for m in logs} == {Log.INFO}
    finally:
        ex.shutdown()
        for node in (bridge, manager, driver):
            if node is not None:
                node.destroy_node()
