"""An along-path pass's compiled cumulative bound, spread and bound between samples: numpy's, bit for bit."""

from __future__ import annotations

import numpy as np
import pytest

from planner.collision.kernels.entries import DEFAULT as KERNELS


def _plain_cum(reach: np.ndarray, steps: np.ndarray) -> np.ndarray:
    return np.vstack([np.zeros((1, reach.shape[1])), np.cumsum(np.minimum(reach, steps), axis=0)])


def _plain_propagate(lower: np.ndarray, cum: np.ndarray, cols: np.ndarray) -> None:
    v, c = lower[:, cols], cum[:, cols]
    fwd = np.maximum.accumulate(v + c, axis=0) - c
    bwd = np.flip(np.maximum.accumulate(np.flip(v - c, axis=0), axis=0), axis=0) + c
    lower[:, cols] = np.maximum(v, np.maximum(fwd, bwd))


@pytest.mark.parametrize("n", [1, 2, 3, 257])
def test_cumulative_bound_is_the_plain_cumsum_bit_for_bit(n: int) -> None:
    """Each step the smaller of the reach and the vertex step (inf and NaN as np.minimum), summed in order."""
    rng = np.random.default_rng(n)
    reach = np.abs(rng.normal(0.0, 1e-3, (n - 1, 35)))
    steps = np.abs(rng.normal(0.0, 2e-3, (n - 1, 35)))
    steps[rng.random(steps.shape) < 0.1] = np.inf  # a step bound that says nothing
    if n > 3:
        reach[n // 2, 3] = np.nan
    cum = KERNELS.cumulative_bound(reach, steps)
    assert cum.shape == (n, 35)
    assert np.array_equal(cum, _plain_cum(reach, steps), equal_nan=True)


def test_propagate_is_the_plain_running_maxima_bit_for_bit() -> None:
    """Over -inf (nothing known yet), NaN and ordinary bounds, on a subset of the columns."""
    rng = np.random.default_rng(7)
    n, t = 600, 12
    lower = rng.normal(0.02, 0.01, (n, t))
    lower[rng.random((n, t)) < 0.7] = -np.inf
    lower[5, 3] = np.nan
    cum = np.vstack([np.zeros((1, t)), np.cumsum(np.abs(rng.normal(0.0, 1e-4, (n - 1, t))), axis=0)])
    cols = np.array([0, 3, 4, 11], dtype=np.int64)
    got, want = lower.copy(), lower.copy()
    KERNELS.propagate(got, cum, cols)
    _plain_propagate(want, cum, cols)
    assert np.array_equal(got, want, equal_nan=True)
    assert np.array_equal(got[:, 1], lower[:, 1])  # other columns untouched
    assert np.all(got[:, 0] >= np.where(np.isfinite(lower[:, 0]), lower[:, 0], -np.inf))


def test_the_entries_refuse_wrong_arguments_by_name() -> None:
    reach, steps = np.zeros((4, 3)), np.zeros((4, 3))
    with pytest.raises(ValueError, match="steps"):
        KERNELS.cumulative_bound(reach, np.zeros((4, 2)))
    with pytest.raises(TypeError, match="reach"):
        KERNELS.cumulative_bound(reach.astype(np.float32), steps)
    lower, cum = np.zeros((5, 3)), np.zeros((5, 3))
    with pytest.raises(ValueError, match="columns"):
        KERNELS.propagate(lower, cum, np.array([3], dtype=np.int64))
    with pytest.raises(ValueError, match="cum"):
        KERNELS.propagate(lower, np.zeros((5, 2)), np.array([0], dtype=np.int64))
    lower.flags.writeable = False
    with pytest.raises(TypeError, match="lower"):
        KERNELS.propagate(lower, cum, np.array([0], dtype=np.int64))


def _plain_between(lower: np.ndarray, reach: np.ndarray, cols: np.ndarray) -> tuple[float, int]:
    lo_a, lo_b = lower[:-1][:, cols], lower[1:][:, cols]
    r = reach[:, cols]
    between = np.maximum(0.5 * (lo_a + lo_b - r), np.maximum(lo_a, lo_b) - r)
    return float(np.min(between)), int(np.argmin(np.min(between, axis=1)))


def test_between_bound_is_the_plain_formula_bit_for_bit() -> None:
    """The smallest bound between samples and its piece, with -inf entries, ties, NaN and a column subset."""
    rng = np.random.default_rng(9)
    n, t = 500, 10
    lower = rng.normal(0.02, 0.005, (n, t))
    reach = np.abs(rng.normal(0.0, 1e-4, (n - 1, t)))
    cols = np.array([1, 4, 5, 9], dtype=np.int64)
    for case in range(4):
        low = lower.copy()
        if case >= 1:
            low[rng.random((n, t)) < 0.05] = -np.inf
        if case == 2:
            low[100:] = low[:100].min()  # ties: the first piece holding the minimum
            low[:100] = 1.0
        if case == 3:
            low[200, 4] = np.nan
        got = KERNELS.between_bound(low, reach, cols)
        want = _plain_between(low, reach, cols)
        assert got[1] == want[1]
        assert np.array_equal(np.float64(got[0]), np.float64(want[0]), equal_nan=True)
    with pytest.raises(ValueError, match="columns"):
        KERNELS.between_bound(lower, reach, np.array([], dtype=np.int64))
    with pytest.raises(ValueError, match="reach"):
        KERNELS.between_bound(lower, reach[:-1], cols)
