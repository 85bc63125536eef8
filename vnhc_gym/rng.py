"""What a task's kernels may use: per-row random draws and inline sine and cosine.

Every row of a batch of episodes (one single env, or one sub-env of a vector env) owns a 64-bit
SplitMix64 state in a ``uint64`` array (``rng``).  All of an episode's randomness (initial state,
parameter mismatch, random current, observation noise, impulses) is drawn from that row's stream
inside compiled kernels, so resetting 4096 sub-envs is one kernel call instead of 4096 Python
calls to ``numpy.random.Generator`` methods, and a row's draws depend only on its own seed: a
vector env seeded with ``s`` equals ``N`` single envs seeded with ``s, s + 1, ...`` draw for draw.
Call the draws as ``uniform_ab(rng, r, low, high)`` with ``r`` the row.

[`psin`][vnhc_gym.mechanics.numerics.psin], [`pcos`][vnhc_gym.mechanics.numerics.pcos] and
[`psincos`][vnhc_gym.mechanics.numerics.psincos] are the sine and cosine of the generated system
code (inline polynomials, the same bits on every machine).

Why SplitMix64: one ``uint64`` of state, a few integer operations per draw, and it passes
BigCrush (Steele, Lea and Flood, "Fast splittable pseudorandom number generators", OOPSLA
2014; it is the seeding generator of the xoshiro family).  A seed is mapped to a state by the
bijective SplitMix64 finaliser, so distinct seeds give distinct streams.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from numba import njit
from numpy.typing import NDArray

from vnhc_gym.mechanics.numerics import pcos, psin, psincos

__all__ = ["draw_mismatch", "entropy_states", "next_u64", "normal_pair", "pcos", "psin", "psincos", "seed_states",
           "sign", "uniform", "uniform_ab"]

_GAMMA = np.uint64(0x9E3779B97F4A7C15)
_M1 = np.uint64(0xBF58476D1CE4E5B9)
_M2 = np.uint64(0x94D049BB133111EB)
_SALT = np.uint64(0x6A09E667F3BCC909)
_S30, _S27, _S31, _S11 = np.uint64(30), np.uint64(27), np.uint64(31), np.uint64(11)
_TWO_M53 = 1.0 / 9007199254740992.0  # 2**-53


@njit(cache=True, inline="always")
def _mix(z: np.uint64) -> np.uint64:
    z = (z ^ (z >> _S30)) * _M1
    z = (z ^ (z >> _S27)) * _M2
    return z ^ (z >> _S31)


@njit(cache=True, inline="always")
def next_u64(state: np.ndarray, r: int) -> np.uint64:
    """Next 64 random bits of row ``r``'s stream (advances ``state[r]``)."""
    s = state[r] + _GAMMA
    state[r] = s
    return _mix(s)


@njit(cache=True, inline="always")
def uniform(state: np.ndarray, r: int) -> float:
    """Uniform on ``[0, 1)`` with 53 random bits."""
    return float(next_u64(state, r) >> _S11) * _TWO_M53


@njit(cache=True, inline="always")
def uniform_ab(state: np.ndarray, r: int, low: float, high: float) -> float:
    """Uniform on ``[low, high)``."""
    return low + (high - low) * uniform(state, r)


@njit(cache=True, inline="always")
def sign(state: np.ndarray, r: int) -> float:
    """-1.0 or 1.0 with equal probability."""
    return 1.0 if uniform(state, r) < 0.5 else -1.0


@njit(cache=True, inline="always")
def normal_pair(state: np.ndarray, r: int) -> tuple[float, float]:
    """Two independent standard normals (Box-Muller on two uniforms)."""
    u1 = 1.0 - uniform(state, r)  # (0, 1]: log is finite
    u2 = uniform(state, r)
    rad = math.sqrt(-2.0 * math.log(u1))
    s, c = psincos(2.0 * math.pi * u2)  # inline polynomial: about half the cost of libm's two calls
    return rad * c, rad * s


@njit(cache=True)
def _seed(seeds: np.ndarray, out: np.ndarray) -> None:
    for i in range(seeds.shape[0]):
        out[i] = _mix(seeds[i] ^ _SALT)


def seed_states(seeds: Sequence[int] | NDArray[np.uint64]) -> NDArray[np.uint64]:
    """Stream states for non-negative integer seeds (taken modulo ``2**64``)."""
    s = np.asarray(seeds, dtype=np.uint64) if isinstance(seeds, np.ndarray) else \
        np.array([int(v) % 2**64 for v in seeds], dtype=np.uint64)
    out = np.empty(s.shape[0], dtype=np.uint64)
    _seed(np.ascontiguousarray(s), out)
    return out


def entropy_states(k: int) -> NDArray[np.uint64]:
    """``k`` stream states from operating-system entropy (unseeded resets)."""
    return np.asarray(np.random.SeedSequence().generate_state(k, dtype=np.uint64), dtype=np.uint64)


@njit(cache=True, inline="always")
def draw_mismatch(state: np.ndarray, r: int, nominal: np.ndarray, mask: np.ndarray, delta: float,
                  out: np.ndarray) -> None:
    """``out = nominal``, times ``U(1 - delta, 1 + delta)`` where ``mask`` (one draw per masked entry,
    from row ``r``'s stream; no draw at all if ``delta == 0``)."""
    for j in range(nominal.shape[0]):
        out[j] = nominal[j]
        if delta > 0 and mask[j]:
            out[j] = nominal[j] * (1.0 + delta * (2.0 * uniform(state, r) - 1.0))
