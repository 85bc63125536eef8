"""The error-phase table grows: rows of agents evaluated elsewhere are kept, the evaluated ones replaced."""

from __future__ import annotations

import importlib.util
from pathlib import Path
from types import ModuleType
from typing import Any

import pytest

SCRIPT = Path(__file__).resolve().parent.parent / "experiments" / "error_phases.py"


@pytest.fixture(scope="module")
def script() -> ModuleType:
    spec = importlib.util.spec_from_file_location("error_phases", SCRIPT)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _row(env: str, policy: str, whole: float) -> dict[str, Any]:
    return {"policy": policy, "env": env, "scenario": "nominal", "whole": whole}


def test_merged_keeps_agents_not_evaluated_and_recomputes_the_law(script: ModuleType) -> None:
    usv, flock = "vnhc_gym/USVStream-v1", "vnhc_gym/FlockingAlign-v1"
    kept = [_row(flock, "tuned law", 1.0), _row(flock, "sac-s0", 2.0),
            _row(usv, "tuned law", 3.0), _row(usv, "ppo-s0", 4.0), _row(usv, "sac-s0", 5.0)]
    fresh = [_row(usv, "tuned law", 30.0), _row(usv, "sac-s0", 50.0), _row(usv, "sac-s1", 60.0)]
    got = [(r["env"], r["policy"], r["whole"]) for r in script.merged(fresh, kept)]
    assert got == [(flock, "tuned law", 1.0), (flock, "sac-s0", 2.0),
                   (usv, "tuned law", 30.0), (usv, "ppo-s0", 4.0), (usv, "sac-s0", 50.0), (usv, "sac-s1", 60.0)]


def test_a_folder_leaves_out_runs_still_training(script: ModuleType, tmp_path: Path) -> None:
    for name in ("done-s0", "done-s0-final", "training-s1"):
        (tmp_path / f"{name}.zip").write_bytes(b"")
    (tmp_path / "done-s0.json").write_text("{}")  # the sidecar is written when a run ends
    assert [p.name for p in script._models([str(tmp_path)], "*")] == ["done-s0.zip"]
