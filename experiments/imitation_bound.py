"""How close can a policy network of a learner's size get to the tuned law, if it is told the answer?

A learner from scratch must find the law's map from observation to action by trial and error.  Here
a network of the same shape as the learners' actors (ReLU layers, a ``tanh`` output as SAC's
deterministic action) is fitted by regression to the tuned law's own actions, on the states the law
and then the network itself visit (DAgger: round 0 runs the law with exploration noise, each later
round runs the current network, and every visited observation is labelled with the law's action).
The network is then tested as a policy on the 20 held-out episodes beside the law.  Its error, as a
multiple of the law's, is what a learner of that width could reach at best with a perfect training
signal: where it is far above 1, the width (or the fit) and not the reinforcement learning limits
the learners; widths side by side show which.

Training episodes use seeds below the validation seeds; nothing is chosen on the test episodes.
Writes ``<out>/imitation_bound.md`` and ``.json``.

    python experiments/imitation_bound.py --out docs/results/imitation_bound   # both cells, width 64
    python experiments/imitation_bound.py --widths 64 128 256 --rounds 4 --final-epochs 200  # a shorter fit
    python experiments/imitation_bound.py --cells usv/nominal --widths 64 --rounds 2 --epochs 5   # quick
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import torch
from torch import nn

from vnhc_gym.baselines.tuning import evaluate_classical, make_classical
from vnhc_gym.benchmark import settings
from vnhc_gym.evaluation import TEST_SEED, evaluate
from vnhc_gym.stats import iqm
from vnhc_gym.tasks import env_id

#: How many steps a collection round runs (one episode of the registered length).
ROUND_STEPS = 400


class Student(nn.Module):
    """A learner-shaped actor: standardised observations, ReLU layers, actions ``tanh``-squashed to the space."""

    def __init__(self, obs_mean: np.ndarray, obs_std: np.ndarray, low: np.ndarray, high: np.ndarray,
                 width: int) -> None:
        super().__init__()
        self.register_buffer("obs_mean", torch.as_tensor(obs_mean, dtype=torch.float32))
        self.register_buffer("obs_std", torch.as_tensor(obs_std, dtype=torch.float32))
        self.register_buffer("act_mid", torch.as_tensor((high + low) / 2, dtype=torch.float32))
        self.register_buffer("act_half", torch.as_tensor((high - low) / 2, dtype=torch.float32))
        self.net = nn.Sequential(nn.Linear(len(obs_mean), width), nn.ReLU(), nn.Linear(width, width), nn.ReLU(),
                                 nn.Linear(width, len(low)))

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        return self.act_mid + self.act_half * torch.tanh(self.net((obs - self.obs_mean) / self.obs_std))

    def predict(self, obs: np.ndarray, state: Any = None, episode_start: Any = None,
                deterministic: bool = True) -> tuple[np.ndarray, Any]:
        """SB3's ``predict``, so that the evaluation runs the network as it runs any agent."""
        with torch.no_grad():
            return self(torch.as_tensor(np.asarray(obs), dtype=torch.float32)).numpy().astype(np.float64), state


def _collect(env: str, scenario: str, gains: dict[str, Any], actor: Student | None, n_envs: int, seed: int,
             noise: float) -> tuple[np.ndarray, np.ndarray]:
    """One round: ``n_envs`` episodes run by ``actor`` (the law plus noise when None), each visited
    observation labelled with the law's action."""
    venv = gym.make_vec(env, num_envs=n_envs, vectorization_mode="vector_entry_point", scenario=scenario)
    law = make_classical("tuned_law", venv, **gains)
    low, high = venv.single_action_space.low, venv.single_action_space.high
    rng = np.random.default_rng(seed)
    obs, _ = venv.reset(seed=seed)
    xs, ys = [], []
    for _ in range(ROUND_STEPS):
        target = np.clip(law.predict(obs)[0], low, high)
        xs.append(obs.copy())
        ys.append(target)
        if actor is None:
            action = target + noise * (high - low) / 2 * rng.standard_normal(target.shape)
        else:
            action = actor.predict(obs)[0]
        obs, _, _, _, _ = venv.step(np.clip(action, low, high))  # an ended episode resets itself
    venv.close()
    return np.concatenate(xs), np.concatenate(ys)


def _regress(student: Student, opt: torch.optim.Optimizer, x: np.ndarray, y: np.ndarray, half: np.ndarray,
             epochs: int, anneal: bool = False) -> float:
    """Minibatch passes of mean squared error, in units of the action's half-range; the last loss."""
    xt, yt = torch.as_tensor(x, dtype=torch.float32), torch.as_tensor(y, dtype=torch.float32)
    scale = torch.as_tensor(half, dtype=torch.float32)
    batches = (len(xt) + 1023) // 1024
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, epochs * batches, eta_min=1e-5) if anneal else None
    loss = torch.zeros(())
    for _ in range(epochs):
        for idx in torch.randperm(len(xt)).split(1024):
            loss = torch.mean((student(xt[idx]) / scale - yt[idx]) ** 2)
            opt.zero_grad()
            loss.backward()
            opt.step()
            if sched is not None:
                sched.step()
    return loss.item()


def fit(cell: str, width: int, rounds: int, epochs: int, final_epochs: int, n_envs: int, noise: float,
        seed: int) -> dict[str, Any]:
    """DAgger rounds of collection and regression; the network tested as a policy on the held-out episodes."""
    task, scenario = cell.split("/")
    env = env_id(task)
    gains = settings().get(task, {}).get(scenario, {}).get("tuned_law", {})
    torch.manual_seed(seed)
    space = gym.make(env).action_space
    t0 = time.perf_counter()
    x, y = _collect(env, scenario, gains, None, n_envs, seed, noise)
    student = Student(x.mean(0), x.std(0) + 1e-6, space.low, space.high, width)
    opt = torch.optim.Adam(student.parameters(), lr=1e-3)
    half = (space.high - space.low) / 2
    for r in range(rounds):
        if r:  # the network's own states, labelled by the law (seeds of their own, below the validation seeds)
            xr, yr = _collect(env, scenario, gains, student, n_envs, seed + 1000 * r, noise)
            x, y = np.concatenate([x, xr]), np.concatenate([y, yr])
        loss = _regress(student, opt, x, y / half, half, epochs)
    # The last fit, on all the data, anneals the step size: the regression's error is what bounds the policy.
    opt = torch.optim.Adam(student.parameters(), lr=1e-3)
    loss = _regress(student, opt, x, y / half, half, final_epochs, anneal=True)
    fit_seconds = time.perf_counter() - t0
    res = evaluate(student, env, scenario, n_episodes=20, seed=TEST_SEED)
    return {"cell": cell, "width": width, "samples": len(x), "final_loss": loss, "fit_seconds": fit_seconds,
            "episodes": {k: res.metrics[k].tolist() for k in ("score", "success", "mean_abs_phi_sf")}}



def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cells", nargs="+", default=["usv/nominal", "flocking/nominal"])
    ap.add_argument("--widths", nargs="+", type=int, default=[64], help="units of each hidden layer")
    ap.add_argument("--rounds", type=int, default=8, help="collection rounds (the first runs the law)")
    ap.add_argument("--epochs", type=int, default=20, help="passes over the data after each round")
    ap.add_argument("--final-epochs", type=int, default=400, help="passes of the last, annealed fit on all the data")
    ap.add_argument("--n-envs", type=int, default=64, help="episodes of each round")
    ap.add_argument("--noise", type=float, default=0.1, help="exploration noise of round 0 (share of the half-range)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default="results/imitation_bound")
    args = ap.parse_args()
    torch.set_num_threads(1)
    rows = []
    lines = ["| cell | policy | width | samples | test score | finished | IQM mean abs phi~ | x the tuned law's |",
             "|---|---|---:|---:|---:|---:|---:|---:|"]
    for cell in args.cells:
        task, scenario = cell.split("/")
        gains = settings().get(task, {}).get(scenario, {}).get("tuned_law", {})
        law = evaluate_classical("tuned_law", gains, env_id(task), scenario, 20, TEST_SEED)
        law_phi = iqm(law.metrics["mean_abs_phi_sf"])
        lines.append(f"| {cell} | tuned law | - | - | {law.metrics['score'].mean():.4f} | "
                     f"{law.metrics['success'].mean():.2f} | {law_phi:.3g} | 1.0 |")
        for width in args.widths:
            row = fit(cell, width, args.rounds, args.epochs, args.final_epochs, args.n_envs, args.noise, args.seed)
            phi = iqm(np.asarray(row["episodes"]["mean_abs_phi_sf"]))
            row.update(law_iqm=law_phi, iqm=phi, ratio=phi / law_phi)
            rows.append(row)
            lines.append(f"| {cell} | network fitted to the law | {width} | {row['samples']} | "
                         f"{np.mean(row['episodes']['score']):.4f} | {np.mean(row['episodes']['success']):.2f} | "
                         f"{phi:.3g} | {phi / law_phi:.1f} |")
            print(lines[-1], flush=True)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    table = "\n".join(lines) + "\n"
    (out / "imitation_bound.md").write_text(table)
    (out / "imitation_bound.json").write_text(json.dumps(rows, indent=1) + "\n")
    print(table)


if __name__ == "__main__":
    main()
