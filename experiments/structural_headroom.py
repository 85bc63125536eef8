"""Where the model is wrong in structure, how much a controller that knows the truth gains over the
classical side at full strength: read from the comparison grid's records.

For each task and each scenario that hides structure from the controller (``delay``, ``lag``,
``unmodelled``) it takes the grid's runs (``experiments/train_compare.py``): the oracle (which
reads the delay's queue, the actuator's state and the forces the model lacks), the informed law
(told the hidden quantities, not the state), the law with k = 5 and the cell's best classical
baseline (chosen on validation episodes among every classical candidate, the predictor bank and the
disturbance observer included).  The headroom is the oracle's test score minus the best classical
one's, paired over the same test episodes, with a percentile bootstrap 95 % interval; the
information part is the oracle above the informed law.  It prints a Markdown table and, with
``--out``, writes it with a JSON of the numbers.

    python experiments/structural_headroom.py --records docs/results/train_compare/runs.jsonl.gz
    python experiments/structural_headroom.py --runs results/train_compare   # a grid's output directory
"""

from __future__ import annotations

import argparse
import gzip
import json
from pathlib import Path
from typing import Any

import numpy as np

from vnhc_gym.envs.config import STRUCTURAL
from vnhc_gym.sweep import CLASSICAL_ALGOS, load_runs

#: Headroom that counts (the oracle's score above the best classical's), as the acceptance states it.
CLEAR = 0.02


def paired_interval(diff: np.ndarray, reps: int = 10_000, seed: int = 0) -> tuple[float, float]:
    """The percentile bootstrap 95 % interval of the mean of paired differences (episodes redrawn)."""
    rng = np.random.default_rng(seed)
    means = diff[rng.integers(0, diff.size, (reps, diff.size))].mean(axis=1)
    return float(np.percentile(means, 2.5)), float(np.percentile(means, 97.5))


def read(args: argparse.Namespace) -> list[dict[str, Any]]:
    """The finished runs of a records file or a grid directory."""
    if args.records:
        with gzip.open(args.records, "rt", encoding="utf-8") as fh:
            return [r for r in map(json.loads, fh) if not r.get("skipped")]
    return load_runs(args.runs)


def scores(run: dict[str, Any]) -> np.ndarray:
    test = run["test"]
    if isinstance(test, str):  # an older record's repr
        raise ValueError(f"run {run['name']}: its test metrics are not JSON")
    return np.asarray(test["metrics"]["score"], dtype=np.float64)


def cell(runs: list[dict[str, Any]]) -> dict[str, Any] | None:
    """The references, the law and the best classical baseline of one cell, with the headroom."""
    by = {r["spec"]["algo"]: r for r in runs}
    if "oracle" not in by:
        return None
    classical = [r for a, r in by.items() if a in CLASSICAL_ALGOS and r.get("validation_score") is not None]
    if not classical:
        return None
    best = max(classical, key=lambda r: r["validation_score"])
    oracle = scores(by["oracle"])
    row: dict[str, Any] = {
        "oracle": float(oracle.mean()), "oracle_success": float(np.mean(by["oracle"]["test"]["metrics"]["success"])),
        "best": best["spec"]["algo"], "best_settings": best.get("settings"), "best_score": float(scores(best).mean()),
        "law": float(scores(by["law"]).mean()) if "law" in by else None,
    }
    diff = oracle - scores(best)
    row["headroom"] = float(diff.mean())
    row["headroom_interval"] = paired_interval(diff)
    if "informed_actuated" in by:
        informed = scores(by["informed_actuated"])
        row["informed"] = float(informed.mean())
        row["information"] = float((oracle - informed).mean())
    row["certified"] = row["headroom"] >= CLEAR and row["headroom_interval"][0] > 0
    return row


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    source = parser.add_mutually_exclusive_group(required=True)
    source.add_argument("--records", type=Path, help="a published grid's runs.jsonl.gz")
    source.add_argument("--runs", type=Path, help="a grid's output directory")
    parser.add_argument("--out", type=Path, default=None, help="write headroom.md and headroom.json here")
    args = parser.parse_args()
    runs = read(args)
    cells: dict[tuple[str, str], list[dict[str, Any]]] = {}
    for r in runs:
        if r["spec"]["scenario"] in STRUCTURAL:
            cells.setdefault((r["spec"]["env"], r["spec"]["scenario"]), []).append(r)
    lines = ["| task | scenario | law (k = 5) | best classical | informed | oracle | headroom [95 %] | "
             "oracle above informed |", "|---|---|---|---|---|---|---|---|"]
    out = []
    for (task, scenario), rs in sorted(cells.items()):
        row = cell(rs)
        if row is None:
            continue
        out.append({"task": task, "scenario": scenario, **row})
        lo, hi = row["headroom_interval"]
        law = "" if row["law"] is None else f"{row['law']:.4f}"
        informed = f"{row['informed']:.4f}" if "informed" in row else ""
        information = f"{row['information']:+.4f}" if "information" in row else ""
        mark = " **certified**" if row["certified"] else ""
        oracle = f"{row['oracle']:.4f} ({row['oracle_success']:.0%})"
        lines.append(f"| {task} | {scenario} | {law} | {row['best']} {row['best_score']:.4f} | {informed} | {oracle} | "
                     f"{row['headroom']:+.4f} [{lo:+.4f}, {hi:+.4f}]{mark} | {information} |")
    n = sum(r["certified"] for r in out)
    lines.append("")
    lines.append(f"{n} of {len(out)} cells: the oracle {CLEAR} or more above the best classical baseline, "
                 f"the interval above 0.")
    text = "\n".join(lines) + "\n"
    print(text)
    if args.out is not None:
        args.out.mkdir(parents=True, exist_ok=True)
        (args.out / "headroom.md").write_text(text)
        (args.out / "headroom.json").write_text(json.dumps(out, indent=1) + "\n")


if __name__ == "__main__":
    main()
