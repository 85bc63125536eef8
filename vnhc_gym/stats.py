"""Statistics over training runs and test episodes: the interquartile mean, bootstrap intervals and
the probability of improvement, as rliable defines them (Agarwal et al. 2021, "Deep RL at the edge
of the statistical precipice").

Data convention: one algorithm's scores are an array of shape ``(n_runs, n_episodes)``, a row per
training run (a training seed) and a column per test episode, every run tested on the same number
of episodes.  A deterministic controller (a classical baseline) has exactly one run:
``scores[None, :]``.

Intervals are percentile intervals of a *two-level* bootstrap over the runs and the episodes: each
replicate redraws ``n_episodes`` test episodes with replacement and ``n_runs`` runs with replacement,
and computes the statistic on every drawn run's drawn episodes.  The episodes are drawn once per
replicate, the same for every run, because every run is tested on the same episode seeds: an
episode that is hard for one run is hard for the others, and redrawing each run's episodes
independently would average that away (five identical runs would get an interval about sqrt(5)
narrower than one of them).  The first level measures how much the result depends on the test
episodes, the second how much it depends on the training seeds; with a single run only the first is
left, and the interval is the ordinary bootstrap over episodes, as rliable's (the tests check
it).  The replicate mean's variance is then exactly ``s_runs^2 / n_runs + s_episodes^2 / n_episodes
+ s_rest^2 / (n_runs n_episodes)`` (the plug-in variances of the runs' effects, the episodes'
effects and the rest of a two-way decomposition of the scores), which the tests check too.  This
is where the scheme departs from rliable's stratified bootstrap, which redraws the episodes within
each run independently, as if each run had its own.  Scores must be finite.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any, overload

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import stats

__all__ = ["Interval", "interval_estimates", "iqm", "probability_of_improvement_interval"]


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


def _as_scores(name: str, value: Any) -> NDArray[np.float64]:
    arr = _as_float_array(name, value)
    if arr.ndim != 2:
        raise ValueError(f"{name} must be a 2-D array of shape (n_runs, n_episodes), got shape {arr.shape}")
    return arr


def _check_bootstrap_args(reps: Any, confidence: Any, seed: Any) -> None:
    if isinstance(reps, bool) or not isinstance(reps, int | np.integer) or reps < 1:
        raise ValueError(f"reps must be a positive integer, got {reps!r}")
    if isinstance(confidence, bool) or not isinstance(confidence, int | float | np.floating) \
            or not 0.0 < confidence < 1.0:
        raise ValueError(f"confidence must be a number strictly between 0 and 1, got {confidence!r}")
    if seed is not None and (isinstance(seed, bool) or not isinstance(seed, int | np.integer) or seed < 0):
        raise ValueError(f"seed must be None or a non-negative integer, got {seed!r}")


# ---------------------------------------------------------------------------------------------
# Point estimates


@overload
def iqm(scores: ArrayLike, axis: None = None) -> float: ...


@overload
def iqm(scores: ArrayLike, axis: int) -> NDArray[np.float64]: ...


def iqm(scores: ArrayLike, axis: int | None = None) -> float | NDArray[np.float64]:
    """Interquartile mean: the mean of the middle 50 % of the scores.

    Identical to rliable's ``metrics.aggregate_iqm``, i.e. ``scipy.stats.trim_mean(scores, 0.25,
    axis=None)``: with ``axis=None`` every value is pooled, and ``int(0.25 * n)`` values are cut at
    each end of the ``n`` sorted scores.

    Parameters
    ----------
    scores : array_like
        Finite scores, of any non-empty shape.
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


#: The statistics [`interval_estimates`][vnhc_gym.stats.interval_estimates] computes, each over the
#: last axis (the pooled episodes of a replicate).
_METRICS: dict[str, Callable[[NDArray[np.float64]], NDArray[np.float64]]] = {
    "mean": lambda values: np.asarray(np.mean(values, axis=-1)),
    "iqm": lambda values: np.asarray(stats.trim_mean(values, 0.25, axis=-1)),
}


# ---------------------------------------------------------------------------------------------
# Two-level bootstrap
#
# rliable has no resampler of this design (its ``StratifiedBootstrap`` redraws the episodes of each
# run independently), and for the probability of improvement no two-level resampler at all; it is
# also only a development dependency, draws from numpy's global generator (a report or an
# evaluation would move the state that seeds training) and loops over replicates in Python.  So the
# draws are these few lines; the tests check them against rliable's on one run and against the
# design's exact variance on several.


def _draw(rng: np.random.Generator, n_runs: int, n_episodes: int, reps: int) -> NDArray[np.intp]:
    """Indices ``(reps, n_runs * n_episodes)`` into the flattened ``(n_runs, n_episodes)`` scores.

    Each replicate draws ``n_episodes`` episodes with replacement, the same for every run (every run
    is tested on the same episode seeds), then ``n_runs`` runs with replacement.  (The episodes are
    drawn first, so that a single run's draws are those of any number of identical runs.)
    """
    episodes = rng.integers(0, n_episodes, size=(reps, 1, n_episodes), dtype=np.intp)
    runs = rng.integers(0, n_runs, size=(reps, n_runs, 1), dtype=np.intp)
    return (runs * n_episodes + episodes).reshape(reps, n_runs * n_episodes)


def _counts(idx: NDArray[np.intp], size: int) -> NDArray[np.float64]:
    """How often each of the ``size`` original episodes appears in each replicate: ``(reps, size)``."""
    reps = idx.shape[0]
    flat = (np.arange(reps)[:, None] * size + idx).ravel()
    return np.bincount(flat, minlength=reps * size).reshape(reps, size).astype(np.float64)


def _percentile_bounds(replicates: NDArray[np.float64], confidence: float) -> tuple[float, float]:
    # Linear-interpolated percentiles of the replicates: arch's "percentile" method, which rliable uses.
    alpha = 100.0 * (1.0 - confidence) / 2.0
    low, high = np.percentile(replicates, [alpha, 100.0 - alpha])
    return float(low), float(high)


def interval_estimates(score_dict: Mapping[str, ArrayLike], metric: str = "mean", reps: int = 2000,
                       confidence: float = 0.95, seed: int | None = 0) -> dict[str, Interval]:
    """Point estimate and two-level bootstrap percentile interval of each algorithm's ``metric``.

    The point estimate is ``metric`` over every episode of every run.  Each replicate redraws the
    episodes (the same for every run) and the runs (see the module docstring), and computes
    ``metric`` over the redrawn episodes; the interval is the central ``confidence`` range of the
    replicates.  With one run (``scores[None, :]``) this is the ordinary bootstrap over episodes.

    Parameters
    ----------
    score_dict : mapping of str to array_like of shape (n_runs, n_episodes)
        Scores per algorithm: a row per training run, a column per test episode.
    metric : {"mean", "iqm"}, optional
        ``"mean"`` (default; with equally many episodes per run, the mean of the runs' means) or
        ``"iqm"``, the [`iqm`][vnhc_gym.stats.iqm] of the pooled episodes.
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
        If ``score_dict`` is not a non-empty mapping of non-empty finite 2-D arrays, ``metric`` is
        unknown, ``reps < 1``, ``confidence`` is outside ``(0, 1)`` or ``seed`` is not a
        non-negative integer or None.
    """
    if not isinstance(score_dict, Mapping) or len(score_dict) == 0:
        raise ValueError(f"score_dict must be a non-empty mapping {{algorithm: scores of shape (n_runs, n_episodes)}}, "
                         f"got {type(score_dict).__name__}{' (empty)' if isinstance(score_dict, Mapping) else ''}")
    if not isinstance(metric, str) or metric not in _METRICS:
        raise ValueError(f"metric must be one of {sorted(_METRICS)}, got {metric!r}")
    _check_bootstrap_args(reps, confidence, seed)
    data = {alg: _as_scores(f"score_dict[{alg!r}]", scores) for alg, scores in score_dict.items()}
    fn = _METRICS[metric]
    out: dict[str, Interval] = {}
    for alg, scores in data.items():
        rng = np.random.default_rng(seed)
        replicates = fn(scores.ravel()[_draw(rng, scores.shape[0], scores.shape[1], int(reps))])
        out[alg] = Interval(float(fn(scores.ravel())), *_percentile_bounds(replicates, confidence))
    return out


def probability_of_improvement_interval(x: ArrayLike, y: ArrayLike, reps: int = 2000, confidence: float = 0.95,
                                        seed: int | None = 0) -> Interval:
    """Probability that an episode of X scores above an episode of Y, with a two-level bootstrap interval.

    The point estimate is the mean, over every pair of an episode of X and an episode of Y, of
    ``1[x > y] + 0.5 * 1[x == y]`` (the Mann-Whitney U statistic over ``n_x * n_y``, rliable's
    ``metrics.probability_of_improvement`` on one task).  Each replicate redraws X's episodes and
    runs as `interval_estimates` does, independently Y's the same way (a classical baseline's single
    run: its episodes only), and computes the same mean on the redrawn episodes.  Higher scores
    are better; negate both arrays for a metric where lower is better.

    Parameters
    ----------
    x : array_like, shape (n_runs_x, n_episodes_x)
        Scores of algorithm X: a row per training run.
    y : array_like, shape (n_runs_y, n_episodes_y)
        Scores of algorithm Y (``(1, n_episodes)`` for a deterministic controller).
    reps : int, optional
        Number of bootstrap replicates.
    confidence : float, optional
        Coverage of the two-sided interval, in ``(0, 1)``.
    seed : int or None, optional
        Seed of the resampling (X's and Y's draws from two streams spawned from it); ``None``
        draws fresh entropy.

    Returns
    -------
    Interval
        Point estimate and interval of P(X improves on Y), in ``[0, 1]``; 0.5 means no difference.

    Raises
    ------
    ValueError
        If ``x`` or ``y`` is not a non-empty finite 2-D array, ``reps < 1``, ``confidence`` is
        outside ``(0, 1)`` or ``seed`` is not a non-negative integer or None.
    """
    xa, ya = _as_scores("x", x), _as_scores("y", y)
    _check_bootstrap_args(reps, confidence, seed)
    nx, ny = xa.size, ya.size
    # Credit of every pair of original episodes, computed once: a replicate's statistic is its
    # count-weighted mean, so no pair is compared again per replicate.
    a, b = xa.reshape(-1, 1), ya.reshape(1, -1)
    win = (a > b) + 0.5 * (a == b)
    # X and Y draw from two streams of the seed, so that Y's draws do not depend on X's shape.
    gx, gy = (np.random.default_rng(s) for s in np.random.SeedSequence(seed).spawn(2))
    cx = _counts(_draw(gx, xa.shape[0], xa.shape[1], int(reps)), nx)
    cy = _counts(_draw(gy, ya.shape[0], ya.shape[1], int(reps)), ny)
    replicates = np.sum((cx @ win) * cy, axis=1) / (nx * ny)
    return Interval(float(np.mean(win)), *_percentile_bounds(replicates, confidence))
