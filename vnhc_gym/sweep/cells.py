"""The statistics of a sweep's cells (an environment and a scenario): its runs grouped per algorithm
(`Cell`), and per algorithm the row of numbers a report writes (the score's interval, the success
rate, the diagnostics, the probability of improvement over the best classical baseline, the steps
and seconds to parity)."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from vnhc_gym.sweep.specs import CLASSICAL_ALGOS, LEARNED_ALGOS, REFERENCE_ALGOS, RESIDUAL_ALGOS, algo_of, label

#: The metric of every choice and table (its mean over episodes), higher is better.
SCORE = "score"


@dataclass
class Cell:
    env: str
    scenario: str
    runs: dict[str, list[dict[str, Any]]] = field(default_factory=dict)


def _episodes(rs: list[dict[str, Any]], metric: str) -> NDArray[np.float64]:
    """The test episodes' values of ``metric``, pooled over a cell's runs of one algorithm."""
    return np.concatenate([np.asarray(r["test"]["metrics"][metric], dtype=np.float64) for r in rs])


def _by_run(rs: list[dict[str, Any]], metric: str) -> NDArray[np.float64]:
    """The test episodes' values of ``metric``, a row per run: ``(n_runs, n_episodes)``, the shape the
    intervals of `vnhc_gym.stats` resample (the runs, and the episodes shared by them)."""
    rows = [np.asarray(r["test"]["metrics"][metric], dtype=np.float64) for r in rs]
    if len({row.size for row in rows}) > 1:
        raise ValueError(f"the runs of one cell and algorithm must have as many test episodes each, got "
                         f"{ {r['name']: row.size for r, row in zip(rs, rows, strict=True)} }")
    return np.stack(rows)


def _parity(r: dict[str, Any], target: float, residual: bool) -> tuple[float | None, float | None]:
    """Env steps and training seconds from the agent's own start until its validation score reaches
    ``target`` (a residual agent, which starts at its base: until the lower end of its score's
    interval is above its base's validation score, i.e. it beats its base), or ``None``."""
    curve = [p for p in r.get("curve", []) if p["steps"] > 0 and "score" in p]
    if residual:
        start = next((p for p in r.get("curve", []) if p["steps"] == 0 and "score" in p), None)
        if start is None:
            return None, None
        hit = next((p for p in curve if p["score_low"] > start["score"]), None)
    else:
        hit = next((p for p in curve if p["score"] >= target), None)
    return (None, None) if hit is None else (float(hit["steps"]), float(hit["wall"]))


def _has_intervals(r: dict[str, Any]) -> bool:
    """Whether every validation point of a run's curve carries its interval (`_parity` needs them)."""
    return all("score_low" in p for p in r.get("curve", []) if "score" in p)


def _validation_score(r: dict[str, Any]) -> float:
    """A run's validation score: a classical run's tuned setting's, a learned run's best checkpoint's
    (the model its test evaluates).  Choices between algorithms read this, never the test episodes."""
    if "validation_score" in r:
        return float(r["validation_score"])
    return max((float(p["score"]) for p in r.get("curve", []) if "score" in p), default=-math.inf)


def _cells(runs: list[dict[str, Any]], log: Callable[[str], None]) -> dict[tuple[str, str], Cell]:
    """The runs grouped by cell (environment, scenario) and algorithm; a run without a score (an
    older format) is left out, and ``log`` says so."""
    cells: dict[tuple[str, str], Cell] = {}
    for r in runs:
        spec = r["spec"]
        if "score" not in r["test"]["metrics"]:
            log(f"report: {r['name']} has no score (an older format): skipped")
            continue
        cell = cells.setdefault((spec["env"], spec["scenario"]), Cell(spec["env"], spec["scenario"]))
        cell.runs.setdefault(label(spec["algo"], spec.get("backend", "sb3")), []).append(r)
    return cells


def _rows(cells: dict[tuple[str, str], Cell], reps: int) -> list[dict[str, Any]]:
    """A row per cell and algorithm: the numbers of `report`, with ``reps`` bootstrap replicates per
    interval."""
    from vnhc_gym import stats

    rows: list[dict[str, Any]] = []
    for (env, scenario), cell in sorted(cells.items()):
        classical = {a: rs[0] for a, rs in cell.runs.items() if a in CLASSICAL_ALGOS}
        best_name = max(classical, key=lambda a: classical[a]["validation_score"]) if classical else None
        best_scores = _by_run([classical[best_name]], SCORE) if best_name else None
        for algo, rs in sorted(cell.runs.items()):
            values = _by_run(rs, SCORE)  # (runs, episodes): a classical baseline has one run
            iv = stats.interval_estimates({"x": values}, metric="mean", reps=reps)["x"]
            row: dict[str, Any] = {
                "env": env, "scenario": scenario, "algo": algo, "runs": len(rs), "episodes": int(values.size),
                "episodes_per_run": int(values.shape[1]), "score": iv.point, "low": iv.low, "high": iv.high,
                "success": float(np.mean(_episodes(rs, "success"))),
                "iqm_abs_phi_sf": stats.iqm(_episodes(rs, "mean_abs_phi_sf")),
                "horizon_abs_phi_sf": float(np.mean(_episodes(rs, "horizon_abs_phi_sf"))),
                "validation_score": float(np.mean([_validation_score(r) for r in rs])),
                "kind": ("learned" if algo_of(algo) in LEARNED_ALGOS else "reference" if algo in REFERENCE_ALGOS
                         else "classical"),
                "best_classical": best_name,
                "settings": rs[0].get("settings"),
            }
            if algo_of(algo) in RESIDUAL_ALGOS:
                # The base(s) its runs corrected, from their configs (no base named: the law).
                bases = {str(r["config"].get("residual_base") or "law") for r in rs if "config" in r}
                if bases:
                    row["base"] = ", ".join(sorted(bases))
            if "solve_seconds_per_step" in rs[0]:  # the planning baseline's cost, beside its score
                row["solve_ms_per_step"] = 1e3 * float(np.mean([r["solve_seconds_per_step"] for r in rs]))
            if algo_of(algo) in LEARNED_ALGOS and best_scores is not None:
                poi = stats.probability_of_improvement_interval(values, best_scores, reps=reps)
                row.update({"poi": poi.point, "poi_low": poi.low, "poi_high": poi.high})
                target = float(classical[best_name]["validation_score"])  # type: ignore[index]
                residual = algo_of(algo) in RESIDUAL_ALGOS
                # A residual run's parity reads its curve's intervals; a run that recorded none (the
                # compiled trainer's before it kept them) is left out of the count, not counted a miss.
                judged = [r for r in rs if not residual or _has_intervals(r)]
                reached = [_parity(r, target, residual) for r in judged]
                hit = [p for p in reached if p[0] is not None]
                row["parity_hits"], row["parity_judged"] = len(hit), len(judged)
                row["parity_runs"] = f"{len(hit)}/{len(judged)}" if judged else "not recorded"
                # The median over the runs, counting a run that never got there as slower than any
                # that did: defined only when at least half of the runs reached parity.
                if 2 * len(hit) > len(judged):
                    missing = [math.inf] * (len(judged) - len(hit))
                    order = sorted(float(p[0] or 0.0) for p in hit) + missing
                    walls = sorted(float(p[1] or 0.0) for p in hit) + missing
                    row["parity_steps"] = order[(len(judged) - 1) // 2]
                    row["parity_seconds"] = walls[(len(judged) - 1) // 2]
                else:
                    row["parity_steps"] = row["parity_seconds"] = None
            rows.append(row)
    return rows
