"""The law where the model is wrong in structure: a predictor through the actuator, and a
disturbance observer.

Under a delay ``d`` the force commanded now acts ``d`` periods later, under a lag it acts through
the actuator's state, and forces the model lacks add a rate to ``phi`` that the law does not
cancel.  [`plan`][vnhc_gym.baselines.actuated.plan] is the law that knows an actuator: it predicts
the state ``d`` periods on through the commands still on their way (a Smith predictor), plans the
sampled-data law there, and commands what makes the actuator's mean force over the period that
law's force.  The oracle runs it on the truth; [`ActuatedLaw`][vnhc_gym.baselines.ActuatedLaw] runs
it as a control engineer would, who knows the structure (a delay of 2-6 periods, a lag of 0.1-0.5 s)
but not the episode's values:

* **a bank of hypotheses** over the structure's range (every delay in it; time constants spaced
  log-uniformly over it), each predicting the last period's motion from the commands it issued; the
  hypothesis with the smallest discounted prediction error (forgetting factor ``forget``) is the
  one planned with, so the bank follows a delay or a time constant that changes mid-episode;
  ``bank="nominal"`` plans with the range's middle instead (the law told the nominal values);
* **a disturbance observer** (the extended-state observer of active disturbance rejection control,
  on the constraint): the estimate ``delta`` of the rate of ``phi`` that the model lacks moves by
  ``observer`` times the last period's prediction error of ``phi`` per period, and the law cancels
  it (`vnhc_gym.mechanics.functional.sampled_law`'s ``bias``).  ``observer=0`` turns it off.

[`InformedActuatedLaw`][vnhc_gym.baselines.InformedActuatedLaw] is a headroom reference: the same law
told the episode's hidden quantities (the delay, the time constant, the forces' coefficients), but
not the state, which it reads from the observation.

Everything per episode is pure JAX (`start`, `update`, `command`), compiled and batched over the
rows of a vector environment.
"""

from __future__ import annotations

import sys
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from numpy.typing import ArrayLike, NDArray

from vnhc_gym.baselines.geometric import DEFAULT_GAIN, StatefulLaw
from vnhc_gym.baselines.policy import batch_of
from vnhc_gym.envs.config import check_number
from vnhc_gym.envs.functional import lag, lag_weights
from vnhc_gym.envs.runtime import function_identity
from vnhc_gym.mechanics import functional as core
from vnhc_gym.tasks.base import bound_fn

__all__ = ["ActuatedLaw", "InformedActuatedLaw", "hypotheses", "plan"]

Array = NDArray[np.float64]

#: Time constants of the bank over a lag's range.
LAG_HYPOTHESES = 6


def plan(system: Any, s: Any, p: Any, queue: Any, delay: Any, z: Any, tau: Any, dt: Any, substeps: int, bound: Any,
         gains: Any, iters: int, singular_tol: float | None, bias: Any = None) -> tuple[Any, Any]:
    """The command of the law that knows its actuator, for one episode: ``(command, singular)``.

    Parameters
    ----------
    system : printed system (or `vnhc_gym.mechanics.functional.WithForces`)
        The model planned with.
    s, p : arrays
        The state now and the parameters.
    queue : array, shape (Q, m)
        The commands issued before, the newest first; under a delay ``d`` the ``d`` newest still act.
    delay : int-valued array
        ``d`` (0: none).
    z, tau : arrays
        The actuator's force now and its time constant (0: no lag).
    dt, substeps, bound
        The control period, its RK4 steps and the force bound.
    gains, iters, singular_tol
        The sampled-data law's ``diag K``, Newton iterations and singular test.
    bias : array, optional
        A rate of ``phi`` the model lacks, cancelled by the law.

    Returns
    -------
    The command (unclipped), and whether the law was singular at the predicted state.
    """
    slots = queue.shape[0]
    for j in range(slots):  # the commands already issued act over the next d periods
        mean, z_next = lag(z, queue[jnp.clip(delay - 1 - j, 0, slots - 1).astype(jnp.int32)], tau, dt)
        s_next = core.rk4_step(system, s, p, jnp.clip(mean, -bound, bound), dt, substeps)
        ahead = (j < delay) & jnp.all(jnp.isfinite(s_next))
        s, z = jnp.where(ahead, s_next, s), jnp.where(ahead, z_next, z)
    u, singular = core.checked_law(system, s, p, gains, singular_tol)
    held, _ = core.sampled_law(system, s, p, dt, gains, substeps, iters, singular_tol=singular_tol, bias=bias)
    u = jnp.where(~singular & jnp.all(jnp.isfinite(held)), held, u)
    # The actuator's mean force over the period is w z + (1 - w) command: command what makes it u.
    w, _ = lag_weights(tau, dt)
    return (u - w * z) / (1.0 - w), singular


def hypotheses(delay_range: tuple[int, int], lag_range: tuple[float, float], bank: str) -> Array:
    """The bank's hypotheses ``(H, 2)`` of ``(delay, time constant)`` over a structure's ranges: every
    delay and ``LAG_HYPOTHESES`` time constants spaced log-uniformly (``bank="identify"``), or the
    ranges' middles (``"nominal"``).  A structure absent from the task is 0."""
    d_lo, d_hi = delay_range
    t_lo, t_hi = lag_range
    if bank == "nominal":
        delays = np.array([round((d_lo + d_hi) / 2)], dtype=np.float64)
        taus = np.array([float(np.sqrt(t_lo * t_hi)) if t_hi > 0 else 0.0])
    else:
        delays = np.arange(d_lo, d_hi + 1, dtype=np.float64)
        taus = np.geomspace(t_lo, t_hi, LAG_HYPOTHESES) if t_hi > 0 else np.zeros(1)
    return np.array([(d, t) for d in delays for t in taus], dtype=np.float64)


class Memory(NamedTuple):
    """One episode of `ActuatedLaw`: what it issued and what it believes."""

    queue: Any  #: (Q, m) its commands, the newest first
    z: Any  #: (H, m) the actuator's force under each hypothesis
    error: Any  #: (H,) each hypothesis' discounted prediction error
    s: Any  #: (2n,) the state read from the last observation
    p: Any  #: the controller's parameters read with it
    delta: Any  #: (m,) the disturbance observer's estimate of the rate of phi the model lacks


class _Core(NamedTuple):
    """The pure functions of one task's `ActuatedLaw` (hashable: a cache key)."""

    system: Any
    inputs: Any  #: the task module's controller_inputs
    recenter: Any  #: the task module's recenter (None: the frame stays)
    unmodelled: Any  #: the task module's unmodelled, on the controller's system (the informed reference)
    substeps: int
    iters: int
    singular_tol: float | None
    slots: int

    def read(self, obs: Any, p_nominal: Any, args: Any) -> tuple[Any, Any]:
        return self.inputs(obs, p_nominal, args)

    def truth(self, coef: Any, args: Any) -> Any:
        """The controller's system with the forces of coefficients ``coef`` (none: the system)."""
        if self.unmodelled is None:
            return self.system
        return core.WithForces(self.system, lambda s, p: self.unmodelled(s, p, coef, args))

    def start(self, obs: Any, p_nominal: Any, args: Any, n_hyp: int, m: int) -> Memory:
        s, p = self.read(obs, p_nominal, args)
        return Memory(queue=jnp.zeros((self.slots, m), s.dtype), z=jnp.zeros((n_hyp, m), s.dtype),
                      error=jnp.zeros(n_hyp, s.dtype), s=s, p=p, delta=jnp.zeros(m, s.dtype))

    def update(self, mem: Memory, obs: Any, issued: Any, p_nominal: Any, args: Any, hyp: Any, coef: Any,
               dt: Any, bound: Any, forget: Any, observer: Any) -> Memory:
        """The memory after the period in which ``issued`` was commanded, seeing its end ``obs``."""
        s, p = self.read(obs, p_nominal, args)
        full = jnp.concatenate([issued[None], mem.queue])
        system = self.truth(coef, args)

        def one(h: Any, z: Any) -> tuple[Any, Any, Any]:
            delayed = full[jnp.clip(h[0], 0, self.slots).astype(jnp.int32)]
            mean, z_next = lag(z, delayed, h[1], dt)
            pred = core.rk4_step(system, mem.s, mem.p, jnp.clip(mean, -bound, bound), dt, self.substeps)
            if self.recenter is not None:
                pred, _ = self.recenter(pred, mem.p, args)
            return pred, z_next, jnp.sum((pred[system.N:] - s[system.N:]) ** 2)

        preds, z, sq = jax.vmap(one)(hyp, mem.z)
        best = jnp.argmin(mem.error)
        miss = system.phi(s, p) - (system.phi(preds[best], p) + mem.delta * dt)
        finite = jnp.all(jnp.isfinite(miss))
        delta = jnp.where(finite, mem.delta + observer * miss / dt, mem.delta)
        error = jnp.where(jnp.isfinite(sq), forget * mem.error + sq, jnp.inf)
        return Memory(queue=full[:-1], z=z, error=error, s=s, p=p, delta=delta)

    def command(self, mem: Memory, hyp: Any, coef: Any, args: Any, dt: Any, bound: Any, gains: Any,
                observer: Any) -> tuple[Any, Any]:
        """The law through the best hypothesis' actuator, on the memory's state."""
        best = jnp.argmin(mem.error)
        h = hyp[best]
        bias = jnp.where(observer > 0, mem.delta, 0.0)
        return plan(self.truth(coef, args), mem.s, mem.p, mem.queue, h[0], mem.z[best], h[1], dt, self.substeps,
                    bound, gains, self.iters, self.singular_tol, bias)


_COMPILED: dict[Any, Any] = {}


def _compiled(law: _Core) -> tuple[Any, Any, Any]:
    """`_Core.start`, `update` and `command` batched over rows and compiled, once per task shape."""
    key = tuple(function_identity(f) for f in law)
    fns = _COMPILED.get(key)
    if fns is None:
        start = jax.jit(jax.vmap(law.start, in_axes=(0, None, None, None, None)), static_argnums=(3, 4))
        update = jax.jit(jax.vmap(law.update, in_axes=(0, 0, 0, None, None, 0, 0, None, None, None, None)))
        command = jax.jit(jax.vmap(law.command, in_axes=(0, 0, 0, None, None, None, None, None)))
        fns = _COMPILED[key] = (start, update, command)
    return fns


class ActuatedLaw(StatefulLaw):
    """The law on a predictor through the actuator, with a bank that identifies it online and a
    disturbance observer (see the module docstring).

    Parameters
    ----------
    env : gymnasium Env or VectorEnv
        A vnhc_gym environment; its configuration gives the structure's ranges (``delay_min`` ..
        ``delay_max``, ``lag_min`` .. ``lag_max``), never an episode's values.
    gain : float or array_like, default 5
        ``diag K`` of the sampled-data law.
    bank : {"identify", "nominal"}
        Plan with the hypothesis that predicts best, or with the ranges' middles.
    forget : float, default 0.8
        Forgetting factor of the hypotheses' prediction errors, in ``[0, 1)``.
    observer : float, default 0
        The disturbance observer's gain per period, in ``[0, 1]`` (0: off).
    iters : int, default 4
        Newton iterations of the sampled-data law.
    """

    keeps_estimate = False

    def __init__(self, env: Any, gain: ArrayLike = DEFAULT_GAIN, bank: str = "identify", forget: float = 0.8,
                 observer: float = 0.0, *, iters: int = 4) -> None:
        super().__init__(env, gain, variant="sampled", iters=iters)
        if bank not in ("identify", "nominal"):
            raise ValueError(f"bank must be 'identify' or 'nominal', got {bank!r}")
        self.bank = bank
        self.forget = check_number("forget", forget, low=0.0, high=0.999)
        self.observer = check_number("observer", observer, low=0.0, high=1.0)
        c = self.task.config
        self.hyp = hypotheses((c.delay_min, c.delay_max), (c.lag_min, c.lag_max), bank)
        self.name = "actuated_law"
        module = sys.modules[type(self.task).__module__]
        system = self.task.controller_functions()
        self._core = _Core(system=system, inputs=bound_fn(module, "controller_inputs", system),
                           recenter=getattr(module, "recenter", None),
                           unmodelled=self._unmodelled(module, system), substeps=int(self.substeps),
                           iters=self.iters, singular_tol=self.model.singular_tol, slots=max(1, int(c.delay_max)))
        self._mem: Memory | None = None

    def _unmodelled(self, module: Any, system: Any) -> Any:
        """The forces the controller plans with (none: it does not know them)."""
        return None

    @staticmethod
    def applies(task: Any) -> bool:
        """Whether the law can act differently from the sampled-data law: where the task's episodes
        hide structure (a delay, a lag, forces the model lacks)."""
        return bool(task.config.structural)

    def __repr__(self) -> str:
        return (f"{type(self).__name__}({self.task.name!r}, gain={self.gain.tolist()}, bank={self.bank!r}, "
                f"forget={self.forget}, observer={self.observer})")

    def reset(self) -> None:
        self._mem = None

    def _hidden(self, b: int) -> tuple[Array, Array]:
        """The hypotheses ``(B, H, 2)`` and the coefficients of the forces planned with ``(B, k)``."""
        # One unused coefficient where none is planned with: no empty arrays in a program.
        return np.broadcast_to(self.hyp, (b, *self.hyp.shape)), np.zeros((b, 1))

    def act(self, obs: Array) -> Array:
        o = np.asarray(obs, dtype=np.float64)
        b = o.shape[0]
        start, update, command = _compiled(self._core)
        hyp, coef = self._hidden(b)
        nominal = np.asarray(self.task.nominal, dtype=np.float64)
        args, dt, bound = self.task.args, float(self.dt), np.asarray(self.force_bound, dtype=np.float64)
        with jax.enable_x64(True):
            fresh = start(o, nominal, args, hyp.shape[1], self.act_dim)
            if self._mem is None or self._u is None or self._fresh is None or self._u.shape[0] != b:
                mem = fresh
                self._fresh = np.zeros(b, dtype=bool)
            else:
                mem = update(self._mem, o, self._u, nominal, args, hyp, coef, dt, bound, self.forget,
                             self.observer)
                restart = self._fresh
                mem = jax.tree.map(lambda a, c: np.where(restart.reshape(-1, *([1] * (a.ndim - 1))), a, c),
                                   fresh, mem)
            u, singular = command(mem, hyp, coef, args, dt, bound, np.asarray(self.gain, dtype=np.float64),
                                  self.observer)
        self._mem = jax.tree.map(np.asarray, mem)
        self._fresh[:] = False
        a = np.asarray(u, dtype=np.float64) / self.force_bound
        a = np.clip(np.where(np.isfinite(a), a, 0.0), -1.0, 1.0)
        # The force the environment receives from this action (``predict`` returns float32).
        self._u = a.astype(np.float32).astype(np.float64) * self.force_bound
        self.last_singular = np.asarray(singular)
        return a


class InformedActuatedLaw(ActuatedLaw):
    """A headroom reference: `ActuatedLaw` told the episode's hidden quantities (the delay, the time
    constant, the coefficients of the forces the model lacks, read from the environment at every
    step), never its state, which it reads from the observation.  The oracle above it is what the
    observation hides; it above the best classical baseline, what not knowing the structure costs.

    Parameters
    ----------
    env : gymnasium Env or VectorEnv
        The vnhc_gym environment it acts on (row ``i`` of a batch is sub-environment ``i``).
    gain : float or array_like, default 5
    iters : int, default 4
    """

    def __init__(self, env: Any, gain: ArrayLike = DEFAULT_GAIN, *, iters: int = 4) -> None:
        super().__init__(env, gain, bank="nominal", iters=iters)
        self.batch = batch_of(env)
        self.name = "informed_actuated"

    def _unmodelled(self, module: Any, system: Any) -> Any:
        return bound_fn(module, "unmodelled", system)

    def __repr__(self) -> str:
        return f"InformedActuatedLaw({self.task.name!r}, gain={self.gain.tolist()})"

    def _hidden(self, b: int) -> tuple[Array, Array]:
        if not self.batch.hides:
            return np.zeros((b, 1, 2)), np.zeros((b, max(1, len(self.task.unmodelled_ranges))))
        now = self.batch.hidden_now(np.arange(b))
        hyp = np.stack([now["delay_steps"].astype(np.float64), now["lag_time_constant"]], axis=1)[:, None, :]
        coef = now["unmodelled_coefficients"]
        if self._core.unmodelled is None or coef.shape[1] == 0:
            coef = np.zeros((b, 1))
        return hyp, coef
