"""The compiled PPO (vnhc_gym.training.ppo_jax, run_jax): its parts against independent formulas,
its settings against the hyperparameter files, and whole short runs (learning, checkpoints, seeds)."""

from __future__ import annotations

import json
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import stats

from vnhc_gym.training import ppo_jax as P
from vnhc_gym.training.hyperparams import env_ids, load_hyperparams

# One xdist worker runs this module, so that its module-scoped fixture (the compiled trainer's runs) is built once.
pytestmark = pytest.mark.xdist_group("test_ppo_jax")
PPO_FILE_IDS = env_ids("ppo")


def test_this_module_runs_on_one_worker(request: pytest.FixtureRequest) -> None:
    """Under ``--dist loadgroup`` the module's tests carry its group, so one worker builds its fixture."""
    import os

    if os.environ.get("PYTEST_XDIST_WORKER") is None or not getattr(request.config.option, "loadgroup", False):
        pytest.skip("runs only under pytest-xdist's --dist loadgroup")
    assert request.node.nodeid.endswith("@test_ppo_jax"), request.node.nodeid


# ---------------------------------------------------------------------------------------------- settings
@pytest.mark.parametrize("env_id", PPO_FILE_IDS)
def test_every_shipped_ppo_section_is_read(env_id: str) -> None:
    hp = load_hyperparams("ppo", env_id)
    s = P.settings_from(hp)
    assert (s.n_envs, s.n_steps, s.batch_size, s.n_epochs) == (hp["n_envs"], hp["n_steps"], hp["batch_size"],
                                                               hp["n_epochs"])
    assert s.log_std_init == hp["policy_kwargs"]["log_std_init"]
    assert s.lr_linear == str(hp["learning_rate"]).startswith("lin_")
    assert s.norm_reward == hp["normalize"]["norm_reward"]


@pytest.mark.parametrize("extra, named", [
    ({"use_sde": True}, "use_sde"),
    ({"policy_kwargs": {"net_arch": [64, 64], "squash_output": True}}, "squash_output"),
    ({"normalize": {"norm_obs": False, "norm_reward": True, "clip_obs": 5.0}}, "clip_obs"),
])
def test_a_key_the_compiled_ppo_does_not_know_raises_naming_it(extra: dict, named: str) -> None:
    hp = {**load_hyperparams("ppo", "vnhc_gym/USVStream-v1"), **extra}
    with pytest.raises(ValueError, match=named):
        P.settings_from(hp)


@pytest.mark.parametrize("extra, words", [
    ({"normalize": True}, "normalises observations"),
    ({"policy": "CnnPolicy"}, "MlpPolicy"),
    ({"batch_size": 1000}, "must divide"),
    ({"policy_kwargs": {"activation_fn": "Softsign"}}, "Softsign"),
])
def test_a_value_the_compiled_ppo_cannot_honour_raises(extra: dict, words: str) -> None:
    hp = {**load_hyperparams("ppo", "vnhc_gym/USVStream-v1"), **extra}
    with pytest.raises(ValueError, match=words):
        P.settings_from(hp)


def test_n_iterations_counts_whole_rollouts_until_the_budget_as_sb3() -> None:
    s = P.PPOSettings(n_envs=256, n_steps=64, n_timesteps=2_000_000)
    assert s.n_iterations == 123  # ceil(2e6 / 16384): SB3 collects until num_timesteps >= total


# ---------------------------------------------------------------------------------------------- parts
def test_gae_matches_the_textbook_recursion() -> None:
    rng = np.random.default_rng(0)
    t, n, gamma, lam = 7, 3, 0.9, 0.8
    r, v = rng.normal(size=(t, n)), rng.normal(size=(t, n))
    d = rng.random((t, n)) < 0.3
    last = rng.normal(size=n)
    want = np.zeros((t, n))
    for j in range(n):  # one episode stream at a time, the definition written out
        acc = 0.0
        for i in reversed(range(t)):
            nv = last[j] if i == t - 1 else v[i + 1, j]
            live = 0.0 if d[i, j] else 1.0
            acc = r[i, j] + gamma * nv * live - v[i, j] + gamma * lam * live * acc
            want[i, j] = acc
    got = P.gae(jnp.asarray(r), jnp.asarray(v), jnp.asarray(d), jnp.asarray(last), gamma, lam)
    np.testing.assert_allclose(np.asarray(got), want, rtol=1e-5, atol=1e-6)


def test_gae_with_lambda_one_and_no_end_is_the_discounted_return_minus_the_value() -> None:
    r = jnp.ones((5, 1))
    v = jnp.zeros((5, 1))
    got = P.gae(r, v, jnp.zeros((5, 1), bool), jnp.zeros(1), 0.5, 1.0)
    np.testing.assert_allclose(np.asarray(got)[:, 0], [1 + 0.5 + 0.25 + 0.125 + 0.0625, 1.875, 1.75, 1.5, 1.0],
                               rtol=1e-6)


def test_running_return_statistics_are_the_mean_and_variance_of_everything_seen() -> None:
    rng = np.random.default_rng(1)
    batches = [rng.normal(3.0, 2.0, size=64) for _ in range(20)]
    st = P.ReturnStats(jnp.float32(0.0), jnp.float32(1.0), jnp.float32(1e-4))
    for b in batches:
        st = P._update_stats(st, jnp.asarray(b, jnp.float32))
    allx = np.concatenate(batches)
    assert float(st.mean) == pytest.approx(allx.mean(), rel=1e-4)
    assert float(st.var) == pytest.approx(allx.var(), rel=1e-4)


def test_log_prob_is_the_diagonal_gaussian_density() -> None:
    rng = np.random.default_rng(2)
    mean, a = rng.normal(size=(4, 3)), rng.normal(size=(4, 3))
    log_std = np.array([-1.5, 0.0, 0.4])
    want = stats.norm.logpdf(a, mean, np.exp(log_std)).sum(axis=1)
    np.testing.assert_allclose(np.asarray(P._log_prob(jnp.asarray(mean), jnp.asarray(log_std), jnp.asarray(a))), want,
                               rtol=1e-5)


@pytest.mark.parametrize("n", [1, 2, 5, 4096, 16384, 100_003])
def test_shuffle_is_a_permutation(n: int) -> None:
    order = np.asarray(P.shuffle(jax.random.key(n), n))
    np.testing.assert_array_equal(np.sort(order), np.arange(n))


def test_shuffle_puts_every_element_anywhere_with_equal_chance() -> None:
    # 4000 shuffles of 5: each element's position is uniform (chi-square), and for a large rollout
    # (two rounds of sorting) element 0 lands before element 1 half the time.
    orders = np.asarray(jax.vmap(lambda k: P.shuffle(k, 5))(jax.random.split(jax.random.key(0), 4000)))
    for element in range(5):
        counts = np.bincount(np.argmax(orders == element, axis=1), minlength=5)
        assert stats.chisquare(counts).pvalue > 1e-3, (element, counts)
    big = jax.vmap(lambda k: P.shuffle(k, 16384))(jax.random.split(jax.random.key(1), 400))
    first = np.asarray(jnp.argmax(big == 0, axis=1) < jnp.argmax(big == 1, axis=1))
    assert stats.binomtest(int(first.sum()), first.size).pvalue > 1e-3
    assert len({tuple(o[:8]) for o in np.asarray(big)}) == 400  # no two shuffles alike


def test_initial_networks_are_sb3s_orthogonal_ones() -> None:
    s = P.PPOSettings(net_arch=(64, 64), log_std_init=-1.5)
    params = P.init_params(jax.random.key(0), s=s, obs_dim=64, act_dim=2)
    for net in ("pi", "vf"):
        for layer in params[net][1:]:  # square hidden layers: W^T W = gain^2 I with gain sqrt(2)
            w = np.asarray(layer["w"], np.float64)
            np.testing.assert_allclose(w.T @ w, 2.0 * np.eye(64), atol=1e-4)
            assert not np.any(np.asarray(layer["b"]))
    w = np.asarray(params["pi_out"]["w"], np.float64)  # the action head: gain 0.01
    np.testing.assert_allclose(w.T @ w, 1e-4 * np.eye(2), atol=1e-8)
    np.testing.assert_array_equal(np.asarray(params["log_std"]), [-1.5, -1.5])


def test_the_numpy_actor_is_the_networks_mean_clipped() -> None:
    from vnhc_gym.training.numpy_actor import JaxActor

    s = P.PPOSettings(net_arch=(16, 8))
    params = P.init_params(jax.random.key(3), s=s, obs_dim=5, act_dim=2)
    params["pi_out"]["w"] = params["pi_out"]["w"] * 400.0  # large enough for some actions to clip
    obs = np.random.default_rng(4).normal(size=(50, 5)).astype(np.float32)
    want = np.clip(np.asarray(P.actor_apply(params, jnp.asarray(obs))), -1.0, 1.0)
    assert np.any(np.abs(want) == 1.0) and np.any(np.abs(want) < 1.0)
    got, state = JaxActor(P.to_numpy(params)).predict(obs)
    assert state is None and got.dtype == np.float32
    np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-6)


# ---------------------------------------------------------------------------------------------- validations
def test_validations_come_after_the_iterations_sb3_validates_after() -> None:
    """SB3's callback validates after the first whole rollout that reaches each multiple of
    ``n_timesteps // eval_points`` steps: the k-th after iteration ceil(k * every / rollout) while
    those differ, and at most once a rollout."""
    from vnhc_gym.training.run_jax import validation_iterations

    # 2 M steps in rollouts of 16 384 (123 of them), 20 validations: one every 100 000 steps.
    assert validation_iterations(123, 16384, 2_000_000, 20) == [math.ceil(k * 100_000 / 16384) for k in range(1, 21)]
    # Rollouts longer than the validations' spacing: one validation a rollout.
    assert validation_iterations(4, 10_000, 40_000, 8) == [1, 2, 3, 4]
    # The run's last iteration always ends with one.
    assert validation_iterations(5, 16384, 5 * 16384, 1) == [5]
    assert validation_iterations(7, 1000, 7000, 2) == [4, 7]


@pytest.mark.parametrize("env_id, scenario", [("vnhc_gym/USVStream-v1", "disturbance"),
                                               ("vnhc_gym/SpacecraftPoint-v1", "noisy")])
def test_the_validation_episodes_are_those_an_sb3_run_validates_on(env_id: str, scenario: str) -> None:
    """In float64 (as the trainer runs them) the compiled validation's episodes, kicks and
    observation noise included, are the Gymnasium environment's of the validation seeds: the same
    policy scores the same on each as `evaluate` measures it."""
    from vnhc_gym import make_jax
    from vnhc_gym.baselines import ZeroPolicy
    from vnhc_gym.evaluation import VALIDATION_SEED, evaluate
    from vnhc_gym.training.run_jax import EPISODE_TIME, validation_scores

    env, params = make_jax(env_id, scenario)
    horizon = round(EPISODE_TIME / float(params.dt))
    keys = jnp.stack([jax.random.key(VALIDATION_SEED + i) for i in range(4)])
    with jax.enable_x64(True):
        got, alive = validation_scores(env, params, lambda o: jnp.zeros(env.num_actions, jnp.float32), keys, horizon)
    want = evaluate(ZeroPolicy, env_id, scenario, n_episodes=4, seed=VALIDATION_SEED).metrics
    np.testing.assert_allclose(np.asarray(got), want["score"], rtol=1e-9)
    np.testing.assert_array_equal(np.asarray(alive, dtype=float), want["success"])
    assert np.ptp(want["score"]) > 0  # four different episodes


# ---------------------------------------------------------------------------------------------- whole runs
@pytest.fixture(scope="module")
def usv_runs(tmp_path_factory: pytest.TempPathFactory) -> dict:
    """Two seeds trained in one program and the second alone, 5 iterations each (81 920 steps),
    validated at the start, after 3 iterations and after 5 (chunks of unequal length)."""
    from vnhc_gym.training.config import TrainConfig
    from vnhc_gym.training.run_jax import train_seeds

    out = tmp_path_factory.mktemp("ppo_jax")
    cfg = TrainConfig(algo="ppo", env="usv", n_timesteps=5 * 16384, eval_points=2, eval_episodes=5,
                      test_episodes=5, backend="jax")
    both = train_seeds(cfg.__class__(**{**cfg.__dict__, "out": str(out / "both")}), [0, 1])
    alone = train_seeds(cfg.__class__(**{**cfg.__dict__, "out": str(out / "alone")}), [1])
    return {"out": out, "both": both, "alone": alone}


@pytest.mark.slow
def test_a_short_compiled_run_improves_the_validation_score(usv_runs: dict) -> None:
    for meta in usv_runs["both"]:
        curve = meta["curve"]
        assert [p["steps"] for p in curve] == [0, 3 * 16384, 5 * 16384]  # SB3's: 40 960 steps reached after 3
        # Gains after 5 iterations, 8 seeds, 10 episodes: 0.05 to 0.15 (0.04 to 0.23 with
        # jax.random.permutation's minibatches): a seed that does not learn stays within 0.01.
        assert curve[-1]["score"] > curve[0]["score"] + 0.03, curve


@pytest.mark.slow
def test_a_checkpoint_loads_as_a_policy_and_scores_its_recorded_test(usv_runs: dict) -> None:
    from vnhc_gym.evaluation import TEST_SEED, evaluate
    from vnhc_gym.training import load_agent

    meta = usv_runs["both"][0]
    path = usv_runs["out"] / "both" / f"{meta['name']}.npz"
    side = json.loads(path.with_suffix(".json").read_text())
    assert side["backend"] == "jax" and side["test"] is not None
    agent = load_agent(path)
    action, state = agent.predict(np.zeros(agent.network.model.layers[0][0].shape[0], np.float32))
    assert action.shape == (1,) and state is None
    result = evaluate(agent, side["env_id"], side["scenario"], n_episodes=5, seed=TEST_SEED)
    assert result.summary()["score"].point == pytest.approx(side["test"]["summary"]["score"][0], rel=1e-6)
    assert (usv_runs["out"] / "both" / f"{meta['name']}-final.npz").exists()


@pytest.mark.slow
def test_a_seed_trains_the_same_beside_others_as_alone(usv_runs: dict) -> None:
    name = usv_runs["alone"][0]["name"]
    with np.load(usv_runs["out"] / "both" / f"{name}-final.npz") as a, \
            np.load(usv_runs["out"] / "alone" / f"{name}-final.npz") as b:
        assert sorted(a.files) == sorted(b.files)
        for k in a.files:  # one program batches the seeds, the other does not: equal to rounding
            np.testing.assert_allclose(a[k], b[k], rtol=1e-3, atol=1e-5, err_msg=k)
    # and the two seeds of one program are different runs
    s0, s1 = (json.loads((usv_runs["out"] / "both" / f"{m['name']}.json").read_text()) for m in usv_runs["both"])
    assert not math.isclose(s0["curve"][-1]["score"], s1["curve"][-1]["score"], rel_tol=1e-9)


def test_the_jax_backend_refuses_what_it_does_not_train() -> None:
    from vnhc_gym.training import TrainConfig, train

    with pytest.raises(ValueError, match="backend must be one of"):
        train(TrainConfig(backend="tf"))
    with pytest.raises(ValueError, match=r"trains \['ppo', 'residual_ppo', 'sac', 'residual_sac'\] only"):
        train(TrainConfig(algo="recurrent_ppo", backend="jax"))
    with pytest.raises(ValueError, match="got base 'observer'"):  # a base not written in JAX
        train(TrainConfig(algo="residual_ppo", backend="jax", residual_base="observer"))
    with pytest.raises(ValueError, match=r"takes gain, variant, got \['alpha'\]"):
        train(TrainConfig(algo="residual_ppo", backend="jax", residual_base_settings={"alpha": 0.1}))
    from vnhc_gym.training.run_jax import train_seeds

    with pytest.raises(ValueError, match="distinct"):
        train_seeds(TrainConfig(backend="jax"), [1, 1])
    with pytest.raises(ValueError, match="one file stem for 2 seeds"):
        train_seeds(TrainConfig(backend="jax", name="mine"), [0, 1])
    with pytest.raises(ValueError, match="its own stem"):
        train_seeds(TrainConfig(backend="jax"), [0, 1], names=["a", "a"])


def test_seeds_on_the_command_line_need_the_jax_backend() -> None:
    from vnhc_gym.cli import main

    with pytest.raises(SystemExit, match="--backend jax"):
        main(["train", "--algo", "ppo", "--backend", "sb3", "--env", "usv", "--seeds", "0", "1"])
    # Recurrent PPO, which only SB3 trains, is on SB3 without being told.
    with pytest.raises(SystemExit, match="--backend jax"):
        main(["train", "--algo", "recurrent_ppo", "--env", "usv", "--seeds", "0", "1"])
