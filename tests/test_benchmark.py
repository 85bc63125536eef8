"""Tests of ``vnhc-gym benchmark`` (vnhc_gym.benchmark): the console command's files, every registered
environment in them, and its numbers against independent evaluations."""

from __future__ import annotations

import csv
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from scipy import stats as sps

import vnhc_gym  # noqa: F401
from vnhc_gym import benchmark
from vnhc_gym.baselines import GeometricController
from vnhc_gym.evaluation import TEST_SEED, evaluate
from vnhc_gym.tasks import env_id, env_ids, shipped_tasks

# One xdist worker runs this module, so that its module-scoped fixture (the quick benchmark's run) is built once.
pytestmark = pytest.mark.xdist_group("test_benchmark")
TASKS = shipped_tasks()  # the package's own tasks (the tutorial's is registered by conftest)

QUICK_POLICIES = ["zero", "random", "law", "inloop"]


def _command() -> list[str]:
    exe = shutil.which("vnhc-gym")
    return [exe] if exe else [sys.executable, "-m", "vnhc_gym.cli"]


@pytest.fixture(scope="module")
def quick(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, subprocess.CompletedProcess]:
    """``vnhc-gym benchmark --quick``'s files and output.  CI runs that command itself just before the
    tests (the README's first command's smoke run) and names its folder in ``$VNHC_GYM_QUICK_BENCHMARK``,
    its output in ``<folder>.out`` and ``<folder>.err``: the tests read that run instead of repeating it."""
    given = os.environ.get("VNHC_GYM_QUICK_BENCHMARK")
    if given:
        out = Path(given)
        return out, subprocess.CompletedProcess(["vnhc-gym", "benchmark", "--quick"], 0,
                                                Path(f"{given}.out").read_text(), Path(f"{given}.err").read_text())
    out = tmp_path_factory.mktemp("bench") / "tmp"
    proc = subprocess.run([*_command(), "benchmark", "--quick", "--out", str(out)], capture_output=True, text=True,
                          timeout=600)
    return out, proc


def test_quick_benchmark_writes_its_files_for_every_env(quick: Any) -> None:
    out, proc = quick
    assert proc.returncode == 0, proc.stderr[-3000:]
    for name in ("benchmark.md", "benchmark.csv", "benchmark.json"):
        assert (out / name).is_file() and (out / name).stat().st_size > 0, name
    for entry in TASKS.values():
        assert (out / f"phi_{entry.env_name}.png").is_file(), entry.env_name
    with open(out / "benchmark.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert {r["env_id"] for r in rows} == set(env_ids("v1", shipped_only=True))
    shipped = env_ids("v1", shipped_only=True)
    expected = {(e, s, p) for e in shipped for s in ("nominal", "noisy") for p in QUICK_POLICIES}
    assert {(r["env_id"], r["scenario"], r["policy"]) for r in rows} == expected and len(rows) == len(expected)
    md = (out / "benchmark.md").read_text()
    assert all(f"**{e}**" in md for e in env_ids("v1", shipped_only=True))
    assert md in proc.stdout  # the printed tables are the written ones
    data = json.loads((out / "benchmark.json").read_text())
    assert data["settings"]["command"] == "vnhc-gym benchmark --quick"
    assert data["settings"]["episodes"] == 3 and data["settings"]["max_time"] == 2.0
    assert len(data["results"]) == len(rows)
    assert all(r["seed"] == TEST_SEED and r["n_episodes"] == 3 for r in data["results"])
    assert "Traceback" not in proc.stderr


def _by_hand(env_id_: str, scenario: str, episodes: int, max_time: float) -> dict[str, np.ndarray]:
    """The law's episodes rolled out here with Gymnasium's own loop, and their metrics by their
    definitions (docs/evaluation.md), without the package's evaluation code: the score is the sum of the
    rewards over the fixed horizon divided by its steps (a failed episode's missing steps add 0), the
    success whether the episode ran to the horizon, mean |phi| the mean of ``info["abs_phi"]`` after
    each step."""
    import gymnasium as gym

    out: dict[str, list[float]] = {"score": [], "success": [], "return": [], "mean_abs_phi": []}
    for i in range(episodes):
        env = gym.make(env_id_, scenario=scenario)
        obs, _ = env.reset(seed=TEST_SEED + i)
        law = GeometricController(env)
        n = round(max_time / env.unwrapped.dt)
        rewards, phis, failed = [], [], False
        for _ in range(n):
            obs, reward, terminated, truncated, info = env.step(law.predict(obs)[0])
            rewards.append(reward)
            phis.append(info["abs_phi"])
            if terminated:
                failed = True
                break
        out["score"].append(sum(rewards) / n)
        out["success"].append(float(not failed))
        out["return"].append(sum(rewards))
        out["mean_abs_phi"].append(float(np.mean(phis)))
    return {k: np.asarray(v) for k, v in out.items()}


@pytest.mark.parametrize("env", env_ids("v1", shipped_only=True), ids=lambda e: e.removeprefix("vnhc_gym/"))
def test_quick_benchmark_numbers_are_the_law_rolled_out_by_hand(quick: Any, env: str) -> None:
    out, proc = quick
    assert proc.returncode == 0, proc.stderr[-3000:]
    with open(out / "benchmark.csv") as fh:
        rows = {(r["env_id"], r["scenario"], r["policy"]): r for r in csv.DictReader(fh)}
    # CI's run of the command compiled at XLA's default optimisation level and the tests at level 0
    # (conftest.py): their arithmetic differs in the last bits, far below a wrong mean's error.
    for scenario in ("nominal", "noisy"):
        hand = _by_hand(env, scenario, episodes=3, max_time=2.0)
        row = rows[(env, scenario, "law")]
        for metric in ("score", "success"):  # plain means over the episodes
            assert float(row[metric]) == pytest.approx(float(np.mean(hand[metric])), rel=1e-7, abs=1e-12)
        for metric in ("return", "mean_abs_phi"):  # interquartile means (rliable's IQM: 25 % trimmed)
            assert float(row[metric]) == pytest.approx(sps.trim_mean(hand[metric], 0.25), rel=1e-7)
    # The in-loop reference does not see the observation noise; the law does.
    assert rows[(env, "noisy", "inloop")]["mean_abs_phi"] == rows[(env, "nominal", "inloop")]["mean_abs_phi"]
    assert rows[(env, "noisy", "law")]["mean_abs_phi"] != rows[(env, "nominal", "law")]["mean_abs_phi"]


def test_policies() -> None:
    assert [p.name for p in benchmark.policies(quick=True, agents=False)] == QUICK_POLICIES
    full = [p.name for p in benchmark.policies(quick=False, agents=False)]
    assert full == ["zero", "random", "law", "law-sampled", "tuned_law", "observer", "adaptive", "inloop", "oracle"]
    assert [p.feedback for p in benchmark.policies(quick=True, agents=False)] == [None, None, None, "continuous"]
    assert isinstance(benchmark.settings(), dict)


def test_run_benchmark_and_outputs_in_process(tmp_path: Path) -> None:
    specs = [p for p in benchmark.policies(quick=False, agents=False) if p.name in ("law-sampled", "observer")]
    tasks = list(TASKS)
    results = benchmark.run_benchmark(tasks, ["noisy"], specs, episodes=2, seed=TEST_SEED, max_time=1.0,
                                      log=lambda s: None)
    assert [(r.env_id, r.policy) for r in results] == [(env_id(t), p.name) for t in tasks for p in specs]
    files = benchmark.write_outputs(results, tmp_path / "out", {"command": "test"})
    assert all(Path(f).is_file() for f in files)
    assert len([f for f in files if str(f).endswith(".png")]) == 0  # figures are of the nominal scenario
    sampled = evaluate(lambda e: GeometricController(e, variant="sampled"), env_id(tasks[0]), "noisy", n_episodes=2,
                       seed=TEST_SEED, max_time=1.0)
    np.testing.assert_array_equal(results[0].metrics["mean_abs_phi"], sampled.metrics["mean_abs_phi"])


@pytest.mark.slow
def test_agents_of_a_zoo_run_on_their_own_task_only(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Shipped agents are ``<task>-<algo>`` files; an agent runs only in the cell it was trained in (its task
    and scenario), under the name ``<algo>@<scenario>``, without a warning."""
    pytest.importorskip("stable_baselines3")
    import warnings

    from vnhc_gym.training import TrainConfig, agents, train

    task = list(TASKS)[0]
    zoo = tmp_path / "zoo"
    train(TrainConfig(algo="ppo", env=task, n_timesteps=512, overrides={"n_envs": 8, "n_steps": 64,
                                                                          "batch_size": 128},
                      out=str(zoo), eval_points=1, eval_episodes=1, test_episodes=1, threads=1, name=f"{task}-ppo"))
    monkeypatch.setattr(agents, "ZOO_DIR", zoo)
    specs = [p for p in benchmark.policies(quick=True, agents=True) if p.name in ("law", "ppo@nominal")]
    assert [p.name for p in specs] == ["law", "ppo@nominal"]
    with warnings.catch_warnings():
        warnings.simplefilter("error", agents.UntrustedFileWarning)
        results = benchmark.run_benchmark(list(TASKS)[:2], ["nominal", "noisy"], specs, episodes=2, seed=TEST_SEED,
                                          max_time=1.0, log=lambda s: None)
    other = env_id(list(TASKS)[1])
    assert [(r.env_id, r.scenario, r.policy) for r in results] == [
        (env_id(task), "nominal", "law"), (env_id(task), "nominal", "ppo@nominal"), (env_id(task), "noisy", "law"),
        (other, "nominal", "law"), (other, "noisy", "law")]
