"""Tests of vnhc_gym.evaluation: the per-episode metrics and the evaluation protocol.

The metrics are checked against values worked out by hand on a synthetic trace, and ``evaluate``
against a plain Gymnasium loop over single environments with the same seeds, and against the
continuous-time law's exponential decay.
"""

from __future__ import annotations

import json
import math
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
from scipy import stats as sps

import vnhc_gym  # noqa: F401
from vnhc_gym.baselines import GeometricController, RandomPolicy, ZeroPolicy
from vnhc_gym.evaluation import (
    HIGHER_IS_BETTER,
    METRICS,
    TEST_SEED,
    VALIDATION_SEED,
    EvalResult,
    episode_metrics,
    evaluate,
)
from vnhc_gym.tasks import env_id, env_ids

ENVS = env_ids("v1")
USV = env_id("usv")
FLOCK = env_id("flocking")


def _short(e: str) -> str:
    return e.removeprefix("vnhc_gym/")


# --------------------------------------------------------------------------- metrics
def test_episode_metrics_on_a_hand_computed_trace() -> None:
    abs_phi = np.array([2.0, 1.0, 0.5, 0.02, 0.01, 0.005])  # 1 % of 2.0 is 0.02: reached at step 3
    abs_phi_sf = np.array([1.0, 0.9, 0.5, 0.3, 0.2, 0.1])  # never below 0.01
    force = np.array([[1.0, 2.0], [0.0, 0.0], [3.0, 0.0], [0.0, -1.0], [1.0, 1.0]])
    reward = np.array([0.1, 0.2, 0.3, 0.4, 0.5])
    m = episode_metrics(abs_phi, abs_phi_sf, force, reward, dt=0.1, terminated=True, horizon=2.0)
    assert list(m) == list(METRICS)
    expected = {
        "mean_abs_phi": (1.0 + 0.5 + 0.02 + 0.01 + 0.005) / 5,  # the reset state is not counted
        "late_abs_phi": (0.02 + 0.01 + 0.005) / 3,  # the second half of the 5 steps: steps 3..5
        "time_to_1pct": 0.3,
        "control_energy": (1 + 4 + 9 + 1 + 1 + 1) * 0.1,
        "return": 1.5,
        "terminated": 1.0,
        "mean_abs_phi_sf": (0.9 + 0.5 + 0.3 + 0.2 + 0.1) / 5,
        "late_abs_phi_sf": (0.3 + 0.2 + 0.1) / 3,
        "time_to_1pct_sf": 2.0,  # never: the horizon
        "reached_1pct": 1.0,
        "length": 5.0,
    }
    for name, value in expected.items():
        assert m[name] == pytest.approx(value, rel=1e-12), name
    assert all(isinstance(v, float) for v in m.values())


def test_episode_metrics_edge_cases() -> None:
    # Exactly 1 % counts as reached; one step; not terminated.
    m = episode_metrics(np.array([1.0, 0.01]), np.array([1.0, 0.02]), np.zeros((1, 1)), np.array([-0.5]),
                        dt=0.05, terminated=False, horizon=0.05)
    assert m["time_to_1pct"] == pytest.approx(0.05) and m["reached_1pct"] == 1.0
    assert m["time_to_1pct_sf"] == pytest.approx(0.05)  # the horizon
    assert m["late_abs_phi"] == pytest.approx(0.01) and m["terminated"] == 0.0 and m["return"] == -0.5
    # Only the first crossing counts, even if phi comes back up.
    m = episode_metrics(np.array([1.0, 0.5, 0.005, 0.9]), np.ones(4), np.zeros((3, 1)), np.zeros(3), dt=0.5,
                        terminated=False, horizon=1.5)
    assert m["time_to_1pct"] == pytest.approx(1.0)
    with pytest.raises(ValueError, match="at least one step"):
        episode_metrics(np.array([1.0]), np.array([1.0]), np.zeros((0, 1)), np.zeros(0), 0.05, False, 1.0)


def test_metric_names() -> None:
    assert len(set(METRICS)) == len(METRICS)
    assert HIGHER_IS_BETTER <= set(METRICS)
    assert {"mean_abs_phi", "mean_abs_phi_sf", "return", "control_energy", "time_to_1pct"} <= set(METRICS)
    assert 0 < VALIDATION_SEED < TEST_SEED


# --------------------------------------------------------------------------- the protocol against a hand loop
def _hand_metrics(env: str, policy_factory: Any, seed: int, steps: int, scenario: str = "nominal",
                  **kwargs: Any) -> dict[str, float]:
    """One episode with a plain Gymnasium loop, measured without episode_metrics."""
    e = gym.make(env, scenario=scenario, max_episode_steps=steps, **kwargs)
    pol = policy_factory(e)
    dt = e.unwrapped.dt
    obs, info = e.reset(seed=seed)
    phi, phi_sf, ret, energy, terminated = [info["abs_phi"]], [info["abs_phi_sf"]], 0.0, 0.0, False
    for _ in range(steps):
        obs, r, term, trunc, info = e.step(pol.predict(obs)[0])
        phi.append(info["abs_phi"])
        phi_sf.append(info["abs_phi_sf"])
        ret += r
        energy += float(np.sum(np.square(info["force"]))) * dt
        terminated = bool(term)
        if term or trunc:
            break
    e.close()
    phi, phi_sf = np.array(phi), np.array(phi_sf)
    t = len(phi) - 1
    missing = steps - t  # steps of the horizon after an early end
    below = [i for i in range(1, t + 1) if phi[i] <= 0.01 * phi[0]]
    below_sf = [i for i in range(1, t + 1) if phi_sf[i] <= 0.01 * phi_sf[0]]
    half = t // 2
    return {"mean_abs_phi": float(np.mean(phi[1:])), "late_abs_phi": float(np.mean(phi[half + 1:])),
            "time_to_1pct": below[0] * dt if below else steps * dt, "control_energy": energy, "return": ret,
            "terminated": float(terminated), "mean_abs_phi_sf": float(np.mean(phi_sf[1:])),
            "late_abs_phi_sf": float(np.mean(phi_sf[half + 1:])),
            "time_to_1pct_sf": below_sf[0] * dt if below_sf else steps * dt, "reached_1pct": float(bool(below)),
            "length": float(t), "score": ret / steps, "success": float(not terminated),
            "horizon_abs_phi_sf": (float(np.sum(phi_sf[1:])) + missing * max(1.0, float(phi_sf[-1]))) / steps}


@pytest.mark.parametrize("scenario", ["nominal", "coarse"])
@pytest.mark.parametrize("env", ENVS, ids=_short)
def test_evaluate_matches_a_hand_rollout(env: str, scenario: str) -> None:
    res = evaluate(GeometricController, env, scenario, n_episodes=3, seed=7, max_time=2.0)
    dt = gym.make(env, scenario=scenario).unwrapped.dt
    steps = round(2.0 / dt)
    assert res.dt == dt and res.abs_phi.shape == (steps + 1, 3) and res.n_episodes == 3
    assert res.env_id == env and res.scenario == scenario and res.seed == 7 and res.policy == "geometric"
    for i in range(3):
        hand = _hand_metrics(env, GeometricController, 7 + i, steps, scenario)
        for name in METRICS:
            assert res.metrics[name][i] == pytest.approx(hand[name], rel=1e-9, abs=1e-12), (name, i)


def test_terminated_episodes_are_measured_to_their_end() -> None:
    """Without control the boat drifts out of a 6 m square within 10 s."""
    res = evaluate(ZeroPolicy, USV, n_episodes=4, seed=TEST_SEED, max_time=10.0, domain=6.0)
    assert res.metrics["terminated"].all() and np.all(res.metrics["length"] < 200)
    for i in range(4):
        n = int(res.metrics["length"][i])
        assert np.all(np.isfinite(res.abs_phi[: n + 1, i])) and np.all(np.isnan(res.abs_phi[n + 1:, i]))
        hand = _hand_metrics(USV, ZeroPolicy, TEST_SEED + i, 200, domain=6.0)
        for name in METRICS:
            assert res.metrics[name][i] == pytest.approx(hand[name], rel=1e-9, abs=1e-12), (name, i)
    json.dumps(res.to_dict(series=True), allow_nan=False)


# --------------------------------------------------------------------------- the in-loop law: phi(t) = phi(0) exp(-k t)
@pytest.mark.parametrize("env", ENVS, ids=_short)
def test_in_loop_law_decays_exponentially(env: str) -> None:
    """The law inside the integrator on the true state is the theorem's setting: every component of
    phi, hence mean |phi|, decays as exp(-k t) (up to RK4's error), whatever the observation noise."""
    for k in (2.0, 3.0):
        res = evaluate(ZeroPolicy, env, "nominal", n_episodes=3, seed=TEST_SEED, max_time=2.0, feedback="continuous",
                       gain=k)
        t = np.arange(res.abs_phi.shape[0]) * res.dt
        np.testing.assert_allclose(res.abs_phi / res.abs_phi[0], np.exp(-k * t)[:, None] * np.ones((1, 3)),
                                   rtol=2e-3)
        # 1 % of phi(0) on the first control step after ln(100) / k.
        expected = math.ceil(math.log(100) / (k * res.dt)) * res.dt
        np.testing.assert_allclose(res.metrics["time_to_1pct"], expected if expected <= 2.0 else 2.0)
        assert np.all(res.metrics["control_energy"] > 0)  # the in-loop law's force is the applied force
        noisy = evaluate(ZeroPolicy, env, "noisy", n_episodes=3, seed=TEST_SEED, max_time=2.0, feedback="continuous",
                         gain=k)
        np.testing.assert_array_equal(noisy.abs_phi, res.abs_phi)


# --------------------------------------------------------------------------- reproducibility and seeds
@pytest.mark.parametrize("env", ENVS, ids=_short)
def test_same_seed_same_numbers(env: str, assert_same: Any) -> None:
    kw = {"n_episodes": 3, "seed": TEST_SEED, "max_time": 2.0}
    a = evaluate(GeometricController, env, "noisy", **kw)
    b = evaluate(GeometricController, env, "noisy", **kw)
    assert_same(a.metrics, b.metrics)
    assert_same(a.abs_phi, b.abs_phi)
    assert_same(a.abs_phi_sf, b.abs_phi_sf)
    c = evaluate(GeometricController, env, "noisy", **{**kw, "seed": TEST_SEED + 100})
    assert not np.array_equal(a.metrics["mean_abs_phi"], c.metrics["mean_abs_phi"])
    # Episode i is seeded seed + i.
    d = evaluate(GeometricController, env, "noisy", n_episodes=1, seed=TEST_SEED + 2, max_time=2.0)
    np.testing.assert_array_equal(d.abs_phi[:, 0], a.abs_phi[:, 2])
    # A class, a factory and an instance built on the same kind of environment are the same policy.
    e = gym.make(env)
    for pol in (lambda venv: GeometricController(venv), GeometricController(e)):
        assert_same(evaluate(pol, env, "noisy", **kw).metrics, a.metrics)
    e.close()


def test_random_policy_evaluation_is_seeded() -> None:
    kw = {"n_episodes": 2, "seed": TEST_SEED, "max_time": 1.0}
    a = evaluate(lambda env: RandomPolicy(env, seed=3), FLOCK, **kw)
    b = evaluate(lambda env: RandomPolicy(env, seed=3), FLOCK, **kw)
    np.testing.assert_array_equal(a.abs_phi, b.abs_phi)
    assert a.policy == "random"


def test_recurrent_state_and_episode_start_are_passed() -> None:
    class Recurrent:
        name = "recurrent"

        def __init__(self) -> None:
            self.calls: list[tuple[Any, Any]] = []

        def predict(self, obs: Any, state: Any = None, episode_start: Any = None, deterministic: bool = True):
            self.calls.append((state, np.array(episode_start)))
            return np.zeros((obs.shape[0], 1), dtype=np.float32), ("h", len(self.calls))

    pol = Recurrent()
    res = evaluate(pol, USV, n_episodes=2, max_time=0.25)
    assert res.policy == "recurrent" and len(pol.calls) == 5
    assert pol.calls[0][0] is None and pol.calls[0][1].tolist() == [True, True]
    for i, (state, starts) in enumerate(pol.calls[1:], start=1):
        assert state == ("h", i) and starts.tolist() == [False, False]


# --------------------------------------------------------------------------- results
def test_summary_is_the_mean_of_the_score_and_the_iqm_of_the_diagnostics() -> None:
    res = evaluate(GeometricController, USV, "noisy", n_episodes=8, seed=TEST_SEED, max_time=2.0)
    summary = res.summary(reps=500)
    assert set(summary) == set(METRICS)
    means = {"score", "success", "terminated", "horizon_abs_phi_sf"}
    for name, iv in summary.items():
        values = res.metrics[name]
        expected = float(np.mean(values)) if name in means else sps.trim_mean(values, 0.25)
        assert iv.point == pytest.approx(expected, rel=1e-12, abs=1e-15), name
        assert iv.low <= iv.point + 1e-12 and iv.point <= iv.high + 1e-12


def test_to_dict_is_json_and_round_trips(tmp_path: Any) -> None:
    res = evaluate(GeometricController, USV, n_episodes=2, seed=TEST_SEED, max_time=1.0, current="northeast",
                   current_params={"c1": 0.5, "c2": 0.0})
    assert isinstance(res, EvalResult)
    for series in (False, True):
        d = res.to_dict(series=series)
        text = json.dumps(d, allow_nan=False)
        back = json.loads(text)
        assert back["env_id"] == USV and back["n_episodes"] == 2 and back["seed"] == TEST_SEED
        assert back["env_kwargs"] == {"current": "northeast"}  # non-scalar arguments are left out
        for name in METRICS:
            assert back["metrics"][name] == res.metrics[name].tolist()
            assert len(back["summary"][name]) == 3
        assert ("abs_phi" in back) is series
        if series:
            assert len(back["abs_phi"]) == res.abs_phi.shape[0]
    res.to_json(tmp_path / "r.json", series=True)
    on_disk = json.loads((tmp_path / "r.json").read_text())
    assert on_disk["metrics"] == res.to_dict()["metrics"]


def test_bad_arguments() -> None:
    for bad in (0, -1, 2.5, True):
        with pytest.raises(ValueError, match="n_episodes"):
            evaluate(ZeroPolicy, USV, n_episodes=bad)
    for bad in (-1, 1.5, True):
        with pytest.raises(ValueError, match="seed"):
            evaluate(ZeroPolicy, USV, n_episodes=1, seed=bad)
    with pytest.raises(ValueError, match="scenario"):
        evaluate(ZeroPolicy, USV, "stormy", n_episodes=1)
    with pytest.raises(ValueError, match="feedback"):
        evaluate(ZeroPolicy, USV, n_episodes=1, max_time=0.1, feedback="sometimes")
