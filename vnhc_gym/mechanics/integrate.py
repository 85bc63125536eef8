"""Fixed-step RK4 simulation of a [`ConstrainedSystem`][vnhc_gym.mechanics.ConstrainedSystem] over
many control periods."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from vnhc_gym.mechanics.model import ConstrainedSystem, Feedback

__all__ = ["Trajectory", "simulate"]


@dataclass(frozen=True)
class Trajectory:
    """A recorded simulation; arrays have a leading time axis of length ``n_records``.

    Attributes
    ----------
    t : ndarray, shape (T,)
    states : ndarray, shape (T, [B,] 2n)
    phi : ndarray, shape (T, [B,] m)
    u : ndarray, shape (T - 1, [B,] m)
        Control applied during each recorded step (average over its substeps).
    energy : ndarray, shape (T, [B])
    flags : ndarray, shape ([B],)
        Bitwise OR of every step's flags (see ``FLAG_SINGULAR`` / ``FLAG_NONFINITE``).
    """

    t: NDArray[np.float64]
    states: NDArray[np.float64]
    phi: NDArray[np.float64]
    u: NDArray[np.float64]
    energy: NDArray[np.float64]
    flags: NDArray[np.int64]


def simulate(model: ConstrainedSystem, state0: ArrayLike, dt: float, n_steps: int, *,
             feedback: Feedback = "continuous", gains: ArrayLike | None = None, params: ArrayLike | None = None,
             u: ArrayLike | None = None, substeps: int = 1, record_every: int = 1) -> Trajectory:
    """Integrate ``n_steps`` control periods of length ``dt`` with RK4.

    Parameters
    ----------
    model : ConstrainedSystem
    state0 : array_like, shape (2n,) or (B, 2n)
    dt : float
        Control period; each is split into ``substeps`` RK4 steps.
    n_steps : int
        Number of control periods.
    feedback : {"continuous", "sampled", "open"}
        See [`ConstrainedSystem.step`][vnhc_gym.mechanics.ConstrainedSystem.step].
    gains, params, u
        As in [`ConstrainedSystem.step`][vnhc_gym.mechanics.ConstrainedSystem.step] (``u`` is held for the whole run).
    record_every : int
        Record one state in every ``record_every`` periods (the last state is always kept).
    """
    if int(n_steps) != n_steps or n_steps < 1:
        raise ValueError(f"n_steps must be an integer >= 1, got {n_steps}")
    if int(record_every) != record_every or record_every < 1:
        raise ValueError(f"record_every must be an integer >= 1, got {record_every}")
    # One checked call validates every argument; the loop then runs the checked rows.
    model.step(state0, dt, u=u, feedback=feedback, gains=gains, params=params, substeps=substeps)
    s, single = model._states(state0)
    b = s.shape[0]
    p = model._params(params, b)
    k = model._gains(gains, b)
    uh = model._rows(u, b, model.m, "u", np.zeros(model.m))
    lo, hi = np.full(model.m, -np.inf), np.full(model.m, np.inf)
    rec_idx = list(range(0, n_steps + 1, record_every))
    if rec_idx[-1] != n_steps:
        rec_idx.append(n_steps)
    n_rec = len(rec_idx)
    states = np.empty((n_rec, b, 2 * model.n))
    us = np.zeros((n_rec - 1, b, model.m))
    states[0] = s
    cur = s.copy()
    all_flags = np.zeros(b, dtype=np.int64)
    j = 1
    for step in range(1, n_steps + 1):
        cur, u_step, flags = model._advance(cur, p, uh, k, float(dt), int(substeps), feedback, lo, hi)
        all_flags |= flags
        if j < n_rec and step == rec_idx[j]:
            states[j] = cur
            us[j - 1] = u_step
            j += 1
    flat = states.reshape(n_rec * b, -1)
    phi = model.phi(flat, np.tile(p, (n_rec, 1))).reshape(n_rec, b, model.m)
    energy = np.asarray(model.energy(flat, np.tile(p, (n_rec, 1)))).reshape(n_rec, b)
    t = np.asarray(rec_idx, dtype=np.float64) * dt
    if single:
        return Trajectory(t, states[:, 0], phi[:, 0], us[:, 0], energy[:, 0], all_flags[0])
    return Trajectory(t, states, phi, us, energy, all_flags)
