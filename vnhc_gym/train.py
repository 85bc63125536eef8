"""``vnhc-gym train``: PPO, residual PPO and SAC agents, and loading them back as policies.

Training
--------
``vnhc-gym train --algo ppo --env flocking --scenario nominal --seed 0`` trains one agent with
Stable-Baselines3 from the hyperparameters in ``agents/hyperparams/<env>.yml`` (RL Zoo's
format, one section per algorithm; see that file's header).  ``--algo`` is one of

* ``ppo``: PPO from scratch, acting on the force directly;
* ``residual_ppo``: PPO acting through :class:`vnhc_gym.wrappers.ResidualAction`: the applied
  action is ``clip(base(obs) + scale * a, -1, 1)`` with ``base`` the paper's geometric law
  (:class:`vnhc_gym.baselines.GeometricController`) and ``a`` the network's action; the policy
  starts near ``a = 0`` (small initial ``log_std``), i.e. near the geometric law;
* ``sac``: SAC (optional; not part of the headline comparison).

Seeds are explicit (``--seed``: SB3's seed and the training envs' seeds ``seed .. seed+n_envs-1``).
Every ``--eval-freq`` steps the current policy is evaluated with the package's protocol
(:func:`vnhc_gym.evaluation.evaluate`) on *validation* seeds (``--eval-seed``, default 5000+),
and the IQM of the per-episode mean ``|phi|`` is logged to TensorBoard (``eval/iqm_abs_phi``).
At the end the selected model (``--select best``: best validation IQM, including the untrained
step-0 policy; ``last``: the final one) is evaluated on held-out *test* seeds (``--test-seed``,
default 10000+).  The output folder gets ``<stem>.zip`` (the SB3 model), ``<stem>.json`` (sidecar:
env id, scenario, algo, seed, steps, wall time, hyperparameters, learning curve, test
evaluation, observation-normalisation statistics), ``<stem>_vecnormalize.pkl`` (SB3's
VecNormalize statistics, if normalisation is used) and ``tb/`` (TensorBoard logs).

Loading
-------
:func:`load_agent` returns an :class:`AgentPolicy`: ``predict(obs, deterministic=True)`` takes
*raw* environment observations (one ``(d,)`` or a batch ``(n, d)``), applies the saved
observation normalisation, runs the network and, for ``residual_ppo``, adds the geometric base
controller, so it returns the action the environment should receive.  Names without a path
(``"flocking-ppo"``) load from the package's ``vnhc_gym/agents_zoo``; any other path loads with a
warning, because SB3 ``.zip`` files contain pickled Python objects (load only files you trust).
"""

from __future__ import annotations

import argparse
import copy
import json
import math
import os
import platform
import sys
import time
import warnings
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

__all__ = [
    "ALGOS", "ENV_ALIASES", "ZOO_DIR", "HYPERPARAMS_DIR", "AgentPolicy", "UntrustedFileWarning",
    "add_arguments", "run", "main", "train", "load_agent", "load_hyperparams", "resolve_env_id", "env_short",
    "list_zoo", "summarize_eval", "evaluate_policy_protocol",
]

ENV_ALIASES = {"flocking": "vnhc_gym/FlockingAlign-v0", "usv": "vnhc_gym/USVStream-v0"}
_SHORT = {v: k for k, v in ENV_ALIASES.items()}
ALGOS = ("ppo", "residual_ppo", "sac")
ZOO_DIR = Path(__file__).resolve().parent / "agents_zoo"
HYPERPARAMS_DIR = Path(__file__).resolve().parent.parent / "agents" / "hyperparams"
VALIDATION_SEED = 5_000  #: first seed of the periodic (validation) evaluation episodes
TEST_SEED = 10_000  #: first seed of the held-out test episodes
SIDECAR_FORMAT = "vnhc_gym-agent/1"


class UntrustedFileWarning(UserWarning):
    """Loading a model file from outside the package (SB3 zips contain pickles)."""


# --------------------------------------------------------------------------- names and hyperparameters
def resolve_env_id(name: str) -> str:
    """``"flocking"`` / ``"usv"`` (or a full id) -> the registered env id."""
    if name in ENV_ALIASES:
        return ENV_ALIASES[name]
    if name in _SHORT:
        return name
    raise ValueError(f"unknown env {name!r}; valid: {sorted(ENV_ALIASES)} or {sorted(_SHORT)}")


def env_short(env_id: str) -> str:
    """``"vnhc_gym/FlockingAlign-v0"`` -> ``"flocking"``."""
    return _SHORT[resolve_env_id(env_id)]


def _hyperparams_dir() -> Path:
    try:  # the installed ``agents`` package (pyproject includes it)
        import agents

        for p in getattr(agents, "__path__", []):
            d = Path(p) / "hyperparams"
            if d.is_dir():
                return d
    except ImportError:  # pragma: no cover - source checkout without the package on the path
        pass
    return HYPERPARAMS_DIR


def load_hyperparams(env_id: str, algo: str, path: str | os.PathLike[str] | None = None) -> dict[str, Any]:
    """The settings of ``algo`` for ``env_id`` from a hyperparameter YAML (``yaml.safe_load`` only).

    ``path`` defaults to ``agents/hyperparams/<env-short>.yml``.  The file's top-level keys are
    algorithms; each section maps env ids to settings (an RL Zoo ``hyperparams/<algo>.yml``).
    """
    import yaml

    env_id = resolve_env_id(env_id)
    if algo not in ALGOS:
        raise ValueError(f"unknown algo {algo!r}; valid: {list(ALGOS)}")
    p = Path(path) if path is not None else _hyperparams_dir() / f"{env_short(env_id)}.yml"
    with open(p, encoding="utf-8") as f:
        doc = yaml.safe_load(f)
    if not isinstance(doc, dict) or algo not in doc or not isinstance(doc[algo], dict):
        raise ValueError(f"{p}: no section {algo!r} (sections: {sorted(doc) if isinstance(doc, dict) else []})")
    if env_id not in doc[algo]:
        raise ValueError(f"{p}: section {algo!r} has no entry {env_id!r} (entries: {sorted(doc[algo])})")
    return copy.deepcopy(doc[algo][env_id])


def parse_overrides(items: Sequence[str] | None) -> dict[str, Any]:
    """``["n_steps=64", "policy_kwargs.net_arch=[32, 32]"]`` -> nested dict (values via ``yaml.safe_load``)."""
    import yaml

    out: dict[str, Any] = {}
    for item in items or ():
        if "=" not in item:
            raise ValueError(f"hyperparameter override must be KEY=VALUE, got {item!r}")
        key, value = item.split("=", 1)
        parts = key.strip().split(".")
        d = out
        for p in parts[:-1]:
            d = d.setdefault(p, {})
        d[parts[-1]] = yaml.safe_load(value)
    return out


def _merge(base: dict[str, Any], over: dict[str, Any]) -> dict[str, Any]:
    out = copy.deepcopy(base)
    for k, v in over.items():
        if isinstance(v, dict) and isinstance(out.get(k), dict):
            out[k] = _merge(out[k], v)
        else:
            out[k] = v
    return out


def _schedule(value: Any) -> Any:
    """RL Zoo's ``"lin_3e-4"`` -> linear schedule; numbers pass through."""
    if isinstance(value, str) and value.startswith("lin_"):
        start = float(value[4:])

        def lin(progress_remaining: float) -> float:
            return progress_remaining * start

        return lin
    if isinstance(value, str):
        return float(value)
    return value


_ACTIVATIONS = {"tanh": "Tanh", "relu": "ReLU", "elu": "ELU", "leaky_relu": "LeakyReLU", "gelu": "GELU"}


def _policy_kwargs(pk: dict[str, Any] | None) -> dict[str, Any]:
    import torch.nn as nn

    pk = dict(pk or {})
    act = pk.get("activation_fn")
    if isinstance(act, str):
        name = _ACTIVATIONS.get(act.lower().removeprefix("nn."), act.removeprefix("nn."))
        if not hasattr(nn, name):
            raise ValueError(f"unknown activation_fn {act!r}; valid: {sorted(_ACTIVATIONS)}")
        pk["activation_fn"] = getattr(nn, name)
    return pk


def _jsonable(x: Any) -> Any:
    if isinstance(x, dict):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [_jsonable(v) for v in x]
    if isinstance(x, np.generic):
        return x.item()
    if isinstance(x, np.ndarray):
        return x.tolist()
    if isinstance(x, float | int | str | bool) or x is None:
        return x
    return repr(x)


# --------------------------------------------------------------------------- environments
def _make_base(env: Any, residual: dict[str, Any]) -> Any:
    from vnhc_gym.baselines import GeometricController
    from vnhc_gym.baselines.geometric import DEFAULT_GAIN

    gain = residual.get("gain")
    return GeometricController(env, gain=DEFAULT_GAIN if gain is None else gain,
                               variant=residual.get("base_variant", "plain"))


def residual_config(hp: dict[str, Any] | None) -> dict[str, Any]:
    """The ``residual`` section with defaults filled in."""
    r = dict((hp or {}).get("residual") or {})
    gain = r.get("gain", r.get("base_gain"))  # None: the baseline's DEFAULT_GAIN
    return {"scale": float(r.get("scale", 0.2)), "base_variant": str(r.get("base_variant", "plain")),
            "gain": None if gain is None else float(gain), "continuous": bool(r.get("continuous", False)),
            "zero_init": bool(r.get("zero_init", True))}


def _wrap_residual(env: Any, residual: dict[str, Any]) -> Any:
    from vnhc_gym.wrappers import ResidualAction

    kwargs: dict[str, Any] = {"base": _make_base(env, residual), "scale": residual["scale"]}
    if residual.get("continuous"):
        kwargs["continuous"] = True
    return ResidualAction(env, **kwargs)


def _residual_vec_env_class() -> type:
    from stable_baselines3.common.vec_env import VecEnvWrapper

    class ResidualVecEnv(VecEnvWrapper):
        """:class:`vnhc_gym.wrappers.ResidualAction` for a whole SB3 VecEnv at once.

        ``applied = clip(base(obs) + scale * clip(a, -1, 1), -1, 1)`` per sub-env, with the base
        policy called once per step on the batch of last observations (the per-env wrapper
        calls it once per sub-env).  Same arithmetic as ``ResidualAction``; the tests check
        that both give the same trajectories.
        """

        def __init__(self, venv: Any, base: Any, scale: float) -> None:
            super().__init__(venv)
            self.base = base
            self.scale = float(scale)
            self._last_obs: np.ndarray | None = None

        def reset(self) -> Any:
            obs = self.venv.reset()
            self._last_obs = np.asarray(obs)
            return obs

        def step_async(self, actions: np.ndarray) -> None:
            if self._last_obs is None:
                raise RuntimeError("call reset() before step()")
            b, _ = self.base.predict(self._last_obs, deterministic=True)
            a = np.asarray(actions, dtype=np.float64).reshape(np.shape(b))
            applied = np.clip(np.asarray(b, dtype=np.float64) + self.scale * np.clip(a, -1.0, 1.0), -1.0, 1.0)
            self.venv.step_async(applied.astype(np.float32))

        def step_wait(self) -> Any:
            obs, rewards, dones, infos = self.venv.step_wait()
            self._last_obs = np.asarray(obs)  # after an auto-reset: the new episode's first observation
            return obs, rewards, dones, infos

    return ResidualVecEnv


def _sb3_adapter() -> Callable[..., Any] | None:
    try:
        from vnhc_gym.sb3 import make_sb3_vec_env
    except ImportError:
        return None
    return make_sb3_vec_env


def make_train_env(env_id: str, scenario: str, n_envs: int, seed: int, residual: dict[str, Any] | None = None,
                   env_kwargs: dict[str, Any] | None = None, use_vector: bool = True) -> Any:
    """A VecEnv of ``n_envs`` training environments seeded ``seed .. seed + n_envs - 1``.

    The package's native vector env through its SB3 adapter (``vnhc_gym.sb3.make_sb3_vec_env``)
    when it is available (residual PPO then adds the residual for the whole batch at once, see
    ``ResidualVecEnv``); otherwise (or ``use_vector=False``) SB3's ``DummyVecEnv`` with a
    ``Monitor`` and, for residual PPO, :class:`vnhc_gym.wrappers.ResidualAction` per env.
    """
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.vec_env import VecMonitor

    kwargs = {"scenario": scenario, **(env_kwargs or {})}
    adapter = _sb3_adapter() if use_vector and not (residual and residual.get("continuous")) else None
    if adapter is not None:
        venv = adapter(env_id, n_envs, seed, **kwargs)
        if not _has_monitor(venv):
            venv = VecMonitor(venv)
        if residual is not None:
            import gymnasium as gym

            probe = gym.make(env_id, **kwargs)  # the base reads the nominal model, force bound and dt
            base = _make_base(probe, residual)
            probe.close()
            venv = _residual_vec_env_class()(venv, base, residual["scale"])
        return venv
    wrapper = None
    if residual is not None:
        def wrapper(env: Any) -> Any:
            return _wrap_residual(env, residual)
    return make_vec_env(env_id, n_envs=n_envs, seed=seed, env_kwargs=kwargs, wrapper_class=wrapper)


def _has_monitor(venv: Any) -> bool:
    from stable_baselines3.common.vec_env import VecEnvWrapper, VecMonitor

    v = venv
    while True:
        if isinstance(v, VecMonitor):
            return True
        if not isinstance(v, VecEnvWrapper):
            return False
        v = v.venv


# --------------------------------------------------------------------------- the policy object
class AgentPolicy:
    """A trained SB3 model as a policy on *raw* env observations (SB3-style ``predict``).

    ``predict`` normalises the observation with the saved statistics (if any), runs the
    network (deterministic by default), clips to ``[-1, 1]`` and, for residual agents, returns
    ``clip(base(obs) + scale * a, -1, 1)``, the action the environment receives.

    The residual base controller reads the *nominal* model, force bound and ``dt`` from an
    environment; it is built for ``meta["scenario"]`` unless :meth:`bind` is given the
    environment the agent will act in (needed when that env's scenario changes the force bound
    or ``dt``: ``saturated``, ``coarse``).
    """

    def __init__(self, model: Any, meta: dict[str, Any] | None = None, obs_rms: dict[str, Any] | None = None,
                 base: Any = None) -> None:
        self.model = model
        self.meta = dict(meta or {})
        self.method = _method_of(self.meta)
        self.env_id = self.meta.get("env_id")
        self.scenario = self.meta.get("scenario", "nominal")
        self.residual = residual_config(self.meta) if self.method == "residual_ppo" else None
        if self.residual is not None and self.residual["continuous"]:
            raise ValueError("a ResidualAction(continuous=True) agent runs the law inside the integrator; evaluate "
                             "its model inside that wrapper instead of as an AgentPolicy")
        self.obs_rms: dict[str, Any] | None = None
        if obs_rms is not None:
            self.obs_rms = {"mean": np.asarray(obs_rms["mean"], dtype=np.float64),
                            "var": np.asarray(obs_rms["var"], dtype=np.float64),
                            "epsilon": float(obs_rms.get("epsilon", 1e-8)),
                            "clip_obs": float(obs_rms.get("clip_obs", 10.0))}
        space = model.action_space
        self._low = np.asarray(space.low, dtype=np.float64)
        self._high = np.asarray(space.high, dtype=np.float64)
        self.obs_dim = int(np.prod(model.observation_space.shape))
        self.base = base
        self._mlp: _MLP | None = _extract_mlp(model)
        if self.residual is not None and self.base is None:
            self.bind(scenario=self.scenario, **(self.meta.get("env_kwargs") or {}))

    def bind(self, env: Any = None, *, scenario: str | None = None, **env_kwargs: Any) -> AgentPolicy:
        """(Re)build the residual base controller for ``env`` (or ``gym.make(env_id, scenario=...)``)."""
        if self.residual is None:
            return self
        if env is None:
            import gymnasium as gym

            import vnhc_gym  # noqa: F401  (registers the envs)

            if self.env_id is None:
                raise ValueError("the agent's env id is unknown (no sidecar): pass env= to bind()")
            env = gym.make(self.env_id, scenario=scenario or self.scenario, **env_kwargs)
            self.base = _make_base(env, self.residual)
            env.close()
        else:
            self.base = _make_base(env, self.residual)
        return self

    def normalize(self, obs: np.ndarray) -> np.ndarray:
        if self.obs_rms is None:
            return obs
        r = self.obs_rms
        return np.clip((obs - r["mean"]) / np.sqrt(r["var"] + r["epsilon"]), -r["clip_obs"], r["clip_obs"])

    def predict(self, obs: Any, state: Any = None, episode_start: Any = None,
                deterministic: bool = True) -> tuple[np.ndarray, None]:
        o = np.asarray(obs, dtype=np.float64)
        single = o.ndim == 1
        batch = o[None, :] if single else o
        if batch.ndim != 2 or batch.shape[1] != self.obs_dim:
            raise ValueError(f"observation must have shape ({self.obs_dim},) or (n, {self.obs_dim}), got {o.shape}")
        x = self.normalize(batch).astype(np.float32)
        if deterministic and self._mlp is not None:
            a = self._mlp_forward(x)
        else:
            a, _ = self.model.predict(x, deterministic=deterministic)
        a = np.clip(np.asarray(a, dtype=np.float64).reshape(batch.shape[0], -1), self._low, self._high)
        if self.residual is not None:
            b, _ = self.base.predict(batch.astype(np.float32), deterministic=True)
            a = np.clip(np.asarray(b, dtype=np.float64).reshape(a.shape) + self.residual["scale"] * a,
                        self._low, self._high)
        a32 = a.astype(np.float32)
        return (a32[0] if single else a32), None

    def _mlp_forward(self, x: np.ndarray) -> np.ndarray:
        h = x.astype(np.float32)
        assert self._mlp is not None
        layers, act = self._mlp
        for i, (w, b) in enumerate(layers):
            h = h @ w.T + b
            if i < len(layers) - 1:
                h = act(h)
        return h

    def __call__(self, obs: Any) -> np.ndarray:
        return self.predict(obs)[0]

    def reset(self) -> None:
        """Start of an episode (stateless: nothing to do)."""

    def __repr__(self) -> str:
        return f"AgentPolicy({self.meta.get('name', self.method)!r}, env={self.env_id!r}, scenario={self.scenario!r})"


_MLP = tuple[list[tuple[np.ndarray, np.ndarray]], Callable[[np.ndarray], np.ndarray]]


def _extract_mlp(model: Any) -> _MLP | None:
    """The deterministic actor of an SB3 PPO MLP policy as numpy layers (None if not that shape).

    ``predict`` then runs a few small matrix products instead of SB3's per-call torch overhead
    (evaluation runs ~10x faster); the tests check it against ``model.predict``.
    """
    try:
        import torch.nn as nn
        from stable_baselines3.common.distributions import DiagGaussianDistribution
        from stable_baselines3.common.policies import ActorCriticPolicy
        from stable_baselines3.common.torch_layers import FlattenExtractor

        pol = model.policy
        if (type(pol) is not ActorCriticPolicy or not isinstance(pol.pi_features_extractor, FlattenExtractor)
                or not isinstance(pol.action_dist, DiagGaussianDistribution) or pol.squash_output
                or len(model.observation_space.shape) != 1):
            return None
        mods = list(pol.mlp_extractor.policy_net) + [pol.action_net]
        acts = {type(m) for m in mods if not isinstance(m, nn.Linear)}
        if len(acts) > 1:
            return None
        table: dict[type, Callable[[np.ndarray], np.ndarray]] = {nn.Tanh: np.tanh,
                                                                 nn.ReLU: lambda v: np.maximum(v, 0.0)}
        act = table.get(next(iter(acts))) if acts else np.tanh
        if act is None:
            return None
        linears = [m for m in mods if isinstance(m, nn.Linear)]
        # Linear, act, Linear, act, ..., action_net: strictly alternating.
        expected = []
        for _ in linears[:-1]:
            expected += [nn.Linear, next(iter(acts))]
        expected.append(nn.Linear)
        if [type(m) for m in mods] != expected:
            return None
        layers = [(m.weight.detach().cpu().numpy().astype(np.float32).copy(),
                   m.bias.detach().cpu().numpy().astype(np.float32).copy()) for m in linears]
        return layers, act
    except Exception:  # noqa: BLE001 - any surprise: use SB3's predict
        return None


def _obs_rms_of(venv: Any) -> dict[str, Any] | None:
    from stable_baselines3.common.vec_env import VecNormalize

    if isinstance(venv, VecNormalize) and venv.norm_obs:
        stats: Any = venv.obs_rms  # a RunningMeanStd (flat observations)
        return {"mean": np.asarray(stats.mean, dtype=np.float64).copy(),
                "var": np.asarray(stats.var, dtype=np.float64).copy(),
                "epsilon": float(venv.epsilon), "clip_obs": float(venv.clip_obs)}
    return None


def _rms_json(rms: dict[str, Any] | None) -> dict[str, Any] | None:
    if rms is None:
        return None
    return {"mean": [float(v) for v in rms["mean"]], "var": [float(v) for v in rms["var"]],
            "epsilon": rms["epsilon"], "clip_obs": rms["clip_obs"]}


# --------------------------------------------------------------------------- evaluation protocol
def summarize_eval(result: Any) -> dict[str, Any]:
    """Plain-dict summary of an :class:`vnhc_gym.evaluation.EvalResult`: per-episode mean |phi|,
    its IQM with the protocol's 95% bootstrap CI, mean, and the termination count."""
    scores = np.asarray(result.mean_abs_phi, dtype=np.float64)
    agg = result.summary()["mean_abs_phi"]
    return {"episodes": [float(v) for v in scores], "n_episodes": int(scores.size), "iqm": float(agg.iqm),
            "ci_low": float(agg.ci_low), "ci_high": float(agg.ci_high), "mean": float(agg.mean),
            "terminated": int(np.sum(result.terminated))}


def iqm_of(x: np.ndarray) -> float:
    """Interquartile mean, ``scipy.stats.trim_mean(x, 0.25)`` (as :func:`vnhc_gym.evaluation.iqm`)."""
    from scipy import stats

    x = np.asarray(x, dtype=np.float64).ravel()
    return float(stats.trim_mean(x, 0.25)) if x.size else float("nan")


def bootstrap_ci(groups: Sequence[np.ndarray], stat: Callable[[np.ndarray], float], n_boot: int = 2000,
                 seed: int = 0, level: float = 0.95) -> tuple[float, float]:
    """Percentile CI of ``stat`` of the pooled scores under a two-level bootstrap.

    ``groups`` are the per-run score arrays (e.g. the test episodes of each training seed):
    runs are resampled with replacement, then episodes within each resampled run.  With a
    single group this is the ordinary bootstrap over episodes.
    """
    rng = np.random.default_rng(seed)
    gs = [np.asarray(g, dtype=np.float64).ravel() for g in groups if np.size(g)]
    if not gs:
        return float("nan"), float("nan")
    vals = np.empty(n_boot)
    for b in range(n_boot):
        pick = rng.integers(len(gs), size=len(gs)) if len(gs) > 1 else [0]
        pooled = np.concatenate([gs[i][rng.integers(gs[i].size, size=gs[i].size)] for i in pick])
        vals[b] = stat(pooled)
    a = (1.0 - level) / 2.0
    return float(np.quantile(vals, a)), float(np.quantile(vals, 1.0 - a))


def evaluate_policy_protocol(policy: Any, env_id: str, scenario: str, n_episodes: int, seed: int,
                             env_kwargs: dict[str, Any] | None = None, max_time: float = 20.0) -> dict[str, Any]:
    """:func:`vnhc_gym.evaluation.evaluate` + :func:`summarize_eval`."""
    from vnhc_gym.evaluation import evaluate

    result = evaluate(policy, env_id, scenario=scenario, n_episodes=n_episodes, seed=seed, env_kwargs=env_kwargs,
                      max_time=max_time)
    out = summarize_eval(result)
    out.update(seed=int(seed), scenario=scenario)
    return out


# --------------------------------------------------------------------------- training
def _callback_class() -> type:
    from stable_baselines3.common.callbacks import BaseCallback

    class PeriodicEvaluation(BaseCallback):
        """Every ``eval_freq`` env steps: evaluate with the package protocol on validation seeds."""

        def __init__(self, make_policy: Callable[[], AgentPolicy], env_id: str, scenario: str, eval_freq: int,
                     n_episodes: int, seed: int, env_kwargs: dict[str, Any] | None, on_best: Callable[[], None],
                     verbose: int = 0) -> None:
            super().__init__(verbose)
            self.make_policy = make_policy
            self.env_id, self.scenario = env_id, scenario
            self.eval_freq, self.n_episodes, self.seed = int(eval_freq), int(n_episodes), int(seed)
            self.env_kwargs = env_kwargs
            self.on_best = on_best
            self.curve: list[dict[str, Any]] = []
            self.best = math.inf
            self.best_step = 0
            self._next = 0
            self._t0 = time.perf_counter()
            self.eval_time = 0.0

        def evaluate_now(self) -> None:
            t = time.perf_counter()
            s = evaluate_policy_protocol(self.make_policy(), self.env_id, self.scenario, self.n_episodes, self.seed,
                                         self.env_kwargs)
            self.eval_time += time.perf_counter() - t
            point = {"step": int(self.num_timesteps), "iqm": s["iqm"], "ci_low": s["ci_low"],
                     "ci_high": s["ci_high"], "mean": s["mean"], "wall_s": time.perf_counter() - self._t0}
            self.curve.append(point)
            self.logger.record("eval/iqm_abs_phi", s["iqm"])
            self.logger.record("eval/mean_abs_phi", s["mean"])
            if np.isfinite(s["iqm"]) and s["iqm"] < self.best:
                self.best, self.best_step = s["iqm"], int(self.num_timesteps)
                self.on_best()
            if self.verbose:
                print(f"[eval] step {self.num_timesteps}: IQM mean|phi| {s['iqm']:.4g} "
                      f"[{s['ci_low']:.4g}, {s['ci_high']:.4g}]", flush=True)

        def _on_training_start(self) -> None:
            self._t0 = time.perf_counter()
            if self.eval_freq > 0:
                self.evaluate_now()
                self.logger.dump(self.num_timesteps)
                self._next = self.eval_freq

        def _on_step(self) -> bool:
            if self.eval_freq > 0 and self.num_timesteps >= self._next:
                self.evaluate_now()
                while self._next <= self.num_timesteps:
                    self._next += self.eval_freq
            return True

    return PeriodicEvaluation


def code_fingerprint() -> str:
    """Behavioural fingerprint of the task definition, recorded by every run.

    A hash of short seeded rollouts of both environments in every scenario (observations,
    rewards, |phi|) under both geometric-law variants with the default gain, of the native
    vector env through the SB3 adapter, and of the evaluation protocol's per-episode metric.
    Runs whose fingerprints differ were trained on environments that behave differently;
    cosmetic code edits do not change it (``experiments/train_compare.py`` retrains stale runs).
    """
    import hashlib
    import warnings as _w

    import gymnasium as gym

    import vnhc_gym
    from vnhc_gym.baselines import GeometricController
    from vnhc_gym.baselines.geometric import DEFAULT_GAIN
    from vnhc_gym.envs.task import SCENARIOS

    h = hashlib.sha256(np.float64(DEFAULT_GAIN).tobytes())
    with _w.catch_warnings():
        _w.simplefilter("ignore")
        for env_id in vnhc_gym.ENV_IDS:
            for scenario in sorted(SCENARIOS):
                env = gym.make(env_id, scenario=scenario)
                for variant in ("plain",):
                    ctrl = GeometricController(env, variant=variant)
                    obs, _ = env.reset(seed=12345)
                    h.update(np.asarray(obs).tobytes())
                    for t in range(25):
                        a, _ = ctrl.predict(obs)
                        a = np.clip(np.asarray(a, dtype=np.float64) + 0.1 * math.sin(t), -1, 1).astype(np.float32)
                        obs, r, term, trunc, info = env.step(a)
                        h.update(np.asarray(obs).tobytes())
                        h.update(np.float64(r).tobytes())
                        h.update(np.float64(info["abs_phi"]).tobytes())
                        if term or trunc:
                            break
                env.close()
            adapter = _sb3_adapter()
            if adapter is not None:
                venv = adapter(env_id, 2, 7, scenario="nominal")
                h.update(np.asarray(venv.reset()).tobytes())
                for t in range(10):
                    act = np.full((2, *venv.action_space.shape), 0.3 * math.cos(t), dtype=np.float32)
                    obs, rew, _, _ = venv.step(act)
                    h.update(np.asarray(obs).tobytes())
                    h.update(np.asarray(rew).tobytes())
                venv.close()
            from vnhc_gym.evaluation import evaluate

            res = evaluate(lambda e: GeometricController(e), env_id, "nominal", n_episodes=2, seed=3, max_time=1.0)
            h.update(np.asarray(res.mean_abs_phi, dtype=np.float64).tobytes())
    return h.hexdigest()[:16]


def _set_threads(n: int = 1) -> None:
    import torch

    torch.set_num_threads(n)
    try:
        torch.set_num_interop_threads(n)
    except RuntimeError:  # already set (or parallel work started) in this process
        pass


def train(env: str, algo: str, scenario: str = "nominal", seed: int = 0, *, n_timesteps: int | None = None,
          hyperparams: dict[str, Any] | None = None, hyperparams_file: str | os.PathLike[str] | None = None,
          output: str | os.PathLike[str] | None = None, name: str | None = None, eval_freq: int | None = None,
          eval_episodes: int = 10, eval_seed: int = VALIDATION_SEED, test_episodes: int = 20,
          test_seed: int = TEST_SEED, select: str = "best", tensorboard: bool = True, progress_bar: bool = True,
          env_kwargs: dict[str, Any] | None = None, use_vector_env: bool = True, torch_threads: int = 1,
          verbose: int = 0, device: str = "cpu") -> dict[str, Any]:
    """Train one agent; write ``<output>/<name>.zip`` + ``.json`` (+ VecNormalize stats); return the sidecar.

    ``hyperparams`` (a nested dict) overrides the YAML entry; ``n_timesteps`` overrides both.
    ``eval_freq`` (env steps; default ``n_timesteps // 10``, 0 disables) sets the periodic
    validation evaluation; ``select`` is ``"best"`` (best validation IQM) or ``"last"``.
    """
    t_start = time.perf_counter()
    fingerprint = code_fingerprint()  # before anything is imported: the code this run uses
    _set_threads(torch_threads)
    import gymnasium  # noqa: F401
    import stable_baselines3 as sb3
    import torch
    from stable_baselines3 import PPO, SAC
    from stable_baselines3.common.utils import set_random_seed
    from stable_baselines3.common.vec_env import VecNormalize

    import vnhc_gym

    env_id = resolve_env_id(env)
    if algo not in ALGOS:
        raise ValueError(f"unknown algo {algo!r}; valid: {list(ALGOS)}")
    if select not in ("best", "last"):
        raise ValueError(f"select must be 'best' or 'last', got {select!r}")
    hp = _merge(load_hyperparams(env_id, algo, hyperparams_file), hyperparams or {})
    if n_timesteps is not None:
        hp["n_timesteps"] = n_timesteps
    hp_used = copy.deepcopy(hp)
    total = int(float(hp.pop("n_timesteps")))
    n_envs = int(hp.pop("n_envs", 1))
    policy = hp.pop("policy", "MlpPolicy")
    normalize = hp.pop("normalize", False)
    residual = residual_config({"residual": hp.pop("residual", None)}) if algo == "residual_ppo" else None
    # Training-only env arguments (reward settings such as phi_scale); evaluation uses the plain scenario.
    train_env_kwargs = {**(hp.pop("train_env_kwargs", None) or {}), **(env_kwargs or {})}
    for key in ("env_wrapper", "frame_stack", "callback", "vec_env_wrapper"):
        if hp.pop(key, None) is not None:
            raise ValueError(f"hyperparameter {key!r} (RL Zoo) is not supported here")
    hp["policy_kwargs"] = _policy_kwargs(hp.get("policy_kwargs"))
    for key in ("learning_rate", "clip_range", "clip_range_vf"):
        if key in hp:
            hp[key] = _schedule(hp[key])
    eval_freq = max(total // 10, 1) if eval_freq is None else int(eval_freq)

    short = env_short(env_id)
    name = name or f"{short}-{algo}"
    out = Path(output) if output is not None else Path("runs") / f"{short}-{algo}-{scenario}-s{seed}"
    out.mkdir(parents=True, exist_ok=True)

    set_random_seed(seed)
    venv = make_train_env(env_id, scenario, n_envs, seed, residual, train_env_kwargs, use_vector=use_vector_env)
    if normalize:
        nk = dict(normalize) if isinstance(normalize, dict) else {}
        nk.setdefault("gamma", float(hp.get("gamma", 0.99)))
        venv = VecNormalize(venv, **nk)
    cls = {"ppo": PPO, "residual_ppo": PPO, "sac": SAC}[algo]
    tb = str(out / "tb") if tensorboard else None
    model = cls(policy, venv, seed=seed, device=device, verbose=verbose, tensorboard_log=tb, **hp)
    if residual is not None and residual.get("zero_init", True):
        # Start exactly at the base controller: the mean residual is 0 for every observation.
        # (SB3's 0.01-gain init still gives a small state-dependent bias, and the flocking
        # constraint is very sensitive to a constant force bias late in an episode.)
        import torch as th

        with th.no_grad():
            model.policy.action_net.weight.zero_()
            model.policy.action_net.bias.zero_()

    # "algo" is the SB3 class name (what `vnhc-gym benchmark` reads), "method" the --algo choice.
    meta: dict[str, Any] = {"format": SIDECAR_FORMAT, "name": name, "env_id": env_id, "env_short": short,
                            "scenario": scenario, "algo": cls.__name__, "method": algo, "seed": int(seed),
                            "residual": residual, "env_kwargs": env_kwargs or {}}
    eval_base = None
    if residual is not None:  # one base controller for all evaluations (the scenario is fixed)
        eval_base = AgentPolicy(model, meta).base

    def current_policy() -> AgentPolicy:
        return AgentPolicy(model, meta, _obs_rms_of(venv), base=eval_base)

    best_state: dict[str, Any] = {}

    def on_best() -> None:
        best_state["params"] = copy.deepcopy(model.policy.state_dict())
        best_state["rms"] = _obs_rms_of(venv)

    cb = _callback_class()(current_policy, env_id, scenario, eval_freq, eval_episodes, eval_seed, env_kwargs,
                           on_best, verbose=verbose)
    t_learn = time.perf_counter()
    model.learn(total_timesteps=total, callback=cb, progress_bar=progress_bar, tb_log_name=name)
    learn_s = time.perf_counter() - t_learn
    if eval_freq > 0 and (not cb.curve or cb.curve[-1]["step"] != model.num_timesteps):
        cb.evaluate_now()  # the final policy is always on the curve (and a best candidate)

    # Test evaluation of the last policy, then of the selected one.
    last_rms = _obs_rms_of(venv)
    last_test = evaluate_policy_protocol(AgentPolicy(model, meta, last_rms, base=eval_base), env_id, scenario,
                                         test_episodes, test_seed, env_kwargs) if test_episodes > 0 else None
    chosen = "last"
    rms = last_rms
    if select == "best" and best_state and cb.best_step != model.num_timesteps:
        model.policy.load_state_dict(best_state["params"])
        rms = best_state["rms"]
        chosen = "best"
        test = evaluate_policy_protocol(AgentPolicy(model, meta, rms, base=eval_base), env_id, scenario,
                                        test_episodes, test_seed, env_kwargs) if test_episodes > 0 else None
    else:
        test = last_test

    model_path = out / f"{name}.zip"
    model.save(model_path)
    vecnorm_path = None
    if isinstance(venv, VecNormalize):
        if rms is not None:  # save the statistics that go with the saved parameters
            stats: Any = venv.obs_rms
            stats.mean[...] = rms["mean"]
            stats.var[...] = rms["var"]
        vecnorm_path = out / f"{name}_vecnormalize.pkl"
        venv.save(str(vecnorm_path))
    venv.close()

    sidecar = {
        **meta,
        "n_timesteps": total,
        "steps": int(model.num_timesteps),
        "n_envs": n_envs,
        "hyperparams": _jsonable(hp_used),
        "wall_time_s": round(time.perf_counter() - t_start, 2),
        "learn_time_s": round(learn_s, 2),
        "eval_time_s": round(cb.eval_time, 2),
        "steps_per_s": round(model.num_timesteps / max(learn_s - cb.eval_time, 1e-9), 1),
        "selected": chosen,
        "selected_step": int(cb.best_step if chosen == "best" else model.num_timesteps),
        "validation": {"seed": int(eval_seed), "n_episodes": int(eval_episodes), "curve": cb.curve},
        "final_eval": test,
        "last_eval": last_test,
        "obs_normalization": _rms_json(rms),
        "files": {"model": model_path.name, "vecnormalize": vecnorm_path.name if vecnorm_path else None},
        "versions": {"vnhc_gym": vnhc_gym.__version__, "stable_baselines3": sb3.__version__,
                     "torch": torch.__version__, "gymnasium": gymnasium.__version__,
                     "python": platform.python_version()},
        "created": time.strftime("%Y-%m-%dT%H:%M:%S"),
        "code_fingerprint": fingerprint,
    }
    with open(out / f"{name}.json", "w", encoding="utf-8") as f:
        json.dump(_jsonable(sidecar), f, indent=1)
    return sidecar


# --------------------------------------------------------------------------- loading
def list_zoo() -> list[str]:
    """Names of the agents shipped in ``vnhc_gym/agents_zoo`` (``"<env-short>-<algo>"``)."""
    if not ZOO_DIR.is_dir():
        return []
    return sorted(p.stem for p in ZOO_DIR.glob("*.zip") if p.with_suffix(".json").exists())


def _resolve_model_path(path_or_name: str | os.PathLike[str]) -> tuple[Path, bool]:
    """-> (path of the .zip, trusted).  Bare names are looked up in the package's zoo."""
    s = str(path_or_name)
    if os.sep not in s and "/" not in s and not s.endswith(".zip"):
        p = ZOO_DIR / f"{s}.zip"
        if p.exists():
            return p, True
        raise FileNotFoundError(f"no shipped agent {s!r} in {ZOO_DIR}; shipped: {list_zoo()}; "
                                "pass a path to load your own file")
    p = Path(s)
    if not p.exists() and p.suffix != ".zip" and p.with_suffix(".zip").exists():
        p = p.with_suffix(".zip")
    if not p.exists():
        raise FileNotFoundError(f"no model file {p}")
    p = p.resolve()
    trusted = p.parent == ZOO_DIR.resolve()
    return p, trusted


def load_agent(path_or_name: str | os.PathLike[str], *, env: Any = None, scenario: str | None = None,
               device: str = "cpu") -> AgentPolicy:
    """Load a trained agent as an :class:`AgentPolicy` (``predict`` on raw observations).

    ``path_or_name``: a shipped agent's name (``"flocking-ppo"``, see :func:`list_zoo`) or a path
    to an SB3 ``.zip`` (its ``.json`` sidecar beside it is read when present).  Files from
    outside the package trigger an :class:`UntrustedFileWarning`: SB3 zips contain pickled
    Python objects, and unpickling runs code; only load files you trust.
    ``env`` / ``scenario``: build a residual agent's base controller for this environment /
    scenario instead of the one it was trained on (matters for ``saturated`` and ``coarse``).
    """
    path, trusted = _resolve_model_path(path_or_name)
    if not trusted:
        warnings.warn(f"loading {path}: Stable-Baselines3 .zip files contain pickled Python objects, and "
                      "loading one can execute arbitrary code. Only load files you trust.",
                      UntrustedFileWarning, stacklevel=2)
    side = path.with_suffix(".json")
    meta: dict[str, Any] = {}
    if side.exists():
        with open(side, encoding="utf-8") as f:
            meta = json.load(f)
    from stable_baselines3 import PPO, SAC

    custom = {"learning_rate": 0.0, "lr_schedule": lambda _: 0.0, "clip_range": lambda _: 0.0}
    model: Any
    if meta.get("algo") is None and meta.get("method") is None:
        if "residual_" in path.stem:
            meta["method"] = "residual_ppo"
        try:
            model = PPO.load(path, device=device, custom_objects=custom)
            meta["algo"] = "PPO"
        except Exception:  # noqa: BLE001 - not a PPO zip: try SAC
            model = SAC.load(path, device=device, custom_objects=custom)
            meta["algo"] = "SAC"
    else:
        cls: Any = SAC if _method_of(meta) == "sac" else PPO
        model = cls.load(path, device=device, custom_objects=custom)
    if meta.get("env_id") is None:
        meta["env_id"] = _guess_env(model)
    rms = meta.get("obs_normalization")
    if rms is None and meta.get("files", {}).get("vecnormalize"):
        rms = _load_vecnormalize_stats(path.parent / meta["files"]["vecnormalize"])
    meta.setdefault("name", path.stem)
    agent = AgentPolicy(model, meta, rms, base=None if (env is None and scenario is None) else _NO_BASE)
    if agent.residual is not None and (env is not None or scenario is not None):
        agent.bind(env, scenario=scenario)
    return agent


def _method_of(meta: dict[str, Any]) -> str:
    """``ppo`` / ``residual_ppo`` / ``sac`` from a sidecar (``method``, else ``algo`` and ``residual``)."""
    method = meta.get("method")
    if method in ALGOS:
        return str(method)
    algo = str(meta.get("algo", "ppo")).lower()
    if algo in ("residual_ppo",):
        return "residual_ppo"
    if meta.get("residual"):
        return "residual_ppo"
    return "sac" if algo == "sac" else "ppo"


_NO_BASE = object()  # placeholder: AgentPolicy builds no default base, bind() follows


def _guess_env(model: Any) -> str | None:
    shape = tuple(getattr(model.observation_space, "shape", None) or ())
    return {(12,): ENV_ALIASES["flocking"], (14,): ENV_ALIASES["usv"]}.get(shape)


def _load_vecnormalize_stats(p: Path) -> dict[str, Any] | None:
    if not p.exists():
        return None
    import pickle

    with open(p, "rb") as f:
        vn = pickle.load(f)  # noqa: S301 - only reached for files the caller was warned about or shipped
    if not getattr(vn, "norm_obs", False):
        return None
    return {"mean": vn.obs_rms.mean, "var": vn.obs_rms.var, "epsilon": vn.epsilon, "clip_obs": vn.clip_obs}


# --------------------------------------------------------------------------- CLI
def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``vnhc-gym train``."""
    parser.add_argument("--algo", required=True, choices=ALGOS, help="ppo, residual_ppo (PPO through ResidualAction) "
                        "or sac")
    parser.add_argument("--env", required=True, help="flocking, usv, or a full env id")
    parser.add_argument("--scenario", default="nominal", help="training (and evaluation) scenario")
    parser.add_argument("--seed", type=int, default=0, help="random seed (SB3 and env seeds)")
    parser.add_argument("-n", "--n-timesteps", type=int, default=None, help="override the YAML's n_timesteps")
    parser.add_argument("-params", "--hyperparams", nargs="+", default=None, metavar="KEY=VALUE",
                        help="override hyperparameters (values parsed as YAML; nested keys with dots), "
                             "e.g. n_steps=64 policy_kwargs.net_arch=[32,32]")
    parser.add_argument("-conf", "--conf-file", default=None, help="hyperparameter YAML (default: "
                        "agents/hyperparams/<env>.yml)")
    parser.add_argument("-f", "--output", default=None,
                        help="output folder (default runs/<env>-<algo>-<scenario>-s<seed>)")
    parser.add_argument("--name", default=None, help="file stem (default <env-short>-<algo>)")
    parser.add_argument("--eval-freq", type=int, default=None, help="validation evaluation every N env steps "
                        "(default n_timesteps/10; 0 disables)")
    parser.add_argument("--eval-episodes", type=int, default=10)
    parser.add_argument("--eval-seed", type=int, default=VALIDATION_SEED, help="first validation episode seed")
    parser.add_argument("--test-episodes", type=int, default=20, help="held-out test episodes at the end (0: none)")
    parser.add_argument("--test-seed", type=int, default=TEST_SEED, help="first test episode seed")
    parser.add_argument("--select", choices=("best", "last"), default="best",
                        help="save the best-on-validation or the last policy")
    parser.add_argument("--no-tensorboard", action="store_true")
    parser.add_argument("--no-progress-bar", action="store_true")
    parser.add_argument("--no-vector-env", action="store_true", help="use DummyVecEnv even if the native "
                        "vector env adapter is available")
    parser.add_argument("--torch-threads", type=int, default=1)
    parser.add_argument("-v", "--verbose", type=int, default=1)


def run(args: argparse.Namespace) -> int:
    """Run ``vnhc-gym train``."""
    side = train(args.env, args.algo, args.scenario, args.seed, n_timesteps=args.n_timesteps,
                 hyperparams=parse_overrides(args.hyperparams), hyperparams_file=args.conf_file, output=args.output,
                 name=args.name, eval_freq=args.eval_freq, eval_episodes=args.eval_episodes,
                 eval_seed=args.eval_seed, test_episodes=args.test_episodes, test_seed=args.test_seed,
                 select=args.select, tensorboard=not args.no_tensorboard, progress_bar=not args.no_progress_bar,
                 use_vector_env=not args.no_vector_env, torch_threads=args.torch_threads,
                 verbose=max(args.verbose - 1, 0))
    default_out = Path("runs") / f"{side['env_short']}-{args.algo}-{args.scenario}-s{args.seed}"
    out = Path(args.output) if args.output else default_out
    fe = side.get("final_eval")
    msg = f"saved {out / side['files']['model']} ({side['steps']} steps, {side['wall_time_s']:.1f} s)"
    if fe:
        msg += (f"; test IQM mean|phi| {fe['iqm']:.4g} [{fe['ci_low']:.4g}, {fe['ci_high']:.4g}] "
                f"on {fe['n_episodes']} episodes (seed {fe['seed']}+), model: {side['selected']}")
    if args.verbose:
        print(msg, flush=True)
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """Stand-alone entry point (``python -m vnhc_gym.train``, ``agents/train.py``)."""
    parser = argparse.ArgumentParser(prog="vnhc-gym train", description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    add_arguments(parser)
    return run(parser.parse_args(argv))


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
