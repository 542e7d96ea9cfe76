"""Start-up: modules load with the cyclic garbage collector suspended, and it is restored afterwards."""

from __future__ import annotations

import gc
import os
import subprocess
import sys

import pytest

from planner.core.startup import loading_modules


def test_the_collector_is_suspended_while_loading_and_restored_after_even_on_error() -> None:
    assert gc.isenabled()
    with loading_modules():
        assert not gc.isenabled()
    assert gc.isenabled()
    with pytest.raises(ImportError), loading_modules():
        import planner.no_such_module  # type: ignore[import-not-found]  # noqa: F401
    assert gc.isenabled()
    gc.disable()
    try:
        with loading_modules():
            pass
        assert not gc.isenabled()  # left as it was found
    finally:
        gc.enable()


def test_freeze_moves_what_is_alive_out_of_later_collections() -> None:
    before = gc.get_freeze_count()
    try:
        with loading_modules(freeze=True):
            kept = [[i] for i in range(1000)]  # container objects alive at the end of the block
        assert gc.get_freeze_count() >= before + len(kept)
        assert gc.isenabled()
    finally:
        gc.unfreeze()


def test_the_command_line_leaves_the_collector_running() -> None:
    import planner.cli  # noqa: F401 - its import loads the commands under loading_modules(freeze=True)

    assert gc.isenabled()


def test_the_install_compiles_the_projects_bytecode() -> None:
    """`make` compiles planner and api (install, run, serve, test): PYTHONDONTWRITEBYTECODE never would.

    On CI (``make test`` on a fresh clone) every module of the plan's import chain has its bytecode
    file, so a `cabinplan plan` does not compile them again.
    """
    import importlib.util
    import os
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parents[2]
    recipe = (root / "Makefile").read_text()
    assert "-m compileall -q planner api" in recipe
    if not os.environ.get("CI"):  # a developer's tree may hold modules added since the last `make`
        pytest.skip("checked on CI's fresh clone (CI set), where `make test` compiled the tree first")
    import planner.plan.pipeline  # noqa: F401 - the chain whose bytecode is checked

    ours = [m for m in list(sys.modules.values()) if getattr(m, "__file__", None)]
    ours = [m for m in ours if str(m.__file__).startswith(str(root / "planner"))]
    assert len(ours) > 50
    missing = [
        m.__name__ for m in ours if not Path(importlib.util.cache_from_source(str(m.__file__))).exists()
    ]
    assert not missing, missing


_FAULTS = """
import resource, sys
import numpy as np
if sys.argv[1] == "tuned":
    from planner.core.startup import tune_allocator
    assert tune_allocator()
def gate_like():
    # A gate's pattern: a few arrays of a profile's samples by its tasks (2-3 MB each) alive together,
    # written, then freed.
    keep = [np.full((5291, 40 + 7 * k), -np.inf) for k in range(6)]
    for a in keep:
        a += 1.0
gate_like()
before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
for _ in range(20):
    gate_like()
print(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's allocator: Linux only")
def test_the_tuned_allocator_serves_large_arrays_again_without_page_faults() -> None:
    """tune_allocator: a gate's arrays, allocated and freed 20 times, fault their pages in once.

    In fresh processes (the test process may be tuned already): untuned, glibc maps and trims them again
    each time (about 43 000 page faults here); tuned, the heap's pages are reused.
    """
    # glibc's defaults: none of its allocator settings from this environment
    env = {k: v for k, v in os.environ.items() if not k.startswith(("MALLOC_", "GLIBC_TUNABLES"))}

    def faults(mode: str) -> int:
        out = subprocess.run(
            [sys.executable, "-c", _FAULTS, mode],
            capture_output=True,
            text=True,
            check=True,
            timeout=60,
            env=env,
        )
        return int(out.stdout.strip())

    plain, tuned = faults("plain"), faults("tuned")
    assert plain > 10_000, plain  # what the gate paid: its arrays' pages faulted in on every call
    assert tuned < 200, tuned
