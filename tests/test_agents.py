"""Training entry point, agent loading and the shipped agents (issue 6).

The smoke tests train each algorithm for a few hundred steps through the console command
``vnhc-gym train`` in a subprocess (as CleanRL tests its scripts), then evaluate the saved
agent with the package's evaluation protocol.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest
import yaml

pytest.importorskip("stable_baselines3")
pytest.importorskip("torch")

import gymnasium as gym  # noqa: E402

import vnhc_gym  # noqa: E402
from vnhc_gym import train as vt  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
HYPER = ROOT / "agents" / "hyperparams"
TINY = ["n_envs=2", "n_steps=64", "batch_size=64", "n_epochs=1", "policy_kwargs.net_arch=[16,16]"]
TINY_SAC = ["n_envs=1", "learning_starts=64", "batch_size=32", "buffer_size=1000", "policy_kwargs.net_arch=[16,16]"]


def _train_cmd() -> list[str]:
    exe = shutil.which("vnhc-gym")
    if exe is not None:
        return [exe, "train"]
    return [sys.executable, "-m", "vnhc_gym.train"]  # pragma: no cover - package not installed as a script


def _env() -> dict[str, str]:
    env = dict(os.environ)
    env.update(OMP_NUM_THREADS="1", MKL_NUM_THREADS="1", NUMBA_NUM_THREADS="1")
    return env


# --------------------------------------------------------------------------- hyperparameter files
def test_yaml_configs_parse_and_cover_both_envs() -> None:
    ids = set()
    for short, env_id in vt.ENV_ALIASES.items():
        path = HYPER / f"{short}.yml"
        with open(path, encoding="utf-8") as f:
            doc = yaml.safe_load(f)  # plain YAML, no Python tags
        assert set(vt.ALGOS) <= set(doc), path
        for algo in vt.ALGOS:
            entry = doc[algo][env_id]  # RL Zoo layout: algorithm section -> env id -> settings
            ids.add(env_id)
            for key in ("n_envs", "n_timesteps", "policy", "normalize"):
                assert key in entry, (path, algo, key)
            assert vt.load_hyperparams(short, algo) == entry
        assert doc["residual_ppo"][env_id]["policy_kwargs"]["log_std_init"] < -1
    assert ids == set(vnhc_gym.ENV_IDS)


def test_hyperparameter_overrides() -> None:
    over = vt.parse_overrides(["n_steps=64", "policy_kwargs.net_arch=[8, 8]", "learning_rate=lin_1e-3"])
    assert over == {"n_steps": 64, "policy_kwargs": {"net_arch": [8, 8]}, "learning_rate": "lin_1e-3"}
    sched = vt._schedule("lin_1e-3")
    assert sched(1.0) == pytest.approx(1e-3) and sched(0.5) == pytest.approx(5e-4)
    with pytest.raises(ValueError, match="KEY=VALUE"):
        vt.parse_overrides(["oops"])
    with pytest.raises(ValueError, match="unknown env"):
        vt.resolve_env_id("cartpole")


# --------------------------------------------------------------------------- CLI smoke tests
@pytest.mark.parametrize(("algo", "env", "extra"), [
    ("ppo", "flocking", TINY),
    ("residual_ppo", "usv", TINY),
    ("sac", "usv", TINY_SAC),
])
def test_train_cli_smoke(tmp_path: Path, algo: str, env: str, extra: list[str]) -> None:
    out = tmp_path / "run"
    steps = 256
    cmd = [*_train_cmd(), "--algo", algo, "--env", env, "--seed", "3", "-n", str(steps), "-f", str(out),
           "--eval-freq", "128", "--eval-episodes", "2", "--test-episodes", "2", "--no-progress-bar",
           "--hyperparams", *extra]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=300, env=_env())
    assert proc.returncode == 0, proc.stdout + proc.stderr
    stem = f"{env}-{algo}"
    side = json.loads((out / f"{stem}.json").read_text())
    assert (out / f"{stem}.zip").exists()
    assert side["env_id"] == vt.ENV_ALIASES[env] and side["method"] == algo and side["seed"] == 3
    assert side["steps"] >= steps and side["wall_time_s"] > 0
    assert side["validation"]["curve"][0]["step"] == 0 and len(side["validation"]["curve"]) >= 2
    assert np.isfinite(side["final_eval"]["iqm"])
    assert list((out / "tb").iterdir()), "TensorBoard logs"
    if algo == "residual_ppo":
        assert side["residual"]["scale"] == pytest.approx(0.2)

    # Evaluate the saved agent with the package's protocol: same episodes -> same numbers.
    from vnhc_gym.evaluation import evaluate

    with pytest.warns(vt.UntrustedFileWarning):
        agent = vt.load_agent(out / f"{stem}.zip")
    res = evaluate(agent, vt.ENV_ALIASES[env], "nominal", n_episodes=2, seed=vt.TEST_SEED)
    np.testing.assert_allclose(res.mean_abs_phi, side["final_eval"]["episodes"], rtol=1e-4)


# --------------------------------------------------------------------------- loading and the policy wrapper
@pytest.fixture(scope="module")
def tiny_agents(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """A tiny PPO and residual PPO trained in-process (no evaluation)."""
    out = tmp_path_factory.mktemp("agents")
    paths = {}
    for algo, env in (("ppo", "flocking"), ("residual_ppo", "usv")):
        hp = vt.parse_overrides(TINY)
        vt.train(env, algo, "nominal", 0, n_timesteps=128, hyperparams=hp, output=out / algo, eval_freq=0,
                 test_episodes=0, tensorboard=False, progress_bar=False)
        paths[algo] = out / algo / f"{env}-{algo}.zip"
    return paths


def test_loading_a_user_file_warns(tiny_agents: dict[str, Path]) -> None:
    with pytest.warns(vt.UntrustedFileWarning, match="pickle"):
        vt.load_agent(tiny_agents["ppo"])
    with pytest.raises(FileNotFoundError):
        vt.load_agent("no-such-agent")


def test_predict_on_raw_observations(tiny_agents: dict[str, Path]) -> None:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", vt.UntrustedFileWarning)
        agent = vt.load_agent(tiny_agents["ppo"])
    env = gym.make(agent.env_id)
    obs = np.stack([env.reset(seed=i)[0] for i in range(5)])
    a, state = agent.predict(obs, deterministic=True)
    assert state is None and a.shape == (5, 3) and a.dtype == np.float32
    assert np.all(np.abs(a) <= 1)
    assert agent._mlp is not None  # the numpy fast path is used ...
    mlp, agent._mlp = agent._mlp, None
    ref, _ = agent.predict(obs)  # ... and agrees with SB3's predict
    agent._mlp = mlp
    np.testing.assert_allclose(a, ref, atol=1e-5)
    single, _ = agent.predict(obs[0])
    np.testing.assert_allclose(single, a[0], atol=1e-6)


def test_residual_agent_matches_the_wrapper(tiny_agents: dict[str, Path]) -> None:
    """AgentPolicy(residual) on the bare env == the raw model inside ResidualAction."""
    from vnhc_gym.baselines import GeometricController
    from vnhc_gym.wrappers import ResidualAction

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", vt.UntrustedFileWarning)
        agent = vt.load_agent(tiny_agents["residual_ppo"])
    assert agent.residual is not None
    wrapped = ResidualAction(gym.make(agent.env_id), base=GeometricController(gym.make(agent.env_id)),
                             scale=agent.residual["scale"])
    bare = gym.make(agent.env_id)
    o1, _ = wrapped.reset(seed=7)
    o2, _ = bare.reset(seed=7)
    for _ in range(40):
        a_res, _ = agent.model.predict(o1, deterministic=True)
        o1, *_ = wrapped.step(a_res)
        o2, *_ = bare.step(agent.predict(o2)[0])
    np.testing.assert_allclose(o1, o2, atol=1e-5)


def test_residual_vec_env_matches_the_wrapper() -> None:
    """Training's batched residual (native vector env) steps like ResidualAction on DummyVecEnv."""
    if vt._sb3_adapter() is None:
        pytest.skip("vnhc_gym.sb3 not available")
    res = vt.residual_config({"residual": {"scale": 0.2}})
    fast = vt.make_train_env("vnhc_gym/USVStream-v0", "nominal", 3, 11, res, use_vector=True)
    slow = vt.make_train_env("vnhc_gym/USVStream-v0", "nominal", 3, 11, res, use_vector=False)
    o1, o2 = fast.reset(), slow.reset()
    np.testing.assert_allclose(o1, o2, atol=1e-6)
    rng = np.random.default_rng(0)
    for _ in range(30):
        a = rng.uniform(-1, 1, size=(3, 1)).astype(np.float32)
        o1, r1, *_ = fast.step(a)
        o2, r2, *_ = slow.step(a)
        np.testing.assert_allclose(o1, o2, atol=1e-5)
        np.testing.assert_allclose(r1, r2, rtol=1e-5)
    fast.close()
    slow.close()


# --------------------------------------------------------------------------- shipped agents
SHIPPED = vt.list_zoo()


def test_zoo_names() -> None:
    for name in SHIPPED:
        env, algo = name.split("-", 1)
        assert env in vt.ENV_ALIASES and algo in vt.ALGOS
        assert (vt.ZOO_DIR / f"{name}.zip").stat().st_size <= 250_000


@pytest.mark.skipif(not SHIPPED, reason="no agents shipped in vnhc_gym/agents_zoo yet")
@pytest.mark.parametrize("name", SHIPPED)
def test_shipped_agent_reproduces_its_recorded_evaluation(name: str) -> None:
    from vnhc_gym.evaluation import evaluate

    side = json.loads((vt.ZOO_DIR / f"{name}.json").read_text())
    rec = side["zoo_eval"]
    with warnings.catch_warnings():
        warnings.simplefilter("error", vt.UntrustedFileWarning)  # the package's own files: no warning
        agent = vt.load_agent(name)
    res = evaluate(agent, side["env_id"], rec["scenario"], n_episodes=rec["n_episodes"], seed=rec["seed"])
    np.testing.assert_allclose(res.mean_abs_phi, rec["episodes"], rtol=1e-3)
    # Shipped models act on raw observations (what `vnhc-gym benchmark` feeds them).
    assert side.get("obs_normalization") is None
    assert side["algo"] in ("PPO", "SAC")
