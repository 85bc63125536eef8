"""Trained agents as policies: a saved SB3 model with its observation statistics and, for residual
agents, the base controller it corrects.

[`load_agent`][vnhc_gym.training.load_agent] returns an `AgentPolicy` whose ``predict`` takes raw environment
observations and returns the action the environment should receive.  Names without a path
(``"usv-ppo"``) load from the agents shipped in ``vnhc_gym/agents_zoo``; a path to your own file
loads with a warning, because SB3 ``.zip`` files contain pickled Python objects (load only files you
trust).
"""

from __future__ import annotations

import json
import warnings
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from vnhc_gym.training.numpy_actor import JaxActor

__all__ = ["ZOO_DIR", "AgentPolicy", "UntrustedFileWarning", "algorithm_class", "list_zoo", "load_agent",
           "sidecar_of"]

#: The agents shipped with the package.
ZOO_DIR = Path(__file__).resolve().parent.parent / "agents_zoo"


class UntrustedFileWarning(UserWarning):
    """Loading a model file from outside the package (SB3 zips contain pickles)."""


def algorithm_class(algo: str) -> Any:
    """The model class of a training algorithm: stable-baselines3's PPO (``ppo``, ``residual_ppo``),
    sb3-contrib's RecurrentPPO (``recurrent_ppo``) or SBX's SAC (``sac``, ``residual_sac``: the JAX
    implementation of SAC by the stable-baselines3 team, several times faster than stable-baselines3's
    on these small networks, see the training docs)."""
    if algo in ("ppo", "residual_ppo"):
        from stable_baselines3 import PPO

        return PPO
    if algo == "recurrent_ppo":
        from sb3_contrib import RecurrentPPO

        return RecurrentPPO
    if algo in ("sac", "residual_sac"):
        import os

        # One XLA thread, as one torch thread: never oversubscribe the cores (set before jax loads).
        os.environ.setdefault("XLA_FLAGS", "--xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1")
        try:
            from sbx import SAC
        except ImportError:
            raise ImportError(f'{algo} needs SBX (JAX): pip install "vnhc-gym[rl]"') from None
        return SAC
    raise ValueError(f"algo must be one of ppo, residual_ppo, recurrent_ppo, sac, residual_sac, got {algo!r}")


def list_zoo() -> list[str]:
    """Names of the shipped agents (``<task>-<algo>``)."""
    return sorted(p.stem for p in ZOO_DIR.glob("*.zip") if p.with_suffix(".json").exists())


def sidecar_of(path: str | Path) -> dict[str, Any]:
    """The JSON sidecar of a saved agent: ``<stem>.json`` beside ``<stem>.zip``.

    A run's final model ``<stem>-final.zip`` shares its run's sidecar ``<stem>.json`` (one record
    per run), whose ``final_obs_rms`` are the observation statistics at the end of training: the
    returned copy has them as ``obs_rms`` and ``checkpoint: "final"``.
    """
    p = Path(path)
    side = p.with_suffix(".json")
    if side.exists():
        return dict(json.loads(side.read_text()))
    run = p.with_name(p.stem.removesuffix("-final") + ".json")
    if p.stem.endswith("-final") and run.exists():
        meta = dict(json.loads(run.read_text()))
        if "final_obs_rms" not in meta:
            raise FileNotFoundError(f"the run's sidecar {run} has no final_obs_rms for {p} (the run did not end)")
        return {**meta, "obs_rms": meta["final_obs_rms"], "checkpoint": "final"}
    raise FileNotFoundError(
        f"no sidecar {side} beside {p}: vnhc-gym train writes one beside every run. To load a model "
        f"without one, wrap it yourself: AgentPolicy(PPO.load({str(p)!r}), {{'algo': 'ppo'}}) "
        f"(vnhc_gym.training.AgentPolicy; the network then sees raw, unnormalised observations, and a "
        f"residual agent needs {{'residual': ...}} as its run's sidecar has it)")


class _Network:
    """The SB3 model on raw observations: normalised with the training statistics and, for the history
    variant, stacked over the last ``frame_stack`` steps."""

    def __init__(self, model: Any, meta: dict[str, Any]) -> None:
        self.model = model
        rms = meta.get("obs_rms")
        self._rms = None if rms is None else (np.asarray(rms["mean"]), np.asarray(rms["var"]), float(rms["clip"]),
                                              float(rms.get("epsilon", 1e-8)))
        self.frame_stack = int(meta.get("frame_stack", 1) or 1)
        self._frames: NDArray[np.float32] | None = None

    def _normalize(self, obs: NDArray[np.float32]) -> NDArray[np.float32]:
        if self._rms is None:
            return obs
        mean, var, clip, eps = self._rms
        return np.clip((obs - mean) / np.sqrt(var + eps), -clip, clip).astype(np.float32)

    def _stack(self, obs: NDArray[np.float32], starts: NDArray[np.bool_] | None) -> NDArray[np.float32]:
        """The last ``frame_stack`` observations of each row, oldest first (zeros before an episode's
        first, as SB3's VecFrameStack has them)."""
        if self.frame_stack <= 1:
            return obs
        b, d = obs.shape
        if self._frames is None or self._frames.shape[0] != b:
            self._frames = np.zeros((b, self.frame_stack * d), dtype=np.float32)
        elif starts is not None:
            self._frames[starts] = 0.0
        self._frames = np.roll(self._frames, -d, axis=1)
        self._frames[:, -d:] = obs
        return self._frames.copy()

    def predict(self, observation: Any, state: Any = None, episode_start: Any = None,
                deterministic: bool = True) -> tuple[NDArray[np.float32], Any]:
        obs = np.asarray(observation, dtype=np.float32)
        single = obs.ndim == 1
        batch = obs[None] if single else obs
        starts = None if episode_start is None else np.asarray(episode_start, dtype=bool).reshape(-1)
        seen = self._stack(self._normalize(batch), starts)
        kwargs = {"state": state, "episode_start": starts} if state is not None or starts is not None else {}
        a, state = self.model.predict(seen, deterministic=deterministic, **kwargs)
        out = np.clip(np.asarray(a, dtype=np.float64).reshape(batch.shape[0], -1), -1.0, 1.0).astype(np.float32)
        return (out[0] if single else out), state


class AgentPolicy:
    """A trained agent on raw observations (SB3 ``predict``; recurrent agents keep their state).

    Parameters
    ----------
    model : stable_baselines3 model
    meta : dict
        The run's sidecar (algorithm, env id, residual settings, observation statistics).
    """

    def __init__(self, model: Any, meta: dict[str, Any]) -> None:
        self.model = model
        self.meta = meta
        self.algo = str(meta.get("algo", "ppo"))
        self.name = str(meta.get("name", self.algo))
        self.residual: dict[str, Any] | None = meta.get("residual")
        self.network = _Network(model, meta)
        self.base: Any = None
        self._policy: Any = self.network if self.residual is None else None

    @property
    def frame_stack(self) -> int:
        """Observations the network sees at once (1, or 4 for the history variant)."""
        return self.network.frame_stack

    def bind(self, env: Any) -> AgentPolicy:
        """Build the residual agent's base controller for ``env`` (its force bound, ``dt``); other
        agents need nothing.  Returns self."""
        if self.residual is not None:
            from vnhc_gym.baselines import make_classical
            from vnhc_gym.wrappers import ResidualPolicy

            settings = {"gain": self.residual.get("gain", 5.0), **(self.residual.get("base_settings") or {})}
            self.base = make_classical(self.residual.get("base") or "law", env, **settings)
            self._policy = ResidualPolicy(self.network, self.base, scale=float(self.residual["scale"]),
                                          observe_base=bool(self.residual.get("observe_base")), name=self.name)
        return self

    def predict(self, observation: Any, state: Any = None, episode_start: Any = None,
                deterministic: bool = True) -> tuple[NDArray[np.float32], Any]:
        if self._policy is None:
            raise RuntimeError("a residual agent needs its base controller: call bind(env) first")
        return self._policy.predict(observation, state=state, episode_start=episode_start,  # type: ignore[no-any-return]
                                    deterministic=deterministic)

    def __repr__(self) -> str:
        return f"AgentPolicy({self.name!r}, env={self.meta.get('env_id')!r})"


def load_agent(path_or_name: str | Path, env: Any = None) -> AgentPolicy:
    """Load a saved agent (a shipped name such as ``"usv-ppo"``, a path to an SB3 ``.zip``, or to a
    compiled PPO's or SAC's ``.npz``, `vnhc_gym.training.run_jax`).

    ``env`` binds a residual agent's base controller (default: an environment made from the
    sidecar's env id and scenario).
    """
    p = Path(path_or_name)
    if p.suffix == ".npz":  # plain arrays, no pickles: no warning
        if not p.exists():
            raise FileNotFoundError(f"no agent {path_or_name!r}")
        meta = sidecar_of(p)
        agent = AgentPolicy(JaxActor.load(p, str(meta.get("activation", "Tanh")), str(meta.get("squash", "clip"))),
                            meta)
    else:
        if p.suffix != ".zip" and not p.exists() and (ZOO_DIR / f"{p.name}.zip").exists():
            p = ZOO_DIR / f"{p.name}.zip"
        elif p.suffix != ".zip":
            p = p.with_suffix(".zip")
        if not p.exists():
            raise FileNotFoundError(f"no agent {path_or_name!r}: not a file, nor one of the shipped agents "
                                    f"{list_zoo()}")
        if p.resolve().parent != ZOO_DIR.resolve():
            warnings.warn(f"loading {p}: SB3 model files contain pickles; load only files you trust",
                          UntrustedFileWarning, stacklevel=2)
        meta = sidecar_of(p)
        agent = AgentPolicy(algorithm_class(str(meta.get("algo", "ppo"))).load(p, device="cpu"), meta)
    if agent.residual is not None:
        if env is None:
            import gymnasium as gym

            env = gym.make(meta["env_id"], scenario=meta.get("scenario", "nominal"))
        agent.bind(env)
    return agent
