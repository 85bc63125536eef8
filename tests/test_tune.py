"""Tests of ``vnhc-gym tune``: tiny Optuna studies of a learner and of a classical baseline.

Checked against what a study must guarantee: it never runs a test episode (every evaluation's
seeds are recorded), its winner file holds the best trial's parameters and loads as an RL Zoo
file, a classical winner's value is an independent evaluation of its gains on the validation
episodes, and a rerun resumes the same study.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

pytest.importorskip("optuna")
pytest.importorskip("stable_baselines3")

import vnhc_gym.evaluation  # noqa: E402
import vnhc_gym.training.run  # noqa: E402
from vnhc_gym.baselines.tuning import evaluate_classical  # noqa: E402
from vnhc_gym.evaluation import TEST_SEED, VALIDATION_SEED, evaluate  # noqa: E402
from vnhc_gym.training.hyperparams import load_hyperparams  # noqa: E402
from vnhc_gym.training.tune import TuneConfig, tune  # noqa: E402


@pytest.fixture
def seeds(monkeypatch: pytest.MonkeyPatch) -> list[tuple[int, int]]:
    """Every evaluation's (first seed, episodes), wherever a study evaluates."""
    calls: list[tuple[int, int]] = []

    def recording(policy: Any, env: str, scenario: str = "nominal", n_episodes: int = 10, seed: int = TEST_SEED,
                  **kwargs: Any) -> Any:
        calls.append((seed, n_episodes))
        return evaluate(policy, env, scenario, n_episodes=n_episodes, seed=seed, **kwargs)

    monkeypatch.setattr(vnhc_gym.training.run, "evaluate", recording)
    monkeypatch.setattr(vnhc_gym.evaluation, "evaluate", recording)
    return calls


def _never_test(calls: list[tuple[int, int]]) -> None:
    assert calls
    assert all(VALIDATION_SEED <= s and s + n - 1 < TEST_SEED for s, n in calls), calls


@pytest.mark.slow
def test_a_two_trial_study_writes_an_rl_zoo_file_and_never_reads_a_test_seed(tmp_path: Path,
                                                                           seeds: list[tuple[int, int]]) -> None:
    cfg = TuneConfig(algo="ppo", env="usv", trials=2, n_timesteps=4096, eval_points=2, eval_episodes=2,
                     out=str(tmp_path), env_kwargs={"reward": "reciprocal"})
    lines: list[str] = []
    summary = tune(cfg, log=lines.append)
    _never_test(seeds)
    assert summary["n_trials"] == 2 and len(lines) == 3
    best = max((t for t in summary["trials"] if t["value"] is not None), key=lambda t: t["value"])
    assert summary["best_value"] == best["value"] and summary["best_params"] == best["params"]
    path = tmp_path / "usv-nominal" / "ppo.yml"
    hp = load_hyperparams("ppo", "vnhc_gym/USVStream-v1", path)
    shipped = load_hyperparams("ppo", "vnhc_gym/USVStream-v1")
    params = best["params"]
    assert hp["learning_rate"] == params["learning_rate"] and hp["n_epochs"] == params["n_epochs"]
    assert hp["batch_size"] == min(params["batch_size"], 256 * params["n_steps"])
    assert hp["policy_kwargs"]["net_arch"] == [params["width"]] * 2
    assert hp["policy_kwargs"]["log_std_init"] == params["log_std_init"]
    # Keys the space does not sample keep the shipped file's values.
    assert hp["policy_kwargs"]["activation_fn"] is shipped["policy_kwargs"]["activation_fn"]
    assert hp["normalize"] == shipped["normalize"] and hp["n_envs"] == shipped["n_envs"]
    # The trials trained on the long-tailed reward: so does the winner's file.
    assert hp["env_kwargs"] == {"reward": "reciprocal"} and "env_kwargs" not in shipped
    # The study is stored: the same command adds trials to it.  A trial left running by a killed process
    # is not finished, so it does not count.
    import optuna

    optuna.load_study(study_name="usv-nominal-ppo", storage=f"sqlite:///{tmp_path / 'studies.db'}").ask()
    again = tune(cfg, log=None)
    assert again["n_trials"] == 4
    assert json.loads((tmp_path / "usv-nominal" / "ppo-study.json").read_text())["n_trials"] == 4


def test_a_classical_study_scores_its_winner_on_validation_episodes(tmp_path: Path,
                                                                   seeds: list[tuple[int, int]]) -> None:
    summary = tune(TuneConfig(algo="tuned_law", env="usv", scenario="noisy", trials=4, eval_episodes=3,
                              out=str(tmp_path)), log=None)
    _never_test(seeds)
    won = json.loads((tmp_path / "usv-noisy" / "tuned_law.json").read_text())
    assert 0.5 <= won["settings"]["gain"] <= 200.0
    independent = evaluate_classical("tuned_law", won["settings"], "vnhc_gym/USVStream-v1", "noisy", 3,
                                     VALIDATION_SEED)
    assert won["validation_score"] == pytest.approx(float(np.mean(independent.metrics["score"])), rel=1e-12)
    assert won["validation_score"] == max(t["value"] for t in summary["trials"])


@pytest.mark.parametrize(("field", "value", "match"), [
    ("algo", "td3", "algo must be one of"), ("trials", 0, "trials must be a positive integer"),
    ("n_timesteps", 1.5, "n_timesteps must be a positive integer"), ("repeats", True, "repeats"),
    ("backend", "tf", "backend must be one of"),
])
def test_bad_configuration_is_refused_by_name(tmp_path: Path, field: str, value: Any, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        tune(TuneConfig(out=str(tmp_path), **{field: value}), log=None)


@pytest.mark.slow
def test_a_study_on_the_compiled_backend_writes_a_file_the_compiled_trainer_reads(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import vnhc_gym.training.run_jax as run_jax
    from vnhc_gym.training.ppo_jax import settings_from

    tested: list[Any] = []
    monkeypatch.setattr(run_jax, "evaluate", lambda *a, **k: tested.append(k))  # the Gymnasium test episodes
    summary = tune(TuneConfig(algo="ppo", env="usv", trials=1, n_timesteps=4096, eval_points=1, eval_episodes=2,
                              out=str(tmp_path), backend="jax"), log=None)
    assert summary["n_trials"] == 1 and not tested
    assert all(t["value"] is not None and 0.0 <= t["value"] <= 1.0 for t in summary["trials"])
    hp = load_hyperparams("ppo", "vnhc_gym/USVStream-v1", tmp_path / "usv-nominal" / "ppo.yml")
    settings = settings_from(hp, "the winner")
    assert settings.learning_rate == summary["best_params"]["learning_rate"]
    assert settings.net_arch == (summary["best_params"]["width"],) * 2


@pytest.mark.parametrize("algo", ["ppo", "sac"])
def test_every_sampled_trial_is_a_file_the_compiled_trainer_accepts(algo: str) -> None:
    """A study on the compiled backend samples only keys and values that trainer reads: 30 random trials
    of the search space, each merged into the shipped file as a study does, are read without error."""
    import optuna

    from vnhc_gym.training import ppo_jax, sac_jax
    from vnhc_gym.training.tune import SPACES, _merge

    settings_from = {"ppo": ppo_jax.settings_from, "sac": sac_jax.settings_from}[algo]
    base = load_hyperparams(algo, "vnhc_gym/USVStream-v1")
    study = optuna.create_study(sampler=optuna.samplers.RandomSampler(seed=0))
    for _ in range(30):
        trial = study.ask()
        hp = _merge(base, SPACES[algo](trial))
        settings_from(hp)
        study.tell(trial, 0.0)


@pytest.mark.parametrize(("choice", "expected"), [("auto", -1.0), ("-5", -5.0)])
def test_sac_space_sets_the_entropy_target_of_the_model(choice: str, expected: float) -> None:
    """The sampled entropy target reaches the model: ``auto`` is minus the action dimensions (one on the USV)."""
    optuna = pytest.importorskip("optuna")
    pytest.importorskip("sbx")
    import gymnasium as gym

    from vnhc_gym.training.agents import algorithm_class
    from vnhc_gym.training.tune import SPACES

    trial = optuna.trial.FixedTrial({"target_entropy": choice, "learning_rate": 3e-4, "batch_size": 256,
                                     "gamma": 0.98, "tau": 0.005, "gradient_steps": 2, "learning_starts": 1000,
                                     "width": 64})
    model = algorithm_class("sac")("MlpPolicy", gym.make("vnhc_gym/USVStream-v1"), **SPACES["sac"](trial))
    assert float(model.target_entropy) == expected
