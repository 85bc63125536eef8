"""Where do the learning curves flatten?  Read from the comparison's run records.

For each task and learner of a comparison (``runs.jsonl.gz`` of a published report, or a grid's
output folder), every run's validation curve (the score on the validation episodes at each of its
evaluation points): the share of the run's whole improvement (its best validation score minus its
score at step 0) reached by each fraction of the budget, and the step by which 90 % and 99 % of it
were reached, each the median over the runs and the cells.  A curve that has flattened reaches 99 %
well before its last point; a budget can be cut to where the runs reach it.  Writes
``<out>/budgets.md``, ``.json`` and ``budgets.png`` (the median normalised curve of each task and
learner).

    python experiments/budgets.py                                             # the published report
    python experiments/budgets.py --records ~/.cache/vnhc_gym_runs/train_compare/runs
"""

from __future__ import annotations

import argparse
import gzip
import json
from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np

FRACTIONS = (0.25, 0.5, 0.75)


def load(records: Path) -> list[dict[str, Any]]:
    """The learned runs' sidecars: a ``runs.jsonl.gz`` file or a folder of ``*.json`` sidecars."""
    if records.is_dir():
        runs = [json.loads(p.read_text()) for p in sorted(records.glob("*.json"))]
    else:
        with gzip.open(records, "rt") as f:
            runs = [json.loads(line) for line in f]
    return [r for r in runs if r.get("curve")]


def normalised(curve: list[dict[str, float]]) -> tuple[np.ndarray, np.ndarray] | None:
    """(steps as a fraction of the budget, the running best validation score as a fraction of the
    run's whole improvement); None for a run that never improved on its start."""
    steps = np.array([p["steps"] for p in curve], dtype=float)
    best = np.maximum.accumulate(np.array([p["score"] for p in curve], dtype=float))
    gain = best[-1] - best[0]
    if not gain > 1e-9:
        return None
    return steps / steps[-1], (best - best[0]) / gain


def summarise(runs: list[dict[str, Any]]) -> list[dict[str, Any]]:
    groups: dict[tuple[str, str], list[tuple[np.ndarray, np.ndarray, int]]] = defaultdict(list)
    flat: dict[tuple[str, str], int] = defaultdict(int)
    for r in runs:
        key = (r["env_id"].split("/")[-1], r.get("sweep_algo") or r["algo"])
        n = normalised(r["curve"])
        if n is None:
            flat[key] += 1
        else:
            groups[key].append((*n, int(r["n_timesteps"])))
    rows = []
    for key in sorted(set(groups) | set(flat)):
        curves = groups.get(key, [])
        row: dict[str, Any] = {"env": key[0], "algo": key[1], "runs": len(curves), "never_improved": flat[key]}
        if curves:
            budget = int(np.median([c[2] for c in curves]))
            for f in FRACTIONS:
                row[f"reached_at_{f:g}"] = float(np.median([np.interp(f, x, y) for x, y, _ in curves]))
            for level in (0.9, 0.99):
                row[f"steps_to_{level:g}"] = float(np.median([x[np.argmax(y >= level)] for x, y, _ in curves])) * budget
            row["budget"] = budget
        rows.append(row)
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--records", default="docs/results/train_compare/runs.jsonl.gz",
                    help="a runs.jsonl.gz file or a folder of run sidecars")
    ap.add_argument("--out", default="docs/results/budgets")
    args = ap.parse_args()
    runs = load(Path(args.records))
    rows = summarise(runs)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "budgets.json").write_text(json.dumps(rows, indent=1) + "\n")
    head = " | ".join(f"at {f:g} of the budget" for f in FRACTIONS)
    lines = [f"| env | learner | runs | never improved | {head} | 90 % by (steps) | 99 % by (steps) | budget |",
             "|---|---|---:|---:|" + "---:|" * (len(FRACTIONS) + 3)]
    for r in rows:
        if not r["runs"]:
            lines.append(f"| {r['env']} | {r['algo']} | 0 | {r['never_improved']} |" + " |" * (len(FRACTIONS) + 3))
            continue
        reached = " | ".join(f"{r[f'reached_at_{f:g}']:.2f}" for f in FRACTIONS)
        lines.append(f"| {r['env']} | {r['algo']} | {r['runs']} | {r['never_improved']} | {reached} | "
                     f"{r['steps_to_0.9']:.3g} | {r['steps_to_0.99']:.3g} | {r['budget']:.3g} |")
    table = "\n".join(lines) + "\n"
    (out / "budgets.md").write_text(table)
    print(table)
    plot(runs, out / "budgets.png")


def plot(runs: list[dict[str, Any]], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    groups: dict[tuple[str, str], list[np.ndarray]] = defaultdict(list)
    grid = np.linspace(0.0, 1.0, 41)
    for r in runs:
        n = normalised(r["curve"])
        if n is not None:
            groups[(r["env_id"].split("/")[-1], r.get("sweep_algo") or r["algo"])].append(np.interp(grid, *n))
    envs = sorted({k[0] for k in groups})
    fig, axes = plt.subplots(1, max(1, len(envs)), figsize=(3.2 * max(1, len(envs)), 3.0), sharey=True, squeeze=False)
    for ax, env in zip(axes[0], envs, strict=False):
        for (e, algo), curves in sorted(groups.items()):
            if e == env:
                ax.plot(grid, np.median(curves, axis=0), label=f"{algo} ({len(curves)})")
        ax.set_title(env, fontsize=9)
        ax.set_xlabel("fraction of the budget")
        ax.axhline(0.99, color="grey", lw=0.5, ls=":")
        ax.legend(fontsize=7)
    axes[0][0].set_ylabel("share of the run's improvement")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


if __name__ == "__main__":
    main()
