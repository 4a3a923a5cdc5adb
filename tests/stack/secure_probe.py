"""A participant that tries things on a formation's domain; prints one JSON line.

    python tests/stack/secure_probe.py SECONDS NAME OP...

(Started by tests/stack/test_secure.py with the environment of the identity under test:
none, another node's enclave, or another CA's.) Joins namespace /formation as node NAME,
then for SECONDS listens and publishes. Each OP is ``listen:TOPIC:TYPE`` (count what
arrives), ``publish:TOPIC:TYPE`` (create a writer, then publish a forged message every
20 ms) or ``call:SERVICE:Trigger`` (create a client, then call the service whenever it is
there; ``received`` counts the answers). The result names, per OP, whether its reader,
writer or client was created (and the error if not), the messages received, and the most
peers it matched.
"""

from __future__ import annotations

import json
import sys
import time
from typing import Any

import rclpy
from geometry_msgs.msg import PoseStamped, Twist
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter
from std_msgs.msg import Bool, String
from std_srvs.srv import Trigger

import msgs_schema as ms

TYPES: dict[str, Any] = {"Twist": Twist, "PoseStamped": PoseStamped, "String": String,
                         "Bool": Bool, "Trigger": Trigger}


def forged(kind: str) -> Any:
    if kind == "Twist":
        t = Twist()
        t.linear.x, t.angular.z = 2.0, 3.0  # a hard turn: any robot it reached would deviate
        return t
    if kind == "Bool":  # an e-stop: it would stop the run
        return Bool(data=True)
    if kind == "String":  # a trial event as the leader would send it
        return String(data=json.dumps({"event": "abort", "trial": 0, "slot": 0, "seq": 99999}))
    return ms.pose_to_msg([5.0, 5.0, 0.0], 0, ms.WORLD_FRAME)


def kind_of(op: str) -> str:
    return op.split(":")[2]


def main() -> int:
    seconds, name, ops = float(sys.argv[1]), sys.argv[2], sys.argv[3:]
    ctx = Context()
    rclpy.init(context=ctx)
    result: dict[str, Any] = {"ops": {}}
    try:
        try:
            # no services of its own (parameters, type descriptions): an identity's
            # permissions grant them under its member's node name only, and an operator
            # on the ground station is another node in the monitor's enclave
            node = rclpy.create_node(name, namespace=ms.NAMESPACE, context=ctx,
                                     start_parameter_services=False,
                                     parameter_overrides=[Parameter(
                                         "start_type_description_service", value=False)])
        except Exception as exc:  # noqa: BLE001 - a refused participant is a result
            print(json.dumps({"node_error": str(exc).splitlines()[0]}))
            return 0
        ends: list[tuple[str, Any, Any]] = []
        for op in ops:
            what, topic, kind = op.split(":")
            entry: dict[str, Any] = {"created": False, "received": 0, "matched": 0}
            result["ops"][op] = entry
            try:
                if what == "call":
                    ends.append((op, node.create_client(TYPES[kind], topic), "call"))
                elif what == "listen":
                    def count(_msg: Any, e: dict[str, Any] = entry) -> None:
                        e["received"] += 1
                    ends.append((op, node.create_subscription(TYPES[kind], topic, count,
                                                              ms.SAMPLE_QOS), None))
                else:
                    ends.append((op, node.create_publisher(TYPES[kind], topic, ms.SAMPLE_QOS),
                                 forged(kind)))
                entry["created"] = True
            except Exception as exc:  # noqa: BLE001 - refused at creation: the result
                entry["error"] = str(exc).splitlines()[0]
        ex = SingleThreadedExecutor(context=ctx)
        ex.add_node(node)
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline:
            for op, end, msg in ends:
                e = result["ops"][op]
                if isinstance(msg, str):  # a client: call whenever the service is there
                    pending = e.setdefault("_pending", [])
                    if end.service_is_ready() and not pending:
                        e["matched"] = 1
                        pending.append(end.call_async(TYPES[kind_of(op)].Request()))
                    if pending and pending[0].done():
                        e["received"] += 1
                        pending.clear()
                elif msg is None:
                    e["matched"] = max(e["matched"], end.get_publisher_count())
                else:
                    e["matched"] = max(e["matched"], end.get_subscription_count())
                    end.publish(msg)
            ex.spin_once(timeout_sec=0.02)  # deliver what arrived; paces the forged writes
        ex.shutdown()
        node.destroy_node()
        for entry in result["ops"].values():
            entry.pop("_pending", None)
    finally:
        rclpy.try_shutdown(context=ctx)
    print(json.dumps(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
