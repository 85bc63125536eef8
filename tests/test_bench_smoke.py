"""Smoke test of experiments/bench_envs.py: the quick run finishes and writes its results."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

SCRIPT = Path(__file__).resolve().parent.parent / "experiments" / "bench_envs.py"


@pytest.mark.slow
def test_bench_envs_quick(tmp_path: Path) -> None:
    out = tmp_path / "bench"
    proc = subprocess.run([sys.executable, str(SCRIPT), "--quick", "--out", str(out)], capture_output=True,
                          text=True, timeout=900)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert (out / "bench_envs.md").is_file() and (out / "bench_envs.json").is_file()
    res = json.loads((out / "bench_envs.json").read_text())
    assert res["meta"]["quick"] is True
    assert set(res["single"]["envs"]) == {"vnhc_gym/FlockingAlign-v0", "vnhc_gym/USVStream-v0"}
    assert res["single"]["pendulum_us"] > 0
    assert {r["n"] for r in res["vector"].values()} == {16, 256}
    assert all(r["rollout_steps_per_s"] > 0 and r["sync_steps_per_s"] > 0 and r["cartpole_steps_per_s"] > 0
               for r in res["vector"].values())
    assert res["jit"]["import_gymnasium_s"] > 0 and len(res["jit"]["envs"]) == 2
    assert all(len(r["reset_over_import_samples_s"]) == 1 for r in res["jit"]["envs"].values())
    bound = res["usv_bound"]
    assert bound["n"] == 256 and bound["cartpole_steps_per_s"] > 0
    assert set(bound["rows"]) == {"random", "northeast", "rk4", "advance"}
    assert all(r["steps_per_s"] > 0 for r in bound["rows"].values())
    assert res["floors"] and all(isinstance(f["pass"], bool) for f in res["floors"])
    text = (out / "bench_envs.md").read_text()
    assert "Pendulum-v1" in text and "CartPole" in text and ("PASS" in text or "FAIL" in text)
    assert "RK4 alone" in text
    assert text in proc.stdout  # the printed table is the written one
