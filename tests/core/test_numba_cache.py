"""numba's cache is keyed on the core's sources (issue 11): an edit of any module is picked
up by the next run, and an unchanged tree loads what it compiled once."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numba
import pytest

import formation_ilc
from formation_ilc.core import _jit

PKG = Path(formation_ilc.__file__).resolve().parent

RUN = """
import json, sys
import formation_ilc
from formation_ilc.core import _jit
from formation_ilc.config.scenario import load_scenario
from formation_ilc.model.simulate import simulate
res = simulate(load_scenario("paper-triangle3"), trials=12)
print(json.dumps({"file": formation_ilc.__file__, "cache": _jit.cache_dir(),
                  "last": float(res.column("max_position_error")[-1])}))
"""

# the reproduction: the heading row of the memory update, sign flipped
ORIGINAL = "out[r, t, 1] = b1 + g * p2"
EDITED = "out[r, t, 1] = b1 - g * p2"


def snapshot(root: Path) -> dict[str, tuple[int, int]]:
    return {str(p.relative_to(root)): (p.stat().st_mtime_ns, p.stat().st_size)
            for p in root.rglob("*") if p.is_file()}


def test_edit_of_a_called_module_is_compiled_and_an_unchanged_tree_loads_the_cache(tmp_path):
    work = tmp_path / "src"
    shutil.copytree(PKG, work / "formation_ilc", ignore=shutil.ignore_patterns("__pycache__"))
    cache = tmp_path / "cache"
    env = {k: v for k, v in os.environ.items() if k not in ("NUMBA_DISABLE_JIT", "PYTHONPATH")}
    env.update(NUMBA_CACHE_DIR=str(cache), PYTHONPATH=str(work), MPLBACKEND="Agg")

    def run() -> dict:
        out = subprocess.run([sys.executable, "-c", RUN], cwd=work, env=env,
                             capture_output=True, text=True, timeout=300)
        assert out.returncode == 0, out.stderr
        return json.loads(out.stdout.strip().splitlines()[-1])

    first = run()
    assert Path(first["file"]).resolve().parent == (work / "formation_ilc").resolve()
    assert Path(first["cache"]).parent == cache / "formation-ilc"
    files = snapshot(cache)
    assert any(f.endswith(".nbi") for f in files) and any(f.endswith(".nbc") for f in files)

    second = run()  # unchanged tree: same directory, nothing compiled, nothing written
    assert second == first
    assert snapshot(cache) == files

    law = work / "formation_ilc" / "core" / "law.py"
    text = law.read_text()
    assert text.count(ORIGINAL) == 1
    law.write_text(text.replace(ORIGINAL, EDITED))
    # law.py is not the file of run_trial, whose cached code inlines learn(): numba's own
    # check (the caller's source only) would load the old result here
    third = run()
    assert third["cache"] != first["cache"]
    assert abs(third["last"] - first["last"]) > 0.5, (first, third)
    # the edited line is in learn_trig (what the simulator calls): compiled into the new one
    assert list(Path(third["cache"]).rglob("law.learn_trig-*.nbi"))


def test_every_kernel_is_cached_in_the_source_keyed_directory():
    if numba.config.DISABLE_JIT:
        pytest.fail("run without NUMBA_DISABLE_JIT: there are no kernels to check")
    from formation_ilc.core import kinematics, law, pcg, uncertainty
    from formation_ilc.model import simulate

    found = []
    for mod in (kinematics, law, simulate, pcg, uncertainty):
        for name, obj in vars(mod).items():
            if isinstance(getattr(obj, "jit", None), _jit.Compiled) and \
                    obj.__module__ == mod.__name__:
                found.append(name)
                disp = obj.jit.dispatcher
                assert isinstance(disp, numba.core.dispatcher.Dispatcher), name
                assert disp._cache._cache_path.startswith(_jit.cache_dir() + os.sep), name
    assert {"command", "learn", "command_trig", "learn_trig", "heading_trig", "run_trial",
            "run_trials", "step_into", "trial_errors", "seed_state", "next_double",
            "fill_plant", "fill_delays"} <= set(found)


def test_no_module_calls_numba_jit_directly():
    """A new kernel module must use formation_ilc.core._jit.njit, or its cache would go stale."""
    offenders = []
    for path in PKG.rglob("*.py"):
        if path.name == "_jit.py" or "__pycache__" in path.parts:
            continue
        text = path.read_text()
        if any(s in text for s in ("from numba import", "numba.njit", "numba.jit", "@jit")):
            offenders.append(path.name)
    assert offenders == []


def test_source_hash_covers_every_module_and_ignores_caches(tmp_path):
    root = tmp_path / "formation_ilc"
    shutil.copytree(PKG, root, ignore=shutil.ignore_patterns("__pycache__"))
    h0 = _jit.source_hash(root)
    assert h0 == _jit.source_hash(PKG)
    (root / "__pycache__" / "numba").mkdir(parents=True)
    (root / "__pycache__" / "x.py").write_text("x = 1\n")
    assert _jit.source_hash(root) == h0
    (root / "config" / "scenarios" / "new_module.py").write_text("# new\n")
    h1 = _jit.source_hash(root)
    assert h1 != h0
    kin = root / "core" / "kinematics.py"
    kin.write_text(kin.read_text() + "\n")
    assert _jit.source_hash(root) not in (h0, h1)


def test_user_cache_dir_is_the_base_and_unwritable_places_are_skipped(tmp_path, monkeypatch):
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path / "user"))
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    parents = _jit.candidate_parents()
    assert parents[0] == tmp_path / "user" / "formation-ilc"
    assert parents[1] == PKG / "__pycache__" / "numba"
    assert parents[2] == tmp_path / "xdg" / "formation-ilc" / "numba"
    monkeypatch.delenv("NUMBA_CACHE_DIR")
    assert _jit.candidate_parents()[0] == PKG / "__pycache__" / "numba"
    # a read-only install: a directory that cannot be made (root can write anywhere, so the
    # test makes the in-tree place impossible rather than read-only)
    blocker = tmp_path / "a-file"
    blocker.write_text("")
    got = _jit.first_writable([blocker / "numba", tmp_path / "xdg" / "numba"])
    assert got == tmp_path / "xdg" / "numba"
    assert _jit.first_writable([blocker / "numba"]) is None


def test_prune_removes_only_old_directories_of_other_sources(tmp_path):
    now = time.time()
    old = now - _jit.PRUNE_AGE_S - 10
    for name, mtime in (("0123456789abcdef", old), ("fedcba9876543210", now - 60),
                        ("aaaaaaaaaaaaaaaa", old), ("not-a-hash", old)):
        (tmp_path / name / "sub").mkdir(parents=True)
        (tmp_path / name / "sub" / "f.nbi").write_text("x")
        os.utime(tmp_path / name, (mtime, mtime))
    removed = _jit.prune(tmp_path, keep="aaaaaaaaaaaaaaaa", now=now)
    assert removed == ["0123456789abcdef"]
    left = sorted(p.name for p in tmp_path.iterdir())
    assert left == ["aaaaaaaaaaaaaaaa", "fedcba9876543210", "not-a-hash"]
    assert _jit.prune(tmp_path, keep="aaaaaaaaaaaaaaaa", now=now) == []  # a second caller


def test_prune_of_a_directory_another_process_took_first_is_skipped(tmp_path, monkeypatch):
    now = time.time()
    d = tmp_path / "0123456789abcdef"
    d.mkdir()
    os.utime(d, (now - 2 * _jit.PRUNE_AGE_S,) * 2)
    real_rename = os.rename

    def racing_rename(src, dst):  # the other process renames it between stat and rename
        real_rename(src, tmp_path / ".trash-0123456789abcdef-other")
        return real_rename(src, dst)

    monkeypatch.setattr(_jit.os, "rename", racing_rename)
    assert _jit.prune(tmp_path, keep="ffffffffffffffff", now=now) == []
    assert [p.name for p in tmp_path.iterdir()] == [".trash-0123456789abcdef-other"]
