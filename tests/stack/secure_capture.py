"""Run a command in a private network namespace and report what its processes sent in clear.

    unshare -n python tests/stack/secure_capture.py MARKERS_HEX -- COMMAND...

(Started by tests/stack/test_secure.py.) Brings ``lo`` up, captures every UDP datagram on it
with a raw packet socket (in a namespace of its own, nothing but COMMAND's traffic is
there), and meanwhile reads every shared-memory file (``/dev/shm/*``: Fast DDS's transport
segments and data-sharing pools) that COMMAND's processes have mapped. Each marker (hex,
comma-separated) is counted where it is seen in clear. Prints one JSON line: the command's
exit status, its output, UDP packets and bytes seen, datagrams the kernel dropped before the
capture read them, shared-memory segments read, and per marker its hits in UDP payloads and
in shared memory.
"""

from __future__ import annotations

import json
import socket
import struct
import subprocess
import sys
import threading
import time
from pathlib import Path

from formation_ilc.system.proctree import children_of

ETH_P_ALL = 0x0003
SOL_PACKET = 263
PACKET_STATISTICS = 6  # struct tpacket_stats: packets, drops (reading resets them)
SO_RCVBUFFORCE = 33
CAPTURE_BUFFER = 256 << 20  # a loaded machine's bursts must not overflow the socket


def shm_segments(pids: set[int]) -> set[str]:
    found = set()
    for pid in pids:
        try:
            maps = Path(f"/proc/{pid}/maps").read_text()
        except OSError:
            continue
        # every shared file: transport segments (fastrtps_*) and data-sharing pools alike
        found |= {line.split()[-1] for line in maps.splitlines() if "/dev/shm/" in line}
    return found


def main() -> int:
    sep = sys.argv.index("--")
    markers = [bytes.fromhex(h) for h in sys.argv[1].split(",")]
    cmd = sys.argv[sep + 1:]
    # lo is the namespace's only interface: multicast discovery on it reaches nothing else
    subprocess.run(["ip", "link", "set", "lo", "up", "multicast", "on"], check=True)
    subprocess.run(["ip", "route", "add", "224.0.0.0/4", "dev", "lo"], check=True)
    sock = socket.socket(socket.AF_PACKET, socket.SOCK_RAW, socket.ntohs(ETH_P_ALL))
    # root may exceed rmem_max: a start-up burst on a loaded machine fills the default
    # buffer before the capture thread reads it, and the kernel drops what does not fit
    sock.setsockopt(socket.SOL_SOCKET, SO_RCVBUFFORCE, CAPTURE_BUFFER)
    sock.bind(("lo", 0))
    sock.settimeout(0.2)
    stop = threading.Event()
    udp_hits = [0] * len(markers)
    shm_hits = [0] * len(markers)
    stats = {"udp_packets": 0, "udp_bytes": 0, "shm_reads": 0}
    shm_seen: set[str] = set()

    def capture() -> None:
        while not stop.is_set():
            try:
                frame = sock.recv(65600)
            except TimeoutError:
                continue
            ip = frame[14:]  # lo frames carry a zeroed Ethernet header
            if len(ip) < 28 or ip[0] >> 4 != 4 or ip[9] != 17:
                continue
            payload = ip[(ip[0] & 0x0F) * 4 + 8:]
            stats["udp_packets"] += 1
            stats["udp_bytes"] += len(payload)
            for k, m in enumerate(markers):
                if m in payload:
                    udp_hits[k] += 1

    t = threading.Thread(target=capture, daemon=True)
    t.start()
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            start_new_session=True)
    reader = threading.Thread(target=lambda: setattr(proc, "output", proc.stdout.read()),
                              daemon=True)
    reader.start()
    while proc.poll() is None:
        for seg in shm_segments({proc.pid} | children_of(proc.pid)):
            try:
                data = Path(seg).read_bytes()
            except OSError:
                continue
            stats["shm_reads"] += 1
            shm_seen.add(seg)
            for k, m in enumerate(markers):
                if m in data:
                    shm_hits[k] += 1
        time.sleep(0.1)  # the segments are read again and again while the run goes on
    reader.join(timeout=10)
    time.sleep(0.5)  # the last datagrams
    stop.set()
    t.join(timeout=5)
    _, drops = struct.unpack("II", sock.getsockopt(SOL_PACKET, PACKET_STATISTICS, 8))
    print(json.dumps({"status": proc.returncode, "output": getattr(proc, "output", ""),
                      **stats, "udp_dropped": drops, "shm_segments": len(shm_seen),
                      "udp_hits": udp_hits,
                      "shm_hits": shm_hits}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
