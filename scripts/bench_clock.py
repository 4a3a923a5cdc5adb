"""The clock estimator (``core.clocksync``, ``protocol.timesync``): its error against time,
and what it costs per message.

Error vs time: two emulated clocks (offsets up to 300 ms, drifts up to 100 ppm each,
seeded), exchanges as the nodes make them (10 a second for the first 3 s, then 2; the
answerer holds each question 0.05-0.5 ms), over paths of several kinds:

* ``loaded``: one loaded machine's DDS and executors: 0.1 ms + exponential 0.3 ms a leg,
  a fifth of the legs queued up to 20 ms (what the stack's realtime runs show);
* ``wifi``: 2 ms + exponential 3 ms a leg, a tenth queued up to 50 ms;
* ``asymmetric``: 3 ms out, 1 ms back, 0.05 ms jitter: no two-way estimate can see the
  2 ms difference; it is off by half of it, inside its stated bound;
* ``netns``: uniform 50-150 ms a leg (``--hosts netns --net-delay-ms 100
  --net-jitter-ms 50``): half the shortest round trip stays near 50 ms, the bound never
  reaches 2 ms.

For each, at 1, 2, 5, 10, 20 and 40 s after the first exchange: the median and largest
|error| of the offset over the seeds, the median stated uncertainty, the share converged
within 2 ms and within 10 ms (a run at dT = 0.2 s: ``protocol.timesync.converged_for``),
and how often the error exceeded the stated uncertainty (the bound must hold: 0).

Cost: CPU per exchange taken (``LinkClock.exchange``: the refit over the window), per
answer handled (``ClockSync.on_answer``, with the delays kept), per estimate read, and per
question and answer built and read as sensor_msgs/TimeReference (``msgs_schema``; needs
the ROS wheels), in one process.

    python scripts/bench_clock.py [--seeds 20] [--seconds 40]
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from collections.abc import Callable

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))

from formation_ilc.core.clocksync import EmulatedClock, LinkClock  # noqa: E402
from formation_ilc.protocol.timesync import BURST_HZ, BURST_S, PING_HZ, ClockSync  # noqa: E402

MS = 1_000_000
S = 1_000_000_000
ORIGIN = 1_795_000_000 * S
CHECK_S = (1, 2, 5, 10, 20, 40)
#: [ns] a run's convergence threshold at dT = 0.2 s (``protocol.timesync.converged_for``)
LOOSE = 10 * MS

Leg = Callable[[np.random.Generator, bool], float]  # [ms]; True: out, False: back


def _loaded(rng: np.random.Generator, out: bool) -> float:
    return 0.1 + rng.exponential(0.3) + (rng.uniform(0, 20) if rng.random() < 0.2 else 0.0)


def _wifi(rng: np.random.Generator, out: bool) -> float:
    return 2.0 + rng.exponential(3.0) + (rng.uniform(0, 50) if rng.random() < 0.1 else 0.0)


def _asymmetric(rng: np.random.Generator, out: bool) -> float:
    return (3.0 if out else 1.0) + abs(rng.normal(0, 0.05))


def _netns(rng: np.random.Generator, out: bool) -> float:
    return float(rng.uniform(50.0, 150.0))


PATHS: dict[str, Leg] = {"loaded": _loaded, "wifi": _wifi, "asymmetric": _asymmetric,
                         "netns": _netns}


def error_vs_time(leg: Leg, seeds: int, seconds: float) -> dict[int, dict[str, float]]:
    """Per checkpoint [s]: the offset's |error| (median, max over seeds) [ms], the median
    uncertainty [ms], the share converged, and the exchanges whose error exceeded their
    stated uncertainty (over the whole run, all seeds)."""
    at: dict[int, list[tuple[float, float, bool, bool]]] = {
        c: [] for c in CHECK_S if c <= seconds}
    broken = total = 0
    for seed in range(seeds):
        rng = np.random.default_rng(seed)
        local = EmulatedClock.seeded(seed, 1, 300.0, 100.0, ORIGIN)
        remote = EmulatedClock.seeded(seed, 2, 300.0, 100.0, ORIGIN)
        lc = LinkClock()
        start = ORIGIN + 10 * S
        t = start
        marks = sorted(at)
        while t < start + seconds * S:
            t2 = t + int(leg(rng, True) * MS)
            t3 = t2 + int(rng.uniform(0.05, 0.5) * MS)
            t4 = t3 + int(leg(rng, False) * MS)
            lc.exchange(local.read(t), remote.read(t2), local.read(t4), remote.read(t3))
            est = lc.estimate(local.read(t4))
            assert est is not None
            err = est.offset_ns - (remote.read(t4) - local.read(t4))
            total += 1
            broken += abs(err) > est.uncertainty_ns
            while marks and t4 - start >= marks[0] * S:
                at[marks.pop(0)].append((abs(err) / MS, est.uncertainty_ns / MS,
                                         est.converged,
                                         est.exchanges >= 4 and est.uncertainty_ns <= LOOSE))
            rate = BURST_HZ if t - start < BURST_S * S else PING_HZ
            t += int(S / rate)
    out = {}
    for c, rows in at.items():
        if not rows:
            continue
        a = np.array([r[:2] for r in rows])
        out[c] = {"err_p50": float(np.median(a[:, 0])), "err_max": float(a[:, 0].max()),
                  "unc_p50": float(np.median(a[:, 1])),
                  "converged": float(np.mean([r[2] for r in rows])),
                  "loose": float(np.mean([r[3] for r in rows]))}
    out[-1] = {"broken": float(broken), "total": float(total)}
    return out


def per_call(fn: Callable[[], object], n: int) -> float:
    """[us] per call of ``fn`` (the best of 3 rounds of ``n``)."""
    best = float("inf")
    for _ in range(3):
        t0 = time.perf_counter()
        for _ in range(n):
            fn()
        best = min(best, (time.perf_counter() - t0) / n)
    return best * 1e6


def costs(n: int) -> dict[str, float]:
    rng = np.random.default_rng(0)
    lc = LinkClock()
    t = [ORIGIN]

    def exchange() -> None:
        t[0] += S // 2
        d = int((0.2 + rng.exponential(0.3)) * MS)
        lc.exchange(t[0], t[0] + d + 300 * MS, t[0] + 2 * d, t[0] + d + 300 * MS)

    for _ in range(80):  # a full window, as in steady state
        exchange()
    out = {"LinkClock.exchange (64 kept)": per_call(exchange, n),
           "LinkClock.estimate": per_call(lambda: lc.estimate(t[0]), n)}
    sync = ClockSync("robot_2", ["robot_1"])
    now = [ORIGIN]

    def answer() -> None:
        now[0] += S // 2
        ((peer, seq),) = sync.questions(now[0])
        sync.on_answer(peer, seq, now[0] + 300 * MS, now[0] + 300 * MS, now[0] + MS)

    for _ in range(80):
        answer()
    out["ClockSync question + on_answer"] = per_call(answer, n)
    try:
        import msgs_schema as ms
    except ImportError:
        return out
    ping = ms.ping_msg(17, ORIGIN, "robot_2")
    pong = ms.pong_msg(17, ORIGIN, ORIGIN + MS, "robot_1")
    out["ping_msg (TimeReference)"] = per_call(lambda: ms.ping_msg(17, ORIGIN, "robot_2"), n)
    out["read_ping"] = per_call(lambda: ms.read_ping(ping), n)
    out["pong_msg"] = per_call(lambda: ms.pong_msg(17, ORIGIN, ORIGIN + MS, "robot_1"), n)
    out["read_pong"] = per_call(lambda: ms.read_pong(pong), n)
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--seconds", type=float, default=40.0)
    ap.add_argument("--calls", type=int, default=2000, help="calls per cost round")
    args = ap.parse_args(argv)
    print(f"load: {os.getloadavg()[0]:.2f} {os.getloadavg()[1]:.2f} "
          f"{os.getloadavg()[2]:.2f} (1/5/15 min); {args.seeds} seeds, 300 ms / 100 ppm "
          f"clocks, {BURST_HZ:g} exchanges/s for {BURST_S:g} s then {PING_HZ:g}/s")
    for name, leg in PATHS.items():
        res = error_vs_time(leg, args.seeds, args.seconds)
        tail = res.pop(-1)
        print(f"\n{name}: error beyond the stated uncertainty in {int(tail['broken'])} of "
              f"{int(tail['total'])} exchanges")
        print(f"  {'t [s]':>6s} {'|err| p50 [ms]':>15s} {'|err| max [ms]':>15s} "
              f"{'unc p50 [ms]':>13s} {'conv. 2 ms':>11s} {'conv. 10 ms':>12s}")
        for c, r in res.items():
            print(f"  {c:6d} {r['err_p50']:15.3f} {r['err_max']:15.3f} {r['unc_p50']:13.3f} "
                  f"{r['converged']:11.0%} {r['loose']:12.0%}")
    print("\ncost per call, one process [us]:")
    for what, us in costs(args.calls).items():
        print(f"  {what:32s} {us:8.1f}")
    per_link = 2 * PING_HZ  # a question and an answer a second each way, steady state
    cost = costs(max(200, args.calls // 10))
    cpu = (cost.get("ping_msg (TimeReference)", 0) + cost.get("read_ping", 0)
           + cost.get("pong_msg", 0) + cost.get("read_pong", 0)
           + cost["ClockSync question + on_answer"]) * PING_HZ
    print(f"steady state per link: {per_link:g} messages/s, about {cpu:.0f} us of Python CPU a "
          f"second (without DDS's own cost per message)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
