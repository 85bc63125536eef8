"""The learner-tuning experiment's report: its rows group the finished runs as their names say, and its
ratio to the law is the IQM computed by hand."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path
from types import ModuleType
from typing import Any

import pytest

SCRIPT = Path(__file__).resolve().parent.parent / "experiments" / "tune_learners.py"


@pytest.fixture(scope="module")
def script() -> ModuleType:
    spec = importlib.util.spec_from_file_location("tune_learners", SCRIPT)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _sidecar(runs: Path, name: str, seed: int, steps: int, phi: list[float],
             overrides: dict[str, Any] | None = None) -> None:
    meta = {"name": name, "seed": seed, "n_timesteps": steps, "train_wall": 60.0 * (seed + 1),
            "config": {"overrides": overrides or {}}, "hyperparams": {"gamma": 0.95, **(overrides or {})},
            "curve": [{"steps": 0, "mean_abs_phi_sf": 1.0}, {"steps": steps, "mean_abs_phi_sf": min(phi)}],
            "test": {"metrics": {"score": [0.9] * len(phi), "success": [1.0] * len(phi), "mean_abs_phi_sf": phi}}}
    (runs / f"{name}.json").write_text(json.dumps(meta))


def test_rows_group_runs_by_learner_reward_settings_and_budget(script: ModuleType, tmp_path: Path) -> None:
    runs = tmp_path / "runs"
    runs.mkdir()
    for seed in range(3):
        _sidecar(runs, f"usv-nominal-sac-bounded-tuned-s{seed}", seed, 1_000_000, [0.1, 0.2, 0.3, 0.4])
    _sidecar(runs, "usv-nominal-sac-bounded-tuned-s0-3000k", 0, 3_000_000, [0.01, 0.02, 0.03, 0.04])
    _sidecar(runs, "usv-nominal-ppo-reciprocal-shipped-s1", 1, 2_000_000, [0.5, 0.5, 0.5, 0.5])
    for seed in range(2):  # a variant: the tuned settings with one hyperparameter replaced
        _sidecar(runs, f"usv-nominal-sac-bounded-tuned+te5-s{seed}-1000k", seed, 1_000_000, [0.05] * 4,
                 overrides={"target_entropy": -5})
    _sidecar(runs, "flocking-nominal-ppo-bounded-shipped-s0", 0, 2_000_000, [1.0])  # another cell
    _sidecar(runs, "sac-usv-nominal-s0", 0, 1_000, [1.0])  # a run of another experiment
    rows = script._rows(tmp_path, ["usv/nominal"])
    keys = [(r["algo"], r["reward"], r["settings"], r["steps"], r["seeds"]) for r in rows]
    assert keys == [("ppo", "reciprocal", "shipped", 2_000_000, [1]),
                    ("sac", "bounded", "tuned", 1_000_000, [0, 1, 2]),
                    ("sac", "bounded", "tuned", 3_000_000, [0]),
                    ("sac", "bounded", "tuned+te5", 1_000_000, [0, 1])]
    assert rows[3]["replaced"] == {"target_entropy": -5} and rows[1]["replaced"] == {}
    assert "| tuned+te5, target_entropy = -5 | 1 M | 2 |" in script._table([_law_row([0.1] * 4), rows[3]])
    assert rows[1]["train_seconds"] == [60.0, 120.0, 180.0]
    assert len(rows[1]["episodes"]["mean_abs_phi_sf"]) == 12 and len(rows[1]["curves"]) == 3
    assert rows[1]["study_trials"] is None  # no study stored: the row says so instead of inventing one
    # IQM of the seeds' twelve episodes: the middle half (0.2 and 0.3) against the law's 0.1; 2 minutes a run.
    assert "| 0.25 | 2.5 | - | 2.0 |" in script._table([_law_row([0.1] * 4), rows[1]])


def _law_row(phi: list[float]) -> dict[str, Any]:
    return {"cell": "usv/nominal", "algo": "tuned_law", "reward": "-", "settings": "{}",
            "episodes": {"score": [1.0] * len(phi), "success": [1.0] * len(phi), "mean_abs_phi_sf": phi}}


def test_table_ratio_is_the_iqm_over_the_laws(script: ModuleType) -> None:
    law = _law_row([0.001, 0.002, 0.003, 100.0])
    agent = {"cell": "usv/nominal", "algo": "sac", "reward": "bounded", "settings": "shipped", "steps": 10**6,
             "seeds": [0], "episodes": {"score": [0.5] * 4, "success": [1.0, 1.0, 0.0, 1.0],
                                        "mean_abs_phi_sf": [0.01, 0.02, 0.03, 100.0]},
             "train_seconds": [120.0], "study_trials": None, "study_seconds": None}
    table = script._table([law, agent])
    # The middle half of each four episodes: (0.002 + 0.003) / 2 and (0.02 + 0.03) / 2, ten times the law's.
    row = next(line for line in table.splitlines() if "| sac |" in line).split("|")
    assert float(row[9]) == pytest.approx(0.025) and float(row[10]) == pytest.approx(10.0)
    assert float(row[8]) == pytest.approx(0.75) and row[12].strip() == "2.0"


def test_final_runs_are_one_job_per_missing_seed(script: ModuleType, tmp_path: Path) -> None:
    (tmp_path / "runs").mkdir()
    _sidecar(tmp_path / "runs", "flocking-nominal-sac-reciprocal-shipped+te5-s1-3000k", 1, 3_000_000, [0.1])
    job = {"cell": "flocking/nominal", "algo": "sac", "reward": "reciprocal", "seeds": 3,
           "final_steps": [3_000_000], "settings": ["shipped"], "variant": ("te5", {"target_entropy": -5}),
           "out": str(tmp_path)}
    todo = script._final_runs(job)
    # Seed 1 is finished; the others each train alone, under names the report reads back.
    assert [run["name"] for run in todo] == ["flocking-nominal-sac-reciprocal-shipped+te5-s0-3000k",
                                             "flocking-nominal-sac-reciprocal-shipped+te5-s2-3000k"]
    assert all(script.RUN_NAME.match(run["name"])["settings"] == "shipped+te5" for run in todo)
    assert [run["seed"] for run in todo] == [0, 2] and todo[0]["hyperparams"] is None
    assert todo[0]["overrides"] == {"target_entropy": -5} and todo[0]["env_kwargs"] == {"reward": "reciprocal"}


def test_merged_report_keeps_the_rows_of_runs_not_here(script: ModuleType) -> None:
    def row(cell: str, algo: str, settings: str, steps: int | None, phi: float) -> dict[str, Any]:
        return {"cell": cell, "algo": algo, "reward": "-" if steps is None else "bounded", "settings": settings,
                "steps": steps, "episodes": {"mean_abs_phi_sf": [phi]}}

    published = [row("usv/nominal", "tuned_law", "{}", None, 1.0), row("usv/nominal", "sac", "tuned", 10**6, 2.0),
                 row("usv/nominal", "ppo", "shipped", 2 * 10**6, 3.0),
                 row("flocking/nominal", "tuned_law", "{}", None, 4.0),
                 row("flocking/nominal", "sac", "shipped", 10**6, 5.0)]
    fresh = [row("usv/nominal", "tuned_law", "{}", None, 10.0), row("usv/nominal", "sac", "tuned", 10**6, 20.0),
             row("usv/nominal", "sac", "tuned+te5", 10**6, 30.0)]
    merged = script._merged(fresh, published)
    got = [(r["cell"], r["algo"], r["settings"], r["episodes"]["mean_abs_phi_sf"][0]) for r in merged]
    # A fresh row replaces the published one of the same learner, settings and budget (and the law's);
    # the rows whose runs are gone, and a cell not reported here, stay.
    assert got == [("usv/nominal", "tuned_law", "{}", 10.0), ("usv/nominal", "ppo", "shipped", 3.0),
                   ("usv/nominal", "sac", "tuned", 20.0), ("usv/nominal", "sac", "tuned+te5", 30.0),
                   ("flocking/nominal", "tuned_law", "{}", 4.0), ("flocking/nominal", "sac", "shipped", 5.0)]
