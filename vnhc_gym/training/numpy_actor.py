"""A compiled PPO's or SAC's policy network run in numpy: how a saved ``.npz`` agent acts.

The compiled trainers (`vnhc_gym.training.run_jax`) save their networks as plain arrays; `JaxActor`
runs them with numpy alone, so loading and evaluating such an agent needs neither JAX nor a pickle.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

__all__ = ["LOG_STD_MAX", "LOG_STD_MIN", "JaxActor"]

LOG_STD_MIN, LOG_STD_MAX = -20.0, 2.0  #: a SAC actor's log standard deviation is clipped to these (SBX's)
_NUMPY_ACTIVATIONS: dict[str, Callable[[Any], Any]] = {
    "Tanh": np.tanh, "ReLU": lambda x: np.maximum(x, 0.0), "ELU": lambda x: np.where(x > 0, x, np.expm1(x)),
    "LeakyReLU": lambda x: np.where(x > 0, x, 0.01 * x), "SiLU": lambda x: x / (1.0 + np.exp(-x))}


class JaxActor:
    """A compiled PPO's or SAC's policy network in numpy (what `load_agent` returns inside an
    `AgentPolicy`).

    ``predict(obs) -> (action, None)``: the deterministic action, the network's mean clipped to
    ``[-1, 1]`` (``squash="clip"``, PPO) or its ``tanh`` (``squash="tanh"``, SAC), for one
    observation or a batch (SB3's interface).  ``deterministic=False`` samples the Gaussian (its
    log standard deviation ``log_std``, or the head ``log_std_out``) before the squash.
    """

    def __init__(self, arrays: dict[str, NDArray[np.float32]], activation: str = "Tanh", squash: str = "clip") -> None:
        if activation not in _NUMPY_ACTIVATIONS:
            raise ValueError(f"activation must be one of {sorted(_NUMPY_ACTIVATIONS)}, got {activation!r}")
        if squash not in ("clip", "tanh"):
            raise ValueError(f"squash must be 'clip' or 'tanh', got {squash!r}")
        hidden = sorted({int(k.split(".")[1]) for k in arrays if k.startswith("pi.")})
        if (hidden != list(range(len(hidden))) or "pi_out.w" not in arrays
                or not ({"log_std"} <= set(arrays) or {"log_std_out.w", "log_std_out.b"} <= set(arrays))):
            raise ValueError(f"not a compiled PPO's or SAC's networks: arrays {sorted(arrays)}")
        self.layers = [(np.asarray(arrays[f"pi.{i}.w"], np.float32), np.asarray(arrays[f"pi.{i}.b"], np.float32))
                       for i in hidden]
        self.out = (np.asarray(arrays["pi_out.w"], np.float32), np.asarray(arrays["pi_out.b"], np.float32))
        self.log_std = np.asarray(arrays["log_std"], np.float32) if "log_std" in arrays else None
        self.log_std_out = ((np.asarray(arrays["log_std_out.w"], np.float32),
                             np.asarray(arrays["log_std_out.b"], np.float32)) if self.log_std is None else None)
        self.act = _NUMPY_ACTIVATIONS[activation]
        self.squash = squash

    @classmethod
    def load(cls, path: str | Path, activation: str = "Tanh", squash: str = "clip") -> JaxActor:
        with np.load(path, allow_pickle=False) as data:
            return cls({k: data[k] for k in data.files}, activation, squash)

    def predict(self, observation: Any, state: Any = None, episode_start: Any = None,
                deterministic: bool = True) -> tuple[NDArray[np.float32], Any]:
        x = np.asarray(observation, dtype=np.float32)
        for w, b in self.layers:
            x = self.act(x @ w + b)
        mean = x @ self.out[0] + self.out[1]
        if not deterministic:
            if self.log_std_out is not None:
                log_std = np.clip(x @ self.log_std_out[0] + self.log_std_out[1], LOG_STD_MIN, LOG_STD_MAX)
            else:
                log_std = self.log_std
            mean = mean + np.exp(log_std) * np.random.default_rng().standard_normal(mean.shape)
        action = np.tanh(mean) if self.squash == "tanh" else np.clip(mean, -1.0, 1.0)
        return action.astype(np.float32), state
