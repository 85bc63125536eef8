"""Tests of the ``vnhc-gym`` command: version, help, argument errors, and short runs of ``train`` and
``sweep`` in a subprocess (the console script, as a user runs it)."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

import vnhc_gym
from vnhc_gym.cli import SUBCOMMANDS, main
from vnhc_gym.evaluation import TEST_SEED


def _command() -> list[str]:
    exe = shutil.which("vnhc-gym")
    return [exe] if exe else [sys.executable, "-m", "vnhc_gym.cli"]


def _run(*args: str, timeout: int = 600) -> subprocess.CompletedProcess:
    return subprocess.run([*_command(), *args], capture_output=True, text=True, timeout=timeout)


def test_version() -> None:
    proc = _run("--version")
    assert proc.returncode == 0 and proc.stdout.strip() == f"vnhc-gym {vnhc_gym.__version__}"


def test_top_level_help_lists_every_subcommand(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exc:
        main(["--help"])
    assert exc.value.code == 0
    out = capsys.readouterr().out
    assert set(SUBCOMMANDS) == {"benchmark", "train", "tune", "sweep", "reproduce"}
    assert all(name in out for name in SUBCOMMANDS)


@pytest.mark.parametrize("sub", sorted(SUBCOMMANDS))
def test_subcommand_help(sub: str, capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exc:
        main([sub, "--help"])
    assert exc.value.code == 0
    out = capsys.readouterr().out
    assert out.startswith(f"usage: vnhc-gym {sub}") and SUBCOMMANDS[sub][1] in out
    assert "--out" in out or sub == "reproduce"


@pytest.mark.parametrize("args", [
    [],
    ["fly"],
    ["train", "--algo", "td3"],
    ["train", "--seed", "abc"],
    ["train", "--scenario", "stormy"],
    ["benchmark", "--scenarios", "stormy"],
    ["benchmark", "--tasks", "no_such_task"],
    ["sweep", "--executor", "slurm"],
], ids=lambda a: " ".join(a) or "nothing")
def test_argument_errors_are_usage_errors(args: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exc:
        main(args)
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "usage: vnhc-gym" in err and "error:" in err


@pytest.mark.parametrize("args", [
    ["train", "--env", "no_such_task", "-n", "10"],
    ["train", "-n", "10", "-params", "n_steps"],
    ["train", "-n", "10", "--env-kwargs", "reward=reciprocal"],
    ["sweep", "--algos", "td3", "--out", "{tmp}"],
    ["benchmark", "--episodes", "0", "--no-agents", "--out", "{tmp}"],
    ["sweep", "--config", "{tmp}/bad.yml", "--out", "{tmp}"],
], ids=["unknown-env", "bad-params", "bad-env-kwargs", "unknown-sweep-algo", "zero-episodes", "unknown-config-key"])
def test_bad_values_give_a_usage_error_not_a_traceback(args: list[str], tmp_path: Path,
                                                       capsys: pytest.CaptureFixture[str]) -> None:
    (tmp_path / "bad.yml").write_text("envs: [usv]\nepisodes: 3\n")
    with pytest.raises(SystemExit) as exc:
        main([a.replace("{tmp}", str(tmp_path)) for a in args])
    assert exc.value.code == 2
    assert "error:" in capsys.readouterr().err


@pytest.mark.slow
def test_train_default_path_in_a_subprocess(tmp_path: Path) -> None:
    """``vnhc-gym train --backend sb3`` with its defaults (PPO on the USV, nominal, seed 0) and a short budget."""
    pytest.importorskip("stable_baselines3")
    out = tmp_path / "runs"
    proc = _run("train", "--backend", "sb3", "-n", "2048", "--out", str(out), "--eval-points", "2",
                "--test-episodes", "3", "-params", "n_envs:8", "n_steps:64", "batch_size:128",
                "--env-kwargs", "reward:reciprocal")
    assert proc.returncode == 0, proc.stderr[-3000:]
    summary = json.loads(proc.stdout[proc.stdout.index("{"):])
    stem = "usv-nominal-ppo-s0"
    assert summary["model"] == f"{out}/{stem}.zip" and summary["steps"] == 2048
    assert (out / f"{stem}.zip").is_file()
    side = json.loads((out / f"{stem}.json").read_text())
    assert side["env_id"] == "vnhc_gym/USVStream-v1" and side["algo"] == "ppo" and side["scenario"] == "nominal"
    assert side["n_envs"] == 8 and side["hyperparams"]["n_steps"] == 64 and side["hyperparams"]["batch_size"] == 128
    assert side["config"]["env_kwargs"] == {"reward": "reciprocal"}  # the training environments' only
    assert side["test"]["seed"] == TEST_SEED and side["test"]["n_episodes"] == 3
    assert summary["test_mean_abs_phi_sf_iqm"] == side["test"]["summary"]["mean_abs_phi_sf"]
    assert summary["test_score"] == side["test"]["summary"]["score"]
    assert "validation score" in proc.stdout
    # Both models the run writes load as policies, each with its own observation statistics, and score.
    from vnhc_gym.evaluation import evaluate
    from vnhc_gym.training import load_agent

    for model, rms in ((f"{stem}.zip", side["obs_rms"]), (f"{stem}-final.zip", side["final_obs_rms"])):
        agent = load_agent(out / model)
        assert agent.meta["obs_rms"] == rms  # each model with the observation statistics it was saved with
        result = evaluate(agent, "vnhc_gym/USVStream-v1", n_episodes=2, max_time=1.0)
        assert 0.0 <= result.summary()["score"].point <= 1.0
    (out / f"{stem}.json").rename(out / "elsewhere.json")
    with pytest.raises(FileNotFoundError, match="AgentPolicy"):  # says how to load it anyway
        load_agent(out / f"{stem}-final.zip")


@pytest.mark.slow
def test_train_sac_with_its_defaults_in_a_subprocess(tmp_path: Path) -> None:
    """``vnhc-gym train --algo sac --backend sb3`` (SBX) with the file's settings and a short budget
    (past the warm-up, so gradient steps run), keeping the best and the final model."""
    pytest.importorskip("sbx")
    out = tmp_path / "runs"
    proc = _run("train", "--algo", "sac", "--backend", "sb3", "-n", "12000", "--out", str(out), "--eval-points", "2",
                "--test-episodes", "3")
    assert proc.returncode == 0, proc.stderr[-3000:]
    stem = "usv-nominal-sac-s0"
    assert (out / f"{stem}.zip").is_file() and (out / f"{stem}-final.zip").is_file()
    side = json.loads((out / f"{stem}.json").read_text())
    assert side["algo"] == "sac" and side["n_envs"] == 32 and side["hyperparams"]["gradient_steps"] == 8
    assert side["curve"][-1]["steps"] >= 12000 and side["test"]["n_episodes"] == 3


@pytest.mark.slow
def test_sweep_of_the_law_in_a_subprocess(tmp_path: Path) -> None:
    out = tmp_path / "sweep"
    config = tmp_path / "sweep.yml"
    config.write_text("envs: [usv]\nalgos: [law]\ntest_episodes: 3\n")
    proc = _run("sweep", "--config", str(config), "--executor", "local", "--out", str(out))
    assert proc.returncode == 0, proc.stderr[-3000:]
    sidecars = list((out / "runs").glob("*.json"))
    assert len(sidecars) == 1 and json.loads(sidecars[0].read_text())["test"]["n_episodes"] == 3
    assert (out / "report" / "comparison.md").is_file()
    first = (out / "report" / "comparison.json").read_text()
    # --report rebuilds the report from the run files alone.
    shutil.rmtree(out / "report")
    proc = _run("sweep", "--report", str(out))
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert json.loads((out / "report" / "comparison.json").read_text()) == json.loads(first)


@pytest.mark.slow
def test_a_task_in_a_file_of_its_own_through_every_command(tmp_path: Path) -> None:
    """The tutorial's task module, saved outside the package, trained, tuned (2 trials), benchmarked
    and swept through the console script with ``--gym-packages`` (from the module's folder, as a
    user runs it)."""
    pytest.importorskip("stable_baselines3")
    import re

    from conftest import TUTORIAL

    block = next(b for b in re.findall(r"```python\n(.*?)```", TUTORIAL.read_text(), re.S)
                 if b.startswith("# puck_task.py"))
    (tmp_path / "puck_task.py").write_text(block)

    def run(*args: str) -> subprocess.CompletedProcess:
        return subprocess.run([*_command(), *args], capture_output=True, text=True, timeout=600, cwd=tmp_path)

    env = "vnhc_gym/PuckSwirl-v1"
    unknown = run("train", "--env", env, "-n", "10")
    assert unknown.returncode == 2 and "unknown environment" in unknown.stderr  # the flag is what makes it known
    proc = run("train", "--gym-packages", "puck_task", "--env", env, "-n", "1024", "--eval-points", "1",
               "--test-episodes", "2", "-params", "n_envs:8", "n_steps:64", "batch_size:128", "--out", "runs")
    assert proc.returncode == 0, proc.stderr[-3000:]
    side = json.loads((tmp_path / "runs" / "puck-nominal-ppo-s0.json").read_text())
    assert side["env_id"] == env and side["test"]["n_episodes"] == 2
    # PPO trains compiled unless told otherwise: the faster backend is the default.
    assert side["backend"] == "jax" and (tmp_path / "runs" / "puck-nominal-ppo-s0.npz").is_file()
    proc = run("tune", "--gym-packages", "puck_task", "--env", "puck", "--algo", "tuned_law", "--trials", "2",
               "--eval-episodes", "2", "--out", "tuned")
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert len(json.loads((tmp_path / "tuned" / "puck-nominal" / "tuned_law.json").read_text())) > 0
    proc = run("benchmark", "--gym-packages", "puck_task", "--tasks", "puck", "--quick", "--out", "bench")
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "PuckSwirl-v1" in (tmp_path / "bench" / "benchmark.md").read_text()
    proc = run("sweep", "--gym-packages", "puck_task", "--envs", "puck", "--algos", "law", "--executor", "local",
               "--jobs", "2", "--test-episodes", "2", "--out", "sweep")
    assert proc.returncode == 0, proc.stderr[-3000:]
    (record,) = (tmp_path / "sweep" / "runs").glob("puck-nominal-law-*.json")
    assert json.loads(record.read_text())["env_id"] == env


def test_the_command_keeps_compiled_programs_on_disk_and_the_package_does_not(tmp_path: Path) -> None:
    """``vnhc-gym`` fills JAX's compilation cache under ``$XDG_CACHE_HOME``, and a second run finds
    what the first compiled; ``off`` turns it off; importing the package sets no cache folder."""
    import os

    env = {k: v for k, v in os.environ.items() if not k.startswith("JAX_") and k != "VNHC_GYM_JAX_CACHE"}
    # One hash seed for both runs: the systems sympy lambdifies at run time print their terms in the
    # order of Python's string hashing, which differs between processes, and with it their programs.
    env.update(XDG_CACHE_HOME=str(tmp_path / "xdg"), PYTHONHASHSEED="0")
    folder = tmp_path / "xdg" / "vnhc_gym" / "jax"

    def reproduce(out: str, **extra: str) -> None:
        proc = subprocess.run([*_command(), "reproduce", "--quick", "--out", str(tmp_path / out)], capture_output=True,
                              text=True, timeout=600, env={**env, **extra})
        assert proc.returncode == 0, proc.stderr[-3000:]

    reproduce("first")
    entries = {p.name for p in folder.iterdir()}
    assert entries  # compiled programs were written
    reproduce("second")
    assert {p.name for p in folder.iterdir()} == entries  # the second run compiled nothing new
    # Turned off, the command's setting step (the one the runs above went through) sets no folder.
    code = "from vnhc_gym.cli import use_compilation_cache; import jax; " \
           "print(use_compilation_cache(), jax.config.jax_compilation_cache_dir)"
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300,
                          env={**env, "VNHC_GYM_JAX_CACHE": "off", "XDG_CACHE_HOME": str(tmp_path / "other")})
    assert proc.returncode == 0 and proc.stdout.split() == ["None", "None"], proc.stderr
    assert not (tmp_path / "other").exists()
    code = "import jax, vnhc_gym; print(jax.config.jax_compilation_cache_dir)"
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, env=env)
    assert proc.returncode == 0 and proc.stdout.strip() == "None", proc.stderr
