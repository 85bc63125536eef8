"""The per-row SplitMix64 streams (vnhc_gym.envs._random): distribution and independence checks
against textbook facts, and the stream isolation the vector envs rely on."""

from __future__ import annotations

import numpy as np
import pytest
from numba import njit
from scipy import stats

from vnhc_gym.envs._random import entropy_states, next_u64, normal_pair, seed_states, sign, uniform, uniform_ab


@njit(cache=True)
def _bits(state, k):
    out = np.empty(k, dtype=np.uint64)
    for i in range(k):
        out[i] = next_u64(state, 0)
    return out


@njit(cache=True)
def _uniforms(state, r, k):
    out = np.empty(k)
    for i in range(k):
        out[i] = uniform(state, r)
    return out


@njit(cache=True)
def _normals(state, r, k):
    out = np.empty((k, 2))
    for i in range(k):
        out[i, 0], out[i, 1] = normal_pair(state, r)
    return out


@njit(cache=True)
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


@pytest.mark.parametrize("env_id", ["vnhc_gym/FlockingAlign-v0", "vnhc_gym/USVStream-v0"])
def test_a_row_draws_only_from_its_own_stream(env_id: str) -> None:
    """Resetting rows together or one by one, in any order, gives every row the same episode:
    what makes a vector env equal N single envs."""
    from vnhc_gym.envs.vector import FlockingAlignVectorEnv, USVStreamVectorEnv

    cls = FlockingAlignVectorEnv if "Flocking" in env_id else USVStreamVectorEnv
    together = cls(4, scenario="mismatch")
    together.reset(seed=[10, 11, 12, 13])
    apart = cls(4, scenario="mismatch")
    apart.reset(seed=[13, 12, 11, 10])  # rows get other streams first ...
    mask = np.zeros(4, dtype=np.bool_)
    for i in (2, 0, 3, 1):  # ... then each row is re-seeded and reset on its own
        mask[:] = False
        mask[i] = True
        apart.reset(seed=[10 + j if j == i else None for j in range(4)], options={"reset_mask": mask})
    np.testing.assert_array_equal(together.task.state, apart.task.state)
    np.testing.assert_array_equal(together.task.params_true, apart.task.params_true)
    np.testing.assert_array_equal(together.task.rng, apart.task.rng)
