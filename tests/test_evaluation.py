"""Tests of vnhc_gym.evaluation."""

from __future__ import annotations

import csv
import json

import gymnasium as gym
import numpy as np
import pytest
from scipy import stats

import vnhc_gym  # noqa: F401
from vnhc_gym.baselines import GeometricController, RandomPolicy, ZeroPolicy
from vnhc_gym.evaluation import EvalResult, aggregate, evaluate, iqm, markdown_table, results_to_csv

FLOCK = "vnhc_gym/FlockingAlign-v0"
USV = "vnhc_gym/USVStream-v0"


def test_metrics_match_a_hand_rollout() -> None:
    """Every metric recomputed from a plain Gymnasium loop with the same seeds."""
    res = evaluate(lambda e: GeometricController(e), USV, n_episodes=3, seed=7, max_time=3.0)
    assert res.max_steps == 60 and res.dt == 0.05
    for i in range(3):
        env = gym.make(USV, max_episode_steps=60, disable_env_checker=True)
        pol = GeometricController(env)
        obs, info = env.reset(seed=7 + i)
        phis, ret, energy, done = [info["abs_phi"]], 0.0, 0.0, False
        while not done:
            obs, r, term, trunc, info = env.step(pol.predict(obs)[0])
            phis.append(info["abs_phi"])
            ret += r
            energy += float(np.sum(info["force"] ** 2)) * 0.05
            done = term or trunc
        phis = np.array(phis)
        assert res.length[i] == len(phis) - 1
        np.testing.assert_allclose(res.phi_series[i, : len(phis)], phis)
        assert res.mean_abs_phi[i] == pytest.approx(np.mean(phis[1:]))
        assert res.final_abs_phi[i] == pytest.approx(phis[-1])
        assert res.returns[i] == pytest.approx(ret)
        assert res.energy[i] == pytest.approx(energy)
        below = np.flatnonzero(phis < 0.01 * phis[0])
        expected = below[0] * 0.05 if below.size else np.inf
        assert res.time_to_eps[i] == pytest.approx(expected)


def test_time_to_eps_follows_exponential_decay() -> None:
    # phi(t) ~ phi(0) exp(-k t): 100-fold reduction after ln(100)/k s.
    res = evaluate(lambda e: GeometricController(e, gain=2.0), USV, n_episodes=3, max_time=6.0)
    np.testing.assert_allclose(res.time_to_eps, np.log(100) / 2.0, atol=0.1)
    assert np.all(res.settle_time >= res.time_to_eps)
    zero = evaluate(ZeroPolicy, FLOCK, n_episodes=2, max_time=2.0)
    assert np.all(np.isinf(zero.time_to_eps))
    np.testing.assert_array_equal(zero.energy, 0.0)
    absolute = evaluate(lambda e: GeometricController(e, gain=2.0), USV, n_episodes=1, max_time=6.0, eps=1e-3)
    assert absolute.eps.startswith("absolute")


def test_horizon_in_seconds_and_seeds() -> None:
    coarse = evaluate(ZeroPolicy, USV, "coarse", n_episodes=1, max_time=4.0)
    nominal = evaluate(ZeroPolicy, USV, "nominal", n_episodes=1, max_time=4.0)
    assert coarse.max_steps == 40 and nominal.max_steps == 80
    assert coarse.times[-1] == pytest.approx(4.0) and nominal.times[-1] == pytest.approx(4.0)
    # Episode i uses seed + i.
    a = evaluate(ZeroPolicy, USV, n_episodes=3, seed=10, max_time=1.0)
    b = evaluate(ZeroPolicy, USV, n_episodes=1, seed=12, max_time=1.0)
    np.testing.assert_array_equal(a.phi_series[2], b.phi_series[0])


def test_batch_and_row_by_row_agree() -> None:
    a = evaluate(lambda e: GeometricController(e), FLOCK, n_episodes=3, max_time=2.0)
    b = evaluate(lambda e: GeometricController(e), FLOCK, n_episodes=3, max_time=2.0, batch=False)
    np.testing.assert_array_equal(a.phi_series, b.phi_series)


def test_unknown_scenario_and_bad_arguments() -> None:
    with pytest.raises(ValueError, match="unknown scenario"):
        evaluate(ZeroPolicy, USV, "stormy")
    with pytest.raises(ValueError, match="n_episodes"):
        evaluate(ZeroPolicy, USV, n_episodes=0)
    with pytest.raises(ValueError, match="max_time"):
        evaluate(ZeroPolicy, USV, max_time=-1)
    with pytest.raises(TypeError, match="predict"):
        evaluate(42, USV, n_episodes=1, max_time=0.5)


def test_aggregate_iqm_and_bootstrap_ci() -> None:
    x = np.array([1.0, 2, 3, 4, 5, 6, 7, 100])
    agg = aggregate(x)
    assert agg.iqm == pytest.approx(np.mean([3, 4, 5, 6]))  # middle 50 %
    assert agg.iqm == pytest.approx(stats.trim_mean(x, 0.25))
    assert agg.ci_low <= agg.iqm <= agg.ci_high
    assert agg.mean == pytest.approx(x.mean()) and agg.n == 8
    assert aggregate(x).ci_low == agg.ci_low  # seeded
    const = aggregate([2.0, 2.0, 2.0])
    assert const.iqm == const.ci_low == const.ci_high == 2.0
    with_inf = aggregate([1.0, 2.0, 3.0, np.inf])
    assert np.isfinite(with_inf.ci_low) and with_inf.ci_high == np.inf
    assert aggregate([np.nan]).n == 0
    assert float(iqm(np.arange(8.0))) == pytest.approx(3.5)


def test_outputs(tmp_path) -> None:
    results = [evaluate(ZeroPolicy, USV, n_episodes=2, max_time=1.0),
               evaluate(lambda e: RandomPolicy(e, 0), USV, n_episodes=2, max_time=1.0, name="random")]
    assert isinstance(results[0], EvalResult) and results[0].policy == "zero"
    results[0].to_csv(tmp_path / "ep.csv")
    rows = list(csv.DictReader(open(tmp_path / "ep.csv")))
    assert len(rows) == 2 and rows[1]["seed"] == "1" and rows[0]["policy"] == "zero"
    data = json.loads(results[0].to_json(tmp_path / "r.json", series=True))
    assert data["summary"]["mean_abs_phi"]["n"] == 2 and len(data["phi_series"][0]) == 21
    assert json.loads((tmp_path / "r.json").read_text())["policy"] == "zero"
    results_to_csv(results, tmp_path / "summary.csv")
    summary = list(csv.DictReader(open(tmp_path / "summary.csv")))
    assert [r["policy"] for r in summary] == ["zero", "random"]
    assert "mean_abs_phi_iqm" in summary[0] and "return_ci_high" in summary[0]
    md = markdown_table(results, ("mean_abs_phi", "time_to_eps"))
    lines = md.splitlines()
    assert len(lines) == 4 and lines[0].startswith("| env | scenario | policy")
    assert "| usv | nominal | random |" in md
    with pytest.raises(ValueError, match="metric"):
        markdown_table(results, ("accuracy",))
