"""Tests of vnhc_gym.training: tiny training runs (PPO, residual PPO, PPO with a history of
observations, SAC and residual SAC), their files, the loaded agents as policies, and the shipped agents.

A run is checked against what it claims: re-evaluating the saved agent on the recorded test seeds
gives the recorded test numbers, the untrained residual agent's validation is the base law's own
evaluation on the validation seeds, and the sidecar's fingerprint is the package's.
"""

from __future__ import annotations

import json
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import pytest

pytest.importorskip("stable_baselines3")
pytest.importorskip("torch")

import gymnasium as gym  # noqa: E402

import vnhc_gym  # noqa: E402
from vnhc_gym.baselines import GeometricController  # noqa: E402
from vnhc_gym.evaluation import METRICS, TEST_SEED, VALIDATION_SEED, evaluate  # noqa: E402
from vnhc_gym.tasks import env_ids, shipped_tasks  # noqa: E402

TASKS = shipped_tasks()  # the package's own tasks (the tutorial's is registered by conftest)
from vnhc_gym.training import (  # noqa: E402
    ALGOS,
    AgentPolicy,
    TrainConfig,
    code_fingerprint,
    list_zoo,
    load_agent,
    resolve_env_id,
    train,
)
from vnhc_gym.training.agents import ZOO_DIR, UntrustedFileWarning  # noqa: E402

# One xdist worker runs this module, so that its module-scoped fixture (the tiny training runs) is built once.
pytestmark = pytest.mark.xdist_group("test_training")
ENVS = env_ids("v1", shipped_only=True)
TINY = {"n_envs": 8, "n_steps": 64, "batch_size": 128}
TINY_SAC = {"n_envs": 8, "learning_starts": 500, "batch_size": 64, "gradient_steps": 2, "buffer_size": 10_000}
#: variant -> (algo, overrides)
VARIANTS = {"ppo": ("ppo", TINY), "residual_ppo": ("residual_ppo", TINY),
            "history": ("ppo", {**TINY, "frame_stack": 4}), "sac": ("sac", TINY_SAC),
            "residual_sac": ("residual_sac", TINY_SAC)}
RESIDUAL = ("residual_ppo", "residual_sac")
#: PPO runs on every task (each task's environment through SB3); the other variants, whose code is the
#: same for every task, on the boat's (whose controllers run a model of their own).
VARIANT_ENVS = [e for e in ENVS if "USVStream" in e]


def _applies(env: str, variant: str) -> bool:
    return variant == "ppo" or env in VARIANT_ENVS


def _short(e: str) -> str:
    return e.removeprefix("vnhc_gym/")


def _task_name(env: str) -> str:
    return next(name for name, entry in TASKS.items() if f"vnhc_gym/{entry.env_name}-v1" == env)


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> dict[tuple[str, str], tuple[Path, dict[str, Any]]]:
    """One tiny run of each variant on each registered task (about 2 000 steps each)."""
    out = tmp_path_factory.mktemp("runs")
    done = {}
    for env in ENVS:
        for variant, (algo, overrides) in VARIANTS.items():
            if not _applies(env, variant):
                continue
            cfg = TrainConfig(algo=algo, env=_task_name(env), n_timesteps=2000, overrides=dict(overrides),
                              out=str(out), eval_points=2, eval_episodes=3, test_episodes=3, threads=1,
                              name=f"{_task_name(env)}-{variant}")
            lines: list[str] = []
            meta = train(cfg, log=lines.append)
            assert lines and all(cfg.name in line for line in lines)
            done[(env, variant)] = (out / f"{cfg.name}.zip", meta)
    return done


CASES = [(e, v) for e in ENVS for v in VARIANTS if _applies(e, v)]


def _case_id(case: tuple[str, str]) -> str:
    return f"{_short(case[0])}-{case[1]}"


@pytest.mark.slow
@pytest.mark.parametrize("case", CASES, ids=_case_id)
def test_a_run_writes_the_model_and_its_sidecar(runs: dict, case: tuple[str, str]) -> None:
    path, meta = runs[case]
    env, variant = case
    assert path.is_file() and path.stat().st_size > 0
    side = json.loads(path.with_suffix(".json").read_text())
    assert side == json.loads(json.dumps(meta))  # the returned sidecar is the written one
    assert side["env_id"] == env and side["scenario"] == "nominal" and side["algo"] == VARIANTS[variant][0]
    assert side["n_envs"] == 8 and side["n_timesteps"] == 2000 and side["seed"] == 0
    assert side["code"] == code_fingerprint() and side["version"] == vnhc_gym.__version__
    assert side["frame_stack"] == (4 if variant == "history" else 1)
    assert (side["residual"] is not None) == (variant in RESIDUAL)
    # The learning curve: validation at step 0, then along the run, to its end.
    curve = side["curve"]
    steps = [p["steps"] for p in curve]
    assert steps[0] == 0 and steps == sorted(steps) and steps[-1] >= 2000
    assert all(np.isfinite(p["mean_abs_phi_sf"]) and 0 <= p["score"] <= 1 and p["wall"] >= 0 for p in curve)
    assert side["best_steps"] in steps
    # The kept checkpoint is the first with the highest validation score; the final model is kept too.
    best = max(p["score"] for p in curve)
    assert side["best_steps"] == next(p["steps"] for p in curve if p["score"] == best)
    assert path.with_name(path.stem + "-final.zip").is_file()
    # The test summary: held-out seeds, every metric, IQM with its interval.
    test = side["test"]
    assert test["seed"] == TEST_SEED and test["n_episodes"] == 3
    assert set(test["metrics"]) == set(METRICS) and all(len(v) == 3 for v in test["metrics"].values())
    for name in METRICS:
        low, point, high = test["summary"][name][1], test["summary"][name][0], test["summary"][name][2]
        assert low <= point <= high
    assert side["steps_per_second"] > 0


@pytest.mark.slow
@pytest.mark.parametrize("case", CASES, ids=_case_id)
def test_the_loaded_agent_reproduces_the_recorded_test(runs: dict, case: tuple[str, str]) -> None:
    path, meta = runs[case]
    with pytest.warns(UntrustedFileWarning, match="pickle"):
        agent = load_agent(path)
    assert isinstance(agent, AgentPolicy) and agent.frame_stack == meta["frame_stack"]
    res = evaluate(agent, meta["env_id"], meta["scenario"], n_episodes=meta["test"]["n_episodes"],
                   seed=meta["test"]["seed"])
    for name in METRICS:
        np.testing.assert_allclose(res.metrics[name], meta["test"]["metrics"][name], rtol=1e-9, atol=1e-12,
                                   err_msg=name)
    # Actions are in range, for one observation or a batch.
    env = gym.make(meta["env_id"])
    obs = np.stack([env.reset(seed=TEST_SEED + i)[0] for i in range(3)])
    a, _ = agent.predict(obs, episode_start=np.ones(3, dtype=bool))
    assert a.dtype == np.float32 and a.shape == (3, env.action_space.shape[0]) and np.all(np.abs(a) <= 1)
    env.close()


@pytest.mark.slow
@pytest.mark.parametrize("env", VARIANT_ENVS, ids=_short)
def test_the_history_variant_sees_four_observations(runs: dict, env: str) -> None:
    path, meta = runs[(env, "history")]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UntrustedFileWarning)
        agent = load_agent(path)
    d = gym.make(env).observation_space.shape[0]
    assert agent.model.observation_space.shape == (4 * d,)
    # The agent stacks raw observations exactly as SB3's VecFrameStack did in training (oldest first,
    # zeros before an episode's first observation).
    from gymnasium.vector import AutoresetMode
    from stable_baselines3.common.vec_env import VecFrameStack

    from vnhc_gym.sb3 import GymnasiumVecEnvAdapter

    venv = gym.make_vec(env, num_envs=2, vectorization_mode="vector_entry_point",
                        autoreset_mode=AutoresetMode.SAME_STEP)
    stacked_env = VecFrameStack(GymnasiumVecEnvAdapter(venv), 4)
    stacked_env.seed(TEST_SEED)
    stacked = stacked_env.reset()
    np.testing.assert_array_equal(stacked[:, : 3 * d], 0.0)
    np.testing.assert_array_equal(agent.network._stack(stacked[:, -d:], np.ones(2, dtype=bool)), stacked)
    rng = np.random.default_rng(0)
    for _ in range(6):
        stacked, *_ = stacked_env.step(rng.uniform(-1, 1, (2, venv.single_action_space.shape[0])).astype(np.float32))
        np.testing.assert_array_equal(agent.network._stack(stacked[:, -d:], np.zeros(2, dtype=bool)), stacked)
    stacked_env.close()


@pytest.mark.slow
@pytest.mark.parametrize(("env", "variant"), [c for c in CASES if c[1] in RESIDUAL],
                         ids=[_case_id(c) for c in CASES if c[1] in RESIDUAL])
def test_the_untrained_residual_agent_is_the_base_law(runs: dict, env: str, variant: str) -> None:
    """The first validation (step 0, zero-initialised mean head) is exactly the law's evaluation."""
    _, meta = runs[(env, variant)]
    first = meta["curve"][0]
    assert first["steps"] == 0
    law = evaluate(lambda e: GeometricController(e, gain=meta["residual"]["gain"]), env, "nominal", n_episodes=3,
                   seed=VALIDATION_SEED)
    summary = law.summary(reps=200)
    for name in ("mean_abs_phi", "mean_abs_phi_sf", "return", "terminated"):
        assert first[name] == summary[name].point, name


def test_an_untrained_residual_agent_acts_like_its_base() -> None:
    """Directly: a PPO model with the last layer zeroed, as train() builds it, through AgentPolicy."""
    import torch
    from stable_baselines3 import PPO

    from vnhc_gym.sb3 import GymnasiumVecEnvAdapter
    from vnhc_gym.wrappers import ResidualVectorAction

    env = ENVS[-1]
    venv = ResidualVectorAction(gym.make_vec(env, num_envs=2, vectorization_mode="vector_entry_point"),
                                observe_base=True, scale=0.2)
    model = PPO("MlpPolicy", GymnasiumVecEnvAdapter(venv), seed=0, device="cpu", n_steps=16, batch_size=32)
    with torch.no_grad():
        model.policy.action_net.weight.zero_()
        model.policy.action_net.bias.zero_()
    agent = AgentPolicy(model, {"algo": "residual_ppo", "residual": {"scale": 0.2, "observe_base": True, "gain": 5.0}})
    with pytest.raises(RuntimeError, match="bind"):
        agent.predict(np.zeros(gym.make(env).observation_space.shape, dtype=np.float32))
    agent.bind(gym.make(env))
    a = evaluate(agent, env, "noisy", n_episodes=3, seed=TEST_SEED, max_time=2.0)
    b = evaluate(GeometricController, env, "noisy", n_episodes=3, seed=TEST_SEED, max_time=2.0)
    np.testing.assert_array_equal(a.abs_phi, b.abs_phi)
    venv.close()


def test_an_untrained_residual_sac_agent_acts_like_its_base_and_explores_little() -> None:
    """SBX's SAC actor as train() starts it: the deterministic action is the base's, and the
    exploration noise has the file's initial log-std whatever the observation."""
    pytest.importorskip("sbx")
    import jax

    from vnhc_gym.sb3 import GymnasiumVecEnvAdapter
    from vnhc_gym.training.agents import algorithm_class
    from vnhc_gym.training.run import _start_at_base
    from vnhc_gym.wrappers import ResidualVectorAction

    env = ENVS[1]
    venv = ResidualVectorAction(gym.make_vec(env, num_envs=2, vectorization_mode="vector_entry_point"),
                                observe_base=True, scale=0.1)
    model = algorithm_class("residual_sac")("MlpPolicy", GymnasiumVecEnvAdapter(venv), seed=0,
                                            policy_kwargs={"net_arch": [64, 64]})
    _start_at_base(model, log_std=-3.0)
    agent = AgentPolicy(model, {"algo": "residual_sac", "residual": {"scale": 0.1, "observe_base": True,
                                                                      "gain": 5.0}}).bind(gym.make(env))
    a = evaluate(agent, env, "noisy", n_episodes=3, seed=TEST_SEED, max_time=2.0)
    b = evaluate(GeometricController, env, "noisy", n_episodes=3, seed=TEST_SEED, max_time=2.0)
    np.testing.assert_array_equal(a.abs_phi, b.abs_phi)
    obs = np.random.default_rng(0).normal(size=(16, *venv.single_observation_space.shape)).astype(np.float32)
    dist = model.policy.actor.apply(model.policy.actor_state.params, obs)
    std = np.asarray(dist.distribution.stddev())
    np.testing.assert_allclose(std, np.exp(-3.0), rtol=1e-6)
    assert jax.numpy.allclose(dist.distribution.mean(), 0.0)
    venv.close()


def test_validations_follow_eval_points_when_a_rollout_outgrows_the_budget(tmp_path: Path) -> None:
    """A budget smaller than one rollout (512 steps here) still validates about eval_points times."""
    meta = train(TrainConfig(algo="ppo", env=_task_name(ENVS[0]), n_timesteps=100, overrides=TINY,
                             out=str(tmp_path), eval_points=2, eval_episodes=1, test_episodes=1, threads=1))
    assert len(meta["curve"]) <= 2 + 2  # step 0, eval_points, and the end


def test_configuration_errors(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="algo"):
        train(TrainConfig(algo="td3", out=str(tmp_path)))
    with pytest.raises(ValueError, match="unknown environment"):
        train(TrainConfig(env="no_such_task", out=str(tmp_path)))
    for bad in (0, -1, 1.5, True, "2"):
        with pytest.raises(ValueError, match="threads must be a positive integer"):
            train(TrainConfig(threads=bad, out=str(tmp_path)))  # type: ignore[arg-type]
    assert set(ALGOS) >= {"ppo", "residual_ppo"}
    for name, entry in TASKS.items():
        full = f"vnhc_gym/{entry.env_name}-v1"
        assert resolve_env_id(name) == full
        assert resolve_env_id(entry.env_name) == full
        assert resolve_env_id(full) == full
        assert resolve_env_id(f"vnhc_gym/{entry.env_name}-v0") == f"vnhc_gym/{entry.env_name}-v0"
    with pytest.raises(ValueError, match="unknown environment"):
        resolve_env_id("no_such_task")


def test_code_fingerprint_is_stable() -> None:
    a, b = code_fingerprint(), code_fingerprint()
    assert a == b and len(a) == 16 and int(a, 16) >= 0


def test_load_agent_errors(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError):
        load_agent("no-such-agent")
    with pytest.raises(FileNotFoundError):
        load_agent(tmp_path / "missing.zip")
    (tmp_path / "lonely.zip").write_bytes(b"PK")
    with pytest.raises(FileNotFoundError, match="sidecar"), warnings.catch_warnings():
        warnings.simplefilter("ignore", UntrustedFileWarning)
        load_agent(tmp_path / "lonely.zip")


SHIPPED = list_zoo()


@pytest.mark.skipif(not SHIPPED, reason="no agents shipped in vnhc_gym/agents_zoo")
@pytest.mark.parametrize("name", SHIPPED)
def test_shipped_agents_load_without_warning_and_reproduce_their_record(name: str) -> None:
    side = json.loads((ZOO_DIR / f"{name}.json").read_text())
    with warnings.catch_warnings():
        warnings.simplefilter("error", UntrustedFileWarning)  # the package's own files: no warning
        agent = load_agent(name)
    rec = side.get("test") or side["zoo_eval"]
    res = evaluate(agent, side["env_id"], side.get("scenario", "nominal"), n_episodes=rec["n_episodes"],
                   seed=rec["seed"])
    recorded = rec["metrics"]["mean_abs_phi"] if "metrics" in rec else rec["episodes"]
    np.testing.assert_allclose(res.metrics["mean_abs_phi"], recorded, rtol=1e-3)


def test_value_warmup_freezes_the_actor_and_only_the_actor() -> None:
    """During the warm-up PPO's updates change the critic and leave the actor (layers and log std)
    exactly as initialised; after it, the actor learns."""
    import torch
    from stable_baselines3 import PPO

    from vnhc_gym.training.callbacks import ValueWarmup

    venv = vnhc_gym.make_sb3_vec_env("vnhc_gym/USVStream-v1", n_envs=4, seed=0)
    model = PPO("MlpPolicy", venv, n_steps=32, batch_size=64, n_epochs=2, seed=0, device="cpu")
    policy: Any = model.policy

    def snapshot() -> tuple[list[torch.Tensor], list[torch.Tensor]]:
        actor = [p.detach().clone() for p in (*policy.mlp_extractor.policy_net.parameters(),
                                              *policy.action_net.parameters(), policy.log_std)]
        critic = [p.detach().clone() for p in (*policy.mlp_extractor.value_net.parameters(),
                                               *policy.value_net.parameters())]
        return actor, critic

    actor0, critic0 = snapshot()
    warm = ValueWarmup(steps=4 * 32 * 3)
    model.learn(4 * 32 * 2, callback=warm)  # two rollouts and their updates, inside the warm-up
    actor1, critic1 = snapshot()
    assert all(torch.equal(a, b) for a, b in zip(actor0, actor1, strict=True))
    assert not all(torch.equal(a, b) for a, b in zip(critic0, critic1, strict=True))
    assert all(p.requires_grad for p in policy.parameters())  # given back at the end of learn()
    model.learn(4 * 32 * 2, callback=ValueWarmup(steps=0), reset_num_timesteps=False)
    actor2, _ = snapshot()
    assert not all(torch.equal(a, b) for a, b in zip(actor1, actor2, strict=True))
    with pytest.raises(ValueError, match="steps"):
        ValueWarmup(steps=-1)
    venv.close()


def test_a_file_callback_is_applied_and_only_the_packages_own(tmp_path: Path) -> None:
    warm = [("vnhc_gym.training.callbacks.ValueWarmup", {"steps": 10**9})]
    meta = train(TrainConfig(algo="residual_ppo", env="usv", n_timesteps=1024, out=str(tmp_path), eval_points=1,
                             eval_episodes=2, test_episodes=0, overrides={**TINY, "callback": warm}))
    # The whole run is warm-up: the policy never moves, so every validation is the base's.
    assert len({p["score"] for p in meta["curve"]}) == 1 and meta["test"] is None
    assert meta["callbacks"] == [["vnhc_gym.training.callbacks.ValueWarmup", {"steps": 10**9}]]  # recorded
    with pytest.raises(ValueError, match="not supported"):
        train(TrainConfig(env="usv", n_timesteps=1024, out=str(tmp_path),
                          overrides={**TINY, "callback": [("os.system", {})]}))


@pytest.mark.slow
def test_a_short_residual_run_on_a_stateful_base_keeps_its_final_model_near_the_base(tmp_path: Path) -> None:
    """Residual PPO with its shipped settings on the observer law (the boat under noise): after a
    short run (five updates) the final model's validation score is within 10 % of the base's."""
    meta = train(TrainConfig(algo="residual_ppo", env="usv", scenario="noisy", n_timesteps=5 * 256 * 64,
                             out=str(tmp_path), eval_points=1, eval_episodes=5, test_episodes=0,
                             residual_base="observer", residual_base_settings={"gain": 10.0, "alpha": 0.03}))
    base, final = meta["curve"][0], meta["curve"][-1]
    assert base["steps"] == 0 and final["steps"] == 5 * 256 * 64
    assert abs(final["score"] - base["score"]) <= 0.1 * base["score"]
    assert (tmp_path / f"{meta['name']}-final.zip").is_file()


def test_a_files_env_kwargs_shape_the_training_envs_only_and_the_callers_win(tmp_path: Path,
                                                                             monkeypatch: pytest.MonkeyPatch) -> None:
    """As RL Zoo: a section's ``env_kwargs`` reach the training environments (not the validation ones),
    and ``TrainConfig.env_kwargs`` (``--env-kwargs``) override them."""
    made: list[Any] = []
    real = gym.make_vec

    def spy(*args: Any, **kwargs: Any) -> Any:
        made.append(kwargs.get("reward"))
        return real(*args, **kwargs)

    monkeypatch.setattr(gym, "make_vec", spy)
    common = dict(algo="ppo", env="usv", n_timesteps=512, out=str(tmp_path), eval_points=1, eval_episodes=2,
                  test_episodes=0)
    meta = train(TrainConfig(**common, overrides={**TINY, "env_kwargs": {"reward": "raw"}}))  # type: ignore[arg-type]
    assert made[0] == "raw" and set(made[1:]) == {None}  # validations run the environment's own reward
    assert meta["config"]["env_kwargs"] == {"reward": "raw"} and "env_kwargs" not in meta["hyperparams"]
    made.clear()
    meta = train(TrainConfig(**common, overrides={**TINY, "env_kwargs": {"reward": "raw"}},  # type: ignore[arg-type]
                             env_kwargs={"reward": "reciprocal"}))
    assert made[0] == "reciprocal" and meta["config"]["env_kwargs"] == {"reward": "reciprocal"}
    with pytest.raises(ValueError, match="env_kwargs must be a mapping"):
        train(TrainConfig(**common, overrides={**TINY, "env_kwargs": "reward=raw"}))  # type: ignore[arg-type]
