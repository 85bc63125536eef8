"""The report of a sweep (`report`): its cells' statistics, written as tables, verdicts and figures
in ``<out>/report``."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

from vnhc_gym.sweep.cells import _cells, _rows
from vnhc_gym.sweep.figures import _figures, _verdict_figure
from vnhc_gym.sweep.records import load_runs
from vnhc_gym.sweep.verdicts import _write_backends, _write_headline, _write_tables

#: Bootstrap replicates of every interval of a report: rliable's default.  A verdict compares an end
#: of an interval with 0.5, and with 2000 replicates the Monte Carlo error of that end (about 0.005
#: on the probability of improvement) can decide a verdict by itself; with 50 000 it is about 0.001.
REPORT_REPS = 50_000


def report(out: str | Path, reps: int = REPORT_REPS, log: Callable[[str], None] = print) -> dict[str, Any]:
    """Tables and figures from the run outputs alone (wherever they ran), in ``out/report``.

    Per cell (environment, scenario) and algorithm: the mean ``score`` over the test episodes of
    all its runs with its 95 % two-level bootstrap interval (`vnhc_gym.stats.interval_estimates`:
    the test episodes redrawn, the same for every run, and the training runs; a classical baseline
    or the oracle is one run), the success rate (episodes that reached the time limit), and the
    diagnostics (the IQM of the completed steps' ``mean |phi~|``, the termination-aware mean
    ``|phi~|``).  The cell's best classical baseline and its best learned agent are the ones with
    the highest *validation* score (chosen without the test episodes); the oracle is the headroom
    reference.  For each learned agent: the probability that one of its episodes scores above one
    of the best classical baseline's, with its interval (the agent's runs and their episodes
    redrawn, and the baseline's episodes: `vnhc_gym.stats.probability_of_improvement_interval`),
    and the median env steps and seconds to parity (`_parity`) over its runs, or "not reached".
    Every row and verdict states the runs x episodes it rests on.  ``reps``: bootstrap replicates of
    each interval (`REPORT_REPS` by default).
    Files: ``comparison.{json,csv,md}`` (every row), ``headline.md`` (one line a cell: the oracle,
    the best classical, the best learned and the verdict), ``verdict.png`` (the same at a glance),
    ``learning_curves_<env>.png``, ``performance_profile.png``, ``backends.{md,json}`` when a
    learner has runs on both backends in a cell (the compiled runs' score against the SB3 runs'
    interval, cell by cell), and ``cost.md`` (what the runs took, `_write_cost`).
    """
    runs = load_runs(out)
    dest = Path(out) / "report"
    dest.mkdir(parents=True, exist_ok=True)
    codes = sorted({r.get("code", "?") for r in runs})
    if len(codes) > 1:
        log(f"report: WARNING: the runs come from {len(codes)} code versions {codes}; numbers may not compare")
    cells = _cells(runs, log)
    rows = _rows(cells, reps)
    (dest / "comparison.json").write_text(json.dumps(rows, indent=1))
    _write_tables(rows, dest)
    verdicts = _write_headline(rows, dest)
    _write_backends(rows, dest)
    _write_cost(runs, dest)
    figures = [*_verdict_figure(rows, dest), *_figures(cells, dest)]
    log(f"report: {len(runs)} runs, {len(cells)} cells -> {dest}")
    return {"rows": rows, "verdicts": verdicts, "figures": figures, "codes": codes}


def _write_cost(runs: list[dict[str, Any]], dest: Path) -> None:
    """``cost.md``: per algorithm, its runs and the minutes they took on one core each (the sum of
    their wall times, each measured with the sweep's other jobs on the other cores; a compiled
    program that trained several seeds counts once), and that divided by two: the wall time of
    those runs on two cores, one job a core."""
    minutes: dict[str, float] = {}
    count: dict[str, int] = {}
    programs = set()
    for r in runs:
        algo = str(r.get("sweep_algo", r["spec"]["algo"]))
        count[algo] = count.get(algo, 0) + 1
        program = (algo, r["spec"]["env"], r["spec"]["scenario"], r.get("run_wall"))
        if r.get("run_wall") is None or program in programs:
            continue
        programs.add(program)
        minutes[algo] = minutes.get(algo, 0.0) + float(r["run_wall"]) / 60.0
    lines = ["| algorithm | runs | core-minutes | minutes on 2 cores |", "|---|---:|---:|---:|"]
    for a in sorted(count):
        lines.append(f"| {a} | {count[a]} | {minutes.get(a, 0.0):.1f} | {minutes.get(a, 0.0) / 2:.1f} |")
    total = sum(minutes.values())
    lines.append(f"| all | {sum(count.values())} | {total:.1f} | {total / 2:.1f} |")
    (dest / "cost.md").write_text("\n".join(lines) + "\n")
