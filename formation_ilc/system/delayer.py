"""Packet delayer: holds the packets of an NFQUEUE for a drawn delay and drops a fraction.

This kernel has no ``tc netem``; netfilter's NFQUEUE target hands packets to a userspace
program instead, which gives each a verdict (accept or drop) whenever it likes. This is
that program, in plain Python: it speaks the nfnetlink_queue protocol over an AF_NETLINK
socket itself (no compiled dependency, no libnetfilter_queue), so it runs wherever the
kernel has NFQUEUE. Inside a network namespace, as root::

    iptables -A OUTPUT -p udp ! -o lo -j NFQUEUE --queue-num 0 --queue-bypass
    python -m formation_ilc.system.delayer --delay-ms 100 --jitter-ms 50 --loss 0.05 --seed 1

Each packet queued is dropped with probability ``--loss`` (independently), else held for a
delay drawn uniformly from [delay - jitter, delay + jitter] ms (at least 0) and then
accepted. Independent delays reorder packets whose spacing is under the jitter, as a
jittery link does. With ``--queue-bypass`` on the rule, packets pass undelayed whenever no
delayer is bound, so traffic never stalls because the delayer is gone.

It prints one line once the queue is bound (starters wait for it), and on SIGTERM or
SIGINT accepts what it still holds, unbinds, and writes its counts to ``--stats`` (JSON):
packets seen, accepted, dropped, the hold time actually applied (a histogram in 1 ms
bins), how late the verdicts were against the drawn delay, and the kernel's own
counters for this queue (packets the kernel dropped because the queue was full).

No ROS import; the standard library only (``random.Random`` seeded: a run is reproducible in
what it draws, not in when packets arrive).
"""

from __future__ import annotations

import argparse
import errno
import heapq
import json
import os
import random
import select
import signal
import socket
import struct
import sys
import time
from collections import Counter
from pathlib import Path
from typing import Any

__all__ = ["NfQueue", "Delayer", "main"]

# netlink / nfnetlink_queue constants (linux/netlink.h, linux/netfilter/nfnetlink_queue.h)
NETLINK_NETFILTER = 12
SOL_NETLINK = 270
NETLINK_NO_ENOBUFS = 5
NLM_F_REQUEST = 0x1
NLM_F_ACK = 0x4
NLMSG_ERROR = 0x2
NLMSG_DONE = 0x3
NFNL_SUBSYS_QUEUE = 3
NFQNL_MSG_PACKET = 0
NFQNL_MSG_VERDICT = 1
NFQNL_MSG_CONFIG = 2
NFQA_PACKET_HDR = 1
NFQA_VERDICT_HDR = 2
NFQA_CFG_CMD = 1
NFQA_CFG_PARAMS = 2
NFQA_CFG_QUEUE_MAXLEN = 3
NFQNL_CFG_CMD_BIND = 1
NFQNL_CFG_CMD_UNBIND = 2
NFQNL_COPY_PACKET = 2
NF_DROP = 0
NF_ACCEPT = 1
NLA_TYPE_MASK = 0x3FFF

_NLMSGHDR = struct.Struct("=IHHII")  # len, type, flags, seq, pid
_NLATTR = struct.Struct("=HH")       # len, type


def _attr(kind: int, data: bytes) -> bytes:
    raw = _NLATTR.pack(_NLATTR.size + len(data), kind) + data
    return raw + b"\0" * (-len(raw) % 4)


class NfQueue:
    """One nfnetlink_queue, bound over a raw AF_NETLINK socket.

    ``packets()`` returns the ids of the packets the kernel queued (non-blocking);
    ``verdict(id, accept)`` releases one. Needs CAP_NET_ADMIN in the network namespace.
    """

    def __init__(self, queue: int, *, maxlen: int = 8192, copy_range: int = 64):
        self.queue = queue
        self._seq = 0
        #: packets that came while a config message waited for its acknowledgement
        self._backlog: list[int] = []
        self.sock = socket.socket(socket.AF_NETLINK, socket.SOCK_RAW, NETLINK_NETFILTER)
        try:
            self.sock.bind((0, 0))
            # a large receive buffer, so a burst never overflows it (a packet whose
            # message is lost would stay queued in the kernel without a verdict)
            try:
                self.sock.setsockopt(socket.SOL_SOCKET, 33, 8 << 20)  # SO_RCVBUFFORCE
            except OSError:
                self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 8 << 20)
            self.sock.setsockopt(SOL_NETLINK, NETLINK_NO_ENOBUFS, 1)
            self._config(_attr(NFQA_CFG_CMD, struct.pack("=Bx", NFQNL_CFG_CMD_BIND)
                               + struct.pack(">H", socket.AF_INET)))
            self._config(_attr(NFQA_CFG_PARAMS, struct.pack(">IB", copy_range,
                                                            NFQNL_COPY_PACKET))
                         + _attr(NFQA_CFG_QUEUE_MAXLEN, struct.pack(">I", maxlen)))
        except BaseException:
            self.sock.close()
            raise
        self.sock.setblocking(False)
        self._buf = bytearray(1 << 16)

    def _message(self, kind: int, payload: bytes, flags: int) -> bytes:
        self._seq += 1
        # nfgenmsg: family, version 0, resource id (the queue number, big-endian)
        body = struct.pack("=BB", socket.AF_UNSPEC, 0) + struct.pack(">H", self.queue) + payload
        return _NLMSGHDR.pack(_NLMSGHDR.size + len(body), (NFNL_SUBSYS_QUEUE << 8) | kind,
                              flags, self._seq, 0) + body

    def _config(self, attrs: bytes) -> None:
        """Send a config message and wait for the kernel's acknowledgement (or error)."""
        self.sock.send(self._message(NFQNL_MSG_CONFIG, attrs, NLM_F_REQUEST | NLM_F_ACK))
        seq = self._seq
        while True:
            data = self.sock.recv(1 << 16)
            self._backlog += _packet_ids(data)
            for kind, _, mseq, body in _split(data):
                if kind == NLMSG_ERROR and mseq == seq:
                    code = struct.unpack_from("=i", body)[0]
                    if code:
                        raise OSError(-code, f"nfnetlink_queue config of queue {self.queue}: "
                                             f"{os.strerror(-code)}")
                    return

    def packets(self) -> list[int]:
        """Ids of the packets queued since the last call (empty when none are waiting)."""
        ids, self._backlog = self._backlog, []
        while True:
            try:
                n = self.sock.recv_into(self._buf)
            except (BlockingIOError, InterruptedError):
                return ids
            except OSError as exc:
                if exc.errno == errno.ENOBUFS:
                    continue
                raise
            ids += _packet_ids(memoryview(self._buf)[:n])

    def verdict(self, packet_id: int, accept: bool) -> None:
        self.sock.send(self._message(
            NFQNL_MSG_VERDICT,
            _attr(NFQA_VERDICT_HDR, struct.pack(">II", NF_ACCEPT if accept else NF_DROP,
                                                packet_id)), NLM_F_REQUEST))

    def close(self) -> None:
        try:
            self.sock.setblocking(True)
            self._config(_attr(NFQA_CFG_CMD, struct.pack("=Bx", NFQNL_CFG_CMD_UNBIND)
                               + struct.pack(">H", socket.AF_INET)))
        except OSError:
            pass
        finally:
            self.sock.close()


def _split(data: bytes | memoryview) -> list[tuple[int, int, int, memoryview]]:
    """(type, flags, seq, body) of each netlink message in a datagram."""
    view = memoryview(data)
    out = []
    off = 0
    while off + _NLMSGHDR.size <= len(view):
        length, kind, flags, seq, _ = _NLMSGHDR.unpack_from(view, off)
        if length < _NLMSGHDR.size:
            break
        out.append((kind, flags, seq, view[off + _NLMSGHDR.size:off + length]))
        off += (length + 3) & ~3
        if kind == NLMSG_DONE:
            break
    return out


def _packet_ids(data: bytes | memoryview) -> list[int]:
    """Ids of the queued packets announced in a datagram."""
    ids = []
    for kind, _, _, body in _split(data):
        if kind != (NFNL_SUBSYS_QUEUE << 8) | NFQNL_MSG_PACKET:
            continue
        for atype, value in _attrs(body[4:]):  # after the nfgenmsg header
            if atype == NFQA_PACKET_HDR:
                ids.append(struct.unpack_from(">I", value)[0])
    return ids


def _attrs(view: memoryview) -> list[tuple[int, memoryview]]:
    out = []
    off = 0
    while off + _NLATTR.size <= len(view):
        length, kind = _NLATTR.unpack_from(view, off)
        if length < _NLATTR.size:
            break
        out.append((kind & NLA_TYPE_MASK, view[off + _NLATTR.size:off + length]))
        off += (length + 3) & ~3
    return out


def kernel_queue_counters(queue: int) -> dict[str, int]:
    """This namespace's kernel counters of ``queue`` (/proc/net/netfilter/nfnetlink_queue):
    packets waiting, dropped by the kernel (queue full), dropped on the way to userspace."""
    try:
        lines = Path("/proc/net/netfilter/nfnetlink_queue").read_text().splitlines()
    except OSError:
        return {}
    for line in lines:
        f = line.split()
        if len(f) >= 7 and int(f[0]) == queue:
            return {"waiting": int(f[2]), "queue_dropped": int(f[5]),
                    "user_dropped": int(f[6])}
    return {}


class Delayer:
    """Delay ``delay_ms`` +- ``jitter_ms`` (uniform) and drop ``loss`` of the packets."""

    def __init__(self, queue: NfQueue, delay_ms: float, jitter_ms: float, loss: float,
                 rng: random.Random):
        self.q = queue
        self.delay_s, self.jitter_s, self.loss = delay_ms / 1e3, jitter_ms / 1e3, loss
        self.rng = rng
        self.pending: list[tuple[float, int, float, int]] = []  # (due, n, received, id)
        self.seen = self.accepted = self.dropped = self.flushed = 0
        self.hold_ms: Counter[int] = Counter()
        self.late_ms: list[float] = []

    def take(self, now: float) -> None:
        for pid in self.q.packets():
            self.seen += 1
            if self.loss > 0.0 and self.rng.random() < self.loss:
                self.q.verdict(pid, False)
                self.dropped += 1
                continue
            d = max(0.0, self.delay_s + self.rng.uniform(-self.jitter_s, self.jitter_s))
            heapq.heappush(self.pending, (now + d, self.seen, now, pid))

    def release(self, now: float) -> None:
        while self.pending and self.pending[0][0] <= now:
            due, _, received, pid = heapq.heappop(self.pending)
            self.q.verdict(pid, True)
            self.accepted += 1
            self.hold_ms[int((now - received) * 1e3)] += 1
            self.late_ms.append((now - due) * 1e3)

    def flush(self) -> None:
        """Accept everything still held (on exit: nothing is lost because we stop)."""
        for _, _, _, pid in self.pending:
            self.q.verdict(pid, True)
            self.flushed += 1
        self.pending.clear()

    def next_due(self) -> float | None:
        return self.pending[0][0] if self.pending else None

    def stats(self) -> dict[str, Any]:
        late = sorted(self.late_ms)

        def pct(p: float) -> float:
            return round(late[min(len(late) - 1, int(p * len(late)))], 3) if late else 0.0

        return {"queue": self.q.queue, "delay_ms": self.delay_s * 1e3,
                "jitter_ms": self.jitter_s * 1e3, "loss": self.loss, "packets": self.seen,
                "accepted": self.accepted, "dropped": self.dropped, "flushed": self.flushed,
                "hold_ms": {str(k): v for k, v in sorted(self.hold_ms.items())},
                "verdict_late_ms": {"p50": pct(0.5), "p99": pct(0.99),
                                    "max": round(late[-1], 3) if late else 0.0},
                "kernel": kernel_queue_counters(self.q.queue)}


def run(args: argparse.Namespace) -> int:
    stop_r, stop_w = os.pipe()
    os.set_blocking(stop_w, False)
    signal.set_wakeup_fd(stop_w)
    stopping = False

    def on_signal(signum: int, frame: Any) -> None:
        nonlocal stopping
        stopping = True

    for sig in (signal.SIGTERM, signal.SIGINT, signal.SIGHUP):
        signal.signal(sig, on_signal)
    try:
        q = NfQueue(args.queue)
    except OSError as exc:
        print(f"error: delayer: cannot bind NFQUEUE {args.queue} ({exc.strerror}; needs "
              f"root, the nfnetlink_queue module, and no other program bound to it)",
              file=sys.stderr)
        return 1
    d = Delayer(q, args.delay_ms, args.jitter_ms, args.loss, random.Random(args.seed))
    print(f"delayer: queue {args.queue} bound, delay {args.delay_ms:g} +- {args.jitter_ms:g} "
          f"ms, loss {args.loss:g}", flush=True)
    try:
        while not stopping:
            due = d.next_due()
            timeout = None if due is None else max(0.0, due - time.monotonic())
            waits: list[Any] = [q.sock, stop_r]  # a socket and a pipe's fd
            ready, _, _ = select.select(waits, [], [], timeout)
            now = time.monotonic()
            if q.sock in ready:
                d.take(now)
            d.release(now)
    finally:
        d.flush()
        stats = d.stats()
        q.close()
        if args.stats is not None:
            args.stats.write_text(json.dumps(stats, indent=1) + "\n")
    print(f"delayer: {stats['packets']} packets, {stats['accepted']} accepted, "
          f"{stats['dropped']} dropped, {stats['flushed']} released at exit", flush=True)
    return 0


def _nonneg(text: str) -> float:
    x = float(text)
    if not x >= 0.0:
        raise argparse.ArgumentTypeError(f"must be >= 0, got {text}")
    return x


def _fraction(text: str) -> float:
    x = float(text)
    if not 0.0 <= x < 1.0:
        raise argparse.ArgumentTypeError(f"a fraction in [0, 1) is required, got {text}")
    return x


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m formation_ilc.system.delayer",
                                description=__doc__.split("\n\n")[0],
                                epilog="Run as root inside the network namespace whose "
                                       "OUTPUT chain has the NFQUEUE rule.")
    p.add_argument("--queue", type=int, default=0, metavar="N", help="NFQUEUE number (0)")
    p.add_argument("--delay-ms", type=_nonneg, default=100.0, metavar="MS",
                   help="mean delay (default 100)")
    p.add_argument("--jitter-ms", type=_nonneg, default=0.0, metavar="MS",
                   help="delays are uniform in delay +- jitter, floored at 0 (default 0)")
    p.add_argument("--loss", type=_fraction, default=0.0, metavar="P",
                   help="fraction of packets dropped, each independently (default 0)")
    p.add_argument("--seed", type=int, default=0, help="seed of the draws (default 0)")
    p.add_argument("--stats", type=Path, metavar="FILE.json",
                   help="write the counts here on exit")
    args = p.parse_args(argv)
    if not 0 <= args.queue <= 65535:
        p.error(f"--queue: 0..65535, got {args.queue}")
    from formation_ilc.system.lifetime import die_with_parent

    die_with_parent()  # started by a launcher: end with it
    return run(args)


if __name__ == "__main__":
    sys.exit(main())
