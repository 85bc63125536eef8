"""float32 against float64: the same episodes, the same policies, every task and scenario, through the
environments as pure JAX functions.  Writes results/precision.md and .json.

    python experiments/precision.py            # about 5 minutes
    python experiments/precision.py --quick    # a smoke run

The Gymnasium environments, the evaluation and the baselines run in float64; the compiled trainers
run the same functions at JAX's default precision, float32.  This measures what that changes, on
the test episodes (seeds from 10 000), with three policies:

- ``law``: the geometric law inside the integrator (``feedback="sampled"``: evaluated once per
  control period on the true state, held), at the reference gain 5;
- ``law40``: the law at gain 40 re-evaluated at every RK4 stage (``feedback="continuous"``), which
  drives ``phi`` to the precision's floor;
- ``random``: uniform random actions (what a learner starts from).

Both precisions start from the same states, drawn in float64 (`starts`).

Per row: the mean score (the return over the horizon per step, an early end's remaining steps
counting 0) in each precision, the largest difference of an episode's score between them, the
episodes that ended early in each, and the median over episodes of the final ``|phi~|`` (the
scale-free ``phi`` of the reward: the floor the law reaches).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from vnhc_gym import make_jax
from vnhc_gym.envs.config import SCENARIOS
from vnhc_gym.evaluation import TEST_SEED
from vnhc_gym.tasks import env_ids

HORIZON = 400
POLICIES = {"law": ("sampled", 5.0), "law40": ("continuous", 40.0), "random": ("open", 1.0)}


def starts(env_id: str, scenario: str, n_episodes: int) -> tuple[Any, np.ndarray]:
    """The test episodes' start states and a random policy's actions, drawn in float64.

    ``jax.random`` draws other numbers at another precision from the same key, so both precisions
    start from these (rounded to float32 for the float32 run): the rows differ only by the
    arithmetic of the steps (and, in the scenarios with observation noise or impulses, by the
    step's own draws).
    """
    with jax.enable_x64(True):
        env, params = make_jax(env_id, scenario)
        keys = jax.vmap(jax.random.key)(jnp.arange(TEST_SEED, TEST_SEED + n_episodes, dtype=jnp.uint64))
        _, state = jax.vmap(env.reset, in_axes=(0, None))(keys, params)
        actions = jax.random.uniform(jax.random.key(0), (n_episodes, HORIZON, env.num_actions), minval=-1.0,
                                     maxval=1.0)
        return jax.device_get(state), np.asarray(actions)


def rollout(env_id: str, scenario: str, policy: str, state0: Any, actions: np.ndarray, x64: bool
            ) -> dict[str, np.ndarray]:
    """Per-episode score, whether it finished, and the final ``|phi~|``, in the given precision."""
    feedback, gain = POLICIES[policy]
    if policy != "random":
        actions = np.zeros_like(actions)
    with jax.enable_x64(x64):
        env, params = make_jax(env_id, scenario, feedback=feedback, gains=gain)
        real = jnp.float64 if x64 else jnp.float32
        state0 = jax.tree.map(lambda x: jnp.asarray(x, real) if np.issubdtype(x.dtype, np.floating) else x, state0)

        def episode(state: Any, acts: Any, seed: Any) -> tuple[Any, Any, Any]:
            def step(carry: tuple[Any, ...], xs: Any) -> tuple[tuple[Any, ...], None]:
                state, total, alive, last = carry
                k, action = xs
                new, out = env.transition(k, state, action, params)
                total = total + jnp.where(alive, out.reward, 0.0)
                last = jnp.where(alive, out.abs_phi_sf, last)
                return (new, total, alive & ~out.terminated, last), None

            zero = jnp.zeros((), real)
            xs = (jax.random.split(jax.random.key(seed), HORIZON), acts)
            (_, total, alive, last), _ = jax.lax.scan(step, (state, zero, jnp.ones((), bool), zero), xs)
            return total / HORIZON, alive, last

        seeds = jnp.arange(TEST_SEED, TEST_SEED + actions.shape[0], dtype=jnp.uint32)
        score, alive, last = jax.jit(jax.vmap(episode))(state0, jnp.asarray(actions, real), seeds)
        return {"score": np.asarray(score, np.float64), "alive": np.asarray(alive),
                "phi_sf": np.asarray(last, np.float64)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="one scenario, 4 episodes")
    ap.add_argument("--episodes", type=int, default=20)
    ap.add_argument("--out", default="results/precision")
    args = ap.parse_args()
    n = 4 if args.quick else args.episodes
    scenarios = ["nominal"] if args.quick else sorted(SCENARIOS)
    rows = []
    for env_id in env_ids("v1"):
        for scenario in scenarios:
            state0, actions = starts(env_id, scenario, n)
            for policy in POLICIES:
                f32 = rollout(env_id, scenario, policy, state0, actions, x64=False)
                f64 = rollout(env_id, scenario, policy, state0, actions, x64=True)
                row = {"env": env_id, "scenario": scenario, "policy": policy,
                       "score32": float(f32["score"].mean()), "score64": float(f64["score"].mean()),
                       "max_episode_diff": float(np.max(np.abs(f32["score"] - f64["score"]))),
                       "ended32": int((~f32["alive"]).sum()), "ended64": int((~f64["alive"]).sum()),
                       "phi_sf32": float(np.median(f32["phi_sf"])), "phi_sf64": float(np.median(f64["phi_sf"]))}
                rows.append(row)
                print(row, flush=True)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "precision.json").write_text(json.dumps(rows, indent=1))
    lines = [f"JAX {jax.__version__}, {n} test episodes per row (seeds from {TEST_SEED}), {HORIZON} steps.", "",
             "| env | scenario | policy | score f32 | score f64 | largest episode difference | ended f32 / f64 "
             "| final median \\|phi~\\| f32 | f64 |",
             "|---|---|---|---:|---:|---:|---:|---:|---:|"]
    for r in rows:
        lines.append(f"| {r['env'].removeprefix('vnhc_gym/')} | {r['scenario']} | {r['policy']} | {r['score32']:.4f} "
                     f"| {r['score64']:.4f} | {r['max_episode_diff']:.1e} | {r['ended32']} / {r['ended64']} "
                     f"| {r['phi_sf32']:.1e} | {r['phi_sf64']:.1e} |")
    (out / "precision.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
