"""SAC compiled with its environment: environment steps, the replay buffer and the gradient steps in
one XLA program.

The environment is the task's pure JAX step (`vnhc_gym.envs.functional`), the replay buffer is an
array in the training state, and a chunk of iterations (each ``train_freq`` steps of ``n_envs``
episodes, then ``gradient_steps`` updates) is one call of a compiled function; ``jax.vmap`` over the
random key trains several seeds in the same program.  The algorithm is SBX's SAC (the JAX SAC of the
Stable-Baselines3 team, which ``vnhc-gym train --algo sac`` runs on the sb3 backend), so that
``agents/hyperparams/sac.yml`` means the same thing to both backends:

* an actor with ``net_arch`` hidden layers and two heads, the Gaussian's mean and its log standard
  deviation (clipped to ``[-20, 2]``), the action ``tanh`` of a sample; two critics ``Q(obs, a)``
  with target copies updated by Polyak averaging (``tau``) after every gradient step; ReLU hidden
  layers and LeCun-normal weights (flax's default), as SBX;
* uniform random actions until ``learning_starts`` env steps, and no update before;
* the critics regress on ``r + gamma (1 - terminated) (min_j Q'_j(s', a') - alpha log pi(a'|s'))``
  with ``a' ~ pi(s')``: a truncated episode bootstraps from its final observation (SB3's
  ``handle_timeout_termination``); then the actor minimises ``alpha log pi - min_j Q_j``, then the
  entropy coefficient (``ent_coef: auto``: ``alpha = exp(log_alpha)`` from 1, towards the target
  entropy ``-act_dim``; a number: fixed); one Adam (``learning_rate``) for each;
* minibatches of ``batch_size`` drawn uniformly from the transitions stored so far, the buffer a
  ring of ``buffer_size`` transitions.

Every key of the file must be one of `KNOWN_KEYS`: a key this trainer does not implement raises
instead of being ignored.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optax

from vnhc_gym.envs.functional import EnvParams, EnvState, FunctionalEnv
from vnhc_gym.training.hyperparams import checked_section
from vnhc_gym.training.numpy_actor import LOG_STD_MAX, LOG_STD_MIN  # the saved actor clips alike

__all__ = ["KNOWN_KEYS", "Learner", "SACSettings", "TrainState", "actor_apply", "init", "iterations", "settings_from",
           "to_numpy"]

Array = Any  # a jax.Array
Params = dict[str, Any]

#: The hyperparameter keys the compiled SAC reads (RL Zoo's and SBX's SAC names).
KNOWN_KEYS = frozenset({"n_envs", "n_timesteps", "policy", "learning_rate", "buffer_size", "learning_starts",
                        "batch_size", "tau", "gamma", "train_freq", "gradient_steps", "ent_coef", "target_entropy",
                        "policy_kwargs"})
_POLICY_KWARGS = frozenset({"net_arch"})


class SACSettings(NamedTuple):
    """SBX's SAC settings with its defaults (hashable: a static argument)."""

    n_envs: int = 1
    n_timesteps: int = 1_000_000
    learning_rate: float = 3e-4
    buffer_size: int = 1_000_000
    learning_starts: int = 100
    batch_size: int = 256
    tau: float = 0.005
    gamma: float = 0.99
    train_freq: int = 1
    gradient_steps: int = 1
    ent_coef: float = 1.0  #: the fixed coefficient, or the start of the learned one
    ent_auto: bool = True
    target_entropy: float | None = None  #: default ``-act_dim``
    net_arch: tuple[int, ...] = (256, 256)

    @property
    def rollout(self) -> int:
        """Env steps per iteration."""
        return self.n_envs * self.train_freq

    @property
    def n_iterations(self) -> int:
        return math.ceil(self.n_timesteps / self.rollout)

    @property
    def capacity(self) -> int:
        """Transitions the buffer holds: ``buffer_size`` (no more than a run stores), whole rollouts."""
        stored = min(self.buffer_size, self.n_iterations * self.rollout)
        return max(self.rollout, stored // self.rollout * self.rollout)


def settings_from(hp: Mapping[str, Any], where: str = "hyperparameters") -> SACSettings:
    """`SACSettings` from a hyperparameter file's section (as `load_hyperparams` returns it).

    Raises ``ValueError`` naming every key (of the section, of ``policy_kwargs``) that the compiled
    SAC does not implement, and a value it cannot honour.
    """
    pk = checked_section(hp, KNOWN_KEYS, _POLICY_KWARGS, "the compiled SAC (backend 'jax')", where)
    kw: dict[str, Any] = {}
    if "net_arch" in pk:
        if not isinstance(pk["net_arch"], (list, tuple)):
            raise ValueError(f"{where}: the compiled SAC needs net_arch as one list for actor and critics, "
                             f"got {pk['net_arch']!r}")
        kw["net_arch"] = tuple(int(n) for n in pk["net_arch"])
    for key in ("n_envs", "n_timesteps", "buffer_size", "learning_starts", "batch_size", "gradient_steps"):
        if key in hp:
            kw[key] = int(hp[key])
    if "train_freq" in hp:
        if not isinstance(hp["train_freq"], (int, np.integer)):
            raise ValueError(f"{where}: the compiled SAC takes train_freq as a number of steps, "
                             f"got {hp['train_freq']!r}")
        kw["train_freq"] = int(hp["train_freq"])
    for key in ("learning_rate", "tau", "gamma"):
        if key in hp:
            if isinstance(hp[key], str):
                raise ValueError(f"{where}: the compiled SAC takes a constant {key}, got {hp[key]!r}")
            kw[key] = float(hp[key])
    ent = hp.get("ent_coef", "auto")
    if isinstance(ent, str):
        if ent != "auto" and not ent.startswith("auto_"):
            raise ValueError(f"{where}: ent_coef must be a number, 'auto' or 'auto_<start>', got {ent!r}")
        kw["ent_auto"], kw["ent_coef"] = True, float(ent[5:]) if ent.startswith("auto_") else 1.0
    else:
        kw["ent_auto"], kw["ent_coef"] = False, float(ent)
    if "target_entropy" in hp and hp["target_entropy"] != "auto":
        kw["target_entropy"] = float(hp["target_entropy"])
    s = SACSettings(**kw)
    for key in ("n_envs", "batch_size", "train_freq", "gradient_steps", "buffer_size"):
        if getattr(s, key) < 1:
            raise ValueError(f"{where}: {key} must be at least 1, got {getattr(s, key)}")
    return s


# ---------------------------------------------------------------------------------------------- networks
def _dense(key: Array, n_in: int, n_out: int) -> dict[str, Array]:
    w = jax.nn.initializers.lecun_normal()(key, (n_in, n_out), jnp.float32)
    return {"w": w, "b": jnp.zeros(n_out, jnp.float32)}


def _stack(key: Array, sizes: tuple[int, ...]) -> list[dict[str, Array]]:
    keys = jax.random.split(key, len(sizes) - 1)
    return [_dense(k, a, b) for k, a, b in zip(keys, sizes[:-1], sizes[1:], strict=True)]


def init_params(key: Array, *, s: SACSettings, obs_dim: int, act_dim: int) -> Params:
    """The actor (``pi`` layers, ``pi_out`` the mean, ``log_std_out``), the two critics (``qf0``,
    ``qf1``, each layers then a last one of width 1) and the entropy coefficient's logarithm."""
    k_pi, k_mean, k_std, k_q0, k_q1 = jax.random.split(key, 5)
    hidden = s.net_arch[-1] if s.net_arch else obs_dim
    return {
        "pi": _stack(k_pi, (obs_dim, *s.net_arch)),
        "pi_out": _dense(k_mean, hidden, act_dim),
        "log_std_out": _dense(k_std, hidden, act_dim),
        "qf0": _stack(k_q0, (obs_dim + act_dim, *s.net_arch, 1)),
        "qf1": _stack(k_q1, (obs_dim + act_dim, *s.net_arch, 1)),
        "log_alpha": jnp.asarray(math.log(s.ent_coef), jnp.float32),
    }


def _hidden(layers: list[dict[str, Array]], x: Array) -> Array:
    for layer in layers:
        x = jax.nn.relu(x @ layer["w"] + layer["b"])
    return x


def actor_apply(params: Params, obs: Array) -> tuple[Array, Array]:
    """The Gaussian's mean and log standard deviation, before the ``tanh``."""
    h = _hidden(params["pi"], obs)
    log_std = h @ params["log_std_out"]["w"] + params["log_std_out"]["b"]
    return h @ params["pi_out"]["w"] + params["pi_out"]["b"], jnp.clip(log_std, LOG_STD_MIN, LOG_STD_MAX)


def _q(layers: list[dict[str, Array]], obs: Array, a: Array) -> Array:
    x = _hidden(layers[:-1], jnp.concatenate([obs, a], axis=-1))
    return (x @ layers[-1]["w"] + layers[-1]["b"])[..., 0]


def _sample(params: Params, obs: Array, key: Array) -> tuple[Array, Array]:
    """A squashed Gaussian action and its log density: ``log N(u) - sum log(1 - tanh(u)^2)``, the
    last term as ``2 (log 2 - u - softplus(-2u))`` (exact, and finite for large ``|u|``)."""
    mean, log_std = actor_apply(params, obs)
    u = mean + jnp.exp(log_std) * jax.random.normal(key, mean.shape)
    z = (u - mean) * jnp.exp(-log_std)
    log_n = jnp.sum(-0.5 * z * z - log_std - 0.5 * jnp.log(2.0 * jnp.pi), axis=-1)
    log_det = jnp.sum(2.0 * (jnp.log(2.0) - u - jax.nn.softplus(-2.0 * u)), axis=-1)
    return jnp.tanh(u), log_n - log_det


# ---------------------------------------------------------------------------------------------- training
class Buffer(NamedTuple):
    """The replay buffer: ``capacity`` transitions, a ring."""

    obs: Array
    action: Array
    reward: Array
    next_obs: Array  #: the step's own next observation (the final one where the episode ended)
    terminated: Array


class TrainState(NamedTuple):
    """One seed's whole training state (a pytree: ``vmap`` stacks seeds on a leading axis)."""

    params: Params
    target: Params  #: the critics' target copies (``qf0``, ``qf1``)
    opt: Any  #: (actor, critics, entropy coefficient) Adam states
    buffer: Buffer
    env: EnvState
    obs: Array
    key: Array
    iteration: Array


def _adam(s: SACSettings) -> optax.GradientTransformation:
    return optax.adam(s.learning_rate)


def _critics(p: Params) -> Params:
    return {"qf0": p["qf0"], "qf1": p["qf1"]}


def init(keys: Array, env: FunctionalEnv, env_params: EnvParams, s: SACSettings) -> TrainState:
    """The seeds' states before training (a leading axis of one per key)."""
    obs_dim, act_dim = env.obs_dim, env.num_actions

    @jax.jit
    @jax.vmap
    def one(key: Array) -> TrainState:
        k_net, k_env, k_run = jax.random.split(key, 3)
        params = init_params(k_net, s=s, obs_dim=obs_dim, act_dim=act_dim)
        obs, state = jax.vmap(env.reset, in_axes=(0, None))(jax.random.split(k_env, s.n_envs), env_params)
        adam = _adam(s)
        opt = (adam.init({k: params[k] for k in ("pi", "pi_out", "log_std_out")}), adam.init(_critics(params)),
               adam.init(params["log_alpha"]))
        c = s.capacity
        buffer = Buffer(obs=jnp.zeros((c, obs_dim), jnp.float32), action=jnp.zeros((c, act_dim), jnp.float32),
                        reward=jnp.zeros(c, jnp.float32), next_obs=jnp.zeros((c, obs_dim), jnp.float32),
                        terminated=jnp.zeros(c, bool))
        return TrainState(params=params, target=_critics(params), opt=opt, buffer=buffer, env=state,
                          obs=obs.astype(jnp.float32), key=k_run, iteration=jnp.zeros((), jnp.int32))

    return one(jnp.asarray(keys))


class Learner(NamedTuple):
    """What a gradient step changes."""

    params: Params
    target: Params
    opt: Any


def _gradient_step(s: SACSettings, target_entropy: float, ln: Learner, batch: Buffer, key: Array) -> Learner:
    """One update of the critics, then the actor, then the entropy coefficient, then the targets."""
    adam = _adam(s)
    params, (opt_pi, opt_q, opt_alpha) = ln.params, ln.opt
    alpha = jnp.exp(params["log_alpha"])
    k_next, k_pi = jax.random.split(key)

    a_next, logp_next = _sample(params, batch.next_obs, k_next)
    q_next = jnp.minimum(_q(ln.target["qf0"], batch.next_obs, a_next), _q(ln.target["qf1"], batch.next_obs, a_next))
    y = batch.reward + s.gamma * (1.0 - batch.terminated.astype(jnp.float32)) * (q_next - alpha * logp_next)
    y = jax.lax.stop_gradient(y)

    def critic_loss(q: Params) -> Array:
        return 0.5 * sum(jnp.mean((_q(q[k], batch.obs, batch.action) - y) ** 2) for k in ("qf0", "qf1"))

    grads, opt_q = adam.update(jax.grad(critic_loss)(_critics(params)), opt_q)
    critics = optax.apply_updates(_critics(params), grads)

    def actor_loss(actor: Params) -> tuple[Array, Array]:
        a, logp = _sample(actor, batch.obs, k_pi)
        q = jnp.minimum(_q(critics["qf0"], batch.obs, a), _q(critics["qf1"], batch.obs, a))
        return jnp.mean(alpha * logp - q), logp

    actor = {k: params[k] for k in ("pi", "pi_out", "log_std_out")}
    grads, logp = jax.grad(actor_loss, has_aux=True)(actor)
    grads, opt_pi = adam.update(grads, opt_pi)
    actor = optax.apply_updates(actor, grads)

    log_alpha = params["log_alpha"]
    if s.ent_auto:
        def alpha_loss(la: Array) -> Array:
            return -jnp.mean(la * jax.lax.stop_gradient(logp + target_entropy))

        g, opt_alpha = adam.update(jax.grad(alpha_loss)(log_alpha), opt_alpha)
        log_alpha = optax.apply_updates(log_alpha, g)

    target = jax.tree.map(lambda t, p: (1.0 - s.tau) * t + s.tau * p, ln.target, critics)
    return Learner(params={**actor, **critics, "log_alpha": log_alpha}, target=target, opt=(opt_pi, opt_q, opt_alpha))


def iteration(env: FunctionalEnv, env_params: EnvParams, s: SACSettings, ts: TrainState,
              until: Array | int | None = None) -> tuple[TrainState, Array]:
    """One iteration of one seed: ``train_freq`` steps of the ``n_envs`` episodes into the buffer
    (random actions until ``learning_starts`` steps are done), then ``gradient_steps`` updates once
    more than ``learning_starts`` steps are done; nothing once the run's iterations are done, or at
    or past iteration ``until`` (a traced value; default the run's end).

    Why no ``lax.cond`` on those phases: under the ``jax.vmap`` over seeds a branch on each seed's
    count becomes a select of both results, and a select of the whole state copies the replay
    buffer (60 MB at a million transitions, a 3x slower iteration, measured).  The selects here
    are of the few rows written, the networks and the episodes' states; the gradient steps of the
    random phase are computed and dropped (one iteration in a hundred at the shipped settings).
    """
    index = ts.iteration
    active = index < (s.n_iterations if until is None else jnp.minimum(s.n_iterations, until))
    target_entropy = -float(env.num_actions) if s.target_entropy is None else s.target_entropy
    key, k_roll, k_grad = jax.random.split(ts.key, 3)
    random_phase = index * s.rollout < s.learning_starts

    def env_step(carry: tuple[Any, ...], key: Array) -> tuple[tuple[Any, ...], tuple[Array, ...]]:
        state, obs = carry
        k_act, k_env = jax.random.split(key)
        a = jnp.where(random_phase, jax.random.uniform(k_act, (s.n_envs, env.num_actions), jnp.float32, -1.0, 1.0),
                      _sample(ts.params, obs, k_act)[0])
        obs2, state2, r, term, _, info = env.step_batch(k_env, state, a, env_params)
        return (state2, obs2.astype(jnp.float32)), (obs, a, r.astype(jnp.float32),
                                                    info["final_observation"].astype(jnp.float32), term)

    (state, obs), rows = jax.lax.scan(env_step, (ts.env, ts.obs), jax.random.split(k_roll, s.train_freq))
    rows = Buffer(*(x.reshape(s.rollout, *x.shape[2:]) for x in rows))
    start = (index * s.rollout) % s.capacity

    def write(b: Array, r: Array) -> Array:
        old = jax.lax.dynamic_slice_in_dim(b, start, s.rollout, 0)
        return jax.lax.dynamic_update_slice_in_dim(b, jnp.where(active, r, old), start, 0)

    buffer = Buffer(*(write(b, r) for b, r in zip(ts.buffer, rows, strict=True)))
    filled = jnp.minimum((index + 1) * s.rollout, s.capacity)

    def one(ln: Learner, key: Array) -> tuple[Learner, None]:
        k_idx, k_step = jax.random.split(key)
        idx = jax.random.randint(k_idx, (s.batch_size,), 0, filled)
        return _gradient_step(s, target_entropy, ln, jax.tree.map(lambda b: b[idx], buffer), k_step), None

    old = Learner(ts.params, ts.target, ts.opt)
    new = jax.lax.scan(one, old, jax.random.split(k_grad, s.gradient_steps))[0]
    learn = active & ((index + 1) * s.rollout > s.learning_starts)
    ln = jax.tree.map(lambda a, b: jnp.where(learn, a, b), new, old)
    state, obs = jax.tree.map(lambda a, b: jnp.where(active, a, b), (state, obs), (ts.env, ts.obs))
    ts = TrainState(params=ln.params, target=ln.target, opt=ln.opt, buffer=buffer, env=state, obs=obs,
                    key=jnp.where(active, key, ts.key), iteration=index + active.astype(index.dtype))
    return ts, jnp.where(active, jnp.mean(rows.reward), jnp.nan)


def iterations(env: FunctionalEnv, env_params: EnvParams, s: SACSettings, ts: TrainState, count: int,
               until: Array | int | None = None) -> tuple[TrainState, Array]:
    """``count`` iterations, of which those at or past ``until`` (a traced value; default the run's
    end) or past the run's last one do nothing, so that every chunk of a run is the same program
    whatever its length.  Returns the state and each iteration's mean reward."""
    return jax.lax.scan(lambda t, _: iteration(env, env_params, s, t, until), ts, None, length=count)


def to_numpy(params: Params) -> dict[str, np.ndarray]:
    """A seed's actor as flat named arrays (the checkpoint: ``pi.<i>.w``, ``pi.<i>.b``, ``pi_out.w``,
    ``pi_out.b``, ``log_std_out.w``, ``log_std_out.b``); the action is ``tanh`` of ``pi_out``."""
    out: dict[str, np.ndarray] = {}
    for i, layer in enumerate(params["pi"]):
        for k, v in layer.items():
            out[f"pi.{i}.{k}"] = np.asarray(v)
    for head in ("pi_out", "log_std_out"):
        for k, v in params[head].items():
            out[f"{head}.{k}"] = np.asarray(v)
    return out
