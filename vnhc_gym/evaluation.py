"""Evaluate a policy on seeded episodes of a vnhc_gym environment, with robust aggregates.

:func:`evaluate` runs any object with a Stable-Baselines3 style ``predict`` method (the
baselines of :mod:`vnhc_gym.baselines`, an SB3 model, ...) on ``n_episodes`` episodes, episode
``i`` reset with seed ``seed + i`` (choose held-out seeds yourself, e.g. ``seed=10_000`` for
agents trained on small seeds), and returns an :class:`EvalResult`.

Episodes
--------
Every episode lasts ``max_time`` seconds: the environment is made with
``max_episode_steps = round(max_time / dt)``, so a scenario with a coarser control period
(``coarse``: ``dt = 0.1``) has the same horizon in seconds as the others.  The episodes of one
call run in lock step on ``n_episodes`` single environments and the policy is asked for all
of their actions at once (``predict`` on an ``(n, d)`` batch; ``batch=False`` asks row by row),
so the policy's Python overhead is paid once per time step, not once per episode.

Per-episode metrics
-------------------
``mean_abs_phi``
    mean of ``info["abs_phi"]`` (mean over constraint components of ``|phi|``, true state, raw
    units: m^2/s^2 for flocking, m/s for the USV) over the episode's steps (the states after
    each action; the reset state is not included).
``late_abs_phi``
    mean of ``info["abs_phi"]`` over the second half of the episode's steps: the level left
    once the initial transient has decayed (this is where a held law's sampled-data floor shows;
    ``mean_abs_phi`` is dominated by the transient).
``final_abs_phi``
    ``info["abs_phi"]`` after the last step.
``time_to_eps``
    first time (s) at which ``abs_phi < eps``; ``inf`` if never.  ``eps=None`` (default) uses a
    threshold *relative* to the episode's start: ``eps_i = 0.01 * abs_phi(t = 0)`` ("phi reduced
    100-fold"), the same meaning for both environments even though their ``phi`` have
    different units and the flocking ``phi`` grows with the leader's speed.  A number gives an
    absolute threshold in the env's units (e.g. ``1e-3`` m/s for the USV).
``settle_time``
    first time after which ``abs_phi < eps`` for the rest of the episode (``inf`` if the last
    value is not below it): robust to a noisy trace that touches the threshold once.
``energy``
    control energy ``sum_t sum_a force_a^2 dt`` (N^2 s) of the applied forces ``info["force"]``.
``return``
    undiscounted sum of rewards.
``length``, ``terminated``, ``truncated``, ``termination_reason``
    steps taken, the flags of the last step and ``info["termination_reason"]`` (or ``""``).

The ``|phi|(t)`` series (``phi_series``, shape ``(n_episodes, T + 1)`` including ``t = 0``,
NaN after a termination) is kept for figures.

Aggregates
----------
For every metric: the interquartile mean (IQM, the mean of the middle 50 %, as recommended by
Agarwal et al. 2021, "Deep RL at the edge of the statistical precipice") with a 95 % percentile
bootstrap confidence interval over episodes, plus mean, median and standard deviation.  The
bootstrap is ``scipy.stats.bootstrap`` (percentile method, 2000 resamples, seeded): the
stratified bootstrap of ``rliable`` resamples runs *within each task* and so reduces, for a
single environment-scenario cell as here, to the plain bootstrap over episodes; scipy is
already a dependency and rliable (with its extra dependencies) would add nothing.  Cells are
never pooled across tasks.  An IQM over values that include ``inf`` (``time_to_eps`` that was
never reached) is computed the same way and may be ``inf``.

Output
------
:meth:`EvalResult.to_json`, :meth:`EvalResult.to_csv` (one row per episode),
:func:`results_to_csv` (one summary row per result) and :func:`markdown_table` (many results).
"""

from __future__ import annotations

import csv
import inspect
import json
import math
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
from numpy.typing import NDArray
from scipy import stats

__all__ = ["evaluate", "EvalResult", "Aggregate", "aggregate", "iqm", "markdown_table", "results_to_csv",
           "METRICS", "short_env_name"]

#: Per-episode metrics, in table order.
METRICS = ("mean_abs_phi", "late_abs_phi", "final_abs_phi", "time_to_eps", "settle_time", "energy", "return", "length")
#: Relative default threshold of ``time_to_eps`` (fraction of the episode's initial ``abs_phi``).
DEFAULT_EPS_RELATIVE = 1e-2


def short_env_name(env_id: str) -> str:
    """``"vnhc_gym/FlockingAlign-v0"`` -> ``"flocking"``, ``"vnhc_gym/USVStream-v0"`` -> ``"usv"``."""
    base = env_id.split("/")[-1].split(":")[-1]
    low = base.lower()
    if low.startswith("flocking"):
        return "flocking"
    if low.startswith("usv"):
        return "usv"
    return base


def iqm(x: NDArray[np.float64], axis: int = -1) -> NDArray[np.float64] | float:
    """Interquartile mean: ``scipy.stats.trim_mean(x, 0.25)`` (25 % cut at each end)."""
    return stats.trim_mean(x, 0.25, axis=axis)


@dataclass(frozen=True)
class Aggregate:
    """Summary of one metric over episodes."""

    iqm: float
    ci_low: float
    ci_high: float
    mean: float
    median: float
    std: float
    n: int

    def to_dict(self) -> dict[str, float]:
        return {"iqm": self.iqm, "ci_low": self.ci_low, "ci_high": self.ci_high, "mean": self.mean,
                "median": self.median, "std": self.std, "n": self.n}

    def format(self, fmt: str = ".3g") -> str:
        """``"IQM [lo, hi]"``."""
        return f"{self.iqm:{fmt}} [{self.ci_low:{fmt}}, {self.ci_high:{fmt}}]"


_BOOT_RNG_KW = "rng" if "rng" in inspect.signature(stats.bootstrap).parameters else "random_state"


def aggregate(values: Sequence[float] | NDArray[np.float64], confidence: float = 0.95, n_resamples: int = 2000,
              seed: int = 0) -> Aggregate:
    """IQM with a percentile-bootstrap confidence interval, plus mean, median and std.

    Non-finite values are kept (an ``inf`` time means "never"); the interval then comes from a
    plain numpy bootstrap with the same resampling, since ``scipy.stats.bootstrap`` rejects them.
    NaN values (missing) are dropped.
    """
    x = np.asarray(values, dtype=np.float64).ravel()
    x = x[~np.isnan(x)]
    n = x.size
    if n == 0:
        nan = float("nan")
        return Aggregate(nan, nan, nan, nan, nan, nan, 0)
    center = float(iqm(x))
    with np.errstate(invalid="ignore"):
        mean, median = float(np.mean(x)), float(np.median(x))
        std = float(np.std(x, ddof=1)) if n > 1 else 0.0
    if n < 2 or np.all(x == x[0]):
        lo = hi = center
    elif np.all(np.isfinite(x)):
        res = stats.bootstrap((x,), iqm, n_resamples=n_resamples, confidence_level=confidence, method="percentile",
                              vectorized=True, **{_BOOT_RNG_KW: np.random.default_rng(seed)})
        lo, hi = float(res.confidence_interval.low), float(res.confidence_interval.high)
    else:
        rng = np.random.default_rng(seed)
        samples = x[rng.integers(0, n, size=(n_resamples, n))]
        boots = np.sort(samples, axis=1)
        cut = int(math.floor(0.25 * n))
        mid = boots[:, cut:n - cut]
        with np.errstate(invalid="ignore"):
            st = np.mean(mid, axis=1)
        alpha = (1 - confidence) / 2
        lo, hi = (float(v) for v in np.quantile(st, [alpha, 1 - alpha], method="lower"))
    return Aggregate(center, lo, hi, mean, median, std, n)


@dataclass
class EvalResult:
    """Per-episode metrics and ``|phi|(t)`` series of one policy on one env and scenario.

    Per-episode arrays have length ``n_episodes``; ``phi_series`` is ``(n_episodes, T + 1)``
    with ``times`` of length ``T + 1`` (NaN after an early termination).
    """

    policy: str
    env_id: str
    scenario: str
    seed: int
    n_episodes: int
    dt: float
    max_steps: int
    eps: str
    mean_abs_phi: NDArray[np.float64]
    late_abs_phi: NDArray[np.float64]
    final_abs_phi: NDArray[np.float64]
    initial_abs_phi: NDArray[np.float64]
    time_to_eps: NDArray[np.float64]
    settle_time: NDArray[np.float64]
    energy: NDArray[np.float64]
    returns: NDArray[np.float64]
    length: NDArray[np.int64]
    terminated: NDArray[np.bool_]
    truncated: NDArray[np.bool_]
    termination_reason: list[str]
    times: NDArray[np.float64]
    phi_series: NDArray[np.float64]
    wall_time: float = 0.0
    env_kwargs: dict[str, Any] = field(default_factory=dict)
    _summary: dict[str, Aggregate] | None = field(default=None, repr=False)

    def metric(self, name: str) -> NDArray[np.float64]:
        """Per-episode values of a metric of :data:`METRICS`."""
        if name == "return":
            return self.returns
        if name not in METRICS:
            raise ValueError(f"unknown metric {name!r}; valid: {list(METRICS)}")
        return np.asarray(getattr(self, name), dtype=np.float64)

    def summary(self) -> dict[str, Aggregate]:
        """:class:`Aggregate` of every metric (computed once)."""
        if self._summary is None:
            self._summary = {m: aggregate(self.metric(m), seed=self.seed) for m in METRICS}
        return self._summary

    @property
    def termination_rate(self) -> float:
        return float(np.mean(self.terminated)) if self.n_episodes else float("nan")

    @property
    def env_short(self) -> str:
        return short_env_name(self.env_id)

    def episodes(self) -> list[dict[str, Any]]:
        """One dict per episode (the CSV rows)."""
        rows = []
        for i in range(self.n_episodes):
            rows.append({
                "policy": self.policy, "env": self.env_short, "env_id": self.env_id, "scenario": self.scenario,
                "episode": i, "seed": self.seed + i, "mean_abs_phi": float(self.mean_abs_phi[i]),
                "late_abs_phi": float(self.late_abs_phi[i]), "final_abs_phi": float(self.final_abs_phi[i]),
                "initial_abs_phi": float(self.initial_abs_phi[i]),
                "time_to_eps": float(self.time_to_eps[i]), "settle_time": float(self.settle_time[i]),
                "energy": float(self.energy[i]), "return": float(self.returns[i]), "length": int(self.length[i]),
                "terminated": bool(self.terminated[i]), "truncated": bool(self.truncated[i]),
                "termination_reason": self.termination_reason[i],
            })
        return rows

    def to_dict(self, series: bool = False) -> dict[str, Any]:
        """JSON-ready dict: settings, summary and episodes (and the series if ``series``)."""
        out: dict[str, Any] = {
            "policy": self.policy, "env_id": self.env_id, "env": self.env_short, "scenario": self.scenario,
            "seed": self.seed, "n_episodes": self.n_episodes, "dt": self.dt, "max_steps": self.max_steps,
            "max_time": self.dt * self.max_steps, "eps": self.eps, "wall_time": self.wall_time,
            "env_kwargs": self.env_kwargs, "termination_rate": self.termination_rate,
            "summary": {k: v.to_dict() for k, v in self.summary().items()},
            "episodes": self.episodes(),
        }
        if series:
            out["times"] = self.times.tolist()
            out["phi_series"] = [[None if not np.isfinite(v) else float(v) for v in row] for row in self.phi_series]
        return out

    def to_json(self, path: str | Path | None = None, series: bool = False) -> str:
        """JSON text (``inf`` written as the string ``"inf"``); written to ``path`` if given."""
        text = json.dumps(_jsonable(self.to_dict(series=series)), indent=2)
        if path is not None:
            Path(path).write_text(text)
        return text

    def to_csv(self, path: str | Path) -> None:
        """One row per episode."""
        rows = self.episodes()
        with open(path, "w", newline="") as fh:
            writer = csv.DictWriter(fh, fieldnames=list(rows[0]) if rows else ["policy"])
            writer.writeheader()
            writer.writerows(rows)

    def summary_row(self) -> dict[str, Any]:
        """One flat row: settings and ``<metric>_{iqm,ci_low,ci_high,mean}``."""
        row: dict[str, Any] = {"env": self.env_short, "scenario": self.scenario, "policy": self.policy,
                               "n_episodes": self.n_episodes, "dt": self.dt, "max_steps": self.max_steps,
                               "termination_rate": self.termination_rate}
        for name, agg in self.summary().items():
            for key in ("iqm", "ci_low", "ci_high", "mean"):
                row[f"{name}_{key}"] = getattr(agg, key)
        return row


def _jsonable(obj: Any) -> Any:
    if isinstance(obj, dict):
        return {k: _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, float | np.floating):
        v = float(obj)
        if math.isnan(v):
            return None
        if math.isinf(v):
            return "inf" if v > 0 else "-inf"
        return v
    if isinstance(obj, np.integer):
        return int(obj)
    if isinstance(obj, np.bool_):
        return bool(obj)
    return obj


def results_to_csv(results: Iterable[EvalResult], path: str | Path) -> None:
    """One summary row per result (see :meth:`EvalResult.summary_row`)."""
    rows = [r.summary_row() for r in results]
    with open(path, "w", newline="") as fh:
        if not rows:
            return
        writer = csv.DictWriter(fh, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)


def markdown_table(results: Iterable[EvalResult], metrics: Sequence[str] = ("mean_abs_phi", "return"),
                   fmt: str = ".3g") -> str:
    """A Markdown table, one row per result: env, scenario, policy and ``IQM [95% CI]`` per metric."""
    for m in metrics:
        if m not in METRICS:
            raise ValueError(f"unknown metric {m!r}; valid: {list(METRICS)}")
    head = ["env", "scenario", "policy", *[f"{m} IQM [95% CI]" for m in metrics], "terminated"]
    lines = ["| " + " | ".join(head) + " |", "|" + "|".join("---" for _ in head) + "|"]
    for r in results:
        s = r.summary()
        cells = [r.env_short, r.scenario, r.policy, *[s[m].format(fmt) for m in metrics],
                 f"{int(np.sum(r.terminated))}/{r.n_episodes}"]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def _accepts_episode_start(policy: Any) -> bool:
    try:
        params = inspect.signature(policy.predict).parameters
    except (TypeError, ValueError):
        return False
    return "episode_start" in params and "state" in params


def _select_state(state: Any, keep: NDArray[np.bool_]) -> Any:
    """Rows ``keep`` of a recurrent state (array, or tuple of arrays with the batch on axis 1 as in SB3-contrib)."""
    if state is None:
        return None
    if isinstance(state, tuple):
        return tuple(_select_state(s, keep) for s in state)
    arr = np.asarray(state)
    if arr.ndim >= 2 and arr.shape[1] == keep.size:
        return arr[:, keep]
    if arr.ndim >= 1 and arr.shape[0] == keep.size:
        return arr[keep]
    return state


def _policy_name(policy: Any) -> str:
    name = getattr(policy, "name", None)
    if isinstance(name, str):
        return name
    return type(policy).__name__


def evaluate(policy: Any, env_id: str, scenario: str = "nominal", n_episodes: int = 10, seed: int = 0,
             env_kwargs: dict[str, Any] | None = None, max_time: float = 20.0, eps: float | None = None, *,
             wrapper: Callable[[gym.Env], gym.Env] | None = None, name: str | None = None, batch: bool = True,
             deterministic: bool = True, record_series: bool = True) -> EvalResult:
    """Run ``policy`` on ``n_episodes`` seeded episodes and compute the metrics (module docstring).

    Parameters
    ----------
    policy : object with ``predict`` or callable
        Anything with ``predict(obs, state=None, episode_start=None, deterministic=True) ->
        (action, state)`` (SB3 models and :mod:`vnhc_gym.baselines` policies).  A callable
        without ``predict`` (or a class) is a *factory*: it is called once with the first (wrapped)
        environment and must return such a policy; use this for policies that read the
        environment, e.g. ``lambda env: GeometricController(env)`` (the force bound and
        ``dt`` depend on the scenario).
    env_id : str
        A registered id, e.g. ``"vnhc_gym/USVStream-v0"``.
    scenario : str
        One of ``vnhc_gym.envs.SCENARIOS``; an unknown name raises ``ValueError``.
    n_episodes : int
        Episodes; episode ``i`` is reset with ``seed + i``.
    seed : int
    env_kwargs : dict, optional
        Extra keyword arguments of the environment (they override the scenario's).
    max_time : float
        Episode length in seconds (``max_episode_steps = round(max_time / dt)``).
    eps : float, optional
        Threshold of ``time_to_eps``: ``None`` = ``0.01 * |phi(0)|`` per episode; a number =
        absolute, in the env's units.
    wrapper : callable, optional
        Applied to every environment after ``gym.make`` (e.g. ``ResidualAction``).
    name : str, optional
        Policy name in the result (default: ``policy.name`` or its class name).
    batch : bool, default True
        Ask the policy for all running episodes' actions in one ``predict`` call.
    deterministic : bool
        Passed to ``predict``.
    record_series : bool
        Keep the ``|phi|(t)`` series.
    """
    from vnhc_gym.envs.task import SCENARIOS

    if scenario not in SCENARIOS:
        raise ValueError(f"unknown scenario {scenario!r}; valid names: {sorted(SCENARIOS)}")
    if int(n_episodes) != n_episodes or n_episodes < 1:
        raise ValueError(f"n_episodes must be an integer >= 1, got {n_episodes!r}")
    if not (np.isfinite(max_time) and max_time > 0):
        raise ValueError(f"max_time must be a finite number > 0, got {max_time!r}")
    if eps is not None and not (np.isfinite(eps) and eps > 0):
        raise ValueError(f"eps must be None or a finite number > 0, got {eps!r}")
    n = int(n_episodes)
    kwargs = dict(env_kwargs or {})
    t_start = time.perf_counter()
    envs: list[gym.Env] = []
    try:
        first = gym.make(env_id, scenario=scenario, disable_env_checker=True, **kwargs)
        dt = float(first.unwrapped.config.dt)  # type: ignore[attr-defined]
        first.close()
        max_steps = max(1, round(max_time / dt))
        for _ in range(n):
            env = gym.make(env_id, scenario=scenario, max_episode_steps=max_steps, disable_env_checker=True, **kwargs)
            envs.append(wrapper(env) if wrapper is not None else env)
        if isinstance(policy, type) or not hasattr(policy, "predict"):
            if not callable(policy):
                raise TypeError("policy must have a predict method or be a factory callable(env) -> policy")
            policy = policy(envs[0])
            if not hasattr(policy, "predict"):
                raise TypeError("the policy factory must return an object with a predict method")
        pname = name or _policy_name(policy)
        if hasattr(policy, "reset"):
            policy.reset()

        obs0 = []
        init_phi = np.empty(n)
        for i, env in enumerate(envs):
            o, info = env.reset(seed=seed + i)
            obs0.append(o)
            init_phi[i] = info["abs_phi"]
        obs = np.stack(obs0)
        series = np.full((n, max_steps + 1), np.nan)
        series[:, 0] = init_phi
        returns = np.zeros(n)
        energy = np.zeros(n)
        length = np.zeros(n, dtype=np.int64)
        terminated = np.zeros(n, dtype=bool)
        truncated = np.zeros(n, dtype=bool)
        reasons = [""] * n
        active = np.ones(n, dtype=bool)
        episode_start = np.ones(n, dtype=bool)
        recurrent = _accepts_episode_start(policy) and batch
        rnn_state: Any = None
        prev_rows = np.arange(n)
        step = 0
        while active.any():
            rows = np.flatnonzero(active)
            if recurrent:
                # SB3 recurrent policies: keep the state; episodes end together or the batch shrinks,
                # in which case the state rows are dropped with the finished episodes.
                if rnn_state is not None and rows.size != prev_rows.size:
                    keep = np.isin(prev_rows, rows)
                    rnn_state = _select_state(rnn_state, keep)
                actions, rnn_state = policy.predict(obs[rows], state=rnn_state, episode_start=episode_start[rows],
                                                    deterministic=deterministic)
                prev_rows = rows
                actions = np.asarray(actions)
            elif batch:
                actions, _ = policy.predict(obs[rows], deterministic=deterministic)
                actions = np.asarray(actions)
                if actions.shape[0] != rows.size:
                    raise ValueError(f"policy returned {actions.shape[0]} actions for a batch of {rows.size}")
            else:
                actions = np.stack([np.asarray(policy.predict(obs[i], deterministic=deterministic)[0])
                                    for i in rows])
            episode_start[:] = False
            step += 1
            for j, i in enumerate(rows.tolist()):
                o, r, term, trunc, info = envs[i].step(actions[j])
                obs[i] = o
                returns[i] += r
                f = info["force"]
                energy[i] += float(np.dot(f, f)) * dt
                series[i, step] = info["abs_phi"]
                length[i] = step
                if term or trunc:
                    active[i] = False
                    terminated[i] = bool(term)
                    truncated[i] = bool(trunc)
                    reasons[i] = str(info.get("termination_reason", ""))
    finally:
        for env in envs:
            env.close()

    with np.errstate(invalid="ignore"):
        mean_abs = np.array([np.mean(series[i, 1:length[i] + 1]) for i in range(n)])
        late_abs = np.array([np.mean(series[i, length[i] // 2 + 1:length[i] + 1]) for i in range(n)])
    final_abs = series[np.arange(n), length]
    thresh = DEFAULT_EPS_RELATIVE * init_phi if eps is None else np.full(n, float(eps))
    t_eps = np.full(n, np.inf)
    t_settle = np.full(n, np.inf)
    times = np.arange(max_steps + 1, dtype=np.float64) * dt
    for i in range(n):
        below = series[i, : length[i] + 1] < thresh[i]
        hit = np.flatnonzero(below)
        if hit.size:
            t_eps[i] = times[hit[0]]
        if below[-1]:
            above = np.flatnonzero(~below)
            t_settle[i] = times[above[-1] + 1] if above.size else 0.0
    eps_text = f"relative {DEFAULT_EPS_RELATIVE:g} * abs_phi(0)" if eps is None else f"absolute {eps:g}"
    return EvalResult(
        policy=pname, env_id=env_id, scenario=scenario, seed=int(seed), n_episodes=n, dt=dt, max_steps=max_steps,
        eps=eps_text, mean_abs_phi=mean_abs, late_abs_phi=late_abs, final_abs_phi=final_abs, initial_abs_phi=init_phi,
        time_to_eps=t_eps,
        settle_time=t_settle, energy=energy, returns=returns, length=length, terminated=terminated,
        truncated=truncated, termination_reason=reasons, times=times,
        phi_series=series if record_series else np.empty((n, 0)), wall_time=time.perf_counter() - t_start,
        env_kwargs=kwargs,
    )
