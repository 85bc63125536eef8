"""Residual PPO on the compiled backend (vnhc_gym.wrappers.residual_jax): the base in JAX against the
numpy law, an untrained agent that is exactly its base, and a checkpoint that loads as a residual policy."""

from __future__ import annotations

import json

import gymnasium as gym
import jax
import numpy as np
import pytest

from vnhc_gym import make_jax
from vnhc_gym.baselines import GeometricController
from vnhc_gym.tasks import env_ids
from vnhc_gym.wrappers.residual_jax import ResidualEnv, law_base

# The plain law on every task; the sampled-data law (Newton steps on the controller's own RK4 map) on
# the boat, whose controller model is not its environment's system.
CASES = [(e, "plain") for e in env_ids("v1")] + [("vnhc_gym/USVStream-v1", "sampled")]


@pytest.mark.parametrize(("env_id", "variant"), CASES, ids=lambda c: str(c).removeprefix("vnhc_gym/"))
def test_the_base_is_the_numpy_law_on_the_same_observations(env_id: str, variant: str) -> None:
    """The compiled base reads the state back and applies the law as `GeometricController` does
    (float64 both; the numpy side returns float32 actions)."""
    env, params = make_jax(env_id, "noisy")
    base = law_base(env, 5.0, variant)
    with jax.enable_x64(True):
        obs, state = jax.vmap(env.reset, in_axes=(0, None))(jax.random.split(jax.random.key(3), 16), params)
        got = np.asarray(jax.vmap(base, in_axes=(0, 0, None))(obs, state.p_nominal, params))
    law = GeometricController(gym.make(env_id, scenario="noisy"), gain=5.0, variant=variant)
    want, _ = law.predict(np.asarray(obs))
    assert np.all(np.abs(got) <= 1.0)
    np.testing.assert_allclose(got, want, atol=1e-6)


def test_the_residual_env_applies_base_plus_scaled_residual_and_shows_the_base() -> None:
    env, params = make_jax("vnhc_gym/SledCruise-v1", "nominal")
    base = law_base(env, 5.0)
    res = ResidualEnv.around(env, base, scale=0.3, observe_base=True)
    with jax.enable_x64(True):
        obs, state = res.reset(jax.random.key(0), params)
        b = np.asarray(base(state.obs, state.p_nominal, params))
        np.testing.assert_array_equal(np.asarray(obs), np.concatenate([np.asarray(state.obs), b]))
        a = np.full(env.num_actions, 0.7)
        new, out = res.transition(jax.random.key(1), state, a, params)
        plain, plain_out = env.transition(jax.random.key(1), state, np.clip(b + 0.3 * 0.7, -1, 1), params)
        np.testing.assert_array_equal(np.asarray(new.s), np.asarray(plain.s))
        assert res.obs_dim == env.obs_dim + env.num_actions == out.obs.shape[0]
    with pytest.raises(ValueError, match="scale"):
        ResidualEnv.around(env, base, scale=1.5)


def test_a_residual_sac_starts_at_its_base_with_the_files_exploration_noise() -> None:
    """The SAC actor after `start_at_base`: mean 0 and log-std ``log_std_init`` at any observation
    (the whole run is the PPO test's below, the same code but the networks)."""
    from vnhc_gym.training import TrainConfig
    from vnhc_gym.training import sac_jax as S
    from vnhc_gym.training.config import hyperparams_of
    from vnhc_gym.training.run_jax import _residual, start_at_base

    cfg = TrainConfig(algo="residual_sac", env="usv", backend="jax")
    hp, cfg = hyperparams_of(cfg, "vnhc_gym/USVStream-v1")
    residual = _residual(hp, cfg, "vnhc_gym/USVStream-v1")
    assert residual["log_std_init"] == -3.0 and residual["scale"] == 0.1
    settings = S.settings_from(hp)  # the file's log_std_init is taken out: the rest is SAC's
    params = start_at_base(S.init_params(jax.random.key(0), s=settings, obs_dim=16, act_dim=2), residual)
    obs = jax.random.normal(jax.random.key(1), (32, 16)) * 3.0
    mean, log_std = S.actor_apply(params, obs)
    np.testing.assert_array_equal(np.asarray(mean), 0.0)
    np.testing.assert_array_equal(np.asarray(log_std), -3.0)


@pytest.mark.slow
def test_an_untrained_residual_is_its_base_and_its_checkpoint_loads_as_a_residual_policy(tmp_path) -> None:
    from vnhc_gym.evaluation import TEST_SEED, VALIDATION_SEED, evaluate
    from vnhc_gym.training import TrainConfig, load_agent
    from vnhc_gym.training.run_jax import EPISODE_TIME, train_seeds, validation_scores

    (meta,) = train_seeds(
        TrainConfig(algo="residual_ppo", env="sled", n_timesteps=16384, eval_points=1, eval_episodes=4,
                    test_episodes=4, backend="jax", out=str(tmp_path)), [0])
    assert meta["residual"] == {"scale": 0.2, "observe_base": True, "base": "law",
                                "base_settings": {"variant": "plain"}, "gain": 5.0}
    # At step 0 the policy's mean is 0: its validation score is the law's on the same episodes (in
    # float64, as the trainer validates).
    env, params = make_jax("vnhc_gym/SledCruise-v1", "nominal")
    base = law_base(env, 5.0)
    keys = jax.numpy.stack([jax.random.key(VALIDATION_SEED + i) for i in range(4)])
    with jax.enable_x64(True):
        scores, _ = jax.jit(lambda k: validation_scores(env, params, lambda o: base(o, params.nominal, params), k,
                                                        round(EPISODE_TIME / float(params.dt))))(keys)
    assert meta["curve"][0]["score"] == pytest.approx(float(np.mean(scores)), rel=1e-6)
    # Its interval is the one an SB3 run records over the same episodes (`EvalResult.summary`): the
    # report reads a residual's parity from its lower end.
    from vnhc_gym import stats
    iv = stats.interval_estimates({"x": np.asarray(scores)[None, :]}, metric="mean", reps=200)["x"]
    point = meta["curve"][0]
    assert point["score_low"] <= point["score"] <= point["score_high"]
    assert (point["score_low"], point["score_high"]) == pytest.approx((iv.low, iv.high), rel=1e-5)
    path = tmp_path / f"{meta['name']}.npz"
    side = json.loads(path.with_suffix(".json").read_text())
    agent = load_agent(path)
    assert agent.base is not None and agent.base.variant == "plain"
    action, state = agent.predict(np.zeros(5, np.float32))
    assert action.shape == (2,) and state is None
    result = evaluate(agent, side["env_id"], side["scenario"], n_episodes=4, seed=TEST_SEED)
    assert result.summary()["score"].point == pytest.approx(side["test"]["summary"]["score"][0], rel=1e-6)


def test_a_cells_tuned_law_becomes_the_compiled_residuals_base() -> None:
    """The sweep passes the cell's best law by name and settings (`TrainConfig.residual_base*`)."""
    from vnhc_gym.training import TrainConfig
    from vnhc_gym.training.config import hyperparams_of
    from vnhc_gym.training.run_jax import _residual

    cfg = TrainConfig(algo="residual_ppo", env="usv", backend="jax", residual_base="tuned_law",
                      residual_base_settings={"gain": 20.0, "variant": "sampled"})
    hp, cfg = hyperparams_of(cfg, "vnhc_gym/USVStream-v1")
    got = _residual(hp, cfg, "vnhc_gym/USVStream-v1")
    assert got == {"scale": 0.2, "observe_base": True, "base": "tuned_law", "base_settings": {"variant": "sampled"},
                   "gain": 20.0}
    assert "env_wrapper" not in hp  # taken out: the rest is PPO's


def test_a_residual_trains_on_the_kalman_base_of_a_task_that_measures_every_entry(tmp_path) -> None:
    """The compiled trainer on the flock's Kalman base (no unmeasured entries; it trains without x64
    and validates with it): the run finishes, and at step 0 its validation score is the numpy
    filter's on the same episodes."""
    from vnhc_gym.baselines import KalmanController
    from vnhc_gym.evaluation import VALIDATION_SEED, evaluate
    from vnhc_gym.training import TrainConfig
    from vnhc_gym.training.run_jax import train_seeds

    settings = {"gain": 80.0, "q": 0.01, "variant": "sampled"}
    (meta,) = train_seeds(
        TrainConfig(algo="residual_ppo", env="flocking", scenario="noisy", n_timesteps=2048, eval_points=1,
                    eval_episodes=2, test_episodes=2, backend="jax", out=str(tmp_path), residual_base="kalman",
                    residual_base_settings=settings), [0])
    want = evaluate(lambda e: KalmanController(e, **settings), "vnhc_gym/FlockingAlign-v1", "noisy", n_episodes=2,
                    seed=VALIDATION_SEED).metrics["score"]
    assert meta["curve"][0]["score"] == pytest.approx(float(np.mean(want)), rel=1e-6)


def test_a_residual_on_the_kalman_base_starts_at_the_filters_score() -> None:
    """The compiled residual environment on `kalman_base` with a zero residual is the numpy
    `KalmanController` on the same validation episodes (the boat under noise: a filtered current,
    a moving frame), and not the plain law."""
    from vnhc_gym.baselines import KalmanController
    from vnhc_gym.evaluation import VALIDATION_SEED, evaluate
    from vnhc_gym.training.run_jax import EPISODE_TIME, validation_scores
    from vnhc_gym.wrappers.residual_jax import kalman_base

    env_id, settings = "vnhc_gym/USVStream-v1", {"gain": 10.0, "variant": "sampled", "q": 0.01}
    env, params = make_jax(env_id, "noisy")
    task = gym.make(env_id, scenario="noisy").unwrapped.task
    res = ResidualEnv.around(env, kalman_base(env, task, **settings), scale=0.2, observe_base=True)
    keys = jax.numpy.stack([jax.random.key(VALIDATION_SEED + i) for i in range(3)])
    horizon = round(EPISODE_TIME / float(params.dt))
    with jax.enable_x64(True):
        got, _ = jax.jit(lambda k: validation_scores(res, params, lambda o: jax.numpy.zeros(1), k, horizon))(keys)
    want = evaluate(lambda e: KalmanController(e, **settings), env_id, "noisy", n_episodes=3,
                    seed=VALIDATION_SEED).metrics["score"]
    law = evaluate(lambda e: GeometricController(e, gain=10.0, variant="sampled"), env_id, "noisy", n_episodes=3,
                   seed=VALIDATION_SEED).metrics["score"]
    np.testing.assert_allclose(np.asarray(got), want, rtol=1e-6)
    assert np.all(np.abs(want - law) > 1e-3)
    # Step by step on one episode: the agent sees (obs, the filter's belief, the base's action), as
    # the numpy residual wrappers show a Kalman base's.
    genv = gym.make(env_id, scenario="noisy")
    ctrl = KalmanController(genv, **settings)
    obs, _ = genv.reset(seed=VALIDATION_SEED)
    key, k_reset = jax.random.split(jax.random.key(VALIDATION_SEED))
    with jax.enable_x64(True):
        seen, state = res.initial(k_reset, params)
        transition = jax.jit(res.transition)
        for _ in range(10):
            action, _ = ctrl.predict(obs)
            d = obs.shape[0]
            np.testing.assert_allclose(np.asarray(seen[:d]), obs, atol=1e-6)
            np.testing.assert_allclose(np.asarray(seen[d:2 * d]), ctrl.belief(obs[None])[0], atol=1e-6)
            np.testing.assert_allclose(np.asarray(seen[2 * d:]), action, atol=1e-6)
            obs, *_ = genv.step(action)
            key, k = jax.random.split(key)
            state, out = transition(k, state, jax.numpy.zeros(1), params)
            seen = out.obs
        with pytest.raises(ValueError, match="shape"):  # the boat has one control
            res.transition(k, state, jax.numpy.zeros(2), params)
    assert res.obs_dim == 2 * env.obs_dim + 1 == seen.shape[0]


def test_a_cells_kalman_filter_becomes_the_compiled_residuals_base_with_its_settings() -> None:
    from vnhc_gym.training import TrainConfig
    from vnhc_gym.training.config import hyperparams_of
    from vnhc_gym.training.run_jax import _residual

    cfg = TrainConfig(algo="residual_ppo", env="usv", backend="jax", residual_base="kalman",
                      residual_base_settings={"gain": 20.0, "variant": "plain", "q": 0.01})
    hp, cfg = hyperparams_of(cfg, "vnhc_gym/USVStream-v1")
    got = _residual(hp, cfg, "vnhc_gym/USVStream-v1")
    assert got["base"] == "kalman" and got["gain"] == 20.0
    assert got["base_settings"] == {"variant": "plain", "q": 0.01}  # as make_classical takes them at the test
    bad = TrainConfig(algo="residual_ppo", env="usv", backend="jax", residual_base="kalman",
                      residual_base_settings={"gain": 20.0, "alpha": 0.1})
    hp, bad = hyperparams_of(bad, "vnhc_gym/USVStream-v1")
    with pytest.raises(ValueError, match="alpha"):
        _residual(hp, bad, "vnhc_gym/USVStream-v1")
    observer = TrainConfig(algo="residual_ppo", env="usv", backend="jax", residual_base="observer")
    hp, observer = hyperparams_of(observer, "vnhc_gym/USVStream-v1")
    with pytest.raises(ValueError, match="observer"):
        _residual(hp, observer, "vnhc_gym/USVStream-v1")
