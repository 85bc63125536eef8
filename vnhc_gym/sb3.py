"""Stable-Baselines3 ``VecEnv`` over a Gymnasium ``VectorEnv`` (SB3 cannot take one directly).

`GymnasiumVecEnvAdapter` presents any ``gymnasium.vector.VectorEnv`` (the native
``vnhc_gym`` vector envs, ``SyncVectorEnv``, ...) with SB3's ``DummyVecEnv`` semantics: a
finished sub-environment is reset in the same step (the returned observation is the new
episode's), its ``info`` is the last step's with ``terminal_observation`` and
``TimeLimit.truncated``, rewards are float32, and ``seed(s)`` makes sub-env ``i`` start from
``s + i`` at the next ``reset()``.  With ``AutoresetMode.SAME_STEP`` vector envs the reset
comes from the step itself; with ``NEXT_STEP`` (or ``DISABLED``) ones the adapter resets the
finished sub-environments with ``reset(options={"reset_mask": dones})``.

One line for training::

    venv = vnhc_gym.make_sb3_vec_env("vnhc_gym/FlockingAlign-v1", n_envs=8, seed=0, scenario="noisy")
    PPO("MlpPolicy", venv).learn(100_000)

Importing this module imports Stable-Baselines3 (and torch); ``import vnhc_gym`` does not.
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium.vector import AutoresetMode
from stable_baselines3.common.vec_env import VecEnv, VecMonitor
from stable_baselines3.common.vec_env.base_vec_env import VecEnvIndices, VecEnvObs, VecEnvStepReturn

__all__ = ["GymnasiumVecEnvAdapter", "make_sb3_vec_env", "infos_to_list"]

_FINAL_KEYS = frozenset({"final_obs", "_final_obs", "final_info", "_final_info"})


def infos_to_list(infos: dict[str, Any], n: int) -> list[dict[str, Any]]:
    """Gymnasium's batched info (arrays with ``_key`` masks) as ``n`` per-env dicts.

    1-D arrays give Python scalars (as a single env's ``info`` has them), higher-dimensional
    ones their rows; nested dicts (``final_info``) are split recursively.
    """
    keys: list[str] = []
    columns: list[Sequence[Any]] = []
    partial: list[tuple[str, Sequence[Any], list[int]]] = []
    for key, value in infos.items():
        if key.startswith("_"):
            continue
        if isinstance(value, dict):
            items: Sequence[Any] = infos_to_list(value, n)
        elif isinstance(value, np.ndarray) and value.ndim == 1:
            items = value.tolist()
        else:
            items = list(value)
        mask = infos.get("_" + key)
        if mask is None or np.count_nonzero(mask) == n:
            keys.append(key)
            columns.append(items)
        else:
            partial.append((key, items, np.flatnonzero(mask).tolist()))
    out = [dict(zip(keys, row, strict=True)) for row in zip(*columns, strict=True)] if columns else \
        [{} for _ in range(n)]
    for key, items, rows in partial:
        for i in rows:
            out[i][key] = items[i]
    return out


class GymnasiumVecEnvAdapter(VecEnv):
    """SB3 ``VecEnv`` with ``DummyVecEnv`` semantics over one Gymnasium ``VectorEnv``.

    Parameters
    ----------
    vector_env : gymnasium.vector.VectorEnv
        Any autoreset mode (``metadata["autoreset_mode"]``); ``SAME_STEP`` needs no extra call.
        ``NEXT_STEP`` / ``DISABLED`` vector envs must support ``reset(options={"reset_mask": ...})``
        (Gymnasium's own and ``vnhc_gym``'s do).

    Notes
    -----
    ``get_attr`` / ``set_attr`` / ``env_method`` go through the vector env's ``get_attr`` /
    ``set_attr`` / ``call`` (per-sub-env for ``SyncVectorEnv``; the native ``vnhc_gym`` vector
    envs share one configuration, so a method call acts on the whole batch).
    ``get_images`` returns the vector env's ``render()`` frames.
    """

    def __init__(self, vector_env: gym.vector.VectorEnv) -> None:
        if not isinstance(vector_env.unwrapped, gym.vector.VectorEnv):
            raise TypeError(f"expected a gymnasium.vector.VectorEnv, got {type(vector_env).__name__}")
        self.venv = vector_env
        mode = vector_env.metadata.get("autoreset_mode", AutoresetMode.NEXT_STEP)
        self.autoreset_mode = mode if isinstance(mode, AutoresetMode) else AutoresetMode(mode)
        super().__init__(vector_env.num_envs, vector_env.single_observation_space, vector_env.single_action_space)
        self.metadata = dict(vector_env.metadata)
        self._actions: np.ndarray | None = None

    # ------------------------------------------------------------------ core API
    def reset(self) -> VecEnvObs:
        seeds = self._seeds
        seed = None if all(s is None for s in seeds) else list(seeds)
        options = self._options
        if any(options):
            if any(o != options[0] for o in options[1:]):
                raise ValueError("the vector env takes one options dict for all sub-environments; "
                                 "set_options() with different dicts is not supported")
            obs, infos = self.venv.reset(seed=seed, options=dict(options[0]))  # type: ignore[arg-type]
        else:
            obs, infos = self.venv.reset(seed=seed)  # type: ignore[arg-type]  # lists are accepted
        self.reset_infos = infos_to_list(infos, self.num_envs)
        self._reset_seeds()
        self._reset_options()
        return obs

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = actions

    def step_wait(self) -> VecEnvStepReturn:
        obs, rewards, terminated, truncated, infos = self.venv.step(self._actions)
        n = self.num_envs
        terminated = np.asarray(terminated, dtype=bool)
        truncated = np.asarray(truncated, dtype=bool)
        dones = terminated | truncated
        done_rows = np.flatnonzero(dones).tolist()
        if self.autoreset_mode is AutoresetMode.SAME_STEP:
            top = infos_to_list({k: v for k, v in infos.items() if k not in _FINAL_KEYS}, n)
            if done_rows:
                final = infos_to_list(infos["final_info"], n)
                final_obs = infos["final_obs"]
                for i in done_rows:
                    self.reset_infos[i] = top[i]
                    top[i] = final[i]
                    top[i]["terminal_observation"] = final_obs[i]
            list_infos = top
        else:
            list_infos = infos_to_list(infos, n)
            if done_rows:
                terminal = obs[done_rows].copy()
                obs, reset_infos = self.venv.reset(options={"reset_mask": dones.copy()})
                reset_list = infos_to_list(reset_infos, n)
                for j, i in enumerate(done_rows):
                    list_infos[i]["terminal_observation"] = terminal[j]
                    self.reset_infos[i] = reset_list[i]
        for info, timeout in zip(list_infos, (truncated & ~terminated).tolist(), strict=True):
            info["TimeLimit.truncated"] = timeout
        return obs, np.asarray(rewards, dtype=np.float32), dones, list_infos

    def close(self) -> None:
        self.venv.close()

    # ------------------------------------------------------------------ attributes and methods
    def get_attr(self, attr_name: str, indices: VecEnvIndices = None) -> list[Any]:
        idx = self._get_indices(indices)
        envs = getattr(self.venv, "envs", None)
        if envs is not None:  # SyncVectorEnv: like DummyVecEnv, from the selected sub-environments
            return [envs[i].get_wrapper_attr(attr_name) for i in idx]
        get = getattr(self.venv, "get_attr", None)
        values = get(attr_name) if get is not None else (getattr(self.venv, attr_name),) * self.num_envs
        return [values[i] for i in idx]

    def set_attr(self, attr_name: str, value: Any, indices: VecEnvIndices = None) -> None:
        idx = list(self._get_indices(indices))
        envs = getattr(self.venv, "envs", None)
        if envs is not None:  # SyncVectorEnv: like DummyVecEnv, on the selected sub-environments
            for i in idx:
                setattr(envs[i], attr_name, value)
            return
        setter = getattr(self.venv, "set_attr", None)
        if setter is None:
            setattr(self.venv, attr_name, value)
            return
        values = [value] * self.num_envs if len(idx) == self.num_envs else list(self.get_attr(attr_name))
        for i in idx:
            values[i] = value
        setter(attr_name, values)

    def env_method(self, method_name: str, *method_args: Any, indices: VecEnvIndices = None,
                   **method_kwargs: Any) -> list[Any]:
        idx = list(self._get_indices(indices))
        envs = getattr(self.venv, "envs", None)
        if envs is not None:  # SyncVectorEnv: call the selected sub-environments only
            return [envs[i].get_wrapper_attr(method_name)(*method_args, **method_kwargs) for i in idx]
        results = self.venv.call(method_name, *method_args, **method_kwargs)  # type: ignore[attr-defined]
        return [results[i] for i in idx]

    def env_is_wrapped(self, wrapper_class: type[gym.Wrapper], indices: VecEnvIndices = None) -> list[bool]:
        idx = list(self._get_indices(indices))
        envs = getattr(self.venv, "envs", None)
        if envs is None:  # a native vector env has no per-sub-env wrappers
            return [False] * len(idx)
        from stable_baselines3.common import env_util

        return [env_util.is_wrapped(envs[i], wrapper_class) for i in idx]

    def get_images(self) -> Sequence[np.ndarray | None]:
        if self.render_mode != "rgb_array":
            warnings.warn(f"The render mode is {self.render_mode}, but this method assumes it is `rgb_array` "
                          "to obtain images.", stacklevel=2)
            return [None] * self.num_envs
        return list(self.venv.render() or ())  # type: ignore[arg-type]

    def render(self, mode: str | None = None) -> np.ndarray | None:
        return super().render(mode=mode)


def make_sb3_vec_env(env_id: str, n_envs: int = 1, seed: int | None = None, *, monitor: bool = True,
                     **kwargs: Any) -> VecEnv:
    """A ready-to-train SB3 ``VecEnv`` of ``n_envs`` copies of ``env_id`` in one line.

    The native vector env (``gym.make_vec(..., vectorization_mode="vector_entry_point",
    autoreset_mode=SAME_STEP, **kwargs)``; ids without a vector entry point get a
    ``SyncVectorEnv``) wrapped in `GymnasiumVecEnvAdapter`, seeded like SB3's
    ``make_vec_env`` (``seed(seed)``: sub-env ``i`` starts from ``seed + i`` at the first
    ``reset()``; None draws a random base seed) and, with ``monitor=True`` (default, the
    counterpart of ``make_vec_env``'s ``Monitor``), wrapped in ``VecMonitor`` so that SB3 logs
    episode returns and lengths.  ``kwargs`` go to the environment (``scenario=...``,
    ``max_episode_steps=...``, ...).
    """
    spec = gym.spec(env_id)
    if spec.vector_entry_point is not None:
        venv = gym.make_vec(env_id, num_envs=n_envs, vectorization_mode="vector_entry_point",
                            autoreset_mode=AutoresetMode.SAME_STEP, **kwargs)
    else:
        venv = gym.make_vec(env_id, num_envs=n_envs, vectorization_mode="sync",
                            vector_kwargs={"autoreset_mode": AutoresetMode.SAME_STEP}, **kwargs)
    adapter = GymnasiumVecEnvAdapter(venv)
    adapter.seed(seed)
    return VecMonitor(adapter) if monitor else adapter
