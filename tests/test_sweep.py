"""Tests of vnhc_gym.sweep: a tiny grid end to end (2 tasks x 1 scenario x 2 seeds, a few thousand
steps per learned run), resuming, failures, the report, and the executors.

The numbers in the report are checked against the run files and against independent evaluations
of the law on the test seeds; resuming is checked by counting calls to ``run_one``.
"""

from __future__ import annotations

import csv
import json
import math
import shutil
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from scipy import stats as sps

pytest.importorskip("stable_baselines3")

import vnhc_gym.evaluation  # noqa: E402
import vnhc_gym.evaluation.protocol  # noqa: E402
import vnhc_gym.sweep.execute  # noqa: E402
from vnhc_gym import stats, sweep  # noqa: E402
from vnhc_gym.baselines import GeometricController  # noqa: E402
from vnhc_gym.baselines.tuning import CLASSICAL  # noqa: E402
from vnhc_gym.evaluation import TEST_SEED, VALIDATION_SEED, evaluate  # noqa: E402
from vnhc_gym.sweep import RunSpec, grid, load_runs, report, run_sweep, status  # noqa: E402
from vnhc_gym.tasks import env_id, shipped_tasks  # noqa: E402

# One xdist worker runs this module, so that its module-scoped fixture (the swept grid) is built once.
pytestmark = pytest.mark.xdist_group("test_sweep")
TASKS = shipped_tasks()  # the package's own tasks (the tutorial's is registered by conftest)

ENVS = list(TASKS)[:2]  # two registered tasks
TINY = {"n_envs": 8, "n_steps": 64, "batch_size": 128}
BAD = (("learning_rate", "not-a-number"),)


def _specs() -> list[RunSpec]:
    return grid(ENVS, ["nominal"], ["law", "ppo"], [0, 1], 2048, overrides=TINY, test_episodes=3, eval_episodes=3)


def _bad_spec() -> RunSpec:
    return RunSpec("ppo", ENVS[0], "nominal", 0, 2048, BAD, test_episodes=3, eval_episodes=3)


@pytest.fixture(scope="module")
def swept(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, list[RunSpec], dict[str, list[str]], list[str]]:
    out = tmp_path_factory.mktemp("sweep")
    lines: list[str] = []
    result = run_sweep([*_specs(), _bad_spec()], out, log=lines.append)
    return out, _specs(), result, lines


def _copy(src: Path, tmp_path: Path) -> Path:
    dest = tmp_path / "copy"
    shutil.copytree(src, dest)
    return dest


def _test_metrics(out: Path, spec: RunSpec) -> dict[str, list[float]]:
    return json.loads((out / "runs" / f"{spec.stem}.json").read_text())["test"]["metrics"]


class _Calls:
    """Wraps run_one: records the stems it runs (and runs them unless ``refuse``)."""

    def __init__(self, real: Any, refuse: bool = False) -> None:
        self.real, self.refuse, self.stems = real, refuse, []

    def __call__(self, spec: RunSpec, out: Any, threads: int = 1, packages: Any = ()) -> Any:
        self.stems.append(spec.stem)
        if self.refuse:
            raise AssertionError(f"{spec.stem} should not run again")
        return self.real(spec, out, threads, packages)


# --------------------------------------------------------------------------- specs
def test_grid_and_run_specs() -> None:
    specs = grid(["flocking", "usv"], ["nominal", "noisy"], ["law", "observer", "ppo", "residual_ppo"], [0, 1, 2],
                 1000, seeds_by_scenario={"noisy": [5]})
    # Classical baselines: one run per cell; learned: one per seed (the cell's own seeds).
    assert len(specs) == 2 * (2 + 2 * 3) + 2 * (2 + 2 * 1)
    noisy_ppo = [s for s in specs if s.scenario == "noisy" and s.algo == "ppo"]
    assert sorted(s.seed for s in noisy_ppo) == [5, 5]
    assert len({s.stem for s in specs}) == len(specs)
    a = RunSpec("ppo", "usv", seed=1, n_timesteps=10)
    assert a.key() == RunSpec("ppo", "usv", seed=1, n_timesteps=10).key()
    assert a.key() != RunSpec("ppo", "usv", seed=2, n_timesteps=10).key()
    assert a.key() != RunSpec("ppo", "usv", seed=1, n_timesteps=20).key()
    assert a.stem.startswith("usv-nominal-ppo-s1-") and a.learned
    law = RunSpec("law", "usv", seed=1, n_timesteps=10)
    assert not law.learned and "-s1" not in law.stem
    assert law.key() == RunSpec("law", "usv", seed=3, n_timesteps=99).key()  # deterministic: no seed, no budget
    assert law.key() != RunSpec("law", "usv", test_episodes=5).key()
    with pytest.raises(ValueError, match="algo"):
        RunSpec("td3", "usv")


def test_a_compiled_run_is_its_own_entry_and_its_cells_seeds_one_unit() -> None:
    from vnhc_gym.sweep.execute import gpus_of, units
    from vnhc_gym.sweep.specs import algo_of

    sb3 = RunSpec("ppo", "usv", seed=1, n_timesteps=10)
    jx = RunSpec("ppo", "usv", seed=1, n_timesteps=10, backend="jax")
    assert jx.stem.startswith("usv-nominal-ppo-jax-s1-") and jx.key() != sb3.key()
    assert (jx.label, sb3.label) == ("ppo-jax", "ppo") and algo_of(jx.label) == algo_of(sb3.label) == "ppo"
    assert algo_of("residual_ppo") == "residual_ppo"
    with pytest.raises(ValueError, match=r"trains \['ppo', 'residual_ppo', 'ppo_history', 'sac', 'residual_sac'\]"):
        RunSpec("law", "usv", backend="jax")  # a classical run has no backend
    with pytest.raises(ValueError, match=r"needs bases among \['law', 'tuned_law', 'kalman'\].*got \['observer'\]"):
        RunSpec("residual_ppo", "usv", backend="jax", bases=("observer",))
    # A compiled residual's base is chosen among the grid's bases written in JAX; on SB3 among all.
    algos = ["law", "tuned_law", "observer", "kalman", "residual_ppo"]
    mixed = grid(["usv"], ["noisy"], algos, [0], 10, backend="jax")
    assert [s.bases for s in mixed if s.algo == "residual_ppo"] == [("law", "tuned_law", "kalman")]
    mixed = grid(["usv"], ["noisy"], algos, [0], 10)
    assert [s.bases for s in mixed if s.algo == "residual_ppo"] == [("law", "tuned_law", "observer", "kalman")]
    with pytest.raises(ValueError, match="backend must be one of"):
        RunSpec("ppo", "usv", backend="torch")
    specs = grid(["usv", "sled"], ["nominal"], ["law", "ppo"], [0, 1, 2], 10, backend="jax")
    assert {s.backend for s in specs if s.algo == "law"} == {"sb3"}  # a classical run has no backend
    groups = units(specs)
    assert [[s.stem for s in u] for u in groups if len(u) > 1] == [
        [s.stem for s in specs if s.env == env and s.algo == "ppo"] for env in ("usv", "sled")]
    assert sum(map(len, groups)) == len(specs) and len(groups) == 4
    nested = grid(["usv"], ["nominal"], ["ppo"], [0, 1], 10, overrides={"policy_kwargs": {"net_arch": [32, 32]}},
                  backend="jax")
    assert [[s.seed for s in u] for u in units(nested)] == [[0, 1]]
    assert gpus_of(jx, True) == 1 and gpus_of(sb3, True) == 0 and gpus_of(jx, False) == 0


# --------------------------------------------------------------------------- a sweep end to end
@pytest.mark.slow
def test_sweep_runs_and_records_a_failure(swept: Any) -> None:
    out, specs, result, lines = swept
    bad = _bad_spec()
    assert sorted(result["done"]) == sorted(s.stem for s in specs)
    assert result["failed"] == [bad.stem] and result["skipped"] == []
    assert any(bad.stem in line and "failed" in line for line in lines)
    error = (out / "runs" / f"{bad.stem}.error").read_text()
    assert "Traceback" in error and "not-a-number" in error
    assert status(bad, out) == "failed" and not (out / "runs" / f"{bad.stem}.json").exists()
    for spec in specs:
        assert status(spec, out) == "done"
        side = json.loads((out / "runs" / f"{spec.stem}.json").read_text())
        assert side["spec"]["algo"] == spec.algo and side["spec"]["seed"] == spec.seed
        assert side["test"]["seed"] == TEST_SEED and side["test"]["n_episodes"] == 3
        assert (out / "runs" / f"{spec.stem}.zip").exists() == spec.learned
    assert status(RunSpec("law", "usv", "noisy"), out) == "todo"


@pytest.mark.slow
def test_the_law_run_is_the_law_on_the_test_seeds(swept: Any) -> None:
    out, specs, _, _ = swept
    for spec in specs:
        if spec.algo != "law":
            continue
        independent = evaluate(GeometricController, env_id(spec.env), "nominal", n_episodes=3, seed=TEST_SEED)
        for name, values in _test_metrics(out, spec).items():
            np.testing.assert_allclose(values, independent.metrics[name], rtol=1e-12, atol=1e-15, err_msg=name)


@pytest.mark.slow
def test_report_files_and_numbers(swept: Any, tmp_path: Path) -> None:
    out = _copy(swept[0], tmp_path)
    specs = swept[1]
    lines: list[str] = []
    rep = report(out, reps=300, log=lines.append)
    dest = out / "report"
    for name in ("comparison.md", "comparison.csv", "comparison.json", "headline.md", "verdicts.json", "verdict.png",
                 *(f"learning_curves_{env}.png" for env in ENVS)):
        assert (dest / name).is_file() and (dest / name).stat().st_size > 0, name
    assert sorted(rep["figures"]) == sorted(str(p) for p in dest.glob("*.png"))
    assert not any("WARNING" in line for line in lines)  # one code version
    rows = json.loads((dest / "comparison.json").read_text())
    assert rows == json.loads(json.dumps(rep["rows"]))
    assert {(r["env"], r["algo"]) for r in rows} == {(e, a) for e in ENVS for a in ("law", "ppo")}
    for row in rows:
        cell = [s for s in specs if s.env == row["env"] and s.algo == row["algo"]]
        pooled = np.concatenate([_test_metrics(out, s)["score"] for s in cell])
        phi = np.concatenate([_test_metrics(out, s)["mean_abs_phi_sf"] for s in cell])
        assert row["runs"] == len(cell) == (2 if row["algo"] == "ppo" else 1)
        # The score: the plain mean over every pooled episode; |phi~|: the IQM, a diagnostic.
        assert row["score"] == pytest.approx(float(np.mean(pooled)), rel=1e-12)
        assert row["iqm_abs_phi_sf"] == pytest.approx(sps.trim_mean(phi, 0.25), rel=1e-12)
        assert row["low"] <= row["score"] <= row["high"]
        # The interval redraws the runs (in the order of their files), then the episodes within each.
        per_run = np.stack([_test_metrics(out, s)["score"] for s in sorted(cell, key=lambda s: s.stem)])
        assert row["episodes_per_run"] == 3
        iv = stats.interval_estimates({"x": per_run}, reps=300)["x"]
        assert (row["low"], row["high"]) == (iv.low, iv.high)
        assert row["best_classical"] == "law"
        if row["algo"] == "ppo":
            assert 0.0 <= row["poi_low"] <= row["poi"] <= row["poi_high"] <= 1.0
            law = next(s for s in specs if s.env == row["env"] and s.algo == "law")
            poi = stats.probability_of_improvement_interval(per_run, [_test_metrics(out, law)["score"]], reps=300)
            assert (row["poi"], row["poi_low"], row["poi_high"]) == (poi.point, poi.low, poi.high)
            assert row["parity_runs"].endswith("/2")
    with open(dest / "comparison.csv") as fh:
        table = list(csv.DictReader(fh))
    assert [(r["env"], r["algo"]) for r in table] == [(r["env"], r["algo"]) for r in rows]
    md = (dest / "comparison.md").read_text()
    assert md.count("| nominal |") == len(rows) and "law (best)" in md
    assert all(f"### {env}" in md for env in ENVS)
    headline = (dest / "headline.md").read_text()
    assert all(f"| {env} | nominal |" in headline for env in ENVS)
    # Every verdict names its data: PPO's two runs of three episodes, the law's one.
    assert all("2 runs x 3 episodes" in v["verdict"] and "1 run x 3 episodes" in v["verdict"] for v in rep["verdicts"])


@pytest.mark.slow
def test_a_compiled_cell_trains_its_seeds_in_one_program_and_is_reported_beside_sb3(
        swept: Any, tmp_path: Path) -> None:
    out = _copy(swept[0], tmp_path)
    specs = grid(ENVS[:1], ["nominal"], ["ppo"], [0, 1], 2048, overrides=TINY, test_episodes=3, eval_episodes=3,
                 backend="jax")
    lines: list[str] = []
    result = run_sweep(specs, out, log=lines.append)
    assert sorted(result["done"]) == sorted(s.stem for s in specs)
    metas = [json.loads((out / "runs" / f"{s.stem}.json").read_text()) for s in specs]
    assert all(m["seeds_in_program"] == 2 and m["sweep_algo"] == "ppo-jax" and m["backend"] == "jax" for m in metas)
    assert [m["spec"]["seed"] for m in metas] == [0, 1] and metas[0]["curve"] != metas[1]["curve"]
    assert all((out / "runs" / f"{s.stem}.npz").is_file() for s in specs)
    rows = report(out, reps=200, log=lines.append)["rows"]
    by = {(r["env"], r["algo"]): r for r in rows}
    jax_row, sb3_row = by[(ENVS[0], "ppo-jax")], by[(ENVS[0], "ppo")]
    assert jax_row["kind"] == sb3_row["kind"] == "learned" and jax_row["runs"] == sb3_row["runs"] == 2
    pooled = np.concatenate([_test_metrics(out, s)["score"] for s in specs])
    assert jax_row["score"] == pytest.approx(float(np.mean(pooled)), rel=1e-12) and "poi" in jax_row
    # backends.json places the compiled score against the SB3 runs' interval, as the two rows say.
    (entry,) = json.loads((out / "report" / "backends.json").read_text())
    lo, hi, score = sb3_row["low"], sb3_row["high"], jax_row["score"]
    assert entry["placement"] == ("below" if score < lo else "above" if score > hi else "within")
    assert entry["overlap"] == (jax_row["low"] <= hi and lo <= jax_row["high"])
    assert "ppo on jax against SB3, 1 cell:" in (out / "report" / "backends.md").read_text()
    # cost.md counts the program that trained both seeds once, and every SB3 run of PPO.
    cost = {line.split(" | ")[0][2:]: line.split(" | ")[1:3] for line in
            (out / "report" / "cost.md").read_text().splitlines()[2:]}
    assert cost["ppo-jax"] == ["2", f"{metas[0]['run_wall'] / 60:.1f}"]
    sb3 = [json.loads(f.read_text()) for f in (out / "runs").glob("*-ppo-s*.json")]
    assert cost["ppo"] == [str(len(sb3)), f"{sum(m['run_wall'] for m in sb3) / 60:.1f}"]


def test_the_backends_table_names_the_base_each_residual_corrected(tmp_path: Path) -> None:
    from vnhc_gym.sweep.verdicts import _write_backends

    def row(algo: str, score: float, low: float, high: float, base: str | None) -> dict[str, Any]:
        r = {"env": "usv", "scenario": "disturbance", "algo": algo, "score": score, "low": low, "high": high,
             "runs": 5}
        return r if base is None else {**r, "base": base}

    rows = [row("residual_ppo", 0.95, 0.94, 0.96, "safe_law"), row("residual_ppo-jax", 0.75, 0.70, 0.80, "tuned_law"),
            row("ppo", 0.80, 0.78, 0.82, None), row("ppo-jax", 0.81, 0.79, 0.83, None)]
    entries = _write_backends(rows, tmp_path)
    by = {e["algo"]: e for e in entries}
    assert (by["residual_ppo"]["sb3"]["base"], by["residual_ppo"]["other"]["base"]) == ("safe_law", "tuned_law")
    assert by["residual_ppo"]["placement"] == "below" and not by["residual_ppo"]["overlap"]
    assert "base" not in by["ppo"]["sb3"] and by["ppo"]["placement"] == "within"
    md = (tmp_path / "backends.md").read_text()
    line = next(x for x in md.splitlines() if "| residual_ppo |" in x)
    assert "(5) on safe_law |" in line and "(5) on tuned_law |" in line
    assert "the bases differ in 1" in md


@pytest.mark.slow
def test_report_warns_about_mixed_code_versions(swept: Any, tmp_path: Path) -> None:
    out = _copy(swept[0], tmp_path)
    side = next((out / "runs").glob("*.json"))
    data = json.loads(side.read_text())
    data["code"] = "0" * 16
    side.write_text(json.dumps(data))
    lines: list[str] = []
    rep = report(out, reps=100, log=lines.append)
    assert len(rep["codes"]) == 2 and any("WARNING" in line for line in lines)


# --------------------------------------------------------------------------- resuming
@pytest.mark.slow
def test_rerunning_does_no_training(swept: Any, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    out = _copy(swept[0], tmp_path)
    specs = swept[1]
    before = {p.name: p.stat().st_mtime_ns for p in (out / "runs").iterdir()}
    calls = _Calls(sweep.run_one, refuse=True)
    monkeypatch.setattr(vnhc_gym.sweep.execute, "run_one", calls)  # where run_sweep looks it up
    result = run_sweep(specs, out, log=lambda s: None)
    assert calls.stems == [] and result["done"] == [] and result["failed"] == []
    assert sorted(result["skipped"]) == sorted(s.stem for s in specs)
    # Not even the failed run, when asked not to retry failures.
    result = run_sweep([*specs, _bad_spec()], out, rerun_failed=False, log=lambda s: None)
    assert calls.stems == [] and len(result["skipped"]) == len(specs) + 1
    assert {p.name: p.stat().st_mtime_ns for p in (out / "runs").iterdir()} == before


@pytest.mark.slow
def test_a_failed_run_is_retried_alone(swept: Any, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    out = _copy(swept[0], tmp_path)
    calls = _Calls(sweep.run_one)
    monkeypatch.setattr(vnhc_gym.sweep.execute, "run_one", calls)  # where run_sweep looks it up
    result = run_sweep([*swept[1], _bad_spec()], out, log=lambda s: None)
    assert calls.stems == [_bad_spec().stem] and result["failed"] == [_bad_spec().stem]


@pytest.mark.slow
def test_deleting_a_sidecar_reruns_only_that_run(swept: Any, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    out = _copy(swept[0], tmp_path)
    specs = swept[1]
    victim = next(s for s in specs if s.algo == "ppo" and s.seed == 1)
    old = _test_metrics(out, victim)
    (out / "runs" / f"{victim.stem}.json").unlink()
    assert status(victim, out) == "todo"
    calls = _Calls(sweep.run_one)
    monkeypatch.setattr(vnhc_gym.sweep.execute, "run_one", calls)  # where run_sweep looks it up
    result = run_sweep(specs, out, log=lambda s: None)
    assert calls.stems == [victim.stem] and result["done"] == [victim.stem]
    assert status(victim, out) == "done"
    assert _test_metrics(out, victim) == old  # same seed, same numbers


# --------------------------------------------------------------------------- the report's statistics
def _record(algo: str, scenario: str, seed: int, scores: np.ndarray, validation: float) -> dict[str, Any]:
    """A finished run's sidecar with the fields the report reads, for given test scores."""
    spec = RunSpec(algo, "usv", scenario, seed, 1000, test_episodes=len(scores))
    n = len(scores)
    record: dict[str, Any] = {
        "name": spec.stem, "spec": asdict(spec), "code": "synthetic", "settings": {},
        "test": {"metrics": {"score": scores.tolist(), "success": [1.0] * n, "mean_abs_phi_sf": (1 - scores).tolist(),
                             "horizon_abs_phi_sf": (1 - scores).tolist()}}}
    if spec.learned:
        record["curve"] = [{"steps": 0, "wall": 0.0, "score": 0.0, "score_low": 0.0},
                           {"steps": 1000, "wall": 1.0, "score": validation, "score_low": validation}]
    else:
        record["validation_score"] = validation
    return record


def test_report_resamples_training_runs(tmp_path: Path) -> None:
    # Five PPO runs whose means differ, against a law whose episodes sit among them: pooled as if every
    # episode were independent, PPO would beat the law; with its runs redrawn the interval crosses 0.5.
    rng = np.random.default_rng(0)
    law = rng.normal(0.90, 0.01, size=20)
    ppo = rng.normal(np.array([0.895, 0.898, 0.905, 0.912, 0.925])[:, None], 0.004, size=(5, 20))
    clear = rng.normal(0.96, 0.004, size=(3, 20))  # another cell: three runs all above the law
    runs = tmp_path / "runs"
    runs.mkdir()
    records = [_record("law", "nominal", 0, law, 0.90), _record("law", "noisy", 0, law, 0.90),
               *(_record("ppo", "nominal", s, ppo[s], 0.91) for s in range(5)),
               *(_record("ppo", "noisy", s, clear[s], 0.96) for s in range(3))]
    for r in records:
        (runs / f"{r['name']}.json").write_text(json.dumps(r))
    reps = 5000
    rep = report(tmp_path, reps=reps, log=lambda s: None)
    row = next(r for r in rep["rows"] if r["scenario"] == "nominal" and r["algo"] == "ppo")
    assert (row["runs"], row["episodes_per_run"], row["episodes"]) == (5, 20, 100)
    iv = stats.interval_estimates({"x": ppo}, reps=reps)["x"]
    poi = stats.probability_of_improvement_interval(ppo, law[None, :], reps=reps)
    assert (row["score"], row["low"], row["high"]) == (iv.point, iv.low, iv.high)
    assert (row["poi"], row["poi_low"], row["poi_high"]) == (poi.point, poi.low, poi.high)
    pooled = stats.probability_of_improvement_interval(ppo.reshape(1, -1), law[None, :], reps=reps)
    assert pooled.low > 0.5 > poi.low  # what pooling the episodes would have concluded, and what the runs say
    law_row = next(r for r in rep["rows"] if r["scenario"] == "nominal" and r["algo"] == "law")
    assert (law_row["runs"], law_row["episodes_per_run"]) == (1, 20)
    assert law_row["low"] == stats.interval_estimates({"x": law[None, :]}, reps=reps)["x"].low
    verdicts = {v["scenario"]: v for v in rep["verdicts"]}
    assert verdicts["nominal"]["winner"] == "none"
    assert verdicts["nominal"]["verdict"] == "no clear winner (ppo, 5 runs x 20 episodes, vs law, 1 run x 20 episodes)"
    assert verdicts["noisy"]["verdict"] == "ppo beats law (3 runs x 20 episodes vs 1 run x 20 episodes)"
    assert verdicts["nominal"]["learned_runs_x_episodes"] == [5, 20]
    assert verdicts["noisy"]["classical_runs_x_episodes"] == [1, 20]
    headline = (tmp_path / "report" / "headline.md").read_text()
    assert "no clear winner (ppo, 5 runs x 20 episodes, vs law, 1 run x 20 episodes)" in headline
    md = (tmp_path / "report" / "comparison.md").read_text()
    assert "| nominal | ppo | 5 x 20 |" in md and "| nominal | law (best) | 1 x 20 |" in md


def test_report_refuses_runs_of_different_lengths(tmp_path: Path) -> None:
    runs = tmp_path / "runs"
    runs.mkdir()
    for r in (_record("law", "nominal", 0, np.full(4, 0.9), 0.9), _record("ppo", "nominal", 0, np.full(4, 0.9), 0.9),
              _record("ppo", "nominal", 1, np.full(3, 0.9), 0.9)):
        (runs / f"{r['name']}.json").write_text(json.dumps(r))
    with pytest.raises(ValueError, match="as many test episodes"):
        report(tmp_path, reps=10, log=lambda s: None)


# --------------------------------------------------------------------------- classical runs
def test_a_classical_run_tunes_on_validation_seeds_and_tests_on_test_seeds(tmp_path: Path,
                                                                           monkeypatch: pytest.MonkeyPatch) -> None:
    calls: list[tuple[int, int]] = []

    def recording(policy: Any, env: str, scenario: str = "nominal", n_episodes: int = 10, seed: int = TEST_SEED,
                  **kwargs: Any) -> Any:
        calls.append((seed, n_episodes))
        return evaluate(policy, env, scenario, n_episodes=n_episodes, seed=seed, **{**kwargs, "max_time": 1.0})

    monkeypatch.setattr(vnhc_gym.evaluation, "evaluate", recording)
    monkeypatch.setattr(vnhc_gym.evaluation.protocol, "evaluate", recording)
    spec = RunSpec("tuned_law", "usv", "nominal", test_episodes=4, eval_episodes=2)
    meta = sweep.run_one(spec, tmp_path)
    grid_of = CLASSICAL["tuned_law"][1]
    n_settings = math.prod(len(values) for values in grid_of.values())
    assert len(calls) == n_settings + 1
    assert all(VALIDATION_SEED <= s and s + n - 1 < TEST_SEED and n == 2 for s, n in calls[:-1])
    assert calls[-1] == (TEST_SEED, 4)
    best = max(meta["tuning"], key=lambda row: row["score"])
    assert meta["settings"] == {k: best[k] for k in grid_of} and meta["validation_score"] == best["score"]
    assert status(spec, tmp_path) == "done"


def test_local_worker_processes_give_the_same_numbers(tmp_path: Path) -> None:
    specs = grid(ENVS, ["nominal"], ["law"], [0], 1, test_episodes=3, eval_episodes=2)
    run_sweep(specs, tmp_path / "serial", log=lambda s: None)
    result = run_sweep(specs, tmp_path / "pool", jobs=2, log=lambda s: None)
    assert sorted(result["done"]) == sorted(s.stem for s in specs)
    for spec in specs:
        assert _test_metrics(tmp_path / "pool", spec) == _test_metrics(tmp_path / "serial", spec)


def test_unknown_executor() -> None:
    with pytest.raises(ValueError, match="executor"):
        run_sweep([RunSpec("law", "usv")], "unused-folder", executor="slurm", log=lambda s: None)


# --------------------------------------------------------------------------- Ray (optional)
@pytest.mark.slow
def test_ray_gives_the_local_numbers(swept: Any, tmp_path: Path) -> None:
    pytest.importorskip("ray")
    out, specs, _, _ = swept
    # The law's run (a PPO run on Ray is the same code path, at a minute more of CI).
    subset = [s for s in specs if s.seed == 0 and s.env == ENVS[0] and s.algo == "law"]
    lines: list[str] = []
    result = run_sweep([*subset, _bad_spec()], tmp_path / "ray", executor="ray", threads=1, retries=0,
                       log=lines.append)
    assert sorted(result["done"]) == sorted(s.stem for s in subset)
    assert result["failed"] == [_bad_spec().stem]
    assert "not-a-number" in (tmp_path / "ray" / "runs" / f"{_bad_spec().stem}.error").read_text()
    for spec in subset:
        assert _test_metrics(tmp_path / "ray", spec) == _test_metrics(out, spec), spec.stem


def test_a_baseline_that_cannot_act_in_a_cell_is_recorded_and_left_out(tmp_path: Path) -> None:
    """The safety filter on the flock (no velocity limit): the run is done (not retried), holds no
    test, and neither the report's runs nor a residual agent's choice of base see it."""
    spec = RunSpec("safe_law", "flocking", "nominal", test_episodes=2, eval_episodes=2)
    meta = sweep.run_one(spec, tmp_path)
    assert meta["skipped"] and meta["test"] is None and status(spec, tmp_path) == "done"
    assert load_runs(tmp_path) == [] and len(load_runs(tmp_path, skipped=True)) == 1


def test_a_residual_agents_bases_are_its_grids_classical_baselines() -> None:
    specs = grid(["usv"], ["nominal"], ["law", "tuned_law", "mpc", "ppo", "residual_ppo"], [0], 10)
    by_algo = {s.algo: s for s in specs}
    assert by_algo["residual_ppo"].bases == ("law", "tuned_law") and by_algo["ppo"].bases == ()
    with pytest.raises(ValueError, match="bases"):
        RunSpec("residual_ppo", "usv", bases=("mpc",))


def test_the_published_runs_keep_their_names() -> None:
    """Runs that name no bases keep the names (and so the records) they were published under."""
    import gzip

    path = Path(__file__).resolve().parent.parent / "docs" / "results" / "train_compare" / "runs.jsonl.gz"
    with gzip.open(path, "rt") as fh:
        records = [json.loads(line) for line in fh]
    assert len(records) > 100
    for r in records:
        spec = dict(r["spec"])
        spec["overrides"] = tuple(tuple(kv) for kv in spec.get("overrides", ()))
        assert RunSpec(**spec).stem == r["name"], r["name"]
