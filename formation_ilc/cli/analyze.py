"""``formation-ilc analyze RUN.mcap``: metrics, delay histograms, plots and a one-page report
from a recording alone (no scenario file, no running ROS graph).

A damaged recording (bytes that do not read back in the middle of the file: a chunk whose
CRC fails, a record that does not parse) is analysed from everything that reads back, and
the command says what was lost (byte ranges, chunks, messages, their log times, the trials
left incomplete) on stderr and in report.html, then exits with status 1 (``DAMAGED``). A
file cut short at its end (a recorder that crashed or was killed) is read up to the cut,
with a note. Whenever a trial of the run (its configuration's ``trials``) is not complete
in the files, the run is not whole: a warning names the trials, and the exit status is 3
(``INCOMPLETE``) unless the file is damaged (1). Messages that do not decode are skipped
and counted per topic.
"""

from __future__ import annotations

import base64
import html
import json
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from formation_ilc.cli.supervisor import trial_ranges
from formation_ilc.core import links
from formation_ilc.core.metrics import write_metrics
from formation_ilc.recordings.recording import Recording, RecordingError, load_recording
from formation_ilc.system.progress import Progress

__all__ = ["analyze", "delay_rows", "findings", "DAMAGED", "INCOMPLETE"]

#: exit status of ``analyze`` on a damaged recording (its results are still written)
DAMAGED = 1
#: exit status of ``analyze`` on an intact recording that lacks trials of its run: the run
#: is not whole (its results are still written)
INCOMPLETE = 3


def findings(rec: Recording) -> tuple[list[str], list[str]]:
    """(warnings, notes) about a recording for a user: damage and what it cost are
    warnings; a file cut short at its end and skipped messages are notes. With several
    parts each finding names its file."""
    warn: list[str] = []
    note: list[str] = []
    parts = rec.parts or [(Path(""), rec.report)]
    many = len(parts) > 1
    for path, rep in parts:
        where = f"{path.name}: " if many else ""
        if rep.damaged:
            lost = rep.lost_messages
            warn.append(f"{where}damaged recording: {rep.messages} messages read back"
                        + (f", {lost} lost" if lost else "") + "; everything after the "
                        "damage that reads back was used")
            warn += [f"  {line}" for line in rep.lines() if not line.startswith("the file ends")]
        if rep.cut_short:
            note.append(f"{where}the file ends cut short (its writer stopped without closing "
                        "it): read up to the last complete chunk"
                        + (f"; {rep.tail_bytes} bytes after it are lost" if rep.tail_bytes
                           else ""))
    damaged = any(rep.damaged for _, rep in parts)
    if rec.incomplete:
        (warn if damaged else note).append(
            f"trial(s) {', '.join(map(str, rec.incomplete))} not complete in the "
            f"file{'s' * many}")
    if rec.missing:
        runs = rec.config.get("trials", len(rec.metrics))
        why = ("the leader's 'done' is there: the recording lost them" if rec.ended else
               "the recording stops before the run's end (no 'done' event: the run was "
               "interrupted, or its recorder was not running)")
        warn.append(f"the run is not whole: {len(rec.missing)} of its {runs} trials are not "
                    f"complete in the file{'s' * many} ({trial_ranges(rec.missing)}); {why}")
    if rec.superseded:
        note.append(f"{rec.superseded} trajectories of aborted slots or of trials run again "
                    f"after an abort were set aside (the first complete copy counts)")
    if rec.undecodable:
        note.append("skipped messages that do not decode: " + ", ".join(
            f"{t} {n}" for t, n in sorted(rec.undecodable.items())))
    if rec.foreign:
        note.append(f"{rec.foreign} trial events not the run leader's (not sealed with its "
                    f"run key, or another run's) were set aside")
    note += rec.notes
    return warn, note


def delay_rows(rec: Recording) -> list[list[Any]]:
    """The rows of delays.csv (``formation_ilc.core.links.DELAY_COLUMNS``) of a recording."""
    if rec.config.get("links") == "direct":
        return links.delay_rows(rec.delays, None, None, rec.clock_links)
    return links.delay_rows(rec.delays, rec.injected, rec.scenario.uncertainty.delay.pmf(),
                            rec.clock_links)


def _plot_delays(rec: Recording, path: Path) -> Path | None:
    if not rec.delays:
        return None
    from formation_ilc.recordings.plots import _plt

    plt = _plt()
    names = sorted(rec.delays)
    cols = min(3, len(names))
    rows = int(np.ceil(len(names) / cols))
    fig, axes = plt.subplots(rows, cols, figsize=(4 * cols, 2.8 * rows), squeeze=False)
    # direct links have no delay model: only what the robots measured
    pmf = {} if rec.config.get("links") == "direct" else rec.scenario.uncertainty.delay.pmf()
    for ax, link in zip(axes.flat, names, strict=False):
        hist = rec.delays[link]
        total = sum(hist.values()) or 1
        taus = sorted({*hist, *pmf})
        ax.bar(taus, [hist.get(t, 0) / total for t in taus], width=0.6,
               label="measured (eq. 11)")
        if pmf:
            ax.plot(taus, [pmf.get(t, 0.0) for t in taus], "o", color="k", label="model")
        ax.set_title(f"{link}  (n = {total})", fontsize=9)
        ax.set_xlabel("delay [samples]")
        ax.set_xticks(taus)
    for ax in list(axes.flat)[len(names):]:
        ax.axis("off")
    axes.flat[0].set_ylabel("fraction")
    axes.flat[0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def plot_clocks(rec: Recording, path: Path) -> Path | None:
    """Each link's clock estimate over the run (the receiver's estimate of the sender's
    clock, with its uncertainty), and in an emulated run its error against the truth;
    None when the recording holds no estimate (lockstep, or an older recording)."""
    if not rec.clocks:
        return None
    from formation_ilc.recordings.plots import _plt

    plt = _plt()
    t0 = min(p.time_ns for p in rec.clocks)
    series: dict[str, list[Any]] = {}
    for p in rec.clocks:
        series.setdefault(links.link_name(p.peer, p.node), []).append(p)
    truth = any(np.isfinite(p.true_offset_ms) for p in rec.clocks)
    fig, axes = plt.subplots(2 if truth else 1, 1, figsize=(8, 6 if truth else 3.5),
                             squeeze=False)
    top = axes[0, 0]
    for name, pts in sorted(series.items()):
        t = np.array([(p.time_ns - t0) / 1e9 for p in pts])
        off = np.array([p.offset_ms for p in pts])
        unc = np.array([p.uncertainty_ms for p in pts])
        line = top.plot(t, off, ".-", ms=3, label=name)[0]
        top.fill_between(t, off - unc, off + unc, color=line.get_color(), alpha=0.2)
        if truth:
            err = off - np.array([p.true_offset_ms for p in pts])
            bottom = axes[1, 0]
            bottom.plot(t, err, ".-", ms=3, color=line.get_color(), label=name)
            bottom.fill_between(t, -unc, unc, color=line.get_color(), alpha=0.15)
    top.set_ylabel("offset of the sender's clock [ms]")
    top.set_title("clock estimates (shaded: the stated uncertainty)", fontsize=10)
    top.legend(fontsize=7)
    if truth:
        bottom = axes[1, 0]
        bottom.axhline(0.0, color="k", lw=0.5)
        bottom.set_ylabel("estimate - truth [ms]")
        lim = max(2.0, 1.2 * max(abs(p.offset_ms - p.true_offset_ms) for p in rec.clocks
                                 if p.converged) if any(p.converged for p in rec.clocks)
                  else 2.0)
        bottom.set_ylim(-lim, lim)
    axes[-1, 0].set_xlabel("time in the recording [s]")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def _plot_snapshots(rec: Recording, trials: list[int], path: Path,
                    edges: list[tuple[int, int]]) -> Path:
    """The formation at a few instants of the chosen trials, each panel centred on the
    desired formation: the shape converging is visible at a glance."""
    from formation_ilc.recordings.plots import _plt

    plt = _plt()
    eta_d = rec.scenario.desired.eta
    m = eta_d.shape[1]
    times = [0, m // 5, 2 * m // 5, 3 * m // 5, 4 * m // 5, m - 1]
    fig, axes = plt.subplots(len(trials), len(times), figsize=(2.3 * len(times),
                                                              2.4 * len(trials)),
                             squeeze=False)
    shape = float(np.ptp(eta_d[:, :, :2] - eta_d[:, :, :2].mean(axis=0, keepdims=True),
                         axis=0).max()) / 2 + 0.3
    for row, k in enumerate(trials):
        eta = rec.eta[k]
        # one scale per trial, wide enough for every robot at every shown instant (an early
        # trial's robots can be metres from their places) and for the desired shape
        far = max(float(np.abs(eta[:, t, :2] - eta_d[:, t, :2].mean(axis=0)).max())
                  for t in times)
        span = max(shape, 1.1 * far + 0.2)
        for col, t in enumerate(times):
            ax = axes[row, col]
            c = eta_d[:, t, :2].mean(axis=0)
            for i, j in edges:
                ax.plot(*zip(eta_d[i, t, :2], eta_d[j, t, :2], strict=True), ":",
                        color="0.5", lw=1)
                ax.plot(*zip(eta[i, t, :2], eta[j, t, :2], strict=True), "-", color="C0",
                        lw=1)
            ax.plot(eta_d[:, t, 0], eta_d[:, t, 1], "o", mfc="none", color="0.4", ms=5)
            ax.plot(eta[:, t, 0], eta[:, t, 1], "o", color="C0", ms=4)
            ax.quiver(eta[:, t, 0], eta[:, t, 1], np.cos(eta[:, t, 2]), np.sin(eta[:, t, 2]),
                      color="C0", scale=12, width=0.01)
            ax.set_xlim(c[0] - span, c[0] + span)
            ax.set_ylim(c[1] - span, c[1] + span)
            ax.set_aspect("equal")
            ax.set_xticks([])
            ax.set_yticks([])
            if row == 0:
                ax.set_title(f"t = {t * rec.scenario.dt:.1f} s", fontsize=9)
            if col == 0:
                ax.set_ylabel(f"trial {k} (panels {2 * span:.3g} m wide)")
    fig.suptitle("formation snapshots: desired (open, dotted) vs measured (filled)")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def _img(path: Path | None) -> str:
    if path is None:
        return ""
    data = base64.b64encode(path.read_bytes()).decode()
    return f'<img src="data:image/png;base64,{data}" alt="{html.escape(path.name)}">'


def _report(rec: Recording, src: Path, out: Path, figs: dict[str, Path | None],
            drows: list[list[Any]]) -> Path:
    warn, note = findings(rec)
    alerts = "".join(f'<p style="color:#a00"><b>{html.escape(w)}</b></p>' for w in warn)
    alerts += "".join(f'<p style="color:#a60">{html.escape(x)}</p>' for x in note)
    sc, m = rec.scenario, rec.metrics
    k = len(m)
    first, last = (m[0], m[-1]) if k else (None, None)
    pick = sorted({0, 1, k // 4, k // 2, 3 * k // 4, k - 1}) if k else []
    rows = "".join(
        f"<tr><td>{int(m[i, 0])}</td><td>{m[i, 1]:.4g}</td><td>{m[i, 2]:.4g}</td>"
        f"<td>{m[i, 3]:.4g}</td><td>{m[i, 5]:.4g}</td><td>{m[i, 6]:.4g}</td></tr>"
        for i in pick if 0 <= i < k)
    verdict = ""
    if k >= 2 and first is not None and last is not None:
        ratio = first[1] / last[1] if last[1] > 0 else float("inf")
        verdict = (f"Max position error {first[1]:.3g} m at trial {int(first[0])} &rarr; "
                   f"{last[1]:.3g} m at trial {int(last[0])} (&times;{1 / ratio:.3g}); "
                   f"heading {first[2]:.3g} &rarr; {last[2]:.3g} rad.")
    per_link: dict[str, list[str]] = {}
    for link, tau, meas, _inj, frac, prob, *_ms in drows:
        model = "" if prob == "" else f"model {prob:.2f}, "
        per_link.setdefault(link, []).append(f"{tau}: {frac:.3f} ({model}n={meas})")
    delay_html = "".join(f"<li><b>{html.escape(a)}</b> &mdash; {'; '.join(b)}</li>"
                         for a, b in per_link.items())
    cfg = rec.config
    page = f"""<!doctype html><html><head><meta charset="utf-8">
<title>formation-ilc: {html.escape(sc.name)}</title>
<style>body{{font-family:sans-serif;max-width:1200px;margin:1em auto;color:#222}}
table{{border-collapse:collapse}}td,th{{border:1px solid #ccc;padding:2px 8px;text-align:right}}
img{{max-width:100%;border:1px solid #eee;margin:4px 0}}.k{{color:#555}}</style></head><body>
<h1>{html.escape(sc.name)}: {k} trials</h1>
<p class="k">recording {html.escape(str(src))}; {rec.messages} messages;
{sc.n} robots, T = {sc.samples} samples of {sc.dt} s; law ({sc.law.kind}), memory
{html.escape(sc.law.memory)}; seed {sc.seed}; noise {'on' if cfg.get('noise') else 'off'},
delays {'on' if cfg.get('delay') else 'off'}; mode {html.escape(str(cfg.get('mode')))};
{html.escape(str(cfg.get('recorded_by', 'distributed stack')))}</p>
<p><b>{verdict}</b></p>
{alerts}
{_img(figs.get('errors'))}
<table><tr><th>trial</th><th>max pos [m]</th><th>max head [rad]</th><th>true max pos [m]</th>
<th>rms pos [m]</th><th>max formation [m]</th></tr>{rows}</table>
<h2>Formation</h2>{_img(figs.get('snapshots'))}{_img(figs.get('trajectories'))}
<h2>Delays measured by the robots (eq. 11)</h2><ul>{delay_html or '<li>none</li>'}</ul>
{_img(figs.get('delays'))}
{'<h2>Clocks</h2>' + _img(figs['clocks']) if figs.get('clocks') else ''}
</body></html>"""
    path = out / "report.html"
    path.write_text(page)
    return path


def analyze(src: Path | list[Path], out: Path, plots: bool = True,
            fallback: dict[str, Any] | None = None) -> int:
    """Analyse the recording ``src`` (one file, or the parts of one run in order) into
    ``out``; returns the exit status (0, DAMAGED, 2 when it is no recording).
    ``fallback``: the run configuration of the run's folder, for files that lost every
    copy of theirs (``load_recording``)."""
    files = [src] if isinstance(src, Path) else list(src)
    src = files[0]
    t0 = time.perf_counter()
    bar = Progress(None, f"reading {src.name}", "messages", interval=0.5)
    try:
        rec = load_recording(files, progress=bar.to, fallback=fallback)
    except RecordingError as exc:
        bar.close(clear=True)  # one line: in place of the progress bar if there is one
        print(f"error: {exc}", file=sys.stderr)
        return 2
    bar.close(clear=True)
    names = src.name + (f" and {len(files) - 1} more part{'s' * (len(files) > 2)} "
                        f"({', '.join(f.name for f in files[1:])})" if len(files) > 1 else "")
    print(f"read {names}: {rec.messages} messages, {len(rec.metrics)} complete trials "
          f"[{time.perf_counter() - t0:.1f} s]", file=sys.stderr)
    out.mkdir(parents=True, exist_ok=True)
    write_metrics(out / "metrics.csv", rec.metrics)
    drows = delay_rows(rec)
    links.write_delays(out / "delays.csv", drows)
    (out / "config.json").write_text(json.dumps(rec.config, indent=2) + "\n")
    (out / "scenario.yaml").write_text(rec.scenario.text)
    written = ["metrics.csv", "delays.csv", "config.json", "scenario.yaml"]
    m = rec.metrics
    if plots and len(m):
        from formation_ilc.recordings.plots import plot_errors, plot_trajectories

        sc = rec.scenario
        title = f"{sc.name}: law ({sc.law.kind}), {sc.law.memory} memory (from {src.name})"
        figs: dict[str, Path | None] = {}
        from formation_ilc.core.metrics import robot_errors

        kept = sorted(k for k in rec.eta if k in set(int(x) for x in m[:, 0]))
        per_robot = (np.array(kept, dtype=float),
                     np.array([robot_errors(rec.eta[k], sc.desired.eta) for k in kept]))
        figs["errors"] = plot_errors(m[:, 0], m[:, 1], m[:, 2], out / "errors.png", title,
                                     per_robot=per_robot if kept else None)
        trials = [int(x) for x in m[:, 0]]
        n = len(trials)
        chosen = sorted({trials[0], trials[max(0, n // 10 - 1)], trials[max(0, 2 * n // 5 - 1)],
                         trials[-1]})
        edges = [(i, j) for i in range(sc.n) for j in sc.graph.neighbours(i)]
        figs["trajectories"] = plot_trajectories(
            sc.desired.eta, {k: rec.eta[k] for k in chosen}, out / "trajectories.png", title,
            edges=edges)
        figs["snapshots"] = _plot_snapshots(rec, sorted({trials[0], trials[-1]}),
                                            out / "formation.png", edges)
        figs["delays"] = _plot_delays(rec, out / "delays.png")
        figs["clocks"] = plot_clocks(rec, out / "clocks.png")
        rep = _report(rec, src, out, figs, drows)
        written += [f.name for f in figs.values() if f is not None] + [rep.name]
    k = len(m)
    if k:
        print(f"{rec.scenario.name}: {k} trials; max position error {m[0, 1]:.4g} m (trial "
              f"{int(m[0, 0])}) -> {m[-1, 1]:.4g} m (trial {int(m[-1, 0])})")
    warn, note = findings(rec)
    for line in note:
        print(f"note: {line}")
    print(f"results in {out}/ ({', '.join(written)})")
    for line in warn:
        print(f"warning: {line}", file=sys.stderr)
    if any(rep.damaged for _, rep in rec.parts):
        return DAMAGED
    return INCOMPLETE if rec.missing else 0
