"""RK4 accuracy at the environments' control period: one RK4 step per 0.05 s against 64 substeps.

Runs the geometric law (sampled feedback, k = 5) for 20 s from 20 random nominal starts of every
registered environment and prints the largest relative state deviation and the largest phi
deviation between the coarse and the fine integration.

    python experiments/rk4_accuracy.py
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np

from vnhc_gym.mechanics import simulate
from vnhc_gym.tasks import env_ids


def main() -> None:
    for env_id in env_ids("v1"):
        env = gym.make(env_id).unwrapped
        model = env.task.model
        buf = env.batch.buf
        worst_state = worst_phi = 0.0
        for seed in range(20):
            env.reset(seed=seed)
            s0, p = buf.state[0].copy(), buf.params_true[0].copy()
            coarse = simulate(model, s0, 0.05, 400, feedback="sampled", gains=5.0, params=p, substeps=1)
            fine = simulate(model, s0, 0.05, 400, feedback="sampled", gains=5.0, params=p, substeps=64)
            scale = np.maximum(1.0, np.abs(fine.states))
            worst_state = max(worst_state, float(np.max(np.abs(coarse.states - fine.states) / scale)))
            worst_phi = max(worst_phi, float(np.max(np.abs(coarse.phi - fine.phi))))
        print(f"{env_id}: max relative state deviation {worst_state:.2e}, max |phi| deviation {worst_phi:.2e}")


if __name__ == "__main__":
    main()
