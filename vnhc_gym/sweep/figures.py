"""The figures of a sweep's report: ``verdict.png`` (every algorithm's test score per cell),
``learning_curves_<env>.png`` and ``performance_profile.png``."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from vnhc_gym.sweep.cells import SCORE, Cell, _episodes
from vnhc_gym.sweep.specs import CLASSICAL_ALGOS, LEARNED_ALGOS, REFERENCE_ALGOS, algo_of

#: One look per algorithm in every figure: classical baselines dashed or dotted, agents solid.
_STYLE: dict[str, dict[str, Any]] = {
    "law": {"color": "black", "ls": "--"}, "tuned_law": {"color": "tab:purple", "ls": "--"},
    "observer": {"color": "tab:brown", "ls": ":"}, "adaptive": {"color": "tab:gray", "ls": "-."},
    "kalman": {"color": "tab:pink", "ls": ":"}, "safe_law": {"color": "darkviolet", "ls": "-."},
    "oracle": {"color": "gold", "ls": "-"}, "mpc": {"color": "tab:cyan", "ls": "--"},
    "ppo": {"color": "tab:blue"}, "ppo_history": {"color": "tab:orange"}, "residual_ppo": {"color": "tab:green"},
    "sac": {"color": "tab:red"}, "residual_sac": {"color": "tab:olive"}, "ppo-jax": {"color": "navy"},
}


def _verdict_figure(rows: list[dict[str, Any]], dest: Path) -> list[str]:
    """``verdict.png``: per task a panel, the scenarios down, every algorithm's test score with its
    interval across, as the reward lost over the horizon (``1 - score``, log axis: good controllers
    differ in the third decimal of the score); the oracle is a star, the cell's best classical
    baseline a ringed marker."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    envs = sorted({r["env"] for r in rows})
    if not envs:
        return []
    order = (*REFERENCE_ALGOS, *CLASSICAL_ALGOS, *LEARNED_ALGOS)
    algos = sorted({r["algo"] for r in rows if algo_of(r["algo"]) in order},
                   key=lambda a: (order.index(algo_of(a)), a))
    n_scen = max(len({r["scenario"] for r in rows if r["env"] == e}) for e in envs)
    fig, axes = plt.subplots(1, len(envs), figsize=(4.2 * len(envs), 0.9 + 0.55 * n_scen * 1.6), squeeze=False)
    for ax, env in zip(axes[0], envs, strict=True):
        scen = sorted({r["scenario"] for r in rows if r["env"] == env})
        for j, algo in enumerate(algos):
            for i, scenario in enumerate(scen):
                r = next((r for r in rows if r["env"] == env and r["scenario"] == scenario and r["algo"] == algo), None)
                if r is None:
                    continue
                y = i + (j - (len(algos) - 1) / 2) * 0.8 / max(1, len(algos))
                style = _STYLE.get(algo, {})
                marker = "*" if algo == "oracle" else "s" if r["kind"] == "classical" else "o"
                lost, lo, hi = (max(1.0 - v, 1e-5) for v in (r["score"], r["high"], r["low"]))
                ax.errorbar(lost, y, xerr=[[max(0.0, lost - lo)], [max(0.0, hi - lost)]],
                            fmt=marker, color=style.get("color"), ms=7 if algo == "oracle" else 4, lw=1,
                            label=algo if i == 0 else None)
                if algo == r["best_classical"]:
                    ax.plot(lost, y, "o", mfc="none", mec="red", ms=10, mew=1.2, label="best classical")
        ax.set_yticks(range(len(scen)), scen)
        ax.invert_yaxis()
        ax.set_xscale("log")
        ax.set_xlabel("1 - test score (mean, 95 % CI; lower is better)")
        ax.set_title(env, fontsize=10)
        ax.grid(axis="x", alpha=0.3)
    handles, labels = [], []
    for ax in axes[0]:
        for h, lab in zip(*ax.get_legend_handles_labels(), strict=True):
            if lab not in labels:
                handles.append(h)
                labels.append(lab)
    fig.legend(handles, labels, loc="lower center", ncol=min(len(labels), 5), fontsize=7)
    fig.tight_layout(rect=(0, 0.12, 1, 1))
    path = dest / "verdict.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return [str(path)]


def _figures(cells: dict[tuple[str, str], Cell], dest: Path) -> list[str]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    files = []
    envs = sorted({env for env, _ in cells})
    for env in envs:
        scen = sorted(s for e, s in cells if e == env)
        fig, axes = plt.subplots(1, len(scen), figsize=(3.2 * len(scen), 3.0), squeeze=False)
        for ax, scenario in zip(axes[0], scen, strict=True):
            cell = cells[(env, scenario)]
            for algo, rs in sorted(cell.runs.items()):
                if algo_of(algo) in LEARNED_ALGOS:
                    curves = [[p for p in r["curve"] if "score" in p] for r in rs if r.get("curve")]
                    curves = [c for c in curves if c]
                    if not curves:
                        continue
                    n = min(len(c) for c in curves)
                    steps = np.array([curves[0][i]["steps"] for i in range(n)])
                    vals = np.median(np.array([[c[i][SCORE] for i in range(n)] for c in curves]), axis=0)
                    ax.plot(steps, vals, label=algo, **_STYLE.get(algo, {}))
                else:
                    ax.axhline(rs[0]["validation_score"], lw=1, label=algo, **_STYLE.get(algo, {}))
            ax.set_title(scenario, fontsize=9)
            ax.set_xlabel("env steps")
        axes[0][0].set_ylabel("validation score (median over seeds)")
        axes[0][-1].legend(fontsize=6)
        fig.tight_layout()
        path = dest / f"learning_curves_{env}.png"
        fig.savefig(path, dpi=110)
        plt.close(fig)
        files.append(str(path))
    # Performance profile: each run's test score over the oracle's in its cell (1: the headroom is used
    # up), the fraction of runs at or above each level.
    ratios: dict[str, list[float]] = {}
    for cell in cells.values():
        oracle = cell.runs.get("oracle")
        if not oracle:
            continue
        ref = float(np.mean(_episodes(oracle, SCORE)))
        if ref <= 0:
            continue
        for algo, rs in cell.runs.items():
            for r in rs:
                ratios.setdefault(algo, []).append(float(np.mean(_episodes([r], SCORE))) / ref)
    if ratios:
        taus = np.linspace(0.0, 1.1, 111)
        fig, ax = plt.subplots(figsize=(5, 3.5))
        for algo, vals in sorted(ratios.items()):
            v = np.asarray(vals)
            ax.plot(taus, [(v >= t).mean() for t in taus], label=algo, **_STYLE.get(algo, {}))
        ax.set_xlabel("test score / the oracle's (per cell)")
        ax.set_ylabel("fraction of runs at or above")
        ax.legend(fontsize=7)
        fig.tight_layout()
        path = dest / "performance_profile.png"
        fig.savefig(path, dpi=110)
        plt.close(fig)
        files.append(str(path))
    return files
