"""Per-episode metrics of a ``|phi|(t)`` trace: how fast and how far a policy holds the constraint.

Every metric comes in the raw units of ``phi`` (m^2/s^2 for flocking, m/s for the USV, ...) and,
suffixed ``_sf``, in the task's scale-free units (``info["abs_phi_sf"]``: the sine of a misalignment
angle for flocking, a speed over 1 m/s for the USV), which compare across the episode's time and
across tasks.

``mean_abs_phi``
    mean of ``|phi|`` over the episode's steps (the states after each action; not the reset state).
``late_abs_phi``
    mean over the second half of the steps: the level left once the transient has decayed, where a
    held law's sampled-data floor shows (the episode mean is dominated by the transient).
``time_to_1pct``
    first time (s) at which ``|phi| <= 0.01 |phi(0)|``; the episode's duration if never (see
    ``reached_1pct``).
``control_energy``
    ``sum_t sum_a u_a^2 dt`` (N^2 s) of the applied forces.
``return``, ``length``, ``terminated``
    undiscounted return, steps taken, and whether the episode ended by termination (a non-finite
    state, leaving the domain, ...) rather than the time limit.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

__all__ = ["METRICS", "episode_metrics"]

#: Per-episode metrics, in table order (raw units, then scale-free ones).
METRICS = ("mean_abs_phi", "late_abs_phi", "time_to_1pct", "control_energy", "return", "terminated",
           "mean_abs_phi_sf", "late_abs_phi_sf", "time_to_1pct_sf", "reached_1pct", "length")
#: Metrics where a larger value is better (all others: smaller is better).
HIGHER_IS_BETTER = frozenset({"return", "reached_1pct"})


def _time_to(trace: NDArray[np.float64], dt: float, horizon: float) -> tuple[float, bool]:
    """First time ``trace[t] <= 0.01 trace[0]`` (the trace includes t = 0), or the horizon."""
    below = np.flatnonzero(trace[1:] <= 0.01 * trace[0])
    if below.size == 0:
        return horizon, False
    return float(below[0] + 1) * dt, True


def episode_metrics(abs_phi: NDArray[np.float64], abs_phi_sf: NDArray[np.float64], force: NDArray[np.float64],
                    reward: NDArray[np.float64], dt: float, terminated: bool, horizon: float) -> dict[str, float]:
    """The metrics of one episode.

    Parameters
    ----------
    abs_phi, abs_phi_sf : ndarray, shape (T + 1,)
        ``|phi|`` and its scale-free version at the reset state and after each of the ``T`` steps.
    force : ndarray, shape (T, m)
        The applied forces (N).
    reward : ndarray, shape (T,)
    dt : float
        The control period (s).
    terminated : bool
    horizon : float
        The episode's full duration (s): ``time_to_1pct`` when it never gets there.
    """
    t = int(reward.shape[0])
    if t == 0:
        raise ValueError("an episode needs at least one step")
    late = slice(1 + t // 2, t + 1)
    time_raw, reached = _time_to(abs_phi, dt, horizon)
    time_sf, _ = _time_to(abs_phi_sf, dt, horizon)
    return {
        "mean_abs_phi": float(np.mean(abs_phi[1:])),
        "late_abs_phi": float(np.mean(abs_phi[late])),
        "time_to_1pct": time_raw,
        "control_energy": float(np.sum(force * force) * dt),
        "return": float(np.sum(reward)),
        "terminated": float(terminated),
        "mean_abs_phi_sf": float(np.mean(abs_phi_sf[1:])),
        "late_abs_phi_sf": float(np.mean(abs_phi_sf[late])),
        "time_to_1pct_sf": time_sf,
        "reached_1pct": float(reached),
        "length": float(t),
    }
