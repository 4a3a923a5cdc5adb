"""Messages taken with their writer's GID, for ``protocol.writers.WriterTable`` to judge.

rclpy of ROS 2 Jazzy gives a subscription callback no publisher GID (its ``MessageInfo``
has the timestamps and sequence numbers only; the GID came to rclpy's rolling branch in
2025), and its EventsExecutor passes no ``MessageInfo`` at all. rcl has the GID of each
sample it takes (``rmw_message_info_t.publisher_gid``): a ``CheckedSubscription`` is an
rcl subscription the executor does not take from. rmw calls back (on its own thread) when
a sample arrives; the callback only re-arms a zero-period timer, and the timer's callback,
on the node's executor like any other, takes every waiting sample with
``rcl_take_serialized_message`` and its writer's GID, asks the table, and hands what is
accepted to the handler (deserialized, or as bytes: ``raw``), with the writer's GID.

A steady timer also asks rcl every ``REFRESH_HELD`` seconds (``poll``): under load the
events executor was seen to miss the re-armed timer. A node with several checked
subscriptions runs one such timer for all of them (``GuardedNode.checked_subscription``):
each timer's callback costs a wake-up of the executor, 20 times a second; a topic of one
message a trial is polled every ``REFRESH_TRIAL`` seconds. A sample whose writer the graph
does not name yet is held (``protocol.writers.HOLD``) and judged again as the graph learns
it; so is one of a second participant under a node name another holds (``PIN_HOLD``).
Costs: ``scripts/bench_writers.py``.
"""

from __future__ import annotations

import ctypes
import time
from collections import deque
from collections.abc import Callable
from typing import Any

from rclpy.clock import Clock, ClockType
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.node import Node
from rclpy.serialization import deserialize_message
from rclpy.type_support import check_is_valid_msg_type

from formation_ilc.protocol.writers import OK, UNKNOWN, WriterTable

__all__ = ["CheckedSubscription", "gid_take_available", "REFRESH_HELD", "REFRESH_TRIAL"]

#: rmw_gid_t's storage in Jazzy (RMW_GID_STORAGE_SIZE)
GID_SIZE = 16
#: held samples of writers the graph does not name yet, per subscription
HELD_MAX = 64


class _Allocator(ctypes.Structure):
    _fields_ = [(n, ctypes.c_void_p) for n in
                ("allocate", "deallocate", "reallocate", "zero_allocate", "state")]


class _Bytes(ctypes.Structure):  # rcutils_uint8_array_t (rcl_serialized_message_t)
    _fields_ = [("buffer", ctypes.POINTER(ctypes.c_uint8)), ("buffer_length", ctypes.c_size_t),
                ("buffer_capacity", ctypes.c_size_t), ("allocator", _Allocator)]


class _Gid(ctypes.Structure):  # rmw_gid_t
    _fields_ = [("implementation_identifier", ctypes.c_char_p),
                ("data", ctypes.c_uint8 * GID_SIZE)]


class _Info(ctypes.Structure):  # rmw_message_info_t
    _fields_ = [("source_timestamp", ctypes.c_int64), ("received_timestamp", ctypes.c_int64),
                ("publication_sequence_number", ctypes.c_uint64),
                ("reception_sequence_number", ctypes.c_uint64),
                ("publisher_gid", _Gid), ("from_intra_process", ctypes.c_bool)]


_ON_NEW = ctypes.CFUNCTYPE(None, ctypes.c_void_p, ctypes.c_size_t)
_LIBS: dict[str, Any] = {}


def _libs() -> tuple[Any, Any]:
    if not _LIBS:
        rcl = ctypes.CDLL("librcl.so")
        rcutils = ctypes.CDLL("librcutils.so")
        rcutils.rcutils_get_default_allocator.restype = _Allocator
        rcutils.rcutils_uint8_array_init.argtypes = [
            ctypes.POINTER(_Bytes), ctypes.c_size_t, ctypes.POINTER(_Allocator)]
        rcutils.rcutils_uint8_array_fini.argtypes = [ctypes.POINTER(_Bytes)]
        rcl.rcl_take_serialized_message.argtypes = [
            ctypes.c_void_p, ctypes.POINTER(_Bytes), ctypes.POINTER(_Info), ctypes.c_void_p]
        rcl.rcl_subscription_set_on_new_message_callback.argtypes = [
            ctypes.c_void_p, _ON_NEW, ctypes.c_void_p]
        rcl.rcl_timer_reset.argtypes = [ctypes.c_void_p]
        _LIBS.update(rcl=rcl, rcutils=rcutils)
    return _LIBS["rcl"], _LIBS["rcutils"]


def gid_take_available() -> bool:
    """Whether rcl's take with the writer's GID can be reached (the libraries load)."""
    try:
        _libs()
    except (OSError, AttributeError):
        return False
    return True


class CheckedSubscription:
    """A subscription of ``node`` to ``topic`` whose every sample is judged by its writer
    (``table``: ``judge``, or, with ``shared``, the handler itself calls ``claims`` with
    the GID it gets) before ``handler(msg, gid)`` sees it. Refusals are counted in the
    table; ``on_refused(why)`` (the node's log) hears each. ``poll`` is due every
    ``period`` seconds (``REFRESH_HELD``, or ``REFRESH_TRIAL`` for a topic of one message
    a trial), from ``next_poll`` on; without ``own_poll`` the caller calls it (one timer
    for a node's subscriptions: ``GuardedNode.checked_subscription``)."""

    def __init__(self, node: Node, msg_type: Any, topic: str, qos: Any, table: WriterTable,
                 handler: Callable[[Any, bytes], None], *, raw: bool = False,
                 shared: bool = False, on_refused: Callable[[str], None] | None = None,
                 own_poll: bool = True, period: float = 0.0):
        rcl, rcutils = _libs()
        check_is_valid_msg_type(msg_type)
        self.node, self.msg_type, self.raw, self.shared = node, msg_type, raw, shared
        self.table, self.handler, self.on_refused = table, handler, on_refused
        with node.handle:
            self.handle = _rclpy.Subscription(node.handle, msg_type, topic,
                                              qos.get_c_qos_profile())
        self.topic_name = self.handle.get_topic_name()
        self.held: deque[tuple[float, bytes, bytes]] = deque()
        self._buf = _Bytes()
        alloc = rcutils.rcutils_get_default_allocator()
        rcutils.rcutils_uint8_array_init(ctypes.byref(self._buf), 1024, ctypes.byref(alloc))
        self._info = _Info()
        # on the steady clock: a node on simulated time (lockstep) has no time passing
        # between trials, when readies come
        steady = Clock(clock_type=ClockType.STEADY_TIME)
        self._timer = node.create_timer(0.0, self._drain, clock=steady)
        self._timer.cancel()
        self.period = float(period) if period > 0.0 else REFRESH_HELD
        #: [s, monotonic] when ``poll`` is next due (``GuardedNode``'s timer)
        self.next_poll = 0.0
        self._hold_timer = (node.create_timer(self.period, self.poll, clock=steady)
                            if own_poll else None)
        # rmw's thread only re-arms the timer, in C: rcl_timer_reset(timer) itself is the
        # callback (its one argument is the callback's first, the user data), so rmw's
        # thread never waits for the interpreter (a Python callback there must take the
        # GIL while rmw holds its locks: runs under load stalled)
        self._on_new = ctypes.cast(rcl.rcl_timer_reset, _ON_NEW)
        with self._timer.handle:
            timer_ptr = self._timer.handle.pointer
        rcl.rcl_subscription_set_on_new_message_callback(self.handle.pointer, self._on_new,
                                                         ctypes.c_void_p(timer_ptr))
        self._drain()  # what came before the callback was set

    def get_publisher_count(self) -> int:
        return int(self.handle.get_publisher_count())

    def _take(self) -> tuple[bytes, bytes] | None:
        rcl, _ = _libs()
        with self.handle:
            ret = rcl.rcl_take_serialized_message(self.handle.pointer, ctypes.byref(self._buf),
                                                  ctypes.byref(self._info), None)
        if ret != 0:  # RCL_RET_SUBSCRIPTION_TAKE_FAILED: nothing more
            return None
        return (ctypes.string_at(self._buf.buffer, self._buf.buffer_length),
                bytes(self._info.publisher_gid.data))

    def _drain(self) -> None:
        self._timer.cancel()  # before taking: a sample after the last take re-arms it
        while (got := self._take()) is not None:
            self._judge(*got, time.monotonic())

    def take_waiting(self) -> None:
        """Take and judge at once what waits in rcl (a handler that must see this topic's
        messages before another's: the executor may run the other's callback first)."""
        self._drain()

    def learn_writers(self) -> None:
        """Ask the graph for the topic's writers now (at most every REFRESH seconds)."""
        self._refresh(time.monotonic())

    def _refresh(self, now: float, gid: bytes | None = None) -> None:
        if self.table.due(self.topic_name, now, gid):
            self.table.learn(self.topic_name, (
                (bytes(i.endpoint_gid), i.node_name, i.node_namespace)
                for i in self.node.get_publishers_info_by_topic(self.topic_name)))

    def _judge(self, data: bytes, gid: bytes, now: float, held_since: float | None = None
               ) -> bool:
        """Hand ``data`` on, refuse it, or hold it; False when held (still unknown)."""
        verdict = self.table.judge(self.topic_name, gid)
        if verdict == UNKNOWN:
            self._refresh(now, gid)
            verdict = self.table.judge(self.topic_name, gid)
        if verdict == UNKNOWN:
            since = now if held_since is None else held_since
            if now - since >= self.table.hold_for(self.topic_name, gid):
                verdict = self.table.judge(self.topic_name, gid, patient=True)
                if verdict == UNKNOWN:  # not even listed: never to be known
                    verdict = self.table.expire(self.topic_name)
            else:
                if held_since is None:
                    if len(self.held) >= HELD_MAX:  # a flood of unnamed writers
                        _, _, old_gid = self.held.popleft()
                        self._refused(self.table.expire(self.topic_name))
                    self.held.append((since, data, gid))
                return False
        if verdict != OK:
            self._refused(verdict)
            return True
        self.handler(data if self.raw else deserialize_message(data, self.msg_type), gid)
        return True

    def poll(self) -> None:
        """Every REFRESH_HELD (or REFRESH_TRIAL) seconds: take what waits in rcl (a
        wake-up the executor missed costs at most this period, never a stall) and judge
        the held again."""
        self._drain()
        if not self.held:
            return
        now = time.monotonic()
        for _ in range(len(self.held)):
            since, data, gid = self.held.popleft()
            if not self._judge(data, gid, now, since):
                self.held.append((since, data, gid))

    def _refused(self, why: str) -> None:
        if self.on_refused is not None:
            self.on_refused(why)

    def destroy(self) -> None:
        rcl, rcutils = _libs()
        with self.handle:
            rcl.rcl_subscription_set_on_new_message_callback(self.handle.pointer,
                                                             _ON_NEW(), None)
        self.handle.destroy_when_not_in_use()
        self.node.destroy_timer(self._timer)
        if self._hold_timer is not None:
            self.node.destroy_timer(self._hold_timer)
        rcutils.rcutils_uint8_array_fini(ctypes.byref(self._buf))


#: [s] how often held samples are judged again, and rcl is asked for samples whose wake-up
#: the executor may have missed (rclpy's events executor, with a timer re-armed from rmw's
#: thread under load: seen as a ready taken only at the leader's next watchdog, 20 s on)
REFRESH_HELD = 0.05
#: [s] the same for a topic of one message a trial (a robot's trajectory): a missed
#: wake-up costs its reader at most this once in a while, and a robot's re-checks wake
#: its executor a fifth as often as REFRESH_HELD's
REFRESH_TRIAL = 0.25
