"""Tests of ``vnhc-gym benchmark`` (vnhc_gym.benchmark)."""

from __future__ import annotations

import csv
import json
import shutil
import subprocess
import sys

import pytest

import vnhc_gym  # noqa: F401
from vnhc_gym import benchmark
from vnhc_gym.cli import main

OUTPUTS = ("benchmark.csv", "benchmark_episodes.csv", "benchmark.md", "benchmark.json", "phi_flocking.png",
           "phi_usv.png")


def _check_outputs(out, envs=("flocking", "usv"), n_scenarios=6, n_policies=5) -> None:
    for name in OUTPUTS:
        if name.startswith("phi_") and name[4:-4] not in envs:
            continue
        assert (out / name).is_file() and (out / name).stat().st_size > 0, name
    rows = list(csv.DictReader(open(out / "benchmark.csv")))
    assert len(rows) == len(envs) * n_scenarios * n_policies
    assert {"env", "scenario", "policy", "mean_abs_phi_iqm", "mean_abs_phi_ci_low", "return_iqm"} <= set(rows[0])
    data = json.loads((out / "benchmark.json").read_text())
    assert len(data["results"]) == len(rows)
    assert "median_phi_series" in data["results"][0]
    md = (out / "benchmark.md").read_text()
    assert "| env | scenario | policy |" in md and "geometric-sampled" in md


def test_cli_benchmark_quick_in_process(tmp_path, capsys) -> None:
    out = tmp_path / "tmp"
    assert main(["benchmark", "--quick", "--out", str(out), "--no-progress", "--no-zoo"]) == 0
    _check_outputs(out)
    printed = capsys.readouterr().out
    assert "mean_abs_phi IQM [95% CI]" in printed and "| usv | coarse | geometric |" in printed


@pytest.mark.skipif(shutil.which("vnhc-gym") is None, reason="console script not installed")
def test_cli_benchmark_console_command(tmp_path) -> None:
    out = tmp_path / "tmp"
    proc = subprocess.run(["vnhc-gym", "benchmark", "--quick", "--out", str(out), "--no-progress",
                           "--envs", "usv", "--scenarios", "nominal", "coarse", "--no-zoo"],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    _check_outputs(out, envs=("usv",), n_scenarios=2)
    assert "| usv | nominal | zero |" in proc.stdout


def test_benchmark_agents_folder(tmp_path) -> None:
    pytest.importorskip("stable_baselines3")
    import gymnasium as gym
    from stable_baselines3 import A2C, PPO

    from vnhc_gym.wrappers import ResidualAction

    agents = tmp_path / "agents"
    agents.mkdir()
    env = gym.make("vnhc_gym/USVStream-v0", disable_env_checker=True)
    PPO("MlpPolicy", env, n_steps=32, batch_size=16, seed=0, device="cpu").save(agents / "usv-ppo.zip")
    PPO("MlpPolicy", ResidualAction(env), n_steps=32, batch_size=16, seed=0, device="cpu").save(
        agents / "usv-residual_ppo.zip")
    A2C("MlpPolicy", env, seed=0, device="cpu").save(agents / "usv-a2c.zip")  # plain SB3 loading path
    (agents / "usv-residual_ppo.json").write_text(json.dumps({"algo": "PPO", "residual": {"scale": 0.1}}))
    (agents / "notes.zip").write_bytes(b"not an agent")
    out = tmp_path / "out"
    with pytest.warns(UserWarning, match="pickle"):
        code = main(["benchmark", "--quick", "--out", str(out), "--no-progress", "--envs", "usv", "--scenarios",
                     "nominal", "saturated", "--policies", "zero", "--agents", str(agents), "--no-figures",
                     "--no-zoo"])
    assert code == 0
    rows = list(csv.DictReader(open(out / "benchmark.csv")))
    assert sorted({r["policy"] for r in rows}) == ["a2c", "ppo", "residual_ppo", "zero"]
    assert len(rows) == 2 * 4


def test_no_agents_and_missing_sb3_are_skipped(tmp_path, monkeypatch) -> None:
    assert benchmark.find_agents([tmp_path / "missing"], log=lambda m: None) == []
    (tmp_path / "flocking-ppo.zip").write_bytes(b"x")
    monkeypatch.setitem(sys.modules, "stable_baselines3", None)  # import fails
    messages = []
    assert benchmark.find_agents([tmp_path], log=messages.append) == []
    assert any("not installed" in m for m in messages)


def test_bad_arguments() -> None:
    with pytest.raises(SystemExit):
        main(["benchmark", "--scenarios", "stormy"])
    assert main(["benchmark", "--episodes", "0", "--no-progress"]) == 2
