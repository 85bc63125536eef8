"""The written verdicts of a sweep's report: `verdict` (a cell's winner, from the best learned agent's
probability of improvement), the reasons behind it, ``headline.md`` and ``verdicts.json`` (a line a
cell), the tables ``comparison.csv`` and ``comparison.md`` (a row per cell and algorithm), and
``backends.md`` (each learner trained on both backends, cell by cell)."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

from vnhc_gym.sweep.specs import RESIDUAL_ALGOS, SWEEP_BACKENDS, algo_of, label


def _fmt(x: float | None) -> str:
    return "n/a" if x is None else f"{x:.3g}"


def _score(r: dict[str, Any]) -> str:
    return f"{r['score']:.4f} [{r['low']:.4f}, {r['high']:.4f}]"


def _basis(r: dict[str, Any]) -> str:
    """The data a row rests on, e.g. ``"5 runs x 20 episodes"``."""
    n = int(r["runs"])
    return f"{n} run{'' if n == 1 else 's'} x {int(r['episodes_per_run'])} episodes"


def _p(v: float) -> str:
    """A probability to two decimals, or three where two would round an end onto 0.5 (where the verdict
    turns): 0.499 and 0.501 must not both read 0.50."""
    return f"{v:.3f}" if v != 0.5 and f"{v:.2f}" == "0.50" else f"{v:.2f}"


def _poi(r: dict[str, Any]) -> str:
    return f"{_p(r['poi'])} [{_p(r['poi_low'])}, {_p(r['poi_high'])}]"


def _parity_text(r: dict[str, Any]) -> tuple[str, str]:
    if "parity_runs" not in r:
        return "", ""
    if not r.get("parity_judged", 1):
        return "not recorded", "not recorded"
    if r["parity_steps"] is None:
        return f"not reached ({r['parity_runs']})", "not reached"
    return f"{r['parity_steps']:.3g} ({r['parity_runs']})", f"{r['parity_seconds']:.0f}"


def _write_tables(rows: list[dict[str, Any]], dest: Path) -> None:
    import csv

    keys = ["env", "scenario", "algo", "kind", "runs", "episodes_per_run", "episodes", "score", "low", "high",
            "success", "iqm_abs_phi_sf", "horizon_abs_phi_sf", "best_classical", "poi", "poi_low", "poi_high",
            "parity_steps", "parity_seconds", "parity_runs", "solve_ms_per_step"]
    with open(dest / "comparison.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=keys, extrasaction="ignore")
        w.writeheader()
        w.writerows(rows)
    lines = []
    for env in sorted({r["env"] for r in rows}):
        lines += [f"### {env}", "",
                  "| scenario | algo | runs x episodes | score [95% CI] | success | IQM mean abs phi~ "
                  "| P(beats best classical) | steps to parity | s to parity |",
                  "|---|---|---:|---|---:|---:|---|---:|---:|"]
        for r in (r for r in rows if r["env"] == env):
            best = " (best)" if r["algo"] == r["best_classical"] else ""
            if "solve_ms_per_step" in r:
                best += f" ({r['solve_ms_per_step']:.0f} ms/step)"
            steps, secs = _parity_text(r)
            lines.append(f"| {r['scenario']} | {r['algo']}{best} | {r['runs']} x {r['episodes_per_run']} | {_score(r)} "
                         f"| {r['success']:.2f} | "
                         f"{_fmt(r['iqm_abs_phi_sf'])} | {_poi(r) if 'poi' in r else ''} | {steps} | {secs} |")
        lines.append("")
    (dest / "comparison.md").write_text("\n".join(lines))


def placement(score: float, low: float, high: float) -> str:
    """Where a score falls against an interval: ``"below"``, ``"within"`` (ends included) or ``"above"``."""
    return "below" if score < low else "above" if score > high else "within"


def _write_backends(rows: list[dict[str, Any]], dest: Path) -> list[dict[str, Any]]:
    """``backends.{md,json}``: every learner with runs on Stable-Baselines3 and on another backend in a
    cell, the other backend's score placed against the SB3 runs' interval (both intervals over
    training runs, then episodes), and whether the two intervals overlap.  Nothing is written when
    no cell has both.  Returns the entries."""
    by = {(r["env"], r["scenario"], r["algo"]): r for r in rows}
    entries = []
    for r in rows:
        backend = r["algo"].rsplit("-", 1)[-1]
        if backend not in SWEEP_BACKENDS or r["algo"] == algo_of(r["algo"]):
            continue
        sb3 = by.get((r["env"], r["scenario"], label(algo_of(r["algo"]))))
        if sb3 is None:
            continue
        entries.append({"env": r["env"], "scenario": r["scenario"], "algo": algo_of(r["algo"]), "backend": backend,
                        "sb3": {k: sb3[k] for k in ("score", "low", "high", "runs", "base") if k in sb3},
                        "other": {k: r[k] for k in ("score", "low", "high", "runs", "base") if k in r},
                        "placement": placement(r["score"], sb3["low"], sb3["high"]),
                        "overlap": bool(r["low"] <= sb3["high"] and sb3["low"] <= r["high"])})
    if not entries:
        return entries
    (dest / "backends.json").write_text(json.dumps(entries, indent=1))
    lines = ["| task | scenario | learner | SB3: score [95% CI] (runs) | other backend: score [95% CI] (runs) "
             "| its score against SB3's interval | intervals overlap |", "|---|---|---|---|---|---|---|"]
    for e in entries:
        # A residual learner's score is its base's plus what it learned: the bases are named, since
        # the two backends may correct different ones.
        on = {k: f" on {e[k]['base']}" if e[k].get("base") else "" for k in ("sb3", "other")}
        lines.append(f"| {e['env']} | {e['scenario']} | {e['algo']} | "
                     f"{_score(e['sb3'])} ({e['sb3']['runs']}){on['sb3']} | "
                     f"{e['backend']}: {_score(e['other'])} ({e['other']['runs']}){on['other']} | {e['placement']} | "
                     f"{'yes' if e['overlap'] else 'no'} |")
    for (algo, backend) in sorted({(e["algo"], e["backend"]) for e in entries}):
        these = [e for e in entries if (e["algo"], e["backend"]) == (algo, backend)]
        counts = ", ".join(f"{sum(e['placement'] == p for e in these)} {p}" for p in ("below", "within", "above"))
        apart = sum(not e["overlap"] for e in these)
        differ = sum(e["sb3"].get("base") != e["other"].get("base") for e in these)
        lines.append(f"\n{algo} on {backend} against SB3, {len(these)} cell{'' if len(these) == 1 else 's'}: "
                     f"{counts} SB3's interval; "
                     f"the intervals are apart in {apart}" + (f"; the bases differ in {differ}." if differ else "."))
    (dest / "backends.md").write_text("\n".join(lines) + "\n")
    return entries


def verdict(best_learned: dict[str, Any] | None, best: dict[str, Any] | None) -> tuple[str, str]:
    """The verdict of a cell, ``(winner, words)``, from the best learned agent's probability of
    improvement over the best classical baseline: its interval above 0.5 (``"learned"``), below 0.5
    (``"classical"``), across it (``"none"``), or no learned agent yet (``"incomplete"``).  The
    words name the runs x episodes of both sides, the data the verdict rests on."""
    if best_learned is None or best is None or "poi" not in best_learned:
        return "incomplete", "incomplete"
    learned, classical = best_learned["algo"], best["algo"]
    if best_learned["poi_low"] > 0.5:
        return "learned", f"{learned} beats {classical} ({_basis(best_learned)} vs {_basis(best)})"
    if best_learned["poi_high"] < 0.5:
        return "classical", (f"{classical} beats every learned agent ({learned}, {_basis(best_learned)}, "
                             f"vs {_basis(best)})")
    return "none", f"no clear winner ({learned}, {_basis(best_learned)}, vs {classical}, {_basis(best)})"


def _cell_rows(rows: list[dict[str, Any]]) -> list[tuple[str, str, dict[str, dict[str, Any]]]]:
    cells = sorted({(r["env"], r["scenario"]) for r in rows})
    return [(e, s, {r["algo"]: r for r in rows if r["env"] == e and r["scenario"] == s}) for e, s in cells]


def _write_headline(rows: list[dict[str, Any]], dest: Path) -> list[dict[str, Any]]:
    """``headline.md``: a line a cell: the oracle, the best classical baseline, the best learned agent
    (the highest mean validation score over its runs), each with the score's interval and success
    rate, the probability of improvement, steps and seconds to parity, and the verdict with the runs
    x episodes it rests on."""
    lines = ["Mean score over held-out test episodes (the return over the fixed horizon per step, in [0, 1]; "
             "a failed episode's remaining steps count 0), its 95 % bootstrap interval and the success rate "
             "(episodes that reached the time limit). P: the probability that an episode of the best learned agent "
             "scores above one of the best classical baseline's, with its 95 % interval (**bold**: above 0.5). "
             "A learned agent's intervals redraw its training runs and the test episodes (the same seeds in every "
             "run); a classical baseline is one run. Each verdict names the runs x episodes it rests on.", "",
             "| env | scenario | oracle | best classical | best learned | P | steps / s to parity | verdict |",
             "|---|---|---|---|---|---|---|---|"]
    verdicts = []
    for env, scenario, cell in _cell_rows(rows):
        oracle = cell.get("oracle")
        best = next((r for r in cell.values() if r["algo"] == r["best_classical"]), None)
        learned = [r for r in cell.values() if r["kind"] == "learned"]
        # Chosen on validation episodes, like the best classical baseline: picking the agent with the
        # best test score would bias its probability of improvement upwards.
        top = max(learned, key=lambda r: r["validation_score"]) if learned else None
        winner, words = verdict(top, best)
        # The reference told what the cell hides: the actuator's structure where it hides one.
        informed = cell.get("informed_actuated") or cell.get("informed_kalman")
        why = _why(winner, oracle, best, top, learned, env, scenario, informed)
        verdicts.append({"env": env, "scenario": scenario, "verdict": words, "winner": winner, "why": why,
                         "best_classical": best["algo"] if best else None, "best_learned": top["algo"] if top else None,
                         "poi_low": top.get("poi_low") if top else None,
                         "learned_runs_x_episodes": [top["runs"], top["episodes_per_run"]] if top else None,
                         "classical_runs_x_episodes": [best["runs"], best["episodes_per_run"]] if best else None})

        def entry(r: dict[str, Any] | None, name: bool = True) -> str:
            if r is None:
                return ""
            return (f"{r['algo']} " if name else "") + f"{_score(r)}, {r['success']:.0%}"

        poi = ""
        if top is not None and "poi" in top:
            poi = f"**{_poi(top)}**" if top["poi_low"] > 0.5 else _poi(top)
        steps, secs = _parity_text(top) if top is not None else ("", "")
        lines.append(f"| {env} | {scenario} | {entry(oracle, name=False)} | {entry(best)} | {entry(top)} | {poi} | "
                     f"{steps} / {secs} | {words}{': ' + why if why else ''} |")
    lines += ["", *_verdict_summary(verdicts)]
    (dest / "headline.md").write_text("\n".join(lines) + "\n")
    (dest / "verdicts.json").write_text(json.dumps(verdicts, indent=1))
    return verdicts


#: A best classical baseline this close to the oracle (in score) leaves nothing measurable to win.
NO_HEADROOM = 0.005

#: Scenario -> the kind of headroom the oracle has there and a controller fed by observations does
#: not.  Each scenario changes one thing from ``nominal``, where the best classical baseline is level
#: with the oracle, so what the oracle gains in a scenario cell comes from that one change.
HEADROOM_KIND = {
    "noisy": "information: the oracle reads the state the observation noise hides",
    "mismatch": "model error: the oracle knows the episode's true parameters",
    "saturated": "the force bound, which binds the oracle too",
    "coarse": "the control period: the oracle's law is exact for the environment's own step",
    "disturbance": "kicks no controller foresees: the oracle acts on the kicked state at once",
    "nominal": "the law on the true state (the oracle's sampled-data law is exact for the step)",
    "delay": "the hidden delay: the oracle predicts through the commands still on their way",
    "lag": "the hidden actuator: the oracle knows its time constant and its force",
    "unmodelled": "forces the model lacks: the oracle plans with them",
}


def headroom_kind(env: str, scenario: str) -> str:
    """The kind of headroom the oracle has in a cell (`HEADROOM_KIND`), with *model error* added where
    the task's controllers run a model of their own (`Task.controller_model`, such as the boat's local
    affine current) rather than the environment's: there a controller's gap has both kinds in every
    scenario."""
    from vnhc_gym.tasks import task_of_env_id
    from vnhc_gym.tasks.base import Task

    kind = HEADROOM_KIND.get(scenario, "")
    try:
        own_model = task_of_env_id(env).task_class.controller_model is not Task.controller_model
    except ValueError:  # a task no longer registered (a published record of a user's task)
        own_model = False
    if own_model and scenario != "mismatch":
        kind += ", and model error: the controllers run a model of their own (Task.controller_model)"
    return kind


def _why(winner: str, oracle: dict[str, Any] | None, best: dict[str, Any] | None, top: dict[str, Any] | None,
         learned: list[dict[str, Any]], env: str = "", scenario: str = "nominal",
         informed: dict[str, Any] | None = None) -> str:
    """The reason behind a cell's verdict, in words, from its numbers: how much the best learned agent
    gains or loses, which one finishes more episodes, how much the oracle leaves to win and of which
    kind, and whether residual agents ever left their base.  With the informed filter's row (the
    Kalman-filter law told the true parameters, not the state) the headroom is split by measurement:
    the oracle above it is what the observations hide, it above the best classical baseline what not
    knowing the model costs; without it the kind is named from the scenario (`headroom_kind`)."""
    if winner == "incomplete" or best is None or top is None:
        return ""
    parts = []
    gap = top["score"] - best["score"]
    finishes = (f"{top['algo']} finishes {top['success']:.0%} of the episodes, {best['algo']} {best['success']:.0%}"
                if top["success"] != best["success"] else "")
    if winner == "learned":
        return "; ".join(p for p in (f"{gap:+.4f} in score", finishes) if p)
    if gap >= 5e-5:  # a gap that shows at the printed precision
        if top["poi"] > 0.5:
            # The pairwise majority too, but an end of the interval on the other side of 0.5: the
            # spread between its training runs and episodes leaves no difference possible.
            parts.append(f"{top['algo']} has the higher mean ({gap:+.4f}) and wins {_p(top['poi'])} of the pairwise "
                         f"comparisons, but the interval reaches {_p(top['poi_low'])}")
        else:
            # A higher mean without the pairwise majority: the classical baseline's episodes mostly score
            # higher, and a few of them (typically failures) pull its mean down.
            parts.append(f"{top['algo']} has the higher mean ({gap:+.4f}) but not most pairwise comparisons")
        if finishes:
            parts.append(finishes)
    if oracle is not None:
        headroom = oracle["score"] - best["score"]
        if headroom < -NO_HEADROOM:
            fails = f": it fails {1 - oracle['success']:.0%} of the episodes" if oracle["success"] < 1 else ""
            parts.append(f"the oracle scores below the best classical ({headroom:+.4f}{fails})")
        elif headroom >= 0 and headroom <= NO_HEADROOM:
            parts.append(f"no headroom (the oracle is {headroom:+.4f} above the best classical)")
        elif headroom < 0:
            parts.append(f"no headroom (the oracle is {-headroom:.4f} below the best classical)")
        elif informed is not None:
            model = max(0.0, informed["score"] - best["score"])
            hidden = oracle["score"] - max(informed["score"], best["score"])
            parts.append(f"headroom {headroom:+.4f} (the oracle above the best classical): {hidden:+.4f} information "
                         f"(the oracle above the filter told the true model), {model:+.4f} model (that filter above "
                         f"the best classical)")
        else:
            kind = headroom_kind(env, scenario)
            parts.append(f"headroom {headroom:+.4f} (the oracle above the best classical)"
                         + (f": {kind}" if kind else ""))
    # Rows are named by label ("residual_ppo-jax"): the algorithm decides what a row is.
    residual = [r for r in learned if algo_of(r["algo"]) in RESIDUAL_ALGOS]
    if residual:
        beat = sum(r.get("parity_hits", 0) for r in residual)
        judged = sum(r.get("parity_judged", 0) for r in residual)
        unjudged = sum(r["runs"] for r in residual) - judged
        if judged and not beat and not unjudged:
            parts.append("no residual run beat its base on validation")
        elif judged:
            parts.append(f"{beat} of {judged} residual runs beat their base on validation"
                         + (f" ({unjudged} more without a recorded interval)" if unjudged else ""))
        else:
            parts.append(f"whether the {unjudged} residual runs beat their base on validation is not recorded")
    scratch = [r for r in learned if algo_of(r["algo"]) not in RESIDUAL_ALGOS]
    if scratch:
        behind = best["score"] - max(r["score"] for r in scratch)
        if behind > 0:
            parts.append(f"from scratch {behind:.4f} behind")
    return "; ".join(parts)


def _verdict_summary(verdicts: list[dict[str, Any]]) -> list[str]:
    """The verdicts grouped in words: where learning wins, where it loses, where neither is shown."""
    def cells(pred: Callable[[dict[str, Any]], bool]) -> str:
        hit = [f"{v['env']}/{v['scenario']}" for v in verdicts if pred(v)]
        return ", ".join(hit) if hit else "none"

    return [f"- **A learned agent beats the best classical baseline** (interval above 0.5): "
            f"{cells(lambda v: v['winner'] == 'learned')}.",
            f"- **The best classical baseline beats every learned agent** (interval below 0.5): "
            f"{cells(lambda v: v['winner'] == 'classical')}.",
            f"- **No clear winner** (interval across 0.5): {cells(lambda v: v['winner'] == 'none')}.",
            f"- Cells without a finished learned run: {cells(lambda v: v['winner'] == 'incomplete')}."]
