"""The evaluation protocol: seeded episodes of a registered environment, run as one vector batch.

[`evaluate`][vnhc_gym.evaluation.evaluate] runs a policy (anything with Stable-Baselines3's
``predict``: the baselines, an SB3 model, a loaded agent) on ``n_episodes`` episodes, episode ``i``
seeded ``seed + i``, and returns an [`EvalResult`][vnhc_gym.evaluation.EvalResult] with the
per-episode metrics of `vnhc_gym.evaluation.metrics`.  Episodes last ``max_time`` seconds whatever
the scenario's control period.  The episodes of one call are the sub-environments of one native
vector environment, so the policy is asked for all of their actions at once; held-out seeds are the
caller's choice (the project uses 10 000 and up for tests, 5 000 and up for validation, and trains
on small seeds).
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
from numpy.typing import NDArray

from vnhc_gym import stats
from vnhc_gym.evaluation.metrics import METRICS, episode_metrics

__all__ = ["AGGREGATE", "EvalResult", "evaluate", "TEST_SEED", "VALIDATION_SEED"]

#: First seed of the held-out test episodes (never used to choose anything).
TEST_SEED = 10_000
#: First seed of the validation episodes (used to tune gains and pick checkpoints).
VALIDATION_SEED = 5_000
#: How a metric is aggregated over episodes: the mean where every episode must count (the score,
#: bounded in [0, 1], and the failure counts), the interquartile mean (robust to a few outlying
#: episodes) for the diagnostics.  The IQM would trim the very failures the score counts.
AGGREGATE = {"score": "mean", "success": "mean", "terminated": "mean", "horizon_abs_phi_sf": "mean"}


@dataclass
class EvalResult:
    """The outcome of [`evaluate`][vnhc_gym.evaluation.evaluate].

    Attributes
    ----------
    env_id, scenario, policy : str
    seed : int
        Episode ``i`` was seeded ``seed + i``.
    dt : float
    metrics : dict of str to ndarray
        Per-episode values of each metric of ``METRICS`` (shape ``(n_episodes,)``).
    abs_phi, abs_phi_sf : ndarray, shape (T + 1, n_episodes)
        The traces (NaN after an episode's end), for figures.
    wall_time : float
        Seconds the evaluation took.
    """

    env_id: str
    scenario: str
    policy: str
    seed: int
    dt: float
    metrics: dict[str, NDArray[np.float64]]
    abs_phi: NDArray[np.float64]
    abs_phi_sf: NDArray[np.float64]
    wall_time: float
    env_kwargs: dict[str, Any] = field(default_factory=dict)

    @property
    def n_episodes(self) -> int:
        return int(self.abs_phi.shape[1])

    def summary(self, reps: int = 2000) -> dict[str, stats.Interval]:
        """Each metric's aggregate over episodes (`AGGREGATE`) with its 95 % bootstrap interval (the
        episodes redrawn: one evaluation is one run of `vnhc_gym.stats`)."""
        return {name: stats.interval_estimates({"x": values[None, :]}, metric=AGGREGATE.get(name, "iqm"),
                                               reps=reps)["x"]
                for name, values in self.metrics.items()}

    def to_dict(self, series: bool = False) -> dict[str, Any]:
        """A JSON-friendly dict (``series``: with the traces)."""
        out: dict[str, Any] = {
            "env_id": self.env_id, "scenario": self.scenario, "policy": self.policy, "seed": self.seed,
            "n_episodes": self.n_episodes, "dt": self.dt, "wall_time": self.wall_time,
            "env_kwargs": {k: v for k, v in self.env_kwargs.items() if isinstance(v, str | int | float | bool)},
            "metrics": {k: v.tolist() for k, v in self.metrics.items()},
            "summary": {k: [iv.point, iv.low, iv.high] for k, iv in self.summary().items()},
        }
        if series:
            out["abs_phi"] = np.where(np.isfinite(self.abs_phi), self.abs_phi, -1.0).tolist()
            out["abs_phi_sf"] = np.where(np.isfinite(self.abs_phi_sf), self.abs_phi_sf, -1.0).tolist()
        return out

    def to_json(self, path: str | Path, series: bool = False) -> None:
        Path(path).write_text(json.dumps(self.to_dict(series), indent=1))


def _name_of(policy: Any) -> str:
    return str(getattr(policy, "name", None) or type(policy).__name__)


def evaluate(policy: Any, env_id: str, scenario: str = "nominal", n_episodes: int = 10, seed: int = TEST_SEED, *,
             max_time: float = 20.0, feedback: str | None = None, gain: float = 5.0, deterministic: bool = True,
             **env_kwargs: Any) -> EvalResult:
    """Run ``policy`` on ``n_episodes`` seeded episodes of ``env_id`` and measure them.

    Parameters
    ----------
    policy : object with ``predict``, or a callable ``env -> policy``
        A baseline instance, an SB3 model, or a class such as ``GeometricController`` (built on the
        evaluation's own environment).  Recurrent policies get their ``state`` back and
        ``episode_start`` at the first step.
    env_id : str
        A registered vnhc_gym id.
    scenario : str
    n_episodes : int
    seed : int
        Episode ``i`` is seeded ``seed + i``.
    max_time : float
        Episode duration (s); ``round(max_time / dt)`` steps.
    feedback : {"continuous", "sampled"} or None
        Run the law inside the integrator on the true state (the in-loop reference; the policy's
        actions are added to it, so pass ``ZeroPolicy``).
    gain : float
        Gain of the in-loop law.
    **env_kwargs
        More environment arguments.
    """
    if isinstance(n_episodes, bool) or not isinstance(n_episodes, int) or n_episodes < 1:
        raise ValueError(f"n_episodes must be an integer >= 1, got {n_episodes!r}")
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise ValueError(f"seed must be an integer >= 0, got {seed!r}")
    probe = gym.make(env_id, scenario=scenario, **env_kwargs).unwrapped
    dt = float(probe.dt)  # type: ignore[attr-defined]
    probe.close()
    steps = max(1, round(max_time / dt))
    venv = gym.make_vec(env_id, num_envs=n_episodes, vectorization_mode="vector_entry_point",
                        max_episode_steps=steps, scenario=scenario, **env_kwargs)
    if feedback is not None:
        venv.unwrapped.batch.set_feedback(feedback, gain)  # type: ignore[attr-defined]
    if isinstance(policy, type) or (not hasattr(policy, "predict") and callable(policy)):
        policy = policy(venv)
    predict: Callable[..., Any] = policy.predict
    n = n_episodes
    t0 = time.perf_counter()
    obs, info = venv.reset(seed=seed)
    abs_phi = np.full((steps + 1, n), np.nan)
    abs_phi_sf = np.full((steps + 1, n), np.nan)
    force = np.zeros((steps, n, venv.unwrapped.task.act_dim))  # type: ignore[attr-defined]
    reward = np.zeros((steps, n))
    abs_phi[0], abs_phi_sf[0] = info["abs_phi"], info["abs_phi_sf"]
    done = np.zeros(n, dtype=bool)
    length = np.zeros(n, dtype=np.int64)
    terminated = np.zeros(n, dtype=bool)
    state = None
    starts = np.ones(n, dtype=bool)
    for t in range(steps):
        action, state = predict(obs, state=state, episode_start=starts, deterministic=deterministic)
        starts = np.zeros(n, dtype=bool)
        obs, r, term, trunc, info = venv.step(np.asarray(action))
        live = ~done
        abs_phi[t + 1, live] = info["abs_phi"][live]
        abs_phi_sf[t + 1, live] = info["abs_phi_sf"][live]
        force[t, live] = info["force"][live]
        reward[t, live] = r[live]
        ended = (term | trunc) & live
        length[ended] = t + 1
        terminated[ended] = term[ended]
        done |= ended
        if done.all():
            break
    wall = time.perf_counter() - t0
    venv.close()
    per_episode = [episode_metrics(abs_phi[: length[i] + 1, i], abs_phi_sf[: length[i] + 1, i],
                                   force[: length[i], i], reward[: length[i], i], dt, bool(terminated[i]),
                                   steps * dt, horizon_steps=steps) for i in range(n)]
    metrics = {name: np.array([m[name] for m in per_episode]) for name in METRICS}
    return EvalResult(env_id=env_id, scenario=scenario, policy=_name_of(policy), seed=seed, dt=dt, metrics=metrics,
                      abs_phi=abs_phi, abs_phi_sf=abs_phi_sf, wall_time=wall, env_kwargs=dict(env_kwargs))
