"""Standard diagnostics (diagnostic_msgs/DiagnosticArray on ``diagnostics``): a node's report
as statuses with levels and key/value pairs (``formation_ilc.protocol.health``), which the
monitor, the recorder and analyze read back without loss, and ROS tools show."""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue

from formation_ilc.protocol.health import (
    DIAG_STATUS_MAX,
    DIAG_VALUES_MAX,
    Status,
    flatten,
    hardware_of,
    node_report,
    plain_value,
    read_statuses,
    statuses,
    task_name,
)
from msgs_schema.convert import ns_to_stamp

__all__ = ["DIAGNOSTICS_TYPE", "DIAG_STATUS_MAX", "DIAG_VALUES_MAX", "diagnostics_to_msg",
           "msg_to_statuses", "msg_to_report", "standard_statuses", "starting_status"]

DIAGNOSTICS_TYPE = "diagnostic_msgs/msg/DiagnosticArray"


def diagnostics_to_msg(report: dict[str, Any], stamp_ns: int, dt: float | None = None,
                       samples: int | None = None, hardware_id: str = "") -> DiagnosticArray:
    """The DiagnosticArray of one node's report (``health.statuses``: levels by the
    documented thresholds; ``dt`` [s] and ``samples`` per trial make the relative ones)."""
    msg = DiagnosticArray()
    msg.header.stamp = ns_to_stamp(stamp_ns)
    for st in statuses(report, dt, samples, hardware_id):
        msg.status.append(DiagnosticStatus(
            level=bytes([st.level]), name=st.name, message=st.message,
            hardware_id=st.hardware_id,
            values=[KeyValue(key=k, value=v) for k, v in flatten(st.values)]))
    return msg


def standard_statuses(msg: DiagnosticArray, node: str, host: str) -> list[DiagnosticStatus]:
    """The statuses of a node's report (``diagnostics_to_msg``) as the standard stream
    carries them: the node's own named ``node: task`` (``health.task_name``), every status
    with a hardware id (its robot, else the host), values as plain text (a string without
    JSON's quotes)."""
    out = []
    for st in msg.status:
        name = task_name(node) if st.name == node else st.name
        out.append(DiagnosticStatus(
            level=st.level, name=name, message=st.message,
            hardware_id=st.hardware_id or hardware_of(node, host),
            values=[KeyValue(key=kv.key, value=plain_value(kv.value)) for kv in st.values]))
    return out


def starting_status(node: str, host: str, message: str) -> DiagnosticStatus:
    """A node's status before its first report (OK: it runs)."""
    return DiagnosticStatus(level=bytes([0]), name=task_name(node), message=message,
                            hardware_id=hardware_of(node, host))


class _Pairs:
    """A status's key/value pairs as ``health.read_statuses`` takes them, read only when
    the count has been checked (a hostile message costs a length check)."""

    def __init__(self, items: Sequence[Any], pair: Any):
        self.items, self.pair = items, pair

    def __len__(self) -> int:
        return len(self.items)

    def __iter__(self) -> Iterator[Any]:
        return (self.pair(x) for x in self.items)


def _status(st: DiagnosticStatus) -> tuple[int, str, str, str, _Pairs]:
    level = st.level[0] if isinstance(st.level, (bytes, bytearray)) else int(st.level)
    return (level, st.name, st.message, st.hardware_id,
            _Pairs(st.values, lambda kv: (kv.key, kv.value)))


def msg_to_statuses(msg: DiagnosticArray) -> list[Status]:
    """Every status of a DiagnosticArray with its fields back (MalformedMessage if one's
    values are not the pairs ``diagnostics_to_msg`` writes, or there are too many:
    ``health.read_statuses``)."""
    return read_statuses(_Pairs(msg.status, _status))  # type: ignore[arg-type]


def msg_to_report(msg: DiagnosticArray, required: Sequence[str] = ()) -> dict[str, Any]:
    """The node's own report in a DiagnosticArray (the status that names its ``node``);
    MalformedMessage if there is none or it lacks a key of ``required``."""
    return node_report(msg_to_statuses(msg), required)
