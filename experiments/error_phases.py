"""Where in an episode does a trained agent lose to the tuned law: reaching the constraint, or holding it?

The score of a cell is the episode's mean ``|phi~|`` over the whole horizon.  This script splits that
mean into phases of the episode (the first 0.5 s, where the law drives ``|phi~|`` down from its
start; 0.5-2 s; 2 s to the end, where the law holds the constraint to rounding error) for the tuned
law and for each trained agent given, on the same held-out test episodes (20 by default).  A learner
whose gap is in the last phase reaches the constraint as fast as the law but does not hold it
exactly: a steady error that a reward near 1 barely penalises.

Writes ``<out>/error_phases.md`` and ``.json``; the rows already in ``<out>`` of agents not given
this time (models trained on another machine) are kept, so that a published table grows.

    python experiments/error_phases.py results/tune_learners/runs/usv-nominal-sac-bounded-tuned-s0-1000k.zip
    python experiments/error_phases.py results/tune_learners/runs --match "*-sac-*" --out docs/results/error_phases
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

import numpy as np

from vnhc_gym.baselines.tuning import evaluate_classical
from vnhc_gym.benchmark import settings
from vnhc_gym.evaluation import TEST_SEED, evaluate
from vnhc_gym.stats import iqm
from vnhc_gym.tasks import task_of_env_id
from vnhc_gym.training.agents import load_agent, sidecar_of

#: Phase edges (s); the last phase runs to the end of the episode.
EDGES = (0.0, 0.5, 2.0)


def _models(items: list[str], match: str) -> list[Path]:
    """Model files named on the command line, or every best-checkpoint file of the folders named.

    In a folder, a checkpoint without its sidecar belongs to a run still training: it is left out.
    """
    out: list[Path] = []
    for item in items:
        path = Path(item)
        if path.is_dir():
            found = sorted(p for p in path.glob(match if match.endswith(".zip") else f"{match}.zip")
                           if not p.stem.endswith("-final"))
            training = [p for p in found if not p.with_suffix(".json").exists()]
            for p in training:
                print(f"{p.stem}: no sidecar yet (still training?), left out", flush=True)
            out += [p for p in found if p not in training]
        elif path.suffix == ".zip" and path.is_file():
            out.append(path)
        else:
            raise SystemExit(f"runs: {item!r} is neither a model file (.zip) nor a folder")
    if not out:
        raise SystemExit(f"runs: no model file in {items} matches {match!r}")
    return out


def phases(abs_phi: np.ndarray, dt: float) -> dict[str, float]:
    """IQM over episodes of each phase's mean ``|phi~|`` (and of the whole horizon's), with the share
    of the whole-horizon mean that each phase contributes."""
    trace = abs_phi[1:]  # after each step, as the score counts it
    t = np.arange(1, trace.shape[0] + 1) * dt
    bounds = [*EDGES, np.inf]
    out: dict[str, float] = {"whole": iqm(np.nanmean(trace, axis=0))}
    total = np.nansum(trace, axis=0)
    for lo, hi in zip(bounds[:-1], bounds[1:], strict=True):
        rows = (t > lo) & (t <= hi)
        label = f"{lo:g}-{hi:g} s" if np.isfinite(hi) else f"{lo:g} s-end"
        out[label] = iqm(np.nanmean(trace[rows], axis=0))
        out[f"share {label}"] = float(np.median(np.nansum(trace[rows], axis=0) / total))
    return out


def merged(fresh: list[dict[str, Any]], kept: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """The fresh rows, and those of ``kept`` (an earlier table's) for agents not evaluated this time.

    Rows are ordered by cell (the tuned law first, then the agents by name).  A cell's law row is
    recomputed whenever one of its agents is evaluated, so only the cells not evaluated keep theirs.
    """
    def key(r: dict[str, Any]) -> tuple[str, str, str]:
        return r["env"], r["scenario"], r["policy"]

    have = {key(r) for r in fresh}
    cells_here = {key(r)[:2] for r in fresh}
    rows = fresh + [r for r in kept if key(r) not in have
                    and not (r["policy"] == "tuned law" and key(r)[:2] in cells_here)]
    return sorted(rows, key=lambda r: (r["env"], r["scenario"], r["policy"] != "tuned law", r["policy"]))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("runs", nargs="+", help="model files, or folders of runs (their best checkpoints)")
    ap.add_argument("--match", default="*", help="glob of the model names in a folder (default every run)")
    ap.add_argument("--episodes", type=int, default=20, help="held-out test episodes")
    ap.add_argument("--out", default="results/error_phases")
    args = ap.parse_args()
    rows: list[dict[str, Any]] = []
    laws: dict[tuple[str, str], dict[str, Any]] = {}
    for path in _models(args.runs, args.match):
        side = sidecar_of(path)
        env_id, scenario = str(side["env_id"]), str(side.get("scenario", "nominal"))
        if (env_id, scenario) not in laws:
            gains = settings().get(task_of_env_id(env_id).name, {}).get(scenario, {}).get("tuned_law", {})
            law = evaluate_classical("tuned_law", gains, env_id, scenario, args.episodes, TEST_SEED)
            laws[(env_id, scenario)] = {"policy": "tuned law", "env": env_id, "scenario": scenario,
                                        **phases(law.abs_phi_sf, law.dt)}
            rows.append(laws[(env_id, scenario)])
        res = evaluate(load_agent(path), env_id, scenario, args.episodes, TEST_SEED)
        rows.append({"policy": path.stem, "env": env_id, "scenario": scenario, **phases(res.abs_phi_sf, res.dt)})
        print(f"{path.stem}: whole {rows[-1]['whole']:.3g} (law {laws[(env_id, scenario)]['whole']:.3g})", flush=True)
    out = Path(args.out)
    if (out / "error_phases.json").exists():
        rows = merged(rows, json.loads((out / "error_phases.json").read_text()))
    labels = [k for k in rows[0] if k not in ("policy", "env", "scenario", "whole") and not k.startswith("share")]
    lines = [f"IQM over {args.episodes} test episodes of the mean |phi~| in each phase, and the median share of "
             "the episode's whole mean from the last phase.", "",
             "| cell | policy | whole | " + " | ".join(labels) + f" | share {labels[-1]} |",
             "|---|---|---:|" + "---:|" * (len(labels) + 1)]
    for r in rows:
        cells = " | ".join(f"{r[k]:.2e}" for k in labels)
        lines.append(f"| {r['env'].split('/')[-1]} {r['scenario']} | {r['policy']} | {r['whole']:.2e} | {cells} | "
                     f"{r['share ' + labels[-1]]:.0%} |")
    out.mkdir(parents=True, exist_ok=True)
    (out / "error_phases.json").write_text(json.dumps(rows, indent=1))
    (out / "error_phases.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
