"""The cache policy of the CasADi C builds (planner.core.builds through planner.kinematics.native).

A compiler that fails leaves one failure marker; the next process does not run the compiler again and uses
the CasADi virtual machine at once; the marker expires after a day; a build that times out leaves none.
"""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import casadi as ca
import numpy as np
import pytest

from planner.core import builds
from planner.kinematics import native as native_module
from planner.kinematics.native import native

#: The function built in every test: its VM evaluation is the reference.
PROBE = """
import casadi as ca
x = ca.SX.sym("x", 2)
fn = ca.Function("sq", [x], [x * x + ca.sin(x)])
"""


def _function() -> ca.Function:
    namespace: dict[str, object] = {}
    exec(PROBE, namespace)  # noqa: S102 - the fixed probe above, shared with the child process
    fn = namespace["fn"]
    assert isinstance(fn, ca.Function)
    return fn


def _compiler(tmp_path: Path, body: str) -> tuple[Path, Path]:
    """A fake C compiler (a shell script) that counts its runs in a file, then runs ``body``."""
    calls = tmp_path / "calls"
    cc = tmp_path / "cc"
    cc.write_text(f'#!/bin/sh\necho run >> "{calls}"\n{body}\n')
    cc.chmod(0o755)
    return cc, calls


def _runs(calls: Path) -> int:
    return len(calls.read_text().splitlines()) if calls.exists() else 0


@pytest.fixture
def cache(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    monkeypatch.setenv("CABINPLAN_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.setenv("CABINPLAN_NATIVE", "1")
    monkeypatch.setattr(native_module, "_WARNED", set())
    return tmp_path / "cache" / "native"


def test_a_failing_compiler_leaves_one_marker_and_the_next_process_uses_the_vm(
    tmp_path: Path, cache: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    cc, calls = _compiler(tmp_path, 'echo "src.c:1: error: no such thing" >&2\nexit 1')
    monkeypatch.setenv("CC", str(cc))
    fn = _function()
    assert native([fn], "policy_probe")[0] is fn  # the VM
    assert _runs(calls) == 1
    markers = list(cache.glob("*.failed"))
    assert len(markers) == 1 and markers[0].name.startswith("policy_probe-")
    report = markers[0].read_text()
    assert report.startswith("exit code 1 at ") and "no such thing" in report
    assert not list(cache.glob("*.so")) and not list(cache.glob("policy_probe-build-*"))

    # The next process: the marker stops it before the compiler runs; it evaluates on the VM.
    child = (
        PROBE
        + "from planner.kinematics.native import native\n"
        + "out = native([fn], 'policy_probe')[0]\n"
        + "print(out is fn, float(out(ca.DM([0.5, -1.0]))[1]))\n"
    )
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[2])}
    res = subprocess.run([sys.executable, "-c", child], env=env, capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr
    is_vm, value = res.stdout.split()
    assert is_vm == "True" and float(value) == pytest.approx(1.0 + np.sin(-1.0), abs=1e-15)
    assert _runs(calls) == 1  # not tried again
    assert "an earlier build failed" in res.stderr

    # A day later the marker has expired: the build is tried again (and fails again, a new marker).
    old = time.time() - builds.FAILED_RETRY_S - 60.0
    os.utime(markers[0], (old, old))
    monkeypatch.setattr(native_module, "_WARNED", set())
    assert native([fn], "policy_probe")[0] is fn
    assert _runs(calls) == 2
    assert markers[0].stat().st_mtime > old + 3600.0


def test_a_build_that_times_out_leaves_no_marker(
    tmp_path: Path, cache: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    cc, calls = _compiler(tmp_path, "exec sleep 5")
    monkeypatch.setenv("CC", str(cc))
    monkeypatch.setattr(native_module, "BUILD_TIMEOUT_S", 0.3)
    fn = _function()
    assert native([fn], "policy_probe")[0] is fn
    assert native([fn], "policy_probe")[0] is fn
    assert _runs(calls) == 2  # interrupted, not failed: tried again
    assert not list(cache.glob("*.failed"))


def test_a_working_compiler_builds_once_and_matches_the_vm(
    cache: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    if native_module._compiler() is None:
        pytest.skip("no C compiler on this machine: the fallback is covered by the tests above")
    monkeypatch.delenv("CC", raising=False)
    fn = _function()
    built = native([fn], "policy_probe")[0]
    assert built is not fn
    libs = list(cache.glob("policy_probe-*.so"))
    assert len(libs) == 1 and not list(cache.glob("*.failed"))
    mtime = libs[0].stat().st_mtime_ns
    again = native([fn], "policy_probe")[0]  # loaded, not rebuilt
    assert libs[0].stat().st_mtime_ns == mtime
    x = ca.DM([0.3, -2.0])
    assert np.array_equal(np.asarray(built(x)), np.asarray(fn(x)))
    assert np.array_equal(np.asarray(again(x)), np.asarray(fn(x)))


def test_a_damaged_library_is_set_aside_and_built_again(cache: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A library another process left damaged (never loaded here): renamed to .bad, built again, once."""
    if native_module._compiler() is None:
        pytest.skip("no C compiler on this machine: the fallback is covered by the tests above")
    monkeypatch.delenv("CC", raising=False)
    child = (
        PROBE
        + "from planner.kinematics.native import native\nassert native([fn], 'policy_damaged')[0] is not fn\n"
    )
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[2])}
    res = subprocess.run([sys.executable, "-c", child], env=env, capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr
    (lib,) = cache.glob("policy_damaged-*.so")
    lib.write_bytes(b"not a library")
    fn = _function()
    rebuilt = native([fn], "policy_damaged")[0]
    assert rebuilt is not fn and lib.with_name(lib.name + ".bad").read_bytes() == b"not a library"
    x = ca.DM([0.3, -2.0])
    assert np.array_equal(np.asarray(rebuilt(x)), np.asarray(fn(x)))
