"""Tests of vnhc_gym.stats: the two-level bootstrap against rliable's bootstrap on one run and against
its exact variance on several, the probability of improvement against hand computations, and input
validation."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np
import pytest
from scipy.stats import norm

from vnhc_gym.stats import Interval, interval_estimates, iqm, probability_of_improvement_interval

N_RUNS, N_EPISODES = 5, 20
#: Five training runs whose means differ (by 0.5, the episodes' spread within a run being 0.3).
RUNS_DIFFER = np.random.default_rng(1).normal(0.5 * np.arange(N_RUNS)[:, None], 0.3, size=(N_RUNS, N_EPISODES))
#: Five training runs drawn from one distribution.
RUNS_ALIKE = np.random.default_rng(2).normal(0.0, 1.0, size=(N_RUNS, N_EPISODES))


def _pooled(scores: np.ndarray) -> np.ndarray:
    """Every episode in one run: what pooling the runs' episodes as independent amounts to."""
    return scores.reshape(1, -1)


def _width(iv: Interval) -> float:
    return iv.high - iv.low


# ---------------------------------------------------------------------------------------------
# Against rliable

# rliable's bootstrap is a Python loop over replicates, so its side uses as few replicates as the
# tolerance allows and ours uses many: the comparison is then limited by rliable's own Monte Carlo
# error.  The two draw from different generators, so they cannot agree replicate by replicate.
RLY_REPS = 5_000
OUR_REPS = 50_000


@pytest.fixture(scope="module")
def rly() -> Iterator[Any]:
    pytest.importorskip("rliable")
    from rliable import library, metrics

    # rliable's resampling draws from numpy's global legacy generator; seed it for a
    # deterministic run and put the caller's state back afterwards.
    state = np.random.get_state()  # noqa: NPY002
    np.random.seed(20210830)  # noqa: NPY002
    try:
        yield library, metrics
    finally:
        np.random.set_state(state)  # noqa: NPY002


def _mc_tolerance(ours: Callable[[float], tuple[float, float]], rly_reps: int,
                  confidence: float = 0.95) -> tuple[float, float]:
    """Tolerance on (low, high) when comparing two bootstrap percentile endpoints.

    The p-quantile of B bootstrap replicates has Monte Carlo standard deviation
    sqrt(p (1 - p) / B) * q'(p), q' being the derivative of the quantile function of the
    bootstrap distribution.  q' is estimated from our many-replicate run as a central difference
    over p +- 0.01 (the endpoints at confidence +- 0.02); the two estimates are independent, so
    their difference has variance (1 / B_rliable + 1 / B_ours) p (1 - p) q'^2.  We allow five
    standard deviations (a chance of about 1e-6 of a false alarm under normality).
    """
    p, h = (1.0 - confidence) / 2.0, 0.01
    low_wide, high_wide = ours(confidence + 2 * h)
    low_narrow, high_narrow = ours(confidence - 2 * h)
    sd_factor = np.sqrt(p * (1 - p) * (1 / rly_reps + 1 / OUR_REPS))
    return (5 * sd_factor * abs(low_narrow - low_wide) / (2 * h) + 1e-12,
            5 * sd_factor * abs(high_wide - high_narrow) / (2 * h) + 1e-12)


def test_interval_of_one_run_matches_rliable_over_episodes(rly: Any) -> None:
    # A classical baseline: one run, whose episodes play rliable's runs of one task.
    library, _ = rly
    episodes = RUNS_DIFFER[2]
    point, ci = library.get_interval_estimates({"x": episodes[:, None]}, lambda s: np.array([np.mean(s)]),
                                               reps=RLY_REPS, confidence_interval_size=0.95)

    def ours(confidence: float) -> tuple[float, float]:
        res = interval_estimates({"x": episodes[None, :]}, reps=OUR_REPS, confidence=confidence)["x"]
        return res.low, res.high

    res = interval_estimates({"x": episodes[None, :]}, reps=OUR_REPS)["x"]
    assert res.point == pytest.approx(point["x"][0], abs=1e-12, rel=0)
    tol_low, tol_high = _mc_tolerance(ours, RLY_REPS)
    assert abs(res.low - ci["x"][0, 0]) <= tol_low
    assert abs(res.high - ci["x"][1, 0]) <= tol_high


def test_probability_of_improvement_point_matches_rliable(rly: Any) -> None:
    _, metrics = rly
    y = RUNS_ALIKE[:1] + 0.7
    # rliable's is per task over runs; one task whose "runs" are the pooled episodes.
    expected = metrics.probability_of_improvement(RUNS_DIFFER.reshape(-1, 1), y.reshape(-1, 1))
    assert probability_of_improvement_interval(RUNS_DIFFER, y).point == pytest.approx(expected, abs=1e-12, rel=0)


def test_iqm_matches_rliable(rly: Any) -> None:
    _, metrics = rly
    for scores in (RUNS_DIFFER, RUNS_ALIKE, np.round(RUNS_ALIKE, 1)):
        assert iqm(scores) == pytest.approx(metrics.aggregate_iqm(scores), abs=1e-12, rel=0)


# ---------------------------------------------------------------------------------------------
# The two-level bootstrap of the mean, exactly


def _two_level_sd(scores: np.ndarray) -> float:
    """Standard deviation of a replicate's mean, from the data alone.

    With the scores decomposed as ``mu + a_run + b_episode + c`` (row and column effects of zero mean,
    ``c`` of zero mean along every row and column), a replicate's mean is ``mu + mean(a) over the
    drawn runs + mean(b) over the drawn episodes + mean(c) over the drawn cells``; the three parts
    are uncorrelated, so its variance is ``var(a) / n_runs + var(b) / n_episodes + var(c) / (n_runs
    n_episodes)`` (plug-in variances).
    """
    n_runs, n_episodes = scores.shape
    a = scores.mean(axis=1) - scores.mean()
    b = scores.mean(axis=0) - scores.mean()
    c = scores - scores.mean() - a[:, None] - b[None, :]
    return float(np.sqrt(np.var(a) / n_runs + np.var(b) / n_episodes + np.var(c) / (n_runs * n_episodes)))


@pytest.mark.parametrize("scores", [RUNS_DIFFER, RUNS_ALIKE], ids=["runs-differ", "runs-alike"])
def test_interval_width_is_the_two_level_variance(scores: np.ndarray) -> None:
    # The replicates of a mean of 100 values are close to normal, so the 95 % interval is
    # 2 * 1.96 standard deviations wide; 4 % covers the Monte Carlo error of 50 000 replicates
    # (under 1 %) and the skewness that remains.
    res = interval_estimates({"x": scores}, reps=OUR_REPS)["x"]
    assert _width(res) == pytest.approx(2 * norm.ppf(0.975) * _two_level_sd(scores), rel=0.04)


def test_identical_runs_have_the_interval_of_one() -> None:
    # Runs tested on the same episode seeds that score the same (a residual agent that stayed at its
    # base) are one run: redrawing their episodes separately would narrow the interval by sqrt(5).
    one = RUNS_DIFFER[2][None, :]
    for metric in ("mean", "iqm"):
        same = interval_estimates({"x": np.repeat(one, N_RUNS, axis=0)}, metric)["x"]
        alone = interval_estimates({"x": one}, metric)["x"]
        assert (same.point, same.low, same.high) == pytest.approx((alone.point, alone.low, alone.high), abs=1e-12)
    y = RUNS_ALIKE[:1]
    assert probability_of_improvement_interval(np.repeat(one, N_RUNS, axis=0), y) == pytest.approx(
        probability_of_improvement_interval(one, y))


def test_runs_that_differ_widen_the_interval() -> None:
    runs = interval_estimates({"x": RUNS_DIFFER}, reps=OUR_REPS)["x"]
    pooled = interval_estimates({"x": _pooled(RUNS_DIFFER)}, reps=OUR_REPS)["x"]
    assert runs.point == pooled.point == pytest.approx(np.mean(RUNS_DIFFER))
    assert runs.low <= pooled.low and pooled.high <= runs.high
    # Run means 0.5 apart and 20 episodes of spread 0.3 each: the spread between runs dominates.
    assert _width(runs) > 2.5 * _width(pooled)


def test_interval_equals_per_replicate_recomputation() -> None:
    # Replays the module's draws (the episodes, the same for every run, then the runs, from a
    # generator seeded with seed) and recomputes every replicate from the redrawn arrays.
    reps, seed = 400, 11
    rng = np.random.default_rng(seed)
    episodes = rng.integers(0, N_EPISODES, size=(reps, N_EPISODES))
    runs = rng.integers(0, N_RUNS, size=(reps, N_RUNS))
    for metric, fn in (("mean", np.mean), ("iqm", iqm)):
        replicates = [fn(np.stack([RUNS_DIFFER[runs[r, k], episodes[r]] for k in range(N_RUNS)]))
                      for r in range(reps)]
        low, high = np.percentile(replicates, [2.5, 97.5])
        res = interval_estimates({"x": RUNS_DIFFER}, metric, reps=reps, seed=seed)["x"]
        assert (res.low, res.high) == pytest.approx((low, high), abs=1e-12)


def test_runs_of_one_episode_are_one_run_of_every_episode() -> None:
    # (n, 1) and (1, n) redraw the same n values the same way, from the same draws.
    values = RUNS_DIFFER[1]
    for metric in ("mean", "iqm"):
        assert interval_estimates({"x": values[:, None]}, metric)["x"] == interval_estimates({"x": values[None, :]},
                                                                                              metric)["x"]


# ---------------------------------------------------------------------------------------------
# Probability of improvement


def test_probability_of_improvement_by_hand() -> None:
    # Pairs (1,2) (1,3) (2,2) (2,3): one tie, counting a half, of four pairs.
    assert probability_of_improvement_interval([[1.0, 2.0]], [[2.0, 3.0]]).point == pytest.approx(0.125)
    assert probability_of_improvement_interval([[2.0, 3.0]], [[1.0, 2.0]]).point == pytest.approx(0.875)
    # Every pair of episodes counts once, whichever run it comes from.
    x, y = RUNS_DIFFER, RUNS_ALIKE[:1] + 0.7
    pairs = [1.0 if a > b else 0.5 if a == b else 0.0 for a in x.ravel() for b in y.ravel()]
    assert probability_of_improvement_interval(x, y).point == pytest.approx(np.mean(pairs), abs=1e-12)


def test_probability_of_improvement_of_one_distribution_is_a_half() -> None:
    x = RUNS_ALIKE
    y = np.random.default_rng(3).normal(0.0, 1.0, size=(1, N_EPISODES))  # a classical baseline: one run
    res = probability_of_improvement_interval(x, y, reps=OUR_REPS)
    assert abs(res.point - 0.5) < 0.1 and res.low < 0.5 < res.high
    assert probability_of_improvement_interval(x, x).point == 0.5  # every tie and its mirror


def test_probability_of_improvement_of_a_clearly_better_agent() -> None:
    # Run r's episodes ~ N(mu_r, 0.5), the baseline's ~ N(0, 0.5): an episode of run r beats one of
    # the baseline's with probability Phi(mu_r / sqrt(0.5^2 + 0.5^2)), and a random episode of the
    # agent with the mean of these over the runs, 0.971.
    mu = np.array([1.0, 1.25, 1.5, 1.75, 2.0])
    rng = np.random.default_rng(4)
    x = rng.normal(mu[:, None], 0.5, size=(N_RUNS, N_EPISODES))
    y = rng.normal(0.0, 0.5, size=(1, N_EPISODES))
    true = float(np.mean(norm.cdf(mu / np.sqrt(0.5))))
    assert true == pytest.approx(0.9714, abs=1e-4)
    res = probability_of_improvement_interval(x, y, reps=OUR_REPS)
    assert res.point > 0.9 and res.low > 0.8
    assert res.low <= true <= res.high


def test_probability_of_improvement_resamples_runs() -> None:
    # Against a baseline in the middle of runs that differ, which run is drawn decides a replicate.
    y = np.random.default_rng(5).normal(1.0, 0.3, size=(1, N_EPISODES))
    runs = probability_of_improvement_interval(RUNS_DIFFER, y, reps=OUR_REPS)
    pooled = probability_of_improvement_interval(_pooled(RUNS_DIFFER), y, reps=OUR_REPS)
    assert runs.point == pooled.point
    assert runs.low <= pooled.low and pooled.high <= runs.high
    assert _width(runs) > 2 * _width(pooled)


def test_probability_of_improvement_equals_per_replicate_recomputation() -> None:
    # Replays the module's draws (x's episodes and runs, y's from a second stream) to recompute every
    # replicate.
    reps, seed = 300, 7
    x, y = RUNS_DIFFER, np.round(RUNS_ALIKE[:2] + 1.0, 1)  # y: two runs, and ties

    def draw(scores: np.ndarray, rng: np.random.Generator) -> list[np.ndarray]:
        n_runs, n_episodes = scores.shape
        episodes = rng.integers(0, n_episodes, size=(reps, n_episodes))
        runs = rng.integers(0, n_runs, size=(reps, n_runs))
        return [np.concatenate([scores[runs[r, k], episodes[r]] for k in range(n_runs)]) for r in range(reps)]

    gx, gy = (np.random.default_rng(s) for s in np.random.SeedSequence(seed).spawn(2))
    xs, ys = draw(x, gx), draw(y, gy)
    replicates = [np.mean((a[:, None] > b[None, :]) + 0.5 * (a[:, None] == b[None, :])) for a, b in zip(xs, ys,
                                                                                                          strict=True)]
    low, high = np.percentile(replicates, [2.5, 97.5])
    res = probability_of_improvement_interval(x, y, reps=reps, seed=seed)
    assert (res.low, res.high) == pytest.approx((low, high), abs=1e-12)


# ---------------------------------------------------------------------------------------------
# Point estimates and the interval's properties


def test_iqm_is_the_mean_of_the_middle_half() -> None:
    assert iqm(np.arange(100.0)) == pytest.approx(np.mean(np.arange(25, 75)), abs=1e-12)
    assert iqm(np.arange(100.0).reshape(20, 5)) == pytest.approx(49.5, abs=1e-12)
    # int(0.25 * 10) = 2 values cut at each end.
    assert iqm([100.0, -100.0, 1, 2, 3, 4, 5, 6, 50.0, -50.0]) == pytest.approx(3.5, abs=1e-12)
    np.testing.assert_allclose(iqm(np.arange(40.0).reshape(4, 10).T, axis=0), [4.5, 14.5, 24.5, 34.5])


def test_confidence_widens_interval() -> None:
    narrow = interval_estimates({"x": RUNS_DIFFER}, confidence=0.5)["x"]
    wide = interval_estimates({"x": RUNS_DIFFER}, confidence=0.99)["x"]
    assert wide.low < narrow.low < narrow.high < wide.high


def test_seed_reproducibility_and_independence_from_other_algorithms() -> None:
    alone = interval_estimates({"x": RUNS_DIFFER}, seed=4)["x"]
    with_other = interval_estimates({"y": RUNS_ALIKE, "x": RUNS_DIFFER}, seed=4)["x"]
    assert alone == with_other == interval_estimates({"x": RUNS_DIFFER}, seed=4)["x"]
    assert alone != interval_estimates({"x": RUNS_DIFFER}, seed=5)["x"]
    y = RUNS_ALIKE[:1]
    assert probability_of_improvement_interval(RUNS_DIFFER, y, seed=1) == probability_of_improvement_interval(
        RUNS_DIFFER, y, seed=1)


def test_constant_scores_give_degenerate_interval() -> None:
    for metric in ("mean", "iqm"):
        assert interval_estimates({"c": np.full((5, 3), 2.0)}, metric)["c"] == Interval(2.0, 2.0, 2.0)


def test_interval_format_and_frozen() -> None:
    iv = Interval(0.123, 0.1, 0.15)
    assert iv.format() == "0.123 [0.1, 0.15]"
    assert str(iv) == "0.123 [0.1, 0.15]"
    assert iv.format(".2f") == "0.12 [0.10, 0.15]"
    with pytest.raises(dataclasses.FrozenInstanceError):
        iv.point = 1.0  # type: ignore[misc]


# ---------------------------------------------------------------------------------------------
# Input validation

X, Y = RUNS_DIFFER, RUNS_ALIKE[:1]
BAD_CALLS: list[tuple[str, Callable[[], Any], str]] = [
    ("iqm empty", lambda: iqm([]), "scores must not be empty"),
    ("iqm nan", lambda: iqm([1.0, np.nan]), "scores must contain only finite"),
    ("iqm text", lambda: iqm(["a", "b"]), "scores must be a numeric array"),
    ("iqm axis", lambda: iqm(X, axis=2), "axis must be"),
    ("dict empty", lambda: interval_estimates({}), "score_dict must be a non-empty mapping"),
    ("dict not mapping", lambda: interval_estimates([X]), "score_dict must be a non-empty mapping"),  # type: ignore[arg-type]
    ("dict nan", lambda: interval_estimates({"x": X, "y": np.full((2, 5), np.nan)}), r"score_dict\['y'\]"),
    ("dict 1-D", lambda: interval_estimates({"x": X[0]}), r"score_dict\['x'\] must be a 2-D array"),
    ("dict 3-D", lambda: interval_estimates({"x": X[None]}), r"score_dict\['x'\] must be a 2-D array"),
    ("dict ragged", lambda: interval_estimates({"x": [[1.0, 2.0], [3.0]]}), "must be a numeric array"),
    ("dict empty runs", lambda: interval_estimates({"x": np.ones((0, 5))}), "must not be empty"),
    ("metric", lambda: interval_estimates({"x": X}, "median"), "metric must be one of"),
    ("reps", lambda: interval_estimates({"x": X}, reps=1.5), "reps must be a positive integer"),  # type: ignore[arg-type]
    ("reps zero", lambda: interval_estimates({"x": X}, reps=0), "reps must be a positive integer"),
    ("confidence", lambda: interval_estimates({"x": X}, confidence=1.0), "confidence must be"),
    ("seed", lambda: interval_estimates({"x": X}, seed=-1), "seed must be"),
    ("poi x shape", lambda: probability_of_improvement_interval([1.0, 2.0], Y), "x must be a 2-D array"),
    ("poi nan", lambda: probability_of_improvement_interval(X, np.where(Y > 0, np.nan, Y)), "y must contain only"),
    ("poi empty", lambda: probability_of_improvement_interval(np.ones((0, 5)), Y), "x must not be empty"),
    ("poi reps", lambda: probability_of_improvement_interval(X, Y, reps=0), "reps must be"),
    ("poi confidence", lambda: probability_of_improvement_interval(X, Y, confidence=0), "confidence must be"),
    ("poi seed", lambda: probability_of_improvement_interval(X, Y, seed=1.5), "seed must be"),  # type: ignore[arg-type]
]


@pytest.mark.parametrize(("call", "match"), [(c, m) for _, c, m in BAD_CALLS], ids=[n for n, _, _ in BAD_CALLS])
def test_bad_input_raises_value_error_naming_the_argument(call: Callable[[], Any], match: str) -> None:
    with pytest.raises(ValueError, match=match):
        call()
