"""PPO compiled with its environment: rollout, advantages and updates in one XLA program.

The environment is the task's pure JAX step (`vnhc_gym.envs.functional`, gymnax's interface), so a
whole training iteration (``n_steps`` steps of ``n_envs`` episodes, GAE, ``n_epochs`` passes of
minibatch updates) is one call of a compiled function, and ``jax.vmap`` over the random key trains
several seeds in the same program.  This is PureJaxRL's design; the algorithm is Stable-Baselines3's
PPO, so that a hyperparameter file means the same thing to both backends:

* separate policy and value networks (``net_arch`` hidden layers each, ``activation_fn``),
  orthogonal initialisation (gain ``sqrt 2`` for hidden layers, 0.01 for the action head, 1 for the
  value head), a state-independent log standard deviation starting at ``log_std_init``;
* a Gaussian action, clipped to ``[-1, 1]`` for the environment, its unclipped value in the loss;
* ``VecNormalize``'s reward scaling (``norm_reward``): the reward divided by the running standard
  deviation of the discounted return, clipped to ``clip_reward``;
* a truncated episode's last reward bootstraps on its final observation's value (SB3's
  ``terminal_observation`` handling), a terminated one does not;
* GAE, advantages normalised per minibatch, the clipped surrogate, the value loss unclipped, Adam
  (``eps = 1e-5``) after clipping the gradient's global norm, a learning rate (and clip range)
  constant or linear to 0 over the run, updated once per iteration.

Every key of the file must be one of `KNOWN_KEYS`: a key this trainer does not implement raises
instead of being ignored.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from functools import partial
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optax

from vnhc_gym.envs.functional import EnvParams, EnvState, FunctionalEnv
from vnhc_gym.training.hyperparams import checked_section

__all__ = ["KNOWN_KEYS", "PPOSettings", "TrainState", "actor_apply", "gae", "init", "init_params", "iteration",
           "iterations", "settings_from", "shuffle", "to_numpy"]

Array = Any  # a jax.Array
Params = dict[str, Any]

#: The hyperparameter keys the compiled PPO reads (RL Zoo's and stable_baselines3.PPO's names).
KNOWN_KEYS = frozenset({"n_envs", "n_timesteps", "policy", "normalize", "n_steps", "batch_size", "n_epochs", "gamma",
                        "gae_lambda", "learning_rate", "clip_range", "ent_coef", "vf_coef", "max_grad_norm",
                        "policy_kwargs"})
_POLICY_KWARGS = frozenset({"net_arch", "activation_fn", "log_std_init", "ortho_init"})
_NORMALIZE_KWARGS = frozenset({"norm_obs", "norm_reward", "clip_reward", "gamma", "epsilon"})
#: Hidden-layer activations by the torch class name a file gives (``nn.Tanh``).
ACTIVATIONS: dict[str, Callable[[Array], Array]] = {"Tanh": jnp.tanh, "ReLU": jax.nn.relu, "ELU": jax.nn.elu,
                                                    "LeakyReLU": jax.nn.leaky_relu, "SiLU": jax.nn.silu}


class PPOSettings(NamedTuple):
    """Stable-Baselines3's PPO settings with their defaults (hashable: a static argument)."""

    n_envs: int = 8
    n_timesteps: int = 1_000_000
    n_steps: int = 2048
    batch_size: int = 64
    n_epochs: int = 10
    gamma: float = 0.99
    gae_lambda: float = 0.95
    learning_rate: float = 3e-4
    lr_linear: bool = False  #: ``lin_<x>``: from x to 0 over the run
    clip_range: float = 0.2
    clip_linear: bool = False
    ent_coef: float = 0.0
    vf_coef: float = 0.5
    max_grad_norm: float = 0.5
    net_arch: tuple[int, ...] = (64, 64)
    activation: str = "Tanh"
    log_std_init: float = 0.0
    ortho_init: bool = True
    norm_reward: bool = False
    clip_reward: float = 10.0
    epsilon: float = 1e-8

    @property
    def rollout(self) -> int:
        """Env steps per iteration."""
        return self.n_envs * self.n_steps

    @property
    def n_iterations(self) -> int:
        """Iterations of a run: as SB3, whole rollouts until ``n_timesteps`` is reached."""
        return math.ceil(self.n_timesteps / self.rollout)


def _schedule(value: Any, key: str) -> tuple[float, bool]:
    if isinstance(value, str):
        if not value.startswith("lin_"):
            raise ValueError(f"{key}: a schedule must be a number or 'lin_<value>', got {value!r}")
        return float(value[4:]), True
    return float(value), False


def settings_from(hp: Mapping[str, Any], where: str = "hyperparameters") -> PPOSettings:
    """`PPOSettings` from a hyperparameter file's section (as `load_hyperparams` returns it).

    Raises ``ValueError`` naming every key (of the section, of ``policy_kwargs``, of ``normalize``)
    that the compiled PPO does not implement, and a value it cannot honour (a policy other than
    ``MlpPolicy``, observation normalisation, a batch size that does not divide the rollout).
    """
    pk = checked_section(hp, KNOWN_KEYS, _POLICY_KWARGS, "the compiled PPO (backend 'jax')", where)
    kw: dict[str, Any] = {}
    if "net_arch" in pk:
        arch = pk["net_arch"]
        if isinstance(arch, dict):
            if list(arch.get("pi", [])) != list(arch.get("vf", [])):
                raise ValueError(f"{where}: the compiled PPO needs the same net_arch for pi and vf, got {arch}")
            arch = arch["pi"]
        kw["net_arch"] = tuple(int(n) for n in arch)
    if "activation_fn" in pk:
        name = getattr(pk["activation_fn"], "__name__", str(pk["activation_fn"])).rsplit(".", 1)[-1]
        if name not in ACTIVATIONS:
            raise ValueError(f"{where}: activation_fn {name!r} is not one of {sorted(ACTIVATIONS)}")
        kw["activation"] = name
    for key in ("log_std_init",):
        if key in pk:
            kw[key] = float(pk[key])
    if "ortho_init" in pk:
        kw["ortho_init"] = bool(pk["ortho_init"])
    norm = hp.get("normalize", False)
    if isinstance(norm, Mapping):
        unknown = sorted(set(norm) - _NORMALIZE_KWARGS)
        if unknown:
            raise ValueError(f"{where}: normalize {unknown} are not implemented by the compiled PPO")
        if norm.get("norm_obs", True):
            raise ValueError(f"{where}: the compiled PPO does not normalise observations (norm_obs=False: "
                             f"the observations of every task are already of order 1)")
        kw["norm_reward"] = bool(norm.get("norm_reward", True))
        kw["clip_reward"] = float(norm.get("clip_reward", 10.0))
        kw["epsilon"] = float(norm.get("epsilon", 1e-8))
    elif norm:
        raise ValueError(f"{where}: normalize: true normalises observations, which the compiled PPO does not; "
                         f"give \"dict(norm_obs=False, norm_reward=True)\"")
    for key in ("n_envs", "n_timesteps", "n_steps", "batch_size", "n_epochs"):
        if key in hp:
            kw[key] = int(hp[key])
    for key in ("gamma", "gae_lambda", "ent_coef", "vf_coef", "max_grad_norm"):
        if key in hp:
            kw[key] = float(hp[key])
    if "learning_rate" in hp:
        kw["learning_rate"], kw["lr_linear"] = _schedule(hp["learning_rate"], "learning_rate")
    if "clip_range" in hp:
        kw["clip_range"], kw["clip_linear"] = _schedule(hp["clip_range"], "clip_range")
    s = PPOSettings(**kw)
    if s.rollout % s.batch_size:
        raise ValueError(f"{where}: batch_size {s.batch_size} must divide n_envs x n_steps = {s.rollout} "
                         f"(the compiled PPO's minibatches are equal)")
    return s


# ---------------------------------------------------------------------------------------------- networks
def _dense(key: Array, n_in: int, n_out: int, gain: float, ortho: bool) -> dict[str, Array]:
    if ortho:
        w = jax.nn.initializers.orthogonal(gain)(key, (n_in, n_out), jnp.float32)
    else:  # torch's default for nn.Linear: U(-1/sqrt(n_in), 1/sqrt(n_in))
        w = jax.random.uniform(key, (n_in, n_out), jnp.float32, -1.0, 1.0) / math.sqrt(n_in)
    return {"w": w, "b": jnp.zeros(n_out, jnp.float32)}


def init_params(key: Array, *, s: PPOSettings, obs_dim: int, act_dim: int) -> Params:
    """The policy (``pi`` layers, ``pi_out``, ``log_std``) and value (``vf`` layers, ``vf_out``)
    networks at SB3's initialisation."""
    sizes = (obs_dim, *s.net_arch)
    keys = iter(jax.random.split(key, 2 * len(s.net_arch) + 2))
    hidden = math.sqrt(2.0)
    return {
        "pi": [_dense(next(keys), a, b, hidden, s.ortho_init) for a, b in zip(sizes[:-1], sizes[1:], strict=True)],
        "pi_out": _dense(next(keys), sizes[-1], act_dim, 0.01, s.ortho_init),
        "log_std": jnp.full(act_dim, s.log_std_init, jnp.float32),
        "vf": [_dense(next(keys), a, b, hidden, s.ortho_init) for a, b in zip(sizes[:-1], sizes[1:], strict=True)],
        "vf_out": _dense(next(keys), sizes[-1], 1, 1.0, s.ortho_init),
    }


def _mlp(layers: list[dict[str, Array]], out: dict[str, Array], x: Array, act: Callable[[Array], Array]) -> Array:
    for layer in layers:
        x = act(x @ layer["w"] + layer["b"])
    return x @ out["w"] + out["b"]


def actor_apply(params: Params, obs: Array, activation: str = "Tanh") -> Array:
    """The policy's mean action (before the clip to ``[-1, 1]``)."""
    return _mlp(params["pi"], params["pi_out"], obs, ACTIVATIONS[activation])


def _value(params: Params, obs: Array, activation: str) -> Array:
    return _mlp(params["vf"], params["vf_out"], obs, ACTIVATIONS[activation])[..., 0]


def _log_prob(mean: Array, log_std: Array, a: Array) -> Array:
    z = (a - mean) * jnp.exp(-log_std)
    return jnp.sum(-0.5 * z * z - log_std - 0.5 * jnp.log(2.0 * jnp.pi), axis=-1)


# ---------------------------------------------------------------------------------------------- training
class ReturnStats(NamedTuple):
    """``VecNormalize``'s running statistics of the discounted return (its ``ret_rms``)."""

    mean: Array
    var: Array
    count: Array


class TrainState(NamedTuple):
    """One seed's whole training state (a pytree: ``vmap`` stacks seeds on a leading axis)."""

    params: Params
    opt: Any
    env: EnvState  #: (n_envs, ...) the training episodes
    obs: Array  #: (n_envs, obs_dim)
    ret: Array  #: (n_envs,) the discounted return so far, for the reward scaling
    stats: ReturnStats
    key: Array
    iteration: Array  #: iterations done


def _optimizer(s: PPOSettings) -> optax.GradientTransformation:
    # The learning rate multiplies the update outside the chain: it changes once per iteration.
    return optax.chain(optax.clip_by_global_norm(s.max_grad_norm), optax.scale_by_adam(eps=1e-5))


def init(keys: Array, env: FunctionalEnv, env_params: EnvParams, s: PPOSettings) -> TrainState:
    """The seeds' states before training (a leading axis of one per key): fresh networks and
    ``n_envs`` fresh episodes each.

    The networks are drawn one seed at a time: XLA:CPU (jaxlib 0.10.2) deadlocked in the next
    program after an orthogonal initialisation (a QR decomposition) batched over five seeds.
    """
    keys = jnp.asarray(keys)
    parts = [jax.random.split(k, 3) for k in keys]
    draw = jax.jit(partial(init_params, s=s, obs_dim=env.obs_dim, act_dim=env.num_actions))
    params = jax.tree.map(lambda *x: jnp.stack(x), *[draw(k[0]) for k in parts])

    @jax.jit
    def rest(params: Params, k_env: Array, k_run: Array) -> TrainState:
        obs, state = jax.vmap(jax.vmap(env.reset, in_axes=(0, None)), in_axes=(0, None))(
            jax.vmap(lambda k: jax.random.split(k, s.n_envs))(k_env), env_params)
        n = k_env.shape[0]
        one = jnp.ones(n, jnp.float32)
        return TrainState(params=params, opt=jax.vmap(_optimizer(s).init)(params), env=state,
                          obs=obs.astype(jnp.float32), ret=jnp.zeros((n, s.n_envs), jnp.float32),
                          stats=ReturnStats(0.0 * one, one, 1e-4 * one), key=k_run,
                          iteration=jnp.zeros(n, jnp.int32))

    return rest(params, jnp.stack([k[1] for k in parts]), jnp.stack([k[2] for k in parts]))


def _update_stats(st: ReturnStats, x: Array) -> ReturnStats:
    """Chan's parallel update of a running mean and variance with a batch ``x`` (SB3's RunningMeanStd)."""
    b_mean, b_var, b_count = jnp.mean(x), jnp.var(x), x.shape[0]
    delta = b_mean - st.mean
    total = st.count + b_count
    m2 = st.var * st.count + b_var * b_count + delta**2 * st.count * b_count / total
    return ReturnStats(st.mean + delta * b_count / total, m2 / total, total)


class _Transition(NamedTuple):
    obs: Array
    action: Array
    log_prob: Array
    value: Array
    reward: Array  #: scaled, with a truncation's bootstrap
    done: Array
    raw_reward: Array


def shuffle(key: Array, n: int) -> Array:
    """A random permutation of ``range(n)`` for the minibatches (as ``jax.random.permutation``, five
    to ten times faster on a CPU).

    Why: ``jax.random.permutation`` sorts ``(key, index)`` pairs, several rounds of them, and
    XLA:CPU's sort of pairs took 13 ms for a rollout of 16384 steps, a third of a PPO iteration's
    time with ``n_epochs = 5``.  Here the index rides in the low bits of one random ``uint32`` per
    element, so each round sorts plain integers (1 ms) and the low bits read the order back.  Two
    elements whose random high bits tie keep their order from the round before; with
    ``rounds * key_bits >= 2 log2(n) + 8`` the expected number of pairs tied in every round (the
    only departure from a uniform permutation) is below 1/256.
    """
    idx_bits = max(1, (n - 1).bit_length())
    key_bits = 32 - idx_bits
    if key_bits < 4:
        raise ValueError(f"shuffle: {n} elements leave too few random bits in a uint32 key")
    rounds = max(1, -(-(2 * idx_bits + 8) // key_bits))
    mask = jnp.uint32((1 << idx_bits) - 1)
    order = jnp.arange(n, dtype=jnp.int32)
    for k in jax.random.split(key, rounds):
        high = jax.random.bits(k, (n,), jnp.uint32) & ~mask
        pos = jnp.sort(high | jnp.arange(n, dtype=jnp.uint32)) & mask
        order = order[pos.astype(jnp.int32)]
    return order


def gae(rewards: Array, values: Array, dones: Array, last_value: Array, gamma: float, lam: float) -> Array:
    """Generalised advantage estimates of a rollout (time first): ``A_t = delta_t + gamma lam
    (1 - d_t) A_{t+1}`` with ``delta_t = r_t + gamma (1 - d_t) V_{t+1} - V_t``, where ``d_t`` says
    that step ``t`` ended its episode and ``V_T`` is ``last_value``."""

    def back(carry: tuple[Array, Array], x: tuple[Array, Array, Array]) -> tuple[tuple[Array, Array], Array]:
        adv, next_value = carry
        r, v, d = x
        live = 1.0 - d.astype(v.dtype)
        adv = r + gamma * next_value * live - v + gamma * lam * live * adv
        return (adv, v), adv

    return jax.lax.scan(back, (jnp.zeros_like(last_value), last_value), (rewards, values, dones), reverse=True)[1]


def iteration(env: FunctionalEnv, env_params: EnvParams, s: PPOSettings, ts: TrainState) -> tuple[TrainState, Array]:
    """One PPO iteration of one seed: a rollout, GAE, ``n_epochs`` of minibatch updates.  Returns
    the new state and the rollout's mean raw reward."""
    act = s.activation

    def env_step(carry: tuple[Any, ...], key: Array) -> tuple[tuple[Any, ...], _Transition]:
        state, obs, ret, stats = carry
        k_act, k_env = jax.random.split(key)
        mean = actor_apply(ts.params, obs, act)
        a = mean + jnp.exp(ts.params["log_std"]) * jax.random.normal(k_act, mean.shape)
        value = _value(ts.params, obs, act)
        obs2, state2, r, term, trunc, info = env.step_batch(k_env, state, jnp.clip(a, -1.0, 1.0), env_params)
        r = r.astype(jnp.float32)
        if s.norm_reward:
            ret = ret * s.gamma + r
            stats = _update_stats(stats, ret)
            scaled = jnp.clip(r / jnp.sqrt(stats.var + s.epsilon), -s.clip_reward, s.clip_reward)
        else:
            scaled = r
        done = term | trunc
        ret = jnp.where(done, 0.0, ret)
        final = info["final_observation"].astype(jnp.float32)
        scaled = scaled + s.gamma * jnp.where(trunc, _value(ts.params, final, act), 0.0)
        return (state2, obs2.astype(jnp.float32), ret, stats), _Transition(
            obs, a, _log_prob(mean, ts.params["log_std"], a), value, scaled, done, r)

    key, k_roll, k_perm = jax.random.split(ts.key, 3)
    (state, obs, ret, stats), tr = jax.lax.scan(env_step, (ts.env, ts.obs, ts.ret, ts.stats),
                                                jax.random.split(k_roll, s.n_steps))
    last_value = _value(ts.params, obs, act)

    advantages = gae(tr.reward, tr.value, tr.done, last_value, s.gamma, s.gae_lambda)
    returns = advantages + tr.value

    # SB3 updates its progress after the rollout: the first iteration already uses (1 - rollout/total).
    progress = 1.0 - jnp.minimum(1.0, (ts.iteration + 1) * s.rollout / s.n_timesteps)
    lr = s.learning_rate * (progress if s.lr_linear else 1.0)
    clip = s.clip_range * (progress if s.clip_linear else 1.0)

    def loss_fn(params: Params, mb: tuple[Array, ...]) -> Array:
        o, a, old_logp, adv, ret_target = mb
        mean = actor_apply(params, o, act)
        logp = _log_prob(mean, params["log_std"], a)
        adv = (adv - adv.mean()) / (adv.std() + 1e-8)
        ratio = jnp.exp(logp - old_logp)
        policy_loss = -jnp.mean(jnp.minimum(adv * ratio, adv * jnp.clip(ratio, 1.0 - clip, 1.0 + clip)))
        value_loss = jnp.mean((ret_target - _value(params, o, act)) ** 2)
        entropy = jnp.sum(params["log_std"] + 0.5 * jnp.log(2.0 * jnp.pi * jnp.e))
        return policy_loss + s.vf_coef * value_loss - s.ent_coef * entropy

    opt = _optimizer(s)
    flat = tuple(x.reshape(s.rollout, *x.shape[2:]) for x in (tr.obs, tr.action, tr.log_prob, advantages, returns))

    def minibatch(carry: tuple[Params, Any], mb: tuple[Array, ...]) -> tuple[tuple[Params, Any], None]:
        params, opt_state = carry
        grads = jax.grad(loss_fn)(params, mb)
        updates, opt_state = opt.update(grads, opt_state, params)
        return (jax.tree.map(lambda p, u: p - lr * u, params, updates), opt_state), None

    def epoch(carry: tuple[Params, Any], key: Array) -> tuple[tuple[Params, Any], None]:
        order = shuffle(key, s.rollout)
        mbs = tuple(x[order].reshape(s.rollout // s.batch_size, s.batch_size, *x.shape[1:]) for x in flat)
        return jax.lax.scan(minibatch, carry, mbs)[0], None

    (params, opt_state), _ = jax.lax.scan(epoch, (ts.params, ts.opt), jax.random.split(k_perm, s.n_epochs))
    new = TrainState(params=params, opt=opt_state, env=state, obs=obs, ret=ret, stats=stats, key=key,
                     iteration=ts.iteration + 1)
    return new, jnp.mean(tr.raw_reward)


def iterations(env: FunctionalEnv, env_params: EnvParams, s: PPOSettings, ts: TrainState, count: int,
               until: Array | int | None = None) -> tuple[TrainState, Array]:
    """``count`` iterations, of which those at or past ``until`` (an iteration number, a traced
    value; default the run's end) or past the run's last one do nothing, so that every chunk of a
    run is the same program whatever its length.  Returns the state and each iteration's mean raw
    reward (NaN for those that did nothing)."""
    stop = s.n_iterations if until is None else jnp.minimum(s.n_iterations, until)

    def one(ts: TrainState, _: None) -> tuple[TrainState, Array]:
        return jax.lax.cond(ts.iteration < stop, partial(iteration, env, env_params, s),
                            lambda t: (t, jnp.float32(jnp.nan)), ts)

    return jax.lax.scan(one, ts, None, length=count)


def to_numpy(params: Params) -> dict[str, np.ndarray]:
    """A seed's networks as flat named arrays (the checkpoint format: ``pi.0.w``, ``pi_out.b``, ...)."""
    out: dict[str, np.ndarray] = {"log_std": np.asarray(params["log_std"])}
    for net in ("pi", "vf"):
        for i, layer in enumerate(params[net]):
            for k, v in layer.items():
                out[f"{net}.{i}.{k}"] = np.asarray(v)
        for k, v in params[f"{net}_out"].items():
            out[f"{net}_out.{k}"] = np.asarray(v)
    return out
