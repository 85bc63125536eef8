"""Tests of vnhc_gym.stats: exact agreement with rliable's estimators, and properties that hold without it."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np
import pytest

from vnhc_gym.stats import (
    Interval,
    aggregate_metrics,
    interval_estimates,
    iqm,
    performance_profile,
    performance_profile_intervals,
    probability_of_improvement,
    probability_of_improvement_interval,
    steps_to_parity,
    time_to_parity,
)


def _scores(seed: int, n_runs: int, n_tasks: int, shift: float = 0.0) -> np.ndarray:
    # Tasks on different scales, so that resampling across tasks instead of within each would
    # change the intervals; rounded to one decimal so that ties occur.
    rng = np.random.default_rng(seed)
    task_scale = 1.0 + np.arange(n_tasks)
    return np.round(task_scale * rng.lognormal(shift, 0.5, size=(n_runs, n_tasks)), 1)


X = _scores(1, 10, 5)
Y = _scores(2, 8, 5, shift=0.3)
TAUS = np.array([0.5, 1.0, 2.0, 4.0, 8.0])


# ---------------------------------------------------------------------------------------------
# Against rliable

# rliable's bootstrap is a Python loop over replicates, so its side uses as few replicates as
# the tolerance allows and ours uses many: the comparison is then limited by rliable's own
# Monte Carlo error.
RLY_REPS = {"iqm": 6_000, "poi": 1_500, "profile": 3_000}
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


def _mc_tolerance(ours: Callable[[float], tuple[Any, Any]], rly_reps: int, confidence: float = 0.95,
                  lattice_step: float = 0.0) -> tuple[Any, Any]:
    """Tolerance on (low, high) when comparing two bootstrap percentile endpoints.

    The p-quantile of B bootstrap replicates has Monte Carlo standard deviation
    sqrt(p (1 - p) / B) * q'(p), q' being the derivative of the quantile function of the
    bootstrap distribution.  q' is estimated from our many-replicate run as a central difference
    over p +- 0.01 (the endpoints at confidence +- 0.02); the two estimates are independent, so
    their difference has variance (1 / B_rliable + 1 / B_ours) p (1 - p) q'^2.  We allow five
    standard deviations (a chance of about 1e-6 of a false alarm under normality) plus one step
    of the lattice a discrete statistic lives on, where the percentile can jump between
    neighbouring values.
    """
    p, h = (1.0 - confidence) / 2.0, 0.01
    low_wide, high_wide = ours(confidence + 2 * h)
    low_narrow, high_narrow = ours(confidence - 2 * h)
    slope_low = np.abs(np.asarray(low_narrow) - np.asarray(low_wide)) / (2 * h)
    slope_high = np.abs(np.asarray(high_wide) - np.asarray(high_narrow)) / (2 * h)
    sd_factor = np.sqrt(p * (1 - p) * (1 / rly_reps + 1 / OUR_REPS))
    # 1e-12 keeps an endpoint exactly one lattice step away from failing on rounding.
    slack = lattice_step + 1e-12
    return 5 * sd_factor * slope_low + slack, 5 * sd_factor * slope_high + slack


def test_point_estimates_match_rliable(rly: Any) -> None:
    _, metrics = rly
    for scores in (X, Y, _scores(3, 7, 1), _scores(4, 33, 12)):
        agg = aggregate_metrics(scores)
        assert agg["iqm"] == pytest.approx(metrics.aggregate_iqm(scores), abs=1e-12, rel=0)
        assert iqm(scores) == pytest.approx(metrics.aggregate_iqm(scores), abs=1e-12, rel=0)
        assert agg["mean"] == pytest.approx(metrics.aggregate_mean(scores), abs=1e-12, rel=0)
        assert agg["median"] == pytest.approx(metrics.aggregate_median(scores), abs=1e-12, rel=0)


def test_probability_of_improvement_matches_rliable(rly: Any) -> None:
    _, metrics = rly
    pairs = [(X, Y), (Y, X), (X, X), (X, np.round(X + 0.1, 1)), (_scores(5, 3, 4), _scores(6, 20, 4))]
    for x, y in pairs:
        assert probability_of_improvement(x, y, False) == pytest.approx(
            metrics.probability_of_improvement(x, y), abs=1e-12, rel=0)
        # Lower is better: an improvement is a larger negated score.
        assert probability_of_improvement(x, y, True) == pytest.approx(
            metrics.probability_of_improvement(-x, -y), abs=1e-12, rel=0)


def test_iqm_interval_matches_rliable(rly: Any) -> None:
    library, metrics = rly
    point, ci = library.get_interval_estimates({"x": X}, lambda s: np.array([metrics.aggregate_iqm(s)]),
                                               reps=RLY_REPS["iqm"], confidence_interval_size=0.95)

    def ours(confidence: float) -> tuple[float, float]:
        res = interval_estimates({"x": X}, "iqm", reps=OUR_REPS, confidence=confidence)["x"]
        return res.low, res.high

    res = interval_estimates({"x": X}, "iqm", reps=OUR_REPS)["x"]
    assert res.point == pytest.approx(point["x"][0], abs=1e-12, rel=0)
    tol_low, tol_high = _mc_tolerance(ours, RLY_REPS["iqm"])
    assert abs(res.low - ci["x"][0, 0]) <= tol_low
    assert abs(res.high - ci["x"][1, 0]) <= tol_high


def test_probability_of_improvement_interval_matches_rliable(rly: Any) -> None:
    library, metrics = rly
    x, y = X[:, :2], Y[:, :2]
    point, ci = library.get_interval_estimates(
        {"x,y": [x, y]}, lambda a, b: np.array([metrics.probability_of_improvement(a, b)]),
        reps=RLY_REPS["poi"], confidence_interval_size=0.95)

    def ours(confidence: float) -> tuple[float, float]:
        res = probability_of_improvement_interval(x, y, False, reps=OUR_REPS, confidence=confidence)
        return res.low, res.high

    res = probability_of_improvement_interval(x, y, False, reps=OUR_REPS)
    assert res.point == pytest.approx(point["x,y"][0], abs=1e-12, rel=0)
    # The statistic is a multiple of 0.5 / (n_x * n_y * n_tasks).
    step = 0.5 / (x.shape[0] * y.shape[0] * x.shape[1])
    tol_low, tol_high = _mc_tolerance(ours, RLY_REPS["poi"], lattice_step=step)
    assert abs(res.low - ci["x,y"][0, 0]) <= tol_low
    assert abs(res.high - ci["x,y"][1, 0]) <= tol_high


def test_performance_profile_matches_rliable(rly: Any) -> None:
    library, _ = rly
    point, ci = library.create_performance_profile({"x": X}, TAUS, reps=RLY_REPS["profile"],
                                                   confidence_interval_size=0.95)
    np.testing.assert_allclose(performance_profile({"x": X}, TAUS, False)["x"], point["x"], rtol=0, atol=1e-12)
    np.testing.assert_allclose(performance_profile({"x": X}, TAUS, True)["x"], 1 - point["x"], rtol=0, atol=1e-12)

    def ours(confidence: float) -> tuple[np.ndarray, np.ndarray]:
        band = performance_profile_intervals({"x": X}, TAUS, False, reps=OUR_REPS, confidence=confidence)["x"]
        return band.low, band.high

    band = performance_profile_intervals({"x": X}, TAUS, False, reps=OUR_REPS)["x"]
    np.testing.assert_allclose(band.point, point["x"], rtol=0, atol=1e-12)
    # Fractions of n_runs * n_tasks values.
    tol_low, tol_high = _mc_tolerance(ours, RLY_REPS["profile"], lattice_step=1 / X.size)
    assert np.all(np.abs(band.low - ci["x"][0]) <= tol_low)
    assert np.all(np.abs(band.high - ci["x"][1]) <= tol_high)


# ---------------------------------------------------------------------------------------------
# Point estimates


def test_iqm_is_the_mean_of_the_middle_half() -> None:
    assert iqm(np.arange(100.0)) == pytest.approx(np.mean(np.arange(25, 75)), abs=1e-12)
    assert iqm(np.arange(100.0).reshape(20, 5)) == pytest.approx(49.5, abs=1e-12)
    # int(0.25 * 10) = 2 values cut at each end.
    assert iqm([100.0, -100.0, 1, 2, 3, 4, 5, 6, 50.0, -50.0]) == pytest.approx(3.5, abs=1e-12)
    np.testing.assert_allclose(iqm(np.arange(40.0).reshape(4, 10).T, axis=0), [4.5, 14.5, 24.5, 34.5])


def test_aggregate_metrics_by_hand() -> None:
    scores = np.array([[1.0, 10.0, 100.0], [3.0, 20.0, 300.0]])
    agg = aggregate_metrics(scores)
    assert agg["mean"] == pytest.approx((2 + 15 + 200) / 3)
    assert agg["median"] == pytest.approx(15.0)
    assert agg["iqm"] == pytest.approx(np.mean([3.0, 10.0, 20.0, 100.0]))


def test_probability_of_improvement_properties() -> None:
    low, high = np.arange(6.0).reshape(3, 2), 10 + np.arange(8.0).reshape(4, 2)
    assert probability_of_improvement(high, low, False) == 1.0
    assert probability_of_improvement(low, high, False) == 0.0
    assert probability_of_improvement(low, high, True) == 1.0
    assert probability_of_improvement(X, X, False) == 0.5
    assert probability_of_improvement(X, X, True) == 0.5
    # Without ties P(X > Y) + P(Y > X) = 1.
    rng = np.random.default_rng(7)
    x, y = rng.normal(size=(9, 4)), rng.normal(0.2, size=(6, 4))
    assert probability_of_improvement(x, y, False) + probability_of_improvement(y, x, False) == pytest.approx(1.0)
    # One task, ties count a half: pairs (1,2) (1,3) (2,2) (2,3) -> 0.5 / 4.
    assert probability_of_improvement([[1.0], [2.0]], [[2.0], [3.0]], False) == pytest.approx(0.125)
    assert probability_of_improvement([[1.0], [2.0]], [[2.0], [3.0]], True) == pytest.approx(0.875)


def test_performance_profile_direction() -> None:
    higher = performance_profile({"x": X, "y": Y}, TAUS, False)
    lower = performance_profile({"x": X, "y": Y}, TAUS, True)
    for alg in ("x", "y"):
        assert higher[alg].shape == TAUS.shape
        np.testing.assert_allclose(higher[alg] + lower[alg], 1.0)
        assert np.all(np.diff(higher[alg]) <= 0) and np.all(np.diff(lower[alg]) >= 0)
    assert performance_profile({"x": [[1.0, 2.0], [3.0, 4.0]]}, 2.0, False)["x"].tolist() == [0.5]
    assert performance_profile({"x": [[1.0, 2.0], [3.0, 4.0]]}, 2.0, True)["x"].tolist() == [0.5]


# ---------------------------------------------------------------------------------------------
# Bootstrap


@pytest.mark.parametrize("metric", ["iqm", "mean", "median"])
def test_vectorised_metric_equals_per_replicate_recomputation(metric: str) -> None:
    # Same seed, same draws: the vectorised replicates must equal the metric recomputed on each resample.
    scores = {"x": X, "y": Y}
    named = interval_estimates(scores, metric, reps=300, seed=3)
    looped = interval_estimates(scores, lambda s: aggregate_metrics(s)[metric], reps=300, seed=3)
    for alg in scores:
        assert named[alg].point == looped[alg].point
        assert named[alg].low == pytest.approx(looped[alg].low, abs=1e-12)
        assert named[alg].high == pytest.approx(looped[alg].high, abs=1e-12)


def test_profile_band_equals_per_replicate_recomputation() -> None:
    band = performance_profile_intervals({"x": X}, TAUS, True, reps=400, seed=5)["x"]
    for k, tau in enumerate(TAUS):

        def fraction_at_or_below(scores: np.ndarray, tau: float = tau) -> float:
            return float(np.mean(scores <= tau))

        ref = interval_estimates({"x": X}, fraction_at_or_below, reps=400, seed=5)["x"]
        assert (band.point[k], band.low[k], band.high[k]) == pytest.approx((ref.point, ref.low, ref.high), abs=1e-12)


def test_probability_of_improvement_interval_equals_per_replicate_recomputation() -> None:
    # Replays the module's draw order (x's runs, then y's, from one generator seeded with seed)
    # to recompute every replicate from the resampled arrays.
    reps, seed = 300, 11
    rng = np.random.default_rng(seed)
    n_tasks = X.shape[1]
    ix = rng.integers(0, X.shape[0], size=(reps, X.shape[0], n_tasks), dtype=np.intp)
    iy = rng.integers(0, Y.shape[0], size=(reps, Y.shape[0], n_tasks), dtype=np.intp)
    task = np.arange(n_tasks)
    replicates = [probability_of_improvement(X[ix[r], task], Y[iy[r], task], True) for r in range(reps)]
    low, high = np.percentile(replicates, [2.5, 97.5])
    res = probability_of_improvement_interval(X, Y, True, reps=reps, seed=seed)
    assert (res.low, res.high) == pytest.approx((low, high), abs=1e-12)


def test_interval_contains_point_and_shrinks_with_runs() -> None:
    rng = np.random.default_rng(0)
    widths = []
    for n_runs in (10, 40, 160):
        res = interval_estimates({"a": rng.normal(size=(n_runs, 6))}, "iqm", reps=2000)["a"]
        assert res.low <= res.point <= res.high
        widths.append(res.high - res.low)
    # Width scales as 1 / sqrt(n_runs): about halves each time.
    assert widths[0] > 1.5 * widths[1] > 2.25 * widths[2]
    poi = probability_of_improvement_interval(X, Y, True)
    assert poi.low <= poi.point <= poi.high


def test_confidence_widens_interval() -> None:
    narrow = interval_estimates({"x": X}, confidence=0.5)["x"]
    wide = interval_estimates({"x": X}, confidence=0.99)["x"]
    assert wide.low < narrow.low < narrow.high < wide.high


def test_seed_reproducibility_and_independence_from_other_algorithms() -> None:
    alone = interval_estimates({"x": X}, seed=4)["x"]
    with_other = interval_estimates({"y": Y, "x": X}, seed=4)["x"]
    assert alone == with_other == interval_estimates({"x": X}, seed=4)["x"]
    assert alone != interval_estimates({"x": X}, seed=5)["x"]
    assert probability_of_improvement_interval(X, Y, False, seed=1) == probability_of_improvement_interval(
        X, Y, False, seed=1)


def test_lower_is_better_flips_probability_of_improvement_interval() -> None:
    up = probability_of_improvement_interval(X, Y, False, seed=2)
    down = probability_of_improvement_interval(X, Y, True, seed=2)
    # Same draws, and each replicate of the lower-is-better statistic is 1 minus the other.
    assert down.point == pytest.approx(1 - up.point, abs=1e-12)
    assert down.low == pytest.approx(1 - up.high, abs=1e-12)
    assert down.high == pytest.approx(1 - up.low, abs=1e-12)


def test_constant_scores_give_degenerate_interval() -> None:
    res = interval_estimates({"c": np.full((5, 3), 2.0)}, "iqm")["c"]
    assert res == Interval(2.0, 2.0, 2.0)


def test_replicates_span_several_blocks() -> None:
    # More replicates than fit in one block must still give one value per replicate.
    many = interval_estimates({"x": np.zeros((1, 1))}, "mean", reps=3_000_000)["x"]
    assert many == Interval(0.0, 0.0, 0.0)


def test_interval_format_and_frozen() -> None:
    iv = Interval(0.123, 0.1, 0.15)
    assert iv.format() == "0.123 [0.1, 0.15]"
    assert str(iv) == "0.123 [0.1, 0.15]"
    assert iv.format(".2f") == "0.12 [0.10, 0.15]"
    with pytest.raises(dataclasses.FrozenInstanceError):
        iv.point = 1.0  # type: ignore[misc]


# ---------------------------------------------------------------------------------------------
# Learning curves


def test_steps_to_parity() -> None:
    steps = [0, 1000, 2000, 3000, 4000]
    curve = [5.0, 3.0, 1.0, 0.5, 2.0]
    assert steps_to_parity(steps, curve, 1.0) == 2000
    assert isinstance(steps_to_parity(steps, curve, 1.0), int)
    assert steps_to_parity(steps, curve, 0.1) is None
    assert steps_to_parity(steps, curve, 5.0) == 0
    assert steps_to_parity(steps, curve, 4.0, lower_is_better=False) == 0
    assert steps_to_parity(steps, [0.0, 1.0, 2.0, 3.0, 4.0], 2.5, lower_is_better=False) == 3000
    assert steps_to_parity(steps, [0.0, 1.0, 2.0, 3.0, 4.0], 9.0, lower_is_better=False) is None
    assert time_to_parity([0.0, 0.5, 1.5], [3.0, 2.0, 1.0], 2.0) == 0.5


# ---------------------------------------------------------------------------------------------
# Input validation

BAD_CALLS: list[tuple[str, Callable[[], Any], str]] = [
    ("iqm empty", lambda: iqm([]), "scores must not be empty"),
    ("iqm nan", lambda: iqm([1.0, np.nan]), "scores must contain only finite"),
    ("iqm text", lambda: iqm(["a", "b"]), "scores must be a numeric array"),
    ("iqm axis", lambda: iqm(X, axis=2), "axis must be"),
    ("aggregate 1-D", lambda: aggregate_metrics([1.0, 2.0]), r"scores must be a 2-D array"),
    ("aggregate 3-D", lambda: aggregate_metrics(np.ones((2, 2, 2))), r"scores must be a 2-D array"),
    ("aggregate inf", lambda: aggregate_metrics([[1.0, np.inf]]), "scores must contain only finite"),
    ("aggregate ragged", lambda: aggregate_metrics([[1.0, 2.0], [3.0]]), "scores must be a numeric array"),
    ("poi x shape", lambda: probability_of_improvement([1.0, 2.0], Y, False), "x must be a 2-D array"),
    ("poi tasks", lambda: probability_of_improvement(X, Y[:, :3], False), "y must have 5 tasks"),
    ("poi nan", lambda: probability_of_improvement(X, np.where(Y > 1, np.nan, Y), False), "y must contain only"),
    ("poi empty", lambda: probability_of_improvement(np.ones((0, 5)), Y, False), "x must not be empty"),
    ("poi direction", lambda: probability_of_improvement(X, Y, "lower"), "lower_is_better must be True"),  # type: ignore[arg-type]
    ("poi interval tasks", lambda: probability_of_improvement_interval(X, Y[:, :1], True), "y must have 5 tasks"),
    ("poi interval reps", lambda: probability_of_improvement_interval(X, Y, True, reps=0), "reps must be"),
    ("dict empty", lambda: interval_estimates({}), "score_dict must be a non-empty mapping"),
    ("dict not mapping", lambda: interval_estimates([X]), "score_dict must be a non-empty mapping"),  # type: ignore[arg-type]
    ("dict nan", lambda: interval_estimates({"x": X, "y": np.full((2, 5), np.nan)}), r"score_dict\['y'\]"),
    ("dict tasks", lambda: interval_estimates({"x": X, "y": Y[:, :4]}), r"score_dict\['y'\] must have 5 tasks"),
    ("dict 1-D", lambda: interval_estimates({"x": X[0]}), r"score_dict\['x'\] must be a 2-D array"),
    ("metric", lambda: interval_estimates({"x": X}, "optimality_gap"), "metric must be one of"),
    ("reps", lambda: interval_estimates({"x": X}, reps=1.5), "reps must be a positive integer"),  # type: ignore[arg-type]
    ("confidence", lambda: interval_estimates({"x": X}, confidence=1.0), "confidence must be"),
    ("profile taus", lambda: performance_profile({"x": X}, [np.nan], True), "taus must contain only finite"),
    ("profile taus 2-D", lambda: performance_profile({"x": X}, np.ones((2, 2)), True), "taus must be a scalar"),
    ("profile taus empty", lambda: performance_profile({"x": X}, [], True), "taus must not be empty"),
    ("profile direction", lambda: performance_profile({"x": X}, TAUS, None), "lower_is_better"),  # type: ignore[arg-type]
    ("profile tasks", lambda: performance_profile_intervals({"x": X, "y": Y[:, :2]}, TAUS, True), r"score_dict\['y'\]"),
    ("profile confidence", lambda: performance_profile_intervals({"x": X}, TAUS, True, confidence=0), "confidence"),
    ("parity lengths", lambda: steps_to_parity([0, 1, 2], [1.0, 2.0], 1.0), "steps and values must be 1-D"),
    ("parity order", lambda: steps_to_parity([0, 2, 1], [1.0, 2.0, 3.0], 1.0), "steps must be non-decreasing"),
    ("parity nan", lambda: steps_to_parity([0, 1], [1.0, np.nan], 1.0), "values must contain only finite"),
    ("parity empty", lambda: steps_to_parity([], [], 1.0), "steps must not be empty"),
    ("parity target", lambda: steps_to_parity([0, 1], [1.0, 2.0], np.nan), "target must be a finite number"),
    ("parity times", lambda: time_to_parity([1.0, 0.0], [1.0, 2.0], 1.0), "times must be non-decreasing"),
    ("parity unsigned", lambda: steps_to_parity(np.array([0, 2, 1], np.uint64), [3.0, 2.0, 1.0], 1.0), "steps must"),
    ("parity text", lambda: time_to_parity(["a"], [1.0], 1.0), "times must be a 1-D array of real numbers"),
]


@pytest.mark.parametrize(("call", "match"), [(c, m) for _, c, m in BAD_CALLS], ids=[n for n, _, _ in BAD_CALLS])
def test_bad_input_raises_value_error_naming_the_argument(call: Callable[[], Any], match: str) -> None:
    with pytest.raises(ValueError, match=match):
        call()
