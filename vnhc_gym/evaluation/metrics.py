"""Per-episode metrics of a ``|phi|(t)`` trace: how fast and how far a policy holds the constraint.

The one number every choice is made on (tuning, checkpoints, the comparison's verdict) is
``score``: the return over the *fixed* horizon divided by its number of steps, every step after an
early termination counting 0.  It lies in ``[0, 1]`` (the per-step reward of the ``-v1`` tasks
does), higher is better, and an episode that fails half-way scores at most one half however well
it held the constraint before, so a failure can never hide behind a mean over the steps that were
taken.  dm_control and brax score their tasks the same way (the return over a fixed number of
steps).  ``success`` says whether the episode reached the time limit.

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
``score``, ``success``
    ``return / horizon_steps`` (above), and ``1 - terminated``.
``horizon_abs_phi_sf``
    the termination-aware ``mean |phi~|``: the mean over the whole horizon with every step after an
    early end counted as ``max(PHI_CAP_SF, |phi~|)`` at the last step (``PHI_CAP_SF = 1``: a
    velocity error as large as the reference speed, or a misalignment of 90 degrees).  The other
    ``mean_*`` metrics average the steps taken only; they stay as diagnostics.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

__all__ = ["HIGHER_IS_BETTER", "METRICS", "PHI_CAP_SF", "SCORE", "episode_metrics"]

#: Per-episode metrics, in table order (the score first, then raw units, then scale-free ones).
METRICS = ("score", "success", "mean_abs_phi", "late_abs_phi", "time_to_1pct", "control_energy", "return",
           "terminated", "mean_abs_phi_sf", "late_abs_phi_sf", "time_to_1pct_sf", "reached_1pct", "length",
           "horizon_abs_phi_sf")
#: Metrics where a larger value is better (all others: smaller is better).
HIGHER_IS_BETTER = frozenset({"score", "success", "return", "reached_1pct"})
#: The metric every choice is made on (see the module docstring).
SCORE = "score"
#: The scale-free ``|phi~|`` that each step after an early termination counts as (at least) in
#: ``horizon_abs_phi_sf``.
PHI_CAP_SF = 1.0


def _time_to(trace: NDArray[np.float64], dt: float, horizon: float) -> tuple[float, bool]:
    """First time ``trace[t] <= 0.01 trace[0]`` (the trace includes t = 0), or the horizon."""
    below = np.flatnonzero(trace[1:] <= 0.01 * trace[0])
    if below.size == 0:
        return horizon, False
    return float(below[0] + 1) * dt, True


def episode_metrics(abs_phi: NDArray[np.float64], abs_phi_sf: NDArray[np.float64], force: NDArray[np.float64],
                    reward: NDArray[np.float64], dt: float, terminated: bool, horizon: float,
                    horizon_steps: int | None = None) -> dict[str, float]:
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
    horizon_steps : int, optional
        Steps of the full horizon, the denominator of ``score`` (default ``round(horizon / dt)``);
        at least the ``T`` steps taken.
    """
    t = int(reward.shape[0])
    if t == 0:
        raise ValueError("an episode needs at least one step")
    n = round(horizon / dt) if horizon_steps is None else int(horizon_steps)
    if n < t:
        raise ValueError(f"horizon_steps must be at least the {t} steps taken, got {n}")
    missing = n - t
    cap = max(PHI_CAP_SF, float(abs_phi_sf[t])) if np.isfinite(abs_phi_sf[t]) else PHI_CAP_SF
    late = slice(1 + t // 2, t + 1)
    time_raw, reached = _time_to(abs_phi, dt, horizon)
    time_sf, _ = _time_to(abs_phi_sf, dt, horizon)
    return {
        "score": float(np.sum(reward)) / n,
        "success": float(not terminated),
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
        "horizon_abs_phi_sf": (float(np.sum(abs_phi_sf[1:])) + missing * cap) / n,
    }
