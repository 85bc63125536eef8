"""The compiled SAC (vnhc_gym.training.sac_jax, run_jax): its parts against independent formulas,
its settings against the hyperparameter files, and whole short runs (learning, checkpoints, seeds)."""

from __future__ import annotations

import json
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import stats

from vnhc_gym.training import sac_jax as S
from vnhc_gym.training.hyperparams import env_ids, load_hyperparams

# One xdist worker runs this module, so that its module-scoped fixture (the compiled trainer's runs) is built once.
pytestmark = pytest.mark.xdist_group("test_sac_jax")


# ---------------------------------------------------------------------------------------------- settings
@pytest.mark.parametrize("env_id", env_ids("sac"))
def test_every_shipped_sac_section_is_read(env_id: str) -> None:
    hp = load_hyperparams("sac", env_id)
    hp.pop("env_kwargs", None)  # the environment's, not the learner's (TrainConfig takes them)
    s = S.settings_from(hp, env_id)
    assert s.n_envs == hp["n_envs"] and s.gradient_steps == hp["gradient_steps"]
    assert s.batch_size == hp["batch_size"] and s.ent_auto == (hp["ent_coef"] == "auto")
    assert s.capacity % s.rollout == 0 and s.capacity <= hp["buffer_size"]


@pytest.mark.parametrize("extra, named", [({"use_sde": True}, "use_sde"),
                                          ({"policy_kwargs": {"n_critics": 3}}, "n_critics"),
                                          ({"learning_rate": "lin_3e-4"}, "learning_rate"),
                                          ({"train_freq": [1, "episode"]}, "train_freq")])
def test_a_key_the_compiled_sac_does_not_honour_raises_naming_it(extra: dict, named: str) -> None:
    hp = load_hyperparams("sac", "vnhc_gym/USVStream-v1")
    with pytest.raises(ValueError, match=named):
        S.settings_from({**hp, **extra})


# ---------------------------------------------------------------------------------------------- parts
def test_the_squashed_action_has_the_change_of_variables_density() -> None:
    # log p(a) = log N(atanh a; mean, std) - sum log(1 - a^2), from the action alone.
    s = S.SACSettings(net_arch=(8,))
    params = S.init_params(jax.random.key(0), s=s, obs_dim=3, act_dim=2)
    params["log_std_out"]["b"] = jnp.array([-0.5, 0.3])
    obs = 0.1 * jax.random.normal(jax.random.key(1), (64, 3))
    a, logp = S._sample(params, obs, jax.random.key(2))
    assert float(jnp.max(jnp.abs(a))) < 0.999  # away from float32's rounding of tanh to 1
    mean, log_std = (np.asarray(x, np.float64) for x in S.actor_apply(params, obs))
    a = np.asarray(a, np.float64)
    u = np.arctanh(a)
    want = (stats.norm.logpdf(u, mean, np.exp(log_std)) - np.log1p(-a * a)).sum(axis=1)
    np.testing.assert_allclose(np.asarray(logp), want, rtol=1e-4, atol=1e-3)


def test_the_log_standard_deviation_is_clipped_to_sbxs_bounds() -> None:
    s = S.SACSettings(net_arch=(4,))
    params = S.init_params(jax.random.key(0), s=s, obs_dim=2, act_dim=1)
    params["log_std_out"]["b"] = jnp.array([50.0])
    assert float(S.actor_apply(params, jnp.zeros((1, 2)))[1][0, 0]) == S.LOG_STD_MAX
    params["log_std_out"]["b"] = jnp.array([-50.0])
    assert float(S.actor_apply(params, jnp.zeros((1, 2)))[1][0, 0]) == S.LOG_STD_MIN


# ---------------------------------------------------------------------------------------------- whole runs
BUDGET = 32 * 1500  # 1500 iterations of 32 steps: 10 000 random steps, then 10 000 gradient steps


def _train(out: Path, n_timesteps: int, seeds: list[int], test_episodes: int = 5) -> list[dict]:
    from vnhc_gym.training.config import TrainConfig
    from vnhc_gym.training.run_jax import train_seeds

    return train_seeds(TrainConfig(algo="sac", env="usv", n_timesteps=n_timesteps, eval_points=1, eval_episodes=5,
                                   test_episodes=test_episodes, backend="jax", out=str(out)), seeds)


@pytest.fixture(scope="module")
def usv_runs(tmp_path_factory: pytest.TempPathFactory) -> dict:
    """One seed, long enough to learn (seeds side by side: the test below)."""
    out = tmp_path_factory.mktemp("sac_jax")
    return {"out": out, "both": _train(out / "both", BUDGET, [0])}


@pytest.mark.slow
def test_a_short_compiled_sac_run_improves_the_validation_score(usv_runs: dict) -> None:
    for meta in usv_runs["both"]:
        curve = meta["curve"]
        assert curve[0]["steps"] == 0 and curve[-1]["steps"] == BUDGET
        assert curve[-1]["score"] > curve[0]["score"] + 0.05, curve


@pytest.mark.slow
def test_a_sac_checkpoint_loads_as_a_policy_and_scores_its_recorded_test(usv_runs: dict) -> None:
    from vnhc_gym.evaluation import TEST_SEED, evaluate
    from vnhc_gym.training import load_agent

    meta = usv_runs["both"][0]
    path = usv_runs["out"] / "both" / f"{meta['name']}.npz"
    side = json.loads(path.with_suffix(".json").read_text())
    assert side["backend"] == "jax" and side["squash"] == "tanh" and side["test"] is not None
    agent = load_agent(path)
    action, state = agent.predict(np.full(agent.network.model.layers[0][0].shape[0], 0.3, np.float32))
    assert action.shape == (1,) and state is None and abs(float(action[0])) < 1.0
    result = evaluate(agent, side["env_id"], side["scenario"], n_episodes=5, seed=TEST_SEED)
    assert result.summary()["score"].point == pytest.approx(side["test"]["summary"]["score"][0], rel=1e-6)


@pytest.mark.slow
def test_a_sac_seed_trains_the_same_beside_others_as_alone(tmp_path: Path) -> None:
    # 18 iterations of gradient steps after the random phase: long enough to go through every part
    # of an iteration, short enough that the batched and unbatched programs' rounding stays small
    # (over thousands of steps it grows as in any chaotic training).
    budget = 32 * 330
    both = _train(tmp_path / "both", budget, [0, 1], test_episodes=0)
    alone = _train(tmp_path / "alone", budget, [1], test_episodes=0)
    name = alone[0]["name"]
    with np.load(tmp_path / "both" / f"{name}-final.npz") as a, np.load(tmp_path / "alone" / f"{name}-final.npz") as b:
        assert sorted(a.files) == sorted(b.files)
        for k in a.files:
            np.testing.assert_allclose(a[k], b[k], rtol=1e-4, atol=1e-6, err_msg=k)
    with np.load(tmp_path / "both" / f"{both[0]['name']}-final.npz") as a, \
            np.load(tmp_path / "alone" / f"{name}-final.npz") as b:
        assert not np.allclose(a["pi.0.w"], b["pi.0.w"])  # and the two seeds of one program are different runs
