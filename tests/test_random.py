"""The per-row SplitMix64 streams of :mod:`vnhc_gym.rng` (what a task's compiled hooks may use):
distribution and independence checks against textbook facts, the parameter-mismatch draw, and the
stream isolation the vector envs rely on."""

from __future__ import annotations

import numpy as np
import pytest
from numba import njit
from scipy import stats

import vnhc_gym.rng as public_kernels
from vnhc_gym.mechanics import numerics as core_kernels
from vnhc_gym.rng import (
    draw_mismatch,
    entropy_states,
    next_u64,
    normal_pair,
    seed_states,
    sign,
    uniform,
    uniform_ab,
)
from vnhc_gym.tasks import TASKS

#: SplitMix64's increment: every draw adds it to the state (mod 2**64).
GAMMA = 0x9E3779B97F4A7C15


# The helpers compile in each test run (no cache=True): numba's disk cache checks only this file,
# so a change in the kernels they call would otherwise be tested with stale machine code.
@njit
def _bits(state, k):
    out = np.empty(k, dtype=np.uint64)
    for i in range(k):
        out[i] = next_u64(state, 0)
    return out


@njit
def _uniforms(state, r, k):
    out = np.empty(k)
    for i in range(k):
        out[i] = uniform(state, r)
    return out


@njit
def _normals(state, r, k):
    out = np.empty((k, 2))
    for i in range(k):
        out[i, 0], out[i, 1] = normal_pair(state, r)
    return out


@njit
def _misc(state, r, k):
    out = np.empty((k, 2))
    for i in range(k):
        out[i, 0] = uniform_ab(state, r, -3.0, 5.0)
        out[i, 1] = sign(state, r)
    return out


def test_splitmix64_reference_values() -> None:
    """SplitMix64 from state 0 gives the published sequence (Vigna's splitmix64.c reference output)."""
    state = np.zeros(1, dtype=np.uint64)

    got = _bits(state, 3)
    assert [int(v) for v in got] == [0xE220A8397B1DCDAF, 0x6E789E6AA1B965F4, 0x06C45D188009454F]


def test_uniform_distribution() -> None:
    u = _uniforms(seed_states([1]), 0, 200_000)
    assert u.min() >= 0.0 and u.max() < 1.0
    assert stats.kstest(u, "uniform").pvalue > 1e-3
    assert abs(u.mean() - 0.5) < 4 * np.sqrt(1 / 12 / u.size)
    # Consecutive draws are uncorrelated.
    assert abs(np.corrcoef(u[:-1], u[1:])[0, 1]) < 4 / np.sqrt(u.size)


def test_normal_pairs_are_independent_standard_normals() -> None:
    z = _normals(seed_states([2]), 0, 100_000)
    for col in (z[:, 0], z[:, 1]):
        assert stats.kstest(col, "norm").pvalue > 1e-3
        assert abs(col.mean()) < 4 / np.sqrt(col.size)
        assert abs(col.var() - 1.0) < 4 * np.sqrt(2 / col.size)
    assert abs(np.corrcoef(z[:, 0], z[:, 1])[0, 1]) < 4 / np.sqrt(len(z))


def test_uniform_ab_and_sign() -> None:
    d = _misc(seed_states([3]), 0, 100_000)
    assert d[:, 0].min() >= -3.0 and d[:, 0].max() < 5.0
    assert abs(d[:, 0].mean() - 1.0) < 4 * 8 / np.sqrt(12 * len(d))
    assert set(np.unique(d[:, 1])) == {-1.0, 1.0}
    assert abs(d[:, 1].mean()) < 4 / np.sqrt(len(d))


def test_seeds_give_distinct_reproducible_uncorrelated_streams() -> None:
    states = seed_states(list(range(10_000)))
    assert len(np.unique(states)) == 10_000
    np.testing.assert_array_equal(seed_states([7, 7]), seed_states([7, 7])[::-1])
    a = _uniforms(seed_states([5]), 0, 10_000)
    b = _uniforms(seed_states([5]), 0, 10_000)
    c = _uniforms(seed_states([6]), 0, 10_000)
    np.testing.assert_array_equal(a, b)
    assert abs(np.corrcoef(a, c)[0, 1]) < 4 / np.sqrt(a.size)  # neighbouring seeds are unrelated
    assert seed_states([2**64 + 5])[0] == seed_states([5])[0]  # taken modulo 2**64
    assert len(np.unique(entropy_states(64))) == 64


@njit
def _mismatch(state, r, nominal, mask, delta, k):
    out = np.empty((k, nominal.shape[0]))
    for i in range(k):
        draw_mismatch(state, r, nominal, mask, delta, out[i])
    return out


def test_draw_mismatch_scales_masked_entries_uniformly() -> None:
    """out = nominal * U(1 - delta, 1 + delta) on masked entries, one draw each, nominal elsewhere."""
    nominal = np.array([2.0, 10.0, -4.0, 0.5])
    mask = np.array([True, False, True, True])
    state = seed_states([9])
    start = int(state[0])
    k = 50_000
    out = _mismatch(state, 0, nominal, mask, 0.3, k)
    assert int(state[0]) == (start + 3 * k * GAMMA) % 2**64  # exactly one draw per masked entry
    np.testing.assert_array_equal(out[:, 1], 10.0)
    factors = out[:, mask] / nominal[mask]
    assert factors.min() >= 0.7 and factors.max() < 1.3
    for col in factors.T:
        assert stats.kstest(col, "uniform", args=(0.7, 0.6)).pvalue > 1e-3
    # The draws are the row's uniforms in order: entry j of draw i is 1 + 0.3 (2 u - 1).
    u = _uniforms(seed_states([9]), 0, 3 * k).reshape(k, 3)
    np.testing.assert_allclose(factors, 1.0 + 0.3 * (2.0 * u - 1.0), rtol=1e-15)


def test_draw_mismatch_without_mismatch_draws_nothing() -> None:
    nominal = np.array([2.0, 10.0])
    state = seed_states([4])
    start = state.copy()
    out = _mismatch(state, 0, nominal, np.array([True, True]), 0.0, 10)
    np.testing.assert_array_equal(out, np.tile(nominal, (10, 1)))
    np.testing.assert_array_equal(state, start)
    out = _mismatch(state, 0, nominal, np.array([False, False]), 0.5, 10)
    np.testing.assert_array_equal(out, np.tile(nominal, (10, 1)))
    np.testing.assert_array_equal(state, start)


def test_a_row_draws_from_its_own_state_only() -> None:
    states = seed_states([1, 2, 3])
    before = states.copy()
    _uniforms(states, 1, 5)
    assert states[0] == before[0] and states[2] == before[2]
    assert int(states[1]) == (int(before[1]) + 5 * GAMMA) % 2**64


def test_public_kernels_module() -> None:
    """The sine and cosine a task may use are the generated code's own (same bits)."""
    assert public_kernels.psin is core_kernels.psin and public_kernels.pcos is core_kernels.pcos
    assert public_kernels.psincos is core_kernels.psincos
    assert set(public_kernels.__all__) >= {"draw_mismatch", "entropy_states", "next_u64", "normal_pair", "pcos",
                                           "psin", "psincos", "seed_states", "sign", "uniform", "uniform_ab"}


@pytest.mark.parametrize("task", sorted(TASKS))
def test_a_row_draws_only_from_its_own_stream(task: str) -> None:
    """Resetting rows together or one by one, in any order, gives every row the same episode:
    what makes a vector env equal N single envs.  (Every registered task.)"""
    entry = TASKS[task]
    cls = entry.vector_class

    together = cls(4, scenario="mismatch")
    together.reset(seed=[10, 11, 12, 13])
    apart = cls(4, scenario="mismatch")
    apart.reset(seed=[13, 12, 11, 10])  # rows get other streams first ...
    mask = np.zeros(4, dtype=np.bool_)
    for i in (2, 0, 3, 1):  # ... then each row is re-seeded and reset on its own
        mask[:] = False
        mask[i] = True
        apart.reset(seed=[10 + j if j == i else None for j in range(4)], options={"reset_mask": mask})
    a, b = together.batch.buf, apart.batch.buf
    np.testing.assert_array_equal(a.state, b.state)
    np.testing.assert_array_equal(a.params_true, b.params_true)
    np.testing.assert_array_equal(a.rng, b.rng)
    assert not np.array_equal(a.params_true, a.params_nominal)  # the mismatch was drawn
    assert len({tuple(row) for row in a.state}) == 4  # four different episodes
