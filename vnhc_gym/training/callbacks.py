"""Training callbacks that RL Zoo's hyperparameter files can name (RL Zoo's ``callback`` key) and
``vnhc-gym train`` applies the same way.

`ValueWarmup` is the safeguard of residual reinforcement learning against a cold critic: a
residual agent starts *at* its base (its mean action is zero), but PPO's first updates follow
advantages estimated by a value function that has not seen a single return yet, and can move the
policy away from the base before the critic knows what the base is worth.  During the warm-up only
the value function learns, on the base's own rollouts; the policy starts to move once the critic
has caught up.
"""

from __future__ import annotations

from typing import Any

from stable_baselines3.common.callbacks import BaseCallback

__all__ = ["ValueWarmup"]


class ValueWarmup(BaseCallback):
    """Freeze the policy (actor) of an on-policy actor-critic for its first ``steps`` env steps, so
    that only the value function learns.

    Parameters
    ----------
    steps : int
        Env steps of the warm-up (the policy is frozen for the updates of the rollouts that end
        before it).

    Notes
    -----
    Works on stable-baselines3's ``ActorCriticPolicy`` with separate actor and critic networks (the
    default for ``MlpPolicy``): the actor's layers (``mlp_extractor.policy_net``, ``action_net``)
    and ``log_std`` get no gradient while frozen; the optimiser skips parameters without one.
    """

    def __init__(self, steps: int, verbose: int = 0) -> None:
        super().__init__(verbose)
        if isinstance(steps, bool) or not isinstance(steps, int) or steps < 0:
            raise ValueError(f"steps must be an integer >= 0, got {steps!r}")
        self.steps = steps
        self.frozen = False

    def _actor_parameters(self) -> list[Any]:
        policy: Any = self.model.policy
        import torch

        params = list(policy.mlp_extractor.policy_net.parameters()) + list(policy.action_net.parameters())
        if isinstance(getattr(policy, "log_std", None), torch.nn.Parameter):
            params.append(policy.log_std)
        return params

    def _set(self, frozen: bool) -> None:
        for p in self._actor_parameters():
            p.requires_grad_(not frozen)
        self.frozen = frozen

    def _on_training_start(self) -> None:
        if not hasattr(self.model.policy, "mlp_extractor"):
            raise TypeError(f"ValueWarmup needs an on-policy actor-critic (PPO), got {type(self.model).__name__}")
        self._set(self.steps > 0)

    def _on_step(self) -> bool:
        return True

    def _on_rollout_end(self) -> None:
        # The update that follows this rollout uses the policy's state now.
        if self.frozen and self.num_timesteps >= self.steps:
            self._set(False)

    def _on_training_end(self) -> None:
        if self.frozen:
            self._set(False)
