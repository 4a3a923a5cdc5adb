"""Progress on stderr (formation_ilc.system.progress): a tqdm bar on a terminal, whole lines
now and then in a log file or a pipe, never a carriage return there."""

from __future__ import annotations

import fcntl
import gc
import io
import os
import re
import struct
import termios
import threading

import pytest

from formation_ilc.system import progress
from formation_ilc.system.progress import Progress


class FakeClock:
    def __init__(self) -> None:
        self.now = 1000.0

    def __call__(self) -> float:
        return self.now


@pytest.fixture
def clock(monkeypatch: pytest.MonkeyPatch) -> FakeClock:
    c = FakeClock()
    monkeypatch.setattr(progress.time, "monotonic", c)
    return c


def test_a_log_gets_a_line_at_the_first_step_each_tenth_and_the_end(clock):
    out = io.StringIO()
    bar = Progress(100, "paper-triangle3 law (9) feedforward", "trials", tenths=True,
                   file=out)
    for k in range(100):
        clock.now += 0.5  # 50 s in all: one line also after 30 s without a new tenth
        bar.step(f"max position {1 / (k + 1):.4g} m  max heading 0.01 rad")
    text = out.getvalue()
    assert "\r" not in text and text.endswith("\n")
    lines = text.splitlines()
    counts = [int(re.search(r"\| (\d+)/100 trials \[", line).group(1)) for line in lines]
    assert counts == [1, 10, 20, 30, 40, 50, 60, 70, 80, 90, 100]
    # the time left is not known at the first step (what came before it may be a start-up)
    assert lines[0] == ("paper-triangle3 law (9) feedforward:   1%|1         | 1/100 trials "
                        "[00:00<?, max position 1 m  max heading 0.01 rad]")
    assert "| 10/100 trials [00:05<00:45, " in lines[1]
    assert lines[-1] == ("paper-triangle3 law (9) feedforward: 100%|##########| 100/100 "
                         "trials [00:50<00:00, max position 0.01 m  max heading 0.01 rad]")
    bar.step("after the end")  # closed at the total: nothing more
    assert out.getvalue() == text


def test_a_log_gets_a_line_every_period_and_the_time_left_from_this_sessions_rate(clock):
    out = io.StringIO()
    bar = Progress(10, "sweep", "points", initial=4, every=5.0, file=out)
    clock.now += 30.0  # starting the workers
    for _ in range(6):
        clock.now += 2.0
        bar.step()
    # the first step, then 5 s after it, then the end; 1 point per 2 s since the first
    assert out.getvalue().splitlines() == [
        "sweep:  50%|#####     | 5/10 points [00:32<?]",
        "sweep:  80%|########  | 8/10 points [00:38<00:04]",
        "sweep: 100%|##########| 10/10 points [00:42<00:00]",
    ]


def test_nothing_is_written_before_the_first_step_nor_for_nothing_to_do(clock):
    out = io.StringIO()
    Progress(10, "sweep", "points", initial=10, file=out).step()
    Progress(0, "tune screen", "points", file=out).close()
    Progress(None, "reading run.mcap", "messages", file=out).close(clear=True)
    assert out.getvalue() == ""
    bar = Progress(None, "reading run.mcap", "messages", file=out)
    bar.to(5000)
    bar.to(10000)  # within the period: no second line
    assert out.getvalue() == "reading run.mcap: 5000 messages [00:00]\n"


@pytest.fixture
def terminal():
    """A pseudo-terminal: (file to write to, function reading what it got)."""
    master, slave = os.openpty()
    f = os.fdopen(slave, "w")

    def read() -> str:
        f.flush()
        chunks = []
        os.set_blocking(master, False)
        while True:
            try:
                chunks.append(os.read(master, 65536))
            except BlockingIOError:
                break
        return b"".join(chunks).decode().replace("\r\n", "\n")  # the tty's own newline

    yield f, read
    f.close()
    os.close(master)


@pytest.mark.parametrize("columns", [100, 0])  # 0: a pseudo-terminal no one gave a size
def test_a_terminal_gets_one_line_redrawn_and_kept_at_the_end(terminal, columns):
    f, read = terminal
    fcntl.ioctl(f.fileno(), termios.TIOCSWINSZ, struct.pack("HHHH", 24, columns, 0, 0))
    threads = threading.active_count()
    bar = Progress(5, "law (9) literal", "trials", interval=0, file=f)
    assert threading.active_count() == threads  # no monitor thread beside forked workers
    for k in range(5):
        bar.step(f"max position {k} m")
    print("next", file=f)
    text = read()
    draws = text.split("\r")[1:]
    assert len(draws) >= 6  # drawn at 0, then at each step
    assert "\n" not in "".join(draws[:-1])  # one line, rewritten in place
    assert re.fullmatch(r"law \(9\) literal: 100%\|█+\| 5/5 trials \[00:00<00:00, max "
                        r"position 4 m\] *\nnext\n", draws[-1])


def test_a_terminals_bar_is_wiped_for_a_message_and_an_abandoned_one_stays_quiet(terminal):
    f, read = terminal
    fcntl.ioctl(f.fileno(), termios.TIOCSWINSZ, struct.pack("HHHH", 24, 100, 0, 0))
    bar = Progress(None, "reading run.mcap", "messages", interval=0, file=f)
    bar.to(5000)
    bar.close(clear=True)
    print("error: run.mcap: no readable run configuration", file=f)
    text = read()
    assert "reading run.mcap: 5000 messages [00:00]" in text
    assert re.search(r"\r *\rerror: run.mcap: no readable run configuration\n$", text)
    # an interrupted run: its bar, dropped unfinished, does not draw itself again below
    # what came after it
    bar = Progress(10, "sweep", "points", interval=0, file=f)
    bar.step()
    print("\ninterrupted", file=f)
    del bar
    gc.collect()
    assert "sweep" not in read().split("interrupted\n")[1]


def test_simulates_bar_names_trials_by_their_number_only(clock):
    """simulate's progress counts trials one way: their numbers from 0 (as metrics.csv, the
    table and the plots), not a count from 1 beside them."""
    from formation_ilc.cli.simulate import Progress as TrialProgress

    out = io.StringIO()
    bar = TrialProgress(20, "paper-triangle3", first=0)
    bar.bar.file = out
    for k in range(20):
        clock.now += 0.1
        bar(k, [k, 1.0, 0.5])
    lines = out.getvalue().splitlines()
    assert lines[0].startswith("paper-triangle3:   5%|")
    assert "trial 0 of 0..19: max position 1 m" in lines[0]
    assert "trial 19 of 0..19" in lines[-1] and "/20" not in out.getvalue()


def test_compile_notes_say_what_numba_compiles_and_a_warm_cache_says_nothing():
    import numba

    from formation_ilc.system.compiling import compile_notes

    def add_one(x):  # noqa: ANN001, ANN202
        return x + 1

    out = io.StringIO()
    fn = numba.njit(cache=False)(add_one)
    with compile_notes("a test kernel", file=out):
        assert fn(1) == 2
    lines = out.getvalue().splitlines()
    assert lines[0].startswith("compiling a test kernel with numba: once after an install")
    assert re.fullmatch(r"  compiled \d+ functions in \d+\.\d s", lines[-1])
    out = io.StringIO()
    with compile_notes("a test kernel", file=out):
        assert fn(2) == 3  # compiled already: nothing to say
    assert out.getvalue() == ""
