"""Smoke tests of the experiment scripts' quick runs: they finish and write (or print) their results."""

from __future__ import annotations

import csv
import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from vnhc_gym.tasks import env_ids

EXPERIMENTS = Path(__file__).resolve().parent.parent / "experiments"


def _run(script: str, out: Path, timeout: int = 900) -> subprocess.CompletedProcess:
    proc = subprocess.run([sys.executable, str(EXPERIMENTS / script), "--quick", "--out", str(out)],
                          capture_output=True, text=True, timeout=timeout)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return proc


@pytest.mark.slow
def test_train_compare_quick_writes_every_table_and_figure(tmp_path: Path) -> None:
    """The quick grid (two tasks) writes every table and figure of the report."""
    pytest.importorskip("stable_baselines3")
    out = tmp_path / "compare"
    proc = _run("train_compare.py", out)
    report = out / "report"
    envs = ("sled", "cartpole")
    for name in ("comparison.md", "comparison.csv", "comparison.json", "headline.md", "verdicts.json", "verdict.png",
                 "performance_profile.png", *(f"learning_curves_{env}.png" for env in envs)):
        assert (report / name).is_file() and (report / name).stat().st_size > 0, name
    rows = json.loads((report / "comparison.json").read_text())
    algos = ("oracle", "law", "tuned_law", "observer", "ppo", "residual_ppo")
    assert {(r["env"], r["algo"]) for r in rows} == {(e, a) for e in envs for a in algos}
    assert all(0.0 <= r["low"] <= r["score"] <= r["high"] <= 1.0 and 0.0 <= r["success"] <= 1.0 for r in rows)
    with open(report / "comparison.csv") as fh:
        assert len(list(csv.DictReader(fh))) == len(rows)
    headline = (report / "headline.md").read_text()
    assert all(f"| {env} | nominal |" in headline for env in envs)
    verdicts = json.loads((report / "verdicts.json").read_text())
    assert {v["env"] for v in verdicts} == set(envs) and all(v["verdict"] for v in verdicts)
    sidecars = list((out / "runs").glob("*.json"))
    assert len(sidecars) == len(envs) * len(algos) and not list((out / "runs").glob("*.error"))
    assert len(list((out / "runs").glob("*-final.zip"))) == len(envs) * 2  # every learned run keeps its final model
    assert "report:" in proc.stdout


@pytest.mark.slow
def test_bench_train_quick_prints_env_steps_per_second(tmp_path: Path) -> None:
    pytest.importorskip("stable_baselines3")
    out = tmp_path / "bench"
    proc = _run("bench_train.py", out)
    lines = re.findall(r"^(\w+)\s+n_envs=\s*(\d+) threads=(\d+)\s+([\d.]+) k env-steps/s", proc.stdout, re.M)
    assert [(task, int(n)) for task, n, _, _ in lines] == [("usv", 8)]
    assert all(float(rate) > 0 for *_, rate in lines)
    res = json.loads((out / "bench_train.json").read_text())
    assert sorted((r["backend"], r["seeds"]) for r in res["backends"]) == [("jax", 2), ("sb3", 1)]
    assert all(r["steps_per_s"] > 0 for r in res["backends"])
    rows = res["throughput"]
    assert len(rows) == 1 and all(r["steps_per_s"] > 0 and 0 < r["rollout_share"] < 1 for r in rows)
    assert res["concurrent"] == []  # whole processes run in the full benchmark only
    assert (out / "bench_train.md").read_text() in proc.stdout
    # Where a compiled iteration spends its time: the environment alone takes part of the whole
    # iteration's time, the update the rest.
    (part,) = json.loads((out / "bench_split.json").read_text())
    assert part["task"] == "usv" and part["compile_s"] > 0
    assert 0 < part["env_us_per_step"] < part["iteration_us_per_step"]
    assert part["update_us_per_step"] == pytest.approx(part["iteration_us_per_step"] - part["env_us_per_step"])
    assert (out / "bench_split.md").read_text() in proc.stdout


@pytest.mark.slow
def test_bench_envs_quick_measures_every_env(tmp_path: Path) -> None:
    out = tmp_path / "envs"
    proc = _run("bench_envs.py", out)
    res = json.loads((out / "bench_envs.json").read_text())
    assert set(res["single_us"]) == {"Pendulum-v1", *env_ids("v1", shipped_only=True)}
    assert all(v > 0 for v in res["single_us"].values())
    shipped = env_ids("v1", shipped_only=True)
    assert {(r["env"], r["n"]) for r in res["vector"]} == {(e, 8) for e in shipped}
    assert all(r["native"] > 0 and r["sync"] > 0 and r["cartpole"] > 0 for r in res["vector"])
    assert (out / "bench_envs.md").read_text() in proc.stdout


@pytest.mark.slow
def test_bench_offpolicy_quick_measures_every_sac_implementation(tmp_path: Path) -> None:
    pytest.importorskip("sbx")
    out = tmp_path / "offpolicy"
    proc = _run("bench_offpolicy.py", out)
    rows = json.loads((out / "bench_offpolicy.json").read_text())
    assert [r["implementation"] for r in rows] == ["stable-baselines3", "SBX", "compiled, 1 seed",
                                                   "compiled, gradient steps alone (bound)"]
    assert all(r["env_steps_per_s"] > 0 and r["gradient_steps_per_s"] > 0 for r in rows)
    assert (out / "bench_offpolicy.md").read_text() in proc.stdout


@pytest.mark.slow
def test_residual_safeguards_quick_runs_every_variant(tmp_path: Path) -> None:
    pytest.importorskip("stable_baselines3")
    out = tmp_path / "safeguards"
    proc = _run("residual_safeguards.py", out)
    rows = json.loads((out / "residual_safeguards.json").read_text())
    assert [r["variant"] for r in rows] == ["shipped", "warm-up", "small", "warm-up + small"]
    assert all(0 < r["base"] <= 1 and r["best"] >= r["base"] for r in rows)
    assert (out / "residual_safeguards.md").read_text() in proc.stdout


@pytest.mark.slow
def test_imitation_bound_fits_a_network_and_tests_it_beside_the_law(tmp_path: Path) -> None:
    """A tiny fit runs end to end; each row's ratio is its test episodes' IQM over the law's."""
    out = tmp_path / "imitation"
    proc = subprocess.run([sys.executable, str(EXPERIMENTS / "imitation_bound.py"), "--cells", "usv/nominal",
                           "--widths", "8", "--rounds", "2", "--epochs", "1", "--final-epochs", "1", "--n-envs", "4",
                           "--out", str(out)], capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    (row,) = json.loads((out / "imitation_bound.json").read_text())
    phi = np.sort(np.asarray(row["episodes"]["mean_abs_phi_sf"]))
    assert len(phi) == 20 and row["samples"] == 2 * 4 * 400  # two rounds of four 400-step episodes
    lo, hi = np.percentile(phi, [25, 75])
    assert row["iqm"] == pytest.approx(phi[(phi >= lo) & (phi <= hi)].mean())
    assert row["ratio"] == pytest.approx(row["iqm"] / row["law_iqm"])
    assert "| usv/nominal | tuned law |" in (out / "imitation_bound.md").read_text()


def test_error_phases_splits_the_score_of_the_law_and_an_agent(tmp_path: Path) -> None:
    """The phases' means are those of the traces (the law decays: its first phase is far above its last),
    and the shares of the phases add up to the whole."""
    pytest.importorskip("stable_baselines3")
    from vnhc_gym.training.agents import ZOO_DIR

    out = tmp_path / "phases"
    proc = subprocess.run([sys.executable, str(EXPERIMENTS / "error_phases.py"), str(ZOO_DIR / "usv-ppo.zip"),
                           "--episodes", "3", "--out", str(out)], capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    rows = json.loads((out / "error_phases.json").read_text())
    assert [r["policy"] for r in rows] == ["tuned law", "usv-ppo"]
    law = rows[0]
    assert law["0-0.5 s"] > 100 * law["2 s-end"]
    for r in rows:
        shares = [v for k, v in r.items() if k.startswith("share")]
        assert len(shares) == 3 and all(0 <= s <= 1 for s in shares)
        assert sum(shares) == pytest.approx(1.0, abs=0.15)  # medians over episodes: close to, not exactly, 1
    assert (out / "error_phases.md").read_text() in proc.stdout
