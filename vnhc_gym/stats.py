"""Statistics for comparing policies across runs and tasks, computed as rliable does but in plain numpy/scipy.

The estimators are the interquartile mean (IQM), stratified-bootstrap confidence intervals,
the probability of improvement and performance profiles.

Data convention, as in rliable (Agarwal et al. 2021, "Deep RL at the edge of the statistical
precipice"): ``score_dict`` maps an algorithm's name to an array of shape ``(n_runs, n_tasks)``,
runs being seeds or episodes and tasks being cells such as ``(env, scenario)``.  Every
algorithm of one ``score_dict`` must be scored on the same tasks; the number of runs may differ.

Intervals are percentile intervals of a *stratified* bootstrap: each replicate redraws, with
replacement and independently for every task, as many runs as that task has, so the set of
tasks is held fixed and only run-to-run variation is measured (rliable's
``StratifiedBootstrap`` with ``task_bootstrap=False``).  Scores must be finite.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass
from typing import Any, overload

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import stats

__all__ = [
    "METRICS",
    "Interval",
    "ProfileBand",
    "aggregate_metrics",
    "interval_estimates",
    "iqm",
    "performance_profile",
    "performance_profile_intervals",
    "probability_of_improvement",
    "probability_of_improvement_interval",
    "steps_to_parity",
    "time_to_parity",
]

METRICS = ("iqm", "mean", "median")
"""Names accepted by [`interval_estimates`][vnhc_gym.stats.interval_estimates] for its vectorised metrics."""

# Bound on the elements of one block of bootstrap replicates (~16 MiB per float64 array), so
# that memory stays flat however many replicates are asked for.
_BLOCK_ELEMENTS = 1 << 21


@dataclass(frozen=True)
class Interval:
    """A point estimate with a confidence interval ``[low, high]``.

    A percentile bootstrap interval need not contain ``point`` when the bootstrap
    distribution is skewed.
    """

    point: float
    low: float
    high: float

    def format(self, fmt: str = ".3g") -> str:
        """Render as ``"point [low, high]"``, e.g. ``"0.123 [0.1, 0.15]"`` with ``fmt=".3g"``."""
        return f"{self.point:{fmt}} [{self.low:{fmt}}, {self.high:{fmt}}]"

    def __str__(self) -> str:
        return self.format()


@dataclass(frozen=True, eq=False)
class ProfileBand:
    """A performance profile with its pointwise confidence band, one value per threshold."""

    taus: NDArray[np.float64]
    point: NDArray[np.float64]
    low: NDArray[np.float64]
    high: NDArray[np.float64]


# ---------------------------------------------------------------------------------------------
# Validation


def _as_float_array(name: str, value: Any) -> NDArray[np.float64]:
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be a numeric array, got {type(value).__name__}") from exc
    if arr.size == 0:
        raise ValueError(f"{name} must not be empty, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must contain only finite values, found {int(np.sum(~np.isfinite(arr)))} NaN/inf")
    return arr


def _as_scores(name: str, value: Any, n_tasks: int | None = None) -> NDArray[np.float64]:
    arr = _as_float_array(name, value)
    if arr.ndim != 2:
        raise ValueError(f"{name} must be a 2-D array of shape (n_runs, n_tasks), got shape {arr.shape}")
    if n_tasks is not None and arr.shape[1] != n_tasks:
        raise ValueError(f"{name} must have {n_tasks} tasks (columns) like the other scores, got shape {arr.shape}")
    return arr


def _as_score_dict(score_dict: Any) -> dict[str, NDArray[np.float64]]:
    if not isinstance(score_dict, Mapping) or len(score_dict) == 0:
        raise ValueError(
            f"score_dict must be a non-empty mapping {{algorithm: scores of shape (n_runs, n_tasks)}}, "
            f"got {type(score_dict).__name__}{' (empty)' if isinstance(score_dict, Mapping) else ''}"
        )
    out: dict[str, NDArray[np.float64]] = {}
    n_tasks: int | None = None
    for alg, scores in score_dict.items():
        arr = _as_scores(f"score_dict[{alg!r}]", scores, n_tasks)
        n_tasks = arr.shape[1]
        out[alg] = arr
    return out


def _check_bool(name: str, value: Any) -> bool:
    if not isinstance(value, bool | np.bool_):
        raise ValueError(f"{name} must be True or False, got {value!r}")
    return bool(value)


def _check_bootstrap_args(reps: Any, confidence: Any) -> None:
    if isinstance(reps, bool) or not isinstance(reps, int | np.integer) or reps < 1:
        raise ValueError(f"reps must be a positive integer, got {reps!r}")
    if isinstance(confidence, bool) or not isinstance(confidence, int | float | np.floating) \
            or not 0.0 < confidence < 1.0:
        raise ValueError(f"confidence must be a number strictly between 0 and 1, got {confidence!r}")


def _as_taus(taus: Any) -> NDArray[np.float64]:
    arr = np.atleast_1d(_as_float_array("taus", taus))
    if arr.ndim != 1:
        raise ValueError(f"taus must be a scalar or a 1-D array of thresholds, got shape {arr.shape}")
    return arr


# ---------------------------------------------------------------------------------------------
# Point estimates


@overload
def iqm(scores: ArrayLike, axis: None = None) -> float: ...


@overload
def iqm(scores: ArrayLike, axis: int) -> NDArray[np.float64]: ...


def iqm(scores: ArrayLike, axis: int | None = None) -> float | NDArray[np.float64]:
    """Interquartile mean: the mean of the middle 50 % of the scores.

    Identical to rliable's ``metrics.aggregate_iqm``, i.e. ``scipy.stats.trim_mean(scores, 0.25,
    axis=None)``: with ``axis=None`` all runs and tasks are pooled, and ``int(0.25 * n)`` values
    are cut at each end of the ``n`` sorted scores.

    Parameters
    ----------
    scores : array_like
        Finite scores, usually of shape ``(n_runs, n_tasks)``; any non-empty shape is accepted.
    axis : int or None, optional
        Axis along which to trim; ``None`` (default) pools every value.

    Returns
    -------
    float or numpy.ndarray
        A float for ``axis=None``, else an array with ``axis`` removed.

    Raises
    ------
    ValueError
        If ``scores`` is empty, not numeric or not finite, or ``axis`` is out of range.
    """
    arr = _as_float_array("scores", scores)
    if axis is None:
        return float(stats.trim_mean(arr, 0.25, axis=None))
    if isinstance(axis, bool) or not isinstance(axis, int | np.integer) or not -arr.ndim <= axis < arr.ndim:
        raise ValueError(f"axis must be None or an integer in [{-arr.ndim}, {arr.ndim}), got {axis!r}")
    return np.asarray(stats.trim_mean(arr, 0.25, axis=int(axis)), dtype=np.float64)


def _mean_of_task_means(samples: NDArray[np.float64]) -> NDArray[np.float64]:
    return np.asarray(np.mean(np.mean(samples, axis=-2), axis=-1))


def _median_of_task_means(samples: NDArray[np.float64]) -> NDArray[np.float64]:
    return np.asarray(np.median(np.mean(samples, axis=-2), axis=-1))


def _batched_iqm(samples: NDArray[np.float64]) -> NDArray[np.float64]:
    flat = samples.reshape(*samples.shape[:-2], -1)
    return np.asarray(stats.trim_mean(flat, 0.25, axis=-1))


# Each takes (..., n_runs, n_tasks) and reduces the last two axes.
_VECTORISED: dict[str, Callable[[NDArray[np.float64]], NDArray[np.float64]]] = {
    "iqm": _batched_iqm,
    "mean": _mean_of_task_means,
    "median": _median_of_task_means,
}


def aggregate_metrics(scores: ArrayLike) -> dict[str, float]:
    """IQM, mean and median of one algorithm's scores, defined as in rliable.

    Parameters
    ----------
    scores : array_like, shape (n_runs, n_tasks)
        Finite scores.

    Returns
    -------
    dict
        ``{"iqm": ..., "mean": ..., "median": ...}`` where ``iqm`` pools all runs and tasks,
        ``mean`` is the mean of the per-task means and ``median`` the median of the per-task
        means (rliable's ``aggregate_iqm``, ``aggregate_mean``, ``aggregate_median``).

    Raises
    ------
    ValueError
        If ``scores`` is not a non-empty finite 2-D array.
    """
    arr = _as_scores("scores", scores)
    return {name: float(fn(arr)) for name, fn in _VECTORISED.items()}


def probability_of_improvement(x: ArrayLike, y: ArrayLike, lower_is_better: bool) -> float:
    """Probability that a run of algorithm X improves on a run of Y, averaged over tasks.

    Per task this is the Mann-Whitney U statistic divided by ``n_runs_x * n_runs_y``, i.e. the
    mean over all pairs of runs of ``1[x > y] + 0.5 * 1[x == y]``, and the result is the mean
    over tasks, as rliable's ``metrics.probability_of_improvement``.  With
    ``lower_is_better=True`` an improvement is a smaller score (``x < y``), so the result is
    ``1 - probability_of_improvement(x, y, False)``.

    Parameters
    ----------
    x : array_like, shape (n_runs_x, n_tasks)
        Scores of algorithm X.
    y : array_like, shape (n_runs_y, n_tasks)
        Scores of algorithm Y on the same tasks, in the same column order.
    lower_is_better : bool
        True when smaller scores are better (e.g. mean ``|phi|``).

    Returns
    -------
    float
        A probability in ``[0, 1]``; 0.5 means no difference.

    Raises
    ------
    ValueError
        If ``x`` or ``y`` is not a non-empty finite 2-D array, their task counts differ, or
        ``lower_is_better`` is not a bool.
    """
    xa, ya, lower = _check_pair(x, y, lower_is_better)
    return float(np.mean(np.mean(_win_matrix(xa, ya, lower), axis=(0, 1))))


def _check_pair(x: Any, y: Any, lower_is_better: Any) -> tuple[NDArray[np.float64], NDArray[np.float64], bool]:
    lower = _check_bool("lower_is_better", lower_is_better)
    xa = _as_scores("x", x)
    ya = _as_scores("y", y, xa.shape[1])
    return xa, ya, lower


def _win_matrix(x: NDArray[np.float64], y: NDArray[np.float64], lower_is_better: bool) -> NDArray[np.float64]:
    """``(n_runs_x, n_runs_y, n_tasks)`` credit of each pair: 1 for a win, 0.5 for a tie."""
    a, b = x[:, None, :], y[None, :, :]
    wins = a < b if lower_is_better else a > b
    return wins + 0.5 * (a == b)


def performance_profile(score_dict: Mapping[str, ArrayLike], taus: ArrayLike,
                        lower_is_better: bool) -> dict[str, NDArray[np.float64]]:
    """Score distribution: the fraction of all runs and tasks whose score beats each threshold.

    "Beats" is ``score > tau`` (rliable's ``create_performance_profile`` with
    ``use_score_distribution=True``) or, with ``lower_is_better=True``, ``score <= tau``, so
    that both profiles are monotone towards 1 in the direction of better thresholds.

    Parameters
    ----------
    score_dict : mapping of str to array_like of shape (n_runs, n_tasks)
        Scores per algorithm.
    taus : array_like, scalar or 1-D
        Thresholds.
    lower_is_better : bool
        Direction of improvement.

    Returns
    -------
    dict of str to numpy.ndarray
        For each algorithm, an array of shape ``(len(taus),)``.

    Raises
    ------
    ValueError
        On an empty or malformed ``score_dict``, mismatched task counts, non-finite ``taus`` or
        a non-bool ``lower_is_better``.
    """
    lower = _check_bool("lower_is_better", lower_is_better)
    data = _as_score_dict(score_dict)
    tau_arr = _as_taus(taus)
    return {alg: np.mean(_beats(scores, tau_arr, lower), axis=(0, 1)) for alg, scores in data.items()}


def _beats(scores: NDArray[np.float64], taus: NDArray[np.float64], lower_is_better: bool) -> NDArray[np.bool_]:
    s = scores[..., None]
    return s <= taus if lower_is_better else s > taus


# ---------------------------------------------------------------------------------------------
# Stratified bootstrap


def _block_sizes(reps: int, elements_per_rep: int) -> Iterator[int]:
    block = max(1, _BLOCK_ELEMENTS // elements_per_rep)
    for start in range(0, reps, block):
        yield min(block, reps - start)


def _draw_runs(rng: np.random.Generator, n_runs: int, n_tasks: int, block: int) -> NDArray[np.intp]:
    """Run indices ``(block, n_runs, n_tasks)``: each task's runs redrawn with replacement."""
    return rng.integers(0, n_runs, size=(block, n_runs, n_tasks), dtype=np.intp)


def _run_counts(idx: NDArray[np.intp], n_runs: int) -> NDArray[np.float64]:
    """How often each original run appears in each replicate: ``(block, n_runs, n_tasks)``."""
    block, _, n_tasks = idx.shape
    cell = np.arange(block)[:, None, None] * n_tasks + np.arange(n_tasks)
    counts = np.bincount((cell * n_runs + idx).ravel(), minlength=block * n_tasks * n_runs)
    return counts.reshape(block, n_tasks, n_runs).transpose(0, 2, 1).astype(np.float64)


def _percentile_bounds(replicates: NDArray[np.float64], confidence: float) -> tuple[Any, Any]:
    # Linear-interpolated percentiles of the replicates: arch's "percentile" method, which rliable uses.
    alpha = 100.0 * (1.0 - confidence) / 2.0
    low, high = np.percentile(replicates, [alpha, 100.0 - alpha], axis=0)
    return low, high


def _resolve_metric(metric: Any) -> tuple[Callable[[NDArray[np.float64]], NDArray[np.float64]],
                                          Callable[[NDArray[np.float64]], float]]:
    """(replicates -> values, one score array -> value) for a metric name or callable."""
    if isinstance(metric, str) and metric in _VECTORISED:
        batched = _VECTORISED[metric]

        def point(scores: NDArray[np.float64]) -> float:
            return float(batched(scores))

        return batched, point
    if callable(metric) and not isinstance(metric, str):
        def point(scores: NDArray[np.float64]) -> float:
            return float(metric(scores))

        def looped(samples: NDArray[np.float64]) -> NDArray[np.float64]:
            return np.array([point(s) for s in samples], dtype=np.float64)

        return looped, point
    raise ValueError(f"metric must be one of {METRICS} or a callable, got {metric!r}")


def interval_estimates(score_dict: Mapping[str, ArrayLike],
                       metric: str | Callable[[NDArray[np.float64]], float] = "iqm", reps: int = 2000,
                       confidence: float = 0.95, seed: int | None = 0) -> dict[str, Interval]:
    """Point estimate and stratified-bootstrap percentile interval of an aggregate metric.

    Equivalent to rliable's ``library.get_interval_estimates(..., method="percentile",
    task_bootstrap=False)``, but vectorised over replicates: 2000 replicates of the IQM of a
    20 x 12 score array take about 10 ms.

    Parameters
    ----------
    score_dict : mapping of str to array_like of shape (n_runs, n_tasks)
        Scores per algorithm, all on the same tasks.
    metric : {"iqm", "mean", "median"} or callable, optional
        Aggregate to estimate, as in [`aggregate_metrics`][vnhc_gym.stats.aggregate_metrics].  A callable receives one
        ``(n_runs, n_tasks)`` array and returns a float; it is called once per replicate, so it
        is much slower than the named metrics.
    reps : int, optional
        Number of bootstrap replicates.
    confidence : float, optional
        Coverage of the two-sided interval, in ``(0, 1)``.
    seed : int or None, optional
        Seed of the resampling.  Every algorithm gets a generator seeded afresh with ``seed``,
        so an algorithm's interval does not depend on the other entries of ``score_dict``.
        ``None`` draws fresh entropy.

    Returns
    -------
    dict of str to Interval
        One [`Interval`][vnhc_gym.stats.Interval] per algorithm, in the order of ``score_dict``.

    Raises
    ------
    ValueError
        On an empty or malformed ``score_dict``, mismatched task counts, an unknown
        ``metric``, ``reps < 1`` or ``confidence`` outside ``(0, 1)``.
    """
    data = _as_score_dict(score_dict)
    _check_bootstrap_args(reps, confidence)
    batched, point_fn = _resolve_metric(metric)
    out: dict[str, Interval] = {}
    for alg, scores in data.items():
        n_runs, n_tasks = scores.shape
        rng = np.random.default_rng(seed)
        task = np.arange(n_tasks)
        replicates = np.concatenate([batched(scores[_draw_runs(rng, n_runs, n_tasks, block), task])
                                     for block in _block_sizes(reps, n_runs * n_tasks)])
        low, high = _percentile_bounds(replicates, confidence)
        out[alg] = Interval(point_fn(scores), float(low), float(high))
    return out


def probability_of_improvement_interval(x: ArrayLike, y: ArrayLike, lower_is_better: bool, reps: int = 2000,
                                        confidence: float = 0.95, seed: int | None = 0) -> Interval:
    """[`probability_of_improvement`][vnhc_gym.stats.probability_of_improvement] with a
    stratified-bootstrap percentile interval.

    Each replicate resamples the runs of ``x`` and, independently, the runs of ``y``, within
    each task (rliable's ``StratifiedIndependentBootstrap``, used for its probability of
    improvement plots).

    Parameters
    ----------
    x : array_like, shape (n_runs_x, n_tasks)
        Scores of algorithm X.
    y : array_like, shape (n_runs_y, n_tasks)
        Scores of algorithm Y on the same tasks.
    lower_is_better : bool
        Direction of improvement.
    reps : int, optional
        Number of bootstrap replicates.
    confidence : float, optional
        Coverage of the two-sided interval, in ``(0, 1)``.
    seed : int or None, optional
        Seed of the resampling; ``None`` draws fresh entropy.

    Returns
    -------
    Interval
        Point estimate and interval of P(X improves on Y).

    Raises
    ------
    ValueError
        As [`probability_of_improvement`][vnhc_gym.stats.probability_of_improvement], or for
        ``reps < 1`` or ``confidence`` outside ``(0, 1)``.
    """
    xa, ya, lower = _check_pair(x, y, lower_is_better)
    _check_bootstrap_args(reps, confidence)
    (nx, n_tasks), ny = xa.shape, ya.shape[0]
    # A replicate's per-task statistic is the count-weighted mean of the original pairs' credits,
    # so the O(n_x * n_y) comparisons are made once, not once per replicate.
    win = _win_matrix(xa, ya, lower)
    win_by_task = win.transpose(2, 0, 1)  # (n_tasks, n_x, n_y)
    rng = np.random.default_rng(seed)
    replicates = []
    for block in _block_sizes(reps, (nx + ny) * n_tasks):
        cx = _run_counts(_draw_runs(rng, nx, n_tasks, block), nx)
        cy = _run_counts(_draw_runs(rng, ny, n_tasks, block), ny)
        per_task = np.sum(np.matmul(cx.transpose(2, 0, 1), win_by_task) * cy.transpose(2, 0, 1), axis=2) / (nx * ny)
        replicates.append(np.mean(per_task, axis=0))
    low, high = _percentile_bounds(np.concatenate(replicates), confidence)
    point = float(np.mean(np.mean(win, axis=(0, 1))))
    return Interval(point, float(low), float(high))


def performance_profile_intervals(score_dict: Mapping[str, ArrayLike], taus: ArrayLike, lower_is_better: bool,
                                  reps: int = 2000, confidence: float = 0.95,
                                  seed: int | None = 0) -> dict[str, ProfileBand]:
    """[`performance_profile`][vnhc_gym.stats.performance_profile] with pointwise stratified-bootstrap percentile bands.

    As rliable's ``create_performance_profile`` (score distributions, percentile method, no
    task bootstrap).

    Parameters
    ----------
    score_dict : mapping of str to array_like of shape (n_runs, n_tasks)
        Scores per algorithm, all on the same tasks.
    taus : array_like, scalar or 1-D
        Thresholds.
    lower_is_better : bool
        Direction of improvement, see [`performance_profile`][vnhc_gym.stats.performance_profile].
    reps : int, optional
        Number of bootstrap replicates.
    confidence : float, optional
        Coverage of the two-sided band at each threshold, in ``(0, 1)``.
    seed : int or None, optional
        Seed of the resampling, fresh for every algorithm as in
        [`interval_estimates`][vnhc_gym.stats.interval_estimates].

    Returns
    -------
    dict of str to ProfileBand
        For each algorithm, arrays of shape ``(len(taus),)``.

    Raises
    ------
    ValueError
        As [`performance_profile`][vnhc_gym.stats.performance_profile], or for ``reps < 1`` or
        ``confidence`` outside ``(0, 1)``.
    """
    lower = _check_bool("lower_is_better", lower_is_better)
    data = _as_score_dict(score_dict)
    tau_arr = _as_taus(taus)
    _check_bootstrap_args(reps, confidence)
    out: dict[str, ProfileBand] = {}
    for alg, scores in data.items():
        n_runs, n_tasks = scores.shape
        beats = _beats(scores, tau_arr, lower)
        # A replicate's fraction is a count-weighted sum of the original runs' indicators.
        flat_beats = beats.reshape(n_runs * n_tasks, -1).astype(np.float64)
        rng = np.random.default_rng(seed)
        replicates = np.concatenate([
            _run_counts(_draw_runs(rng, n_runs, n_tasks, block), n_runs).reshape(block, -1) @ flat_beats
            / (n_runs * n_tasks)
            for block in _block_sizes(reps, n_runs * n_tasks + tau_arr.size)
        ])
        low, high = _percentile_bounds(replicates, confidence)
        out[alg] = ProfileBand(tau_arr.copy(), np.mean(beats, axis=(0, 1)), low, high)
    return out


# ---------------------------------------------------------------------------------------------
# Learning curves


def _first_reach(x_name: str, x: Any, values: Any, target: Any, lower_is_better: Any) -> float | None:
    lower = _check_bool("lower_is_better", lower_is_better)
    xs = np.asarray(x)
    if xs.dtype.kind not in "iuf":
        raise ValueError(f"{x_name} must be a 1-D array of real numbers, got dtype {xs.dtype}")
    _as_float_array(x_name, xs)
    vals = _as_float_array("values", values)
    if xs.ndim != 1 or vals.ndim != 1 or xs.shape != vals.shape:
        raise ValueError(f"{x_name} and values must be 1-D arrays of the same length, "
                         f"got shapes {xs.shape} and {vals.shape}")
    if np.any(xs[1:] < xs[:-1]):  # not np.diff, which wraps around for unsigned steps
        raise ValueError(f"{x_name} must be non-decreasing")
    if isinstance(target, bool) or not isinstance(target, int | float | np.integer | np.floating) \
            or not math.isfinite(target):
        raise ValueError(f"target must be a finite number, got {target!r}")
    reached = vals <= target if lower else vals >= target
    hits = np.flatnonzero(reached)
    return xs[hits[0]].item() if hits.size else None


def steps_to_parity(steps: ArrayLike, values: ArrayLike, target: float, lower_is_better: bool = True) -> float | None:
    """First step at which a learning curve reaches ``target``.

    Parameters
    ----------
    steps : array_like, shape (n,)
        Non-decreasing x coordinates of the curve (environment steps, updates, ...).
    values : array_like, shape (n,)
        Finite metric at each step.
    target : float
        Level to reach, e.g. a baseline's score.
    lower_is_better : bool, optional
        Reached means ``value <= target`` if True (default), ``value >= target`` otherwise.

    Returns
    -------
    int, float or None
        The first such entry of ``steps`` (a Python ``int`` for integer steps), or ``None`` if
        the curve never reaches ``target``.

    Raises
    ------
    ValueError
        If ``steps`` or ``values`` is empty, not 1-D, not finite or of different lengths,
        ``steps`` decreases anywhere, or ``target`` is not a finite number.
    """
    return _first_reach("steps", steps, values, target, lower_is_better)


def time_to_parity(times: ArrayLike, values: ArrayLike, target: float, lower_is_better: bool = True) -> float | None:
    """First time at which a learning curve reaches ``target``.

    The same computation as [`steps_to_parity`][vnhc_gym.stats.steps_to_parity] with wall-clock (or simulated) times as
    the x coordinates; only the name of the argument in error messages differs.
    """
    return _first_reach("times", times, values, target, lower_is_better)
