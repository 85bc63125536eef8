"""The score counts every failure, every choice ranks on it, stateful bases see the applied action,
and the oracle is the law on the true state and parameters."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pytest

import vnhc_gym  # noqa: F401  (registers the environments)
from vnhc_gym.baselines import GeometricController, OracleController, make_classical, tuning
from vnhc_gym.evaluation import METRICS, PHI_CAP_SF, TEST_SEED, VALIDATION_SEED, EvalResult, episode_metrics, evaluate
from vnhc_gym.tasks import env_ids
from vnhc_gym.wrappers import ResidualAction, ResidualPolicy, ResidualVectorAction

USV = "vnhc_gym/USVStream-v1"


# --------------------------------------------------------------------------- the metric
def test_score_is_the_return_over_the_whole_horizon() -> None:
    """An episode that ended after 3 of 6 steps: its missing steps count 0 in the score and the cap in
    the termination-aware |phi~|; the completed-steps means do not see the end."""
    phi = np.array([1.0, 0.2, 0.1, 0.3])
    reward = np.array([0.9, 0.8, 0.7])
    m = episode_metrics(phi, phi, np.zeros((3, 1)), reward, dt=0.5, terminated=True, horizon=3.0)
    assert m["score"] == pytest.approx((0.9 + 0.8 + 0.7) / 6)
    assert m["success"] == 0.0 and m["terminated"] == 1.0 and m["length"] == 3
    assert m["mean_abs_phi_sf"] == pytest.approx(0.2)
    assert m["horizon_abs_phi_sf"] == pytest.approx((0.2 + 0.1 + 0.3 + 3 * PHI_CAP_SF) / 6)
    # A last value above the cap carries on instead.
    phi[-1] = 4.0
    m = episode_metrics(phi, phi, np.zeros((3, 1)), reward, dt=0.5, terminated=True, horizon=3.0)
    assert m["horizon_abs_phi_sf"] == pytest.approx((0.2 + 0.1 + 4.0 * 4) / 6)
    # The full horizon: the score is the mean reward, a success.
    full = episode_metrics(np.ones(7), np.ones(7), np.zeros((6, 1)), np.full(6, 0.5), dt=0.5, terminated=False,
                           horizon=3.0)
    assert full["score"] == pytest.approx(0.5) and full["success"] == 1.0
    with pytest.raises(ValueError, match="horizon_steps"):
        episode_metrics(phi, phi, np.zeros((3, 1)), reward, dt=0.5, terminated=True, horizon=3.0, horizon_steps=2)


class _LawThenSpin:
    """The law for ``hold`` steps, then full force until the boat spins past its turn-rate limit."""

    def __init__(self, env: Any, hold: int = 100) -> None:
        self.law = GeometricController(env)
        self.hold = hold
        self.t = 0

    def predict(self, obs: Any, state: Any = None, episode_start: Any = None, deterministic: bool = True) -> Any:
        a, _ = self.law.predict(obs)
        self.t += 1
        return (a if self.t <= self.hold else np.ones_like(a)), state


def test_a_policy_that_fails_late_scores_below_the_law() -> None:
    kw = {"n_episodes": 6, "seed": TEST_SEED}
    law = evaluate(GeometricController, USV, "nominal", **kw)
    spin = evaluate(_LawThenSpin, USV, "nominal", **kw)
    assert spin.metrics["success"].mean() < 1.0 and law.metrics["success"].mean() == 1.0
    assert spin.metrics["score"].mean() < law.metrics["score"].mean()
    assert spin.summary()["score"].point < law.summary()["score"].point
    assert spin.metrics["horizon_abs_phi_sf"].mean() > law.metrics["horizon_abs_phi_sf"].mean()


def _result(score: float, phi: float, n: int = 4) -> EvalResult:
    """An evaluation whose every episode has the given score and completed-steps mean |phi~|."""
    values = {name: np.full(n, 0.5) for name in METRICS}
    values.update({"score": np.full(n, score), "mean_abs_phi_sf": np.full(n, phi), "mean_abs_phi": np.full(n, phi),
                   "success": np.full(n, float(score > 0.5)), "terminated": np.full(n, float(score <= 0.5))})
    return EvalResult(env_id=USV, scenario="nominal", policy="fake", seed=VALIDATION_SEED, dt=0.05, metrics=values,
                      abs_phi=np.zeros((2, n)), abs_phi_sf=np.zeros((2, n)), wall_time=0.0)


def test_tuning_ranks_on_the_score_where_the_completed_steps_mean_disagrees(monkeypatch: pytest.MonkeyPatch) -> None:
    # Gain 20 holds |phi~| lowest while it lasts but fails episodes; gain 5 is the best score.
    table = {20.0: (0.4, 1e-4), 5.0: (0.95, 1e-2)}

    def fake(name: str, settings: dict, env_id: str, scenario: str, n_episodes: int, seed: int, **kw: Any) -> Any:
        assert seed >= VALIDATION_SEED and seed + n_episodes <= TEST_SEED
        score, phi = table.get(settings["gain"], (0.9, 2e-2))
        return _result(score, phi, n_episodes)

    monkeypatch.setattr(tuning, "evaluate_classical", fake)
    best, rows = tuning.tune("tuned_law", USV, "nominal", n_episodes=4)
    assert best["gain"] == 5.0  # (the first of the grid's settings at that gain: ties go to the first)
    assert min(rows, key=lambda r: table.get(r["gain"], (0.9, 2e-2))[1])["gain"] == 20.0  # the other ranking
    assert {r["gain"]: r["success"] for r in rows}[20.0] == 0.0


def test_checkpoint_selection_ranks_on_the_score(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    pytest.importorskip("stable_baselines3")
    from vnhc_gym.training import run as run_module

    # Validation results in call order: the second has the lowest |phi~| but fails; the third scores best.
    plan = [(0.5, 0.5), (0.3, 1e-4), (0.9, 1e-2), (0.2, 0.3), (0.2, 0.3), (0.2, 0.3), (0.2, 0.3)]
    calls: list[int] = []

    def fake(policy: Any, env_id: str, scenario: str = "nominal", n_episodes: int = 10, seed: int = TEST_SEED,
             **kw: Any) -> EvalResult:
        calls.append(seed)
        score, phi = plan[min(len(calls) - 1, len(plan) - 1)] if seed == VALIDATION_SEED else (0.5, 0.5)
        return _result(score, phi, n_episodes)

    monkeypatch.setattr(run_module, "evaluate", fake)
    meta = run_module.train(algo="ppo", env="usv", n_timesteps=2048, out=str(tmp_path), eval_points=4,
                            eval_episodes=2, test_episodes=2, threads=1,
                            overrides={"n_envs": 8, "n_steps": 64, "batch_size": 128})
    curve = meta["curve"]
    assert len(curve) >= 3 and curve[2]["score"] == 0.9
    assert meta["best_steps"] == curve[2]["steps"] != curve[1]["steps"]
    assert (tmp_path / f"{meta['name']}-final.zip").is_file()


# --------------------------------------------------------------------------- stateful bases under a residual
class _Noise:
    """Exploration noise like PPO's at initialisation: a Gaussian action of standard deviation e^-2."""

    def __init__(self, m: int, seed: int = 0) -> None:
        self.m = m
        self.rng = np.random.default_rng(seed)

    def predict(self, obs: Any, state: Any = None, episode_start: Any = None, deterministic: bool = True) -> Any:
        batch = np.asarray(obs).reshape(-1, np.asarray(obs).shape[-1]).shape[0]
        return self.rng.normal(0.0, math.exp(-2.0), size=(batch, self.m)), state


def test_observer_base_keeps_its_level_under_residual_noise() -> None:
    """Told the applied force, the observer base on the boat's noisy scenario stays within 3x of its own
    mean |phi~| when a residual adds noise (scale 0.2); told nothing, it would be tens of times worse."""
    kw = {"n_episodes": 12, "seed": VALIDATION_SEED}
    alone = evaluate(lambda env: make_classical("observer", env, gain=5.0, alpha=0.03), USV, "noisy", **kw)
    noisy = evaluate(lambda env: ResidualPolicy(_Noise(1), make_classical("observer", env, gain=5.0, alpha=0.03),
                                                scale=0.2), USV, "noisy", **kw)
    ratio = noisy.metrics["mean_abs_phi_sf"].mean() / alone.metrics["mean_abs_phi_sf"].mean()
    assert ratio < 3.0, ratio


def test_the_vector_wrapper_tells_its_base_the_applied_action() -> None:
    n, steps = 8, 400
    venv = gym.make_vec(USV, num_envs=n, vectorization_mode="vector_entry_point", scenario="noisy")
    wrapped = ResidualVectorAction(venv, base="observer", base_settings={"gain": 5.0, "alpha": 0.03}, scale=0.2)
    plain = gym.make_vec(USV, num_envs=n, vectorization_mode="vector_entry_point", scenario="noisy")
    base = make_classical("observer", plain, gain=5.0, alpha=0.03)
    told = _record_applied(wrapped.base)
    noise = _Noise(1)
    obs_w, _ = wrapped.reset(seed=VALIDATION_SEED)
    obs_p, _ = plain.reset(seed=VALIDATION_SEED)
    phi_w, phi_p = [], []
    for _ in range(steps):
        a, _ = noise.predict(obs_w)
        obs_w, _, term_w, trunc_w, info_w = wrapped.step(a)
        obs_p, _, _, _, info_p = plain.step(base.predict(obs_p)[0])
        phi_w.append(info_w["abs_phi_sf"])
        phi_p.append(info_p["abs_phi_sf"])
        # The base was told the force the environment received.
        np.testing.assert_allclose(told[-1] * wrapped.base.force_bound, info_w["force"], rtol=1e-6)
    assert len(told) == steps
    assert np.mean(phi_w) < 3.0 * np.mean(phi_p)


def _record_applied(base: Any) -> list[np.ndarray]:
    """Record what a base is told through ``applied`` (and still tell it)."""
    told: list[np.ndarray] = []
    original = base.applied

    def applied(action: Any) -> None:
        told.append(np.asarray(action, dtype=np.float64).copy())
        original(action)

    base.applied = applied
    return told


def test_the_single_wrapper_and_the_policy_tell_their_base_the_applied_action() -> None:
    env = ResidualAction(gym.make(USV, scenario="noisy"), base="adaptive", scale=0.2)
    told = _record_applied(env.base)
    env.reset(seed=0)
    for a in (0.7, -1.0, 0.3):
        _, _, _, _, info = env.step(np.array([a], dtype=np.float32))
        np.testing.assert_allclose(told[-1].reshape(-1) * env.base.force_bound, info["force"], rtol=1e-6)
    plain = gym.make(USV, scenario="noisy")
    policy = ResidualPolicy(_Noise(1), make_classical("observer", plain), scale=0.2)
    told = _record_applied(policy.base)
    obs, _ = plain.reset(seed=0)
    for _ in range(3):
        action, _ = policy.predict(obs)
        obs, _, _, _, info = plain.step(action)
        np.testing.assert_allclose(told[-1].reshape(-1) * policy.base.force_bound, info["force"], rtol=1e-6)


# --------------------------------------------------------------------------- the oracle
@pytest.mark.parametrize("env_id", env_ids("v1", shipped_only=True), ids=lambda e: e.removeprefix("vnhc_gym/"))
def test_oracle_decays_phi_exactly_on_the_true_model(env_id: str) -> None:
    """Under mismatch the oracle still makes phi after each control period exp(-k dt) times the last (the
    sampled-data law on the true parameters), where the force bound does not bind."""
    k = 5.0
    env = gym.make(env_id, scenario="mismatch")
    _, info = env.reset(seed=TEST_SEED)
    oracle = OracleController(env, gain=k)
    dt = env.unwrapped.dt
    checked = 0
    phi = np.asarray(info["phi"], dtype=np.float64)
    for _ in range(10):
        action, _ = oracle.predict(np.zeros(env.observation_space.shape, dtype=np.float32))
        saturated = bool(oracle.last_saturated[0])
        _, _, term, trunc, info = env.step(action)
        new = np.asarray(info["phi"], dtype=np.float64)
        if not saturated and np.max(np.abs(phi)) > 1e-6:
            np.testing.assert_allclose(new, math.exp(-k * dt) * phi, rtol=1e-5, atol=1e-9)
            checked += 1
        phi = new
        if term or trunc:
            break
    assert checked >= 5


def test_oracle_ignores_the_observation_noise_and_beats_the_law() -> None:
    kw = {"n_episodes": 4, "seed": TEST_SEED, "max_time": 5.0}

    def oracle(env: Any) -> Any:
        return OracleController(env, gain=40.0)

    nominal = evaluate(oracle, USV, "nominal", **kw)
    noisy = evaluate(oracle, USV, "noisy", **kw)
    law_noisy = evaluate(GeometricController, USV, "noisy", **kw)
    np.testing.assert_allclose(noisy.metrics["score"], nominal.metrics["score"], rtol=1e-12)
    assert noisy.metrics["score"].mean() > law_noisy.metrics["score"].mean()


# --------------------------------------------------------------------------- the report
def _side(algo: str, seed: int, scores: list[float], curve: list[dict[str, float]] | None = None,
          validation: float | None = None, backend: str = "sb3") -> dict[str, Any]:
    n = len(scores)
    metrics = {"score": scores, "success": [1.0] * n, "mean_abs_phi_sf": [0.01] * n,
               "horizon_abs_phi_sf": [0.01] * n}
    side: dict[str, Any] = {"name": f"usv-nominal-{algo}-{backend}-s{seed}", "algo": algo, "code": "x",
                            "spec": {"env": "usv", "scenario": "nominal", "algo": algo, "seed": seed,
                                     "backend": backend},
                            "test": {"metrics": metrics}}
    if curve is not None:
        side["curve"] = curve
    if validation is not None:
        side.update({"validation_score": validation, "settings": {"gain": 5.0}})
    return side


def _point(steps: int, score: float, low: float, wall: float) -> dict[str, float]:
    return {"steps": steps, "wall": wall, "score": score, "score_low": low, "score_high": score + 0.01}


def _report(tmp_path: Path, sides: list[dict[str, Any]]) -> dict[str, Any]:
    """The report of a run folder holding these sidecars."""
    from vnhc_gym.sweep import report

    runs = tmp_path / "runs"
    runs.mkdir(parents=True, exist_ok=True)
    for s in sides:
        (runs / f"{s['name']}.json").write_text(json.dumps(s))
    return report(tmp_path, reps=200, log=lambda s: None)


def test_parity_is_counted_from_the_agents_own_start(tmp_path: Path) -> None:
    rep = _report(tmp_path, [
        _side("law", 0, [0.80] * 10, validation=0.80),
        _side("tuned_law", 0, [0.90] * 10, validation=0.90),
        # Residual runs start at their base: parity is beating it with the interval, not the start.
        _side("residual_ppo", 0, [0.91] * 10, [_point(0, 0.90, 0.88, 0.0), _point(100, 0.905, 0.89, 1.0),
                                               _point(200, 0.93, 0.91, 2.0)]),
        _side("residual_ppo", 1, [0.90] * 10, [_point(0, 0.90, 0.88, 0.0), _point(100, 0.90, 0.88, 1.0)]),
        _side("residual_ppo", 2, [0.92] * 10, [_point(0, 0.90, 0.88, 0.0), _point(300, 0.95, 0.92, 3.0)]),
        # From scratch: reaching the best classical's validation score.
        _side("ppo", 0, [0.5] * 10, [_point(0, 0.1, 0.0, 0.0), _point(400, 0.90, 0.8, 4.0)]),
    ])
    rows = {r["algo"]: r for r in rep["rows"]}
    assert rows["law"]["best_classical"] == "tuned_law"
    res = rows["residual_ppo"]
    assert res["parity_runs"] == "2/3" and res["parity_steps"] == 300.0 and res["parity_seconds"] == 3.0
    assert rows["ppo"]["parity_steps"] == 400.0 and rows["ppo"]["parity_runs"] == "1/1"
    # The score's interval and the probability of improvement over the best classical baseline.
    assert rows["ppo"]["poi"] == 0.0 and rows["residual_ppo"]["poi"] > 0.5
    verdict = {v["env"]: v for v in rep["verdicts"]}["usv"]
    assert verdict["best_learned"] == "residual_ppo" and verdict["best_classical"] == "tuned_law"


def test_the_best_learned_agent_is_chosen_on_validation_episodes(tmp_path: Path) -> None:
    """The agent with the better *test* score but the worse validation score is not the cell's best
    learned agent: the test episodes never pick the rows they then judge."""
    rep = _report(tmp_path, [
        _side("tuned_law", 0, [0.90] * 10, validation=0.90),
        _side("ppo", 0, [0.99] * 10, [_point(0, 0.1, 0.0, 0.0), _point(100, 0.80, 0.7, 1.0)]),
        _side("residual_ppo", 0, [0.91] * 10, [_point(0, 0.90, 0.88, 0.0), _point(100, 0.95, 0.94, 1.0)]),
    ])
    rows = {r["algo"]: r for r in rep["rows"]}
    assert rows["ppo"]["score"] > rows["residual_ppo"]["score"]
    assert rows["ppo"]["validation_score"] == 0.80 and rows["residual_ppo"]["validation_score"] == 0.95
    assert rep["verdicts"][0]["best_learned"] == "residual_ppo"
    assert rep["verdicts"][0]["winner"] == "learned" and rep["verdicts"][0]["why"] == "+0.0100 in score"


def test_a_verdict_says_why_from_the_numbers(tmp_path: Path) -> None:
    """Where learning does not win, the reason comes from the cell's own numbers: the oracle leaves
    nothing to win, no residual run left its base, the agents from scratch fall short."""
    rep = _report(tmp_path, [
        _side("oracle", 0, [0.907] * 10, validation=0.907),
        _side("tuned_law", 0, [0.90, 0.91] * 5, validation=0.90),
        _side("ppo", 0, [0.5] * 10, [_point(0, 0.1, 0.0, 0.0), _point(100, 0.50, 0.4, 1.0)]),
        _side("residual_ppo", 0, [0.91, 0.90] * 5, [_point(0, 0.90, 0.88, 0.0), _point(100, 0.90, 0.88, 1.0)]),
    ])
    (cell,) = rep["verdicts"]
    assert cell["winner"] == "none" and cell["best_learned"] == "residual_ppo"
    assert cell["why"] == ("no headroom (the oracle is +0.0020 above the best classical); no residual run beat its "
                           "base on validation; from scratch 0.4050 behind")


def test_a_compiled_residual_agent_is_read_as_residual_not_from_scratch(tmp_path: Path) -> None:
    """The compiled backend's rows are named ``residual_ppo-jax``: its parity is still beating its own
    base, its runs are counted among the residual ones, and the gap from scratch is the compiled PPO's."""
    rep = _report(tmp_path, [
        _side("tuned_law", 0, [0.90] * 10, validation=0.90),
        _side("ppo", 0, [0.5] * 10, [_point(0, 0.1, 0.0, 0.0), _point(100, 0.50, 0.4, 1.0)], backend="jax"),
        # Seed 0's interval clears its start (its base) at 200 steps; seed 1 never leaves it.
        _side("residual_ppo", 0, [0.90] * 10, [_point(0, 0.90, 0.88, 0.0), _point(100, 0.92, 0.89, 1.0),
                                               _point(200, 0.93, 0.91, 2.0)], backend="jax"),
        _side("residual_ppo", 1, [0.90] * 10, [_point(0, 0.90, 0.88, 0.0), _point(100, 0.90, 0.88, 1.0)],
              backend="jax"),
        # A curve of means only: whether it beat its base is not known, so it is not counted a miss.
        _side("residual_ppo", 2, [0.90] * 10, [{"steps": 0, "wall": 0.0, "score": 0.90},
                                               {"steps": 100, "wall": 1.0, "score": 0.95}], backend="jax"),
    ])
    rows = {r["algo"]: r for r in rep["rows"]}
    assert rows["residual_ppo-jax"]["parity_runs"] == "1/2" and rows["ppo-jax"]["parity_runs"] == "0/1"
    (cell,) = rep["verdicts"]
    assert cell["best_learned"] == "residual_ppo-jax"
    assert cell["why"].endswith("1 of 2 residual runs beat their base on validation (1 more without a recorded "
                                "interval); from scratch 0.4000 behind")


@pytest.mark.parametrize(("oracle", "says"), [
    (0.902, "no headroom (the oracle is 0.0030 below the best classical)"),
    (0.895, "the oracle scores below the best classical (-0.0100)"),
])
def test_an_oracle_below_the_best_classical_is_named_only_beyond_the_noise(tmp_path: Path, oracle: float,
                                                                         says: str) -> None:
    """Within ``NO_HEADROOM`` of the best classical baseline, above or below, the oracle leaves nothing
    to win; only further below is it named as scoring below (and a failure share only if it fails)."""
    rep = _report(tmp_path, [
        _side("oracle", 0, [oracle] * 10, validation=oracle),
        _side("tuned_law", 0, [0.90, 0.91] * 5, validation=0.90),
        _side("residual_ppo", 0, [0.91, 0.90] * 5, [_point(0, 0.90, 0.88, 0.0), _point(100, 0.90, 0.88, 1.0)]),
    ])
    (cell,) = rep["verdicts"]
    assert cell["why"].split("; ")[0] == says


@pytest.mark.parametrize(("env", "scenario", "kind", "own_model"), [
    ("cartpole", "noisy", "information", False),
    ("usv", "noisy", "information", True),  # the boat's controllers read the current through a local model
    ("usv", "mismatch", "model error", False),
])
def test_a_verdict_names_the_kind_of_headroom_left(tmp_path: Path, env: str, scenario: str, kind: str,
                                                   own_model: bool) -> None:
    """Beyond ``NO_HEADROOM`` the reason gives the oracle's lead and its kind, which the scenario's one
    change from nominal decides, with model error added for a task whose controllers run a model of
    their own."""
    sides = [
        _side("oracle", 0, [0.96] * 10, validation=0.96),
        _side("tuned_law", 0, [0.90, 0.91] * 5, validation=0.90),
        _side("residual_ppo", 0, [0.91, 0.90] * 5, [_point(0, 0.90, 0.88, 0.0), _point(100, 0.90, 0.88, 1.0)]),
    ]
    for s in sides:
        s["spec"].update(env=env, scenario=scenario)
        s["name"] = s["name"].replace("usv-nominal", f"{env}-{scenario}")
    (cell,) = _report(tmp_path, sides)["verdicts"]
    assert (cell["env"], cell["scenario"]) == (env, scenario)
    reason = cell["why"].split("; ")[0]
    assert reason.startswith(f"headroom +0.0550 (the oracle above the best classical): {kind}:")
    assert ("and model error: the controllers run a model of their own" in reason) is own_model


@pytest.mark.parametrize(("informed", "says"), [
    (0.93, "+0.0300 information (the oracle above the filter told the true model), +0.0250 model (that filter "
           "above the best classical)"),
    (0.90, "+0.0550 information (the oracle above the filter told the true model), +0.0000 model (that filter "
           "above the best classical)"),  # told the model, no better: the whole headroom is information
])
def test_the_informed_filter_splits_the_headroom(tmp_path: Path, informed: float, says: str) -> None:
    """With the informed filter's run in the cell the headroom is split by measurement, whatever the
    scenario: the oracle above that filter, and that filter above the best classical baseline."""
    rep = _report(tmp_path, [
        _side("oracle", 0, [0.96] * 10, validation=0.96),
        _side("informed_kalman", 0, [informed] * 10, validation=informed),
        _side("tuned_law", 0, [0.90, 0.91] * 5, validation=0.90),
        _side("residual_ppo", 0, [0.91, 0.90] * 5, [_point(0, 0.90, 0.88, 0.0), _point(100, 0.90, 0.88, 1.0)]),
    ])
    (cell,) = rep["verdicts"]
    assert cell["best_classical"] == "tuned_law"  # a reference is never the cell's best classical
    assert cell["why"].split("; ")[0] == f"headroom +0.0550 (the oracle above the best classical): {says}"


def test_published_records_restore_the_report(tmp_path: Path) -> None:
    """`save_records` then `restore_records` elsewhere gives the same report; a restored run is
    finished for a sweep, and a run already there is not overwritten."""
    from vnhc_gym.sweep import RunSpec, report, restore_records, save_records, status

    spec = RunSpec("ppo", "usv", "nominal", seed=0)
    runs = tmp_path / "a" / "runs"
    runs.mkdir(parents=True)
    sides = [_side("tuned_law", 0, [0.90] * 10, validation=0.90),
             {**_side("ppo", 0, [0.5, 0.7] * 5, [_point(0, 0.1, 0.0, 0.0)]), "name": spec.stem}]
    for s in sides:
        (runs / f"{s['name']}.json").write_text(json.dumps(s))
    assert save_records(tmp_path / "a", tmp_path / "runs.jsonl.gz") == 2
    assert restore_records(tmp_path / "runs.jsonl.gz", tmp_path / "b") == 2
    assert status(spec, tmp_path / "b") == "done"
    a = report(tmp_path / "a", reps=100, log=lambda s: None)["rows"]
    b = report(tmp_path / "b", reps=100, log=lambda s: None)["rows"]
    assert a == b and len(a) == 2
    mine = tmp_path / "b" / "runs" / f"{spec.stem}.json"
    mine.write_text(json.dumps({**sides[1], "code": "mine"}))
    assert restore_records(tmp_path / "runs.jsonl.gz", tmp_path / "b") == 0
    assert json.loads(mine.read_text())["code"] == "mine"


def test_the_planning_baseline_reports_its_solve_time_and_is_never_a_residual_base(tmp_path: Path) -> None:
    """MPC can be a cell's best classical baseline (it is fielded as it is), its solve time sits beside
    its score, and a residual agent's base is the best of the others (MPC would plan at every step of
    every training environment)."""
    from vnhc_gym.sweep import RunSpec
    from vnhc_gym.sweep.execute import _best_classical

    scores = {"law": 0.80, "tuned_law": 0.85, "observer": 0.83, "adaptive": 0.84, "mpc": 0.90}
    sides = [{**_side(algo, 0, [v] * 10, validation=v), "name": RunSpec(algo, "usv", "nominal").stem}
             for algo, v in scores.items()]
    sides[-1]["solve_seconds_per_step"] = 0.025
    rows = {r["algo"]: r for r in _report(tmp_path, sides)["rows"]}
    assert rows["law"]["best_classical"] == "mpc" and rows["mpc"]["solve_ms_per_step"] == pytest.approx(25.0)
    assert "mpc (best) (25 ms/step)" in (tmp_path / "report" / "comparison.md").read_text()
    spec = RunSpec("residual_ppo", "usv", "nominal", bases=("law", "tuned_law", "observer", "adaptive"))
    base, settings = _best_classical(spec, tmp_path, "vnhc_gym/USVStream-v1")
    assert base == "tuned_law" and settings == {"gain": 5.0}
    with pytest.raises(ValueError, match="bases"):
        RunSpec("residual_ppo", "usv", "nominal", bases=("mpc",))


def test_a_residual_base_is_read_from_its_cells_classical_runs_of_the_same_grid(tmp_path: Path,
                                                                               monkeypatch: pytest.MonkeyPatch) -> None:
    """A grid with overrides gives them to every run: a residual agent's base comes from the cell's
    finished classical runs of that grid, never from tuning the cell again."""
    from vnhc_gym import sweep
    from vnhc_gym.baselines import tuning
    from vnhc_gym.sweep.execute import _best_classical

    specs = sweep.grid(["usv"], ["nominal"], ["law", "tuned_law", "residual_ppo"], [0], 1000,
                       overrides={"learning_rate": 1e-4})
    (tmp_path / "runs").mkdir()
    for spec, v in zip(specs[:2], (0.80, 0.85), strict=True):
        side = {**_side(spec.algo, 0, [v] * 10, validation=v), "name": spec.stem, "settings": {"gain": v * 100}}
        (tmp_path / "runs" / f"{spec.stem}.json").write_text(json.dumps(side))

    def tune(*args: object, **kwargs: object) -> None:
        raise AssertionError("the cell was tuned again")

    monkeypatch.setattr(tuning, "tune", tune)
    assert _best_classical(specs[2], tmp_path, "vnhc_gym/USVStream-v1") == ("tuned_law", {"gain": 85.0})


def test_only_runs_that_compute_on_jax_ask_ray_for_a_gpu() -> None:
    from vnhc_gym.sweep import RunSpec, gpus_of

    for algo in ("law", "mpc", "ppo", "residual_ppo", "ppo_history"):
        assert gpus_of(RunSpec(algo, "usv"), gpu_available=True) == 0, algo
    assert gpus_of(RunSpec("sac", "usv"), gpu_available=True) == 1
    assert gpus_of(RunSpec("residual_sac", "usv"), gpu_available=False) == 0


def test_a_higher_mean_without_the_pairwise_majority_is_explained() -> None:
    """The boat under kicks in miniature: the law finishes three episodes in four with a high score
    and fails the fourth; an agent that finishes all of them at a lower level has the higher mean
    but loses most pairwise comparisons, and the verdict says both."""
    import tempfile

    law = _side("tuned_law", 0, [0.97, 0.97, 0.97, 0.30] * 5, validation=0.80)
    law["test"]["metrics"]["success"] = [1.0, 1.0, 1.0, 0.0] * 5
    agent = _side("ppo", 0, [0.85] * 20, [_point(0, 0.1, 0.0, 0.0), _point(100, 0.85, 0.84, 1.0)])
    with tempfile.TemporaryDirectory() as tmp:
        (cell,) = _report(Path(tmp), [law, agent])["verdicts"]
    assert cell["winner"] in ("classical", "none")
    assert cell["why"].startswith("ppo has the higher mean (+0.0475) but not most pairwise comparisons; "
                                  "ppo finishes 100% of the episodes, tuned_law 75%")
