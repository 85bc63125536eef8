"""The geometric law on an extended Kalman filter's estimate: for noisy observations.

[`KalmanController`][vnhc_gym.baselines.KalmanController] keeps, per episode, an estimate ``z`` of
the controller model's state (and of the parameters the task lists in ``filtered_params``, such as
the local current a boat reads from its observation) with its covariance ``P``:

* **predict** with the nominal model and the force the environment actually applied: one control
  period of RK4 (the map the environment integrates with), ``P- = A P A^T + Q`` with ``A`` the
  exact Jacobian of that step, by forward-mode automatic differentiation of the printed JAX model
  (`vnhc_gym.mechanics.functional`); the filtered parameters follow a random walk.  Where the
  controller's frame moves with the system ([`recenter`][vnhc_gym.tasks.base.Task.recenter]: the
  boat at the origin, the sled heading along x) the prediction and its covariance are carried into
  the new frame;
* **correct** with the observation itself: the measurement model is the task's own observation of
  a state ([`observation_of`][vnhc_gym.tasks.base.Task.observation_of]), so every entry the agent
  sees counts, the observed ``phi`` entries included; ``R = sigma^2 I`` with the environment's own
  observation noise ``sigma`` (``obs_noise``, which it declares).

Every Jacobian is exact, by forward-mode differentiation of the task's pure functions: the filter is
`EKF`, pure JAX functions of one episode, which the controller runs batched over its rows and the
compiled backend's residual learners run inside their training program
(`vnhc_gym.wrappers.residual_jax.kalman_base`).

The process noise is white noise on the accelerations, ``Q = q^2 [[dt^3/3, dt^2/2], [dt^2/2, dt]]``
per coordinate (``q`` is tuned on validation episodes beside the law's gain: it stands for the
model error and the kicks the filter cannot predict), and a random walk of each filtered parameter,
``q_params^2 dt`` per step, which also moves the state the parameter carries
([`parameter_drift`][vnhc_gym.tasks.base.Task.parameter_drift]: the velocity a boat drifts with).
The law acts on the estimate.  Without observation noise the filter returns the observed state: the
plain law.

Why a filter of our own rather than filterpy or dynamax: it runs online inside a controller,
batched over episodes, on a process model that is itself JAX code whose Jacobian JAX gives exactly;
the update is the dozen lines of `correct`, which those libraries would only wrap.
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from dataclasses import dataclass
from functools import cache
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from numpy.typing import ArrayLike, NDArray

from vnhc_gym.baselines.geometric import DEFAULT_GAIN
from vnhc_gym.baselines.observer import ObserverController
from vnhc_gym.baselines.policy import batch_of
from vnhc_gym.envs.config import check_number
from vnhc_gym.mechanics import functional as F
from vnhc_gym.tasks.base import Task

__all__ = ["EKF", "FilterNoise", "FilterState", "InformedKalmanController", "KalmanController", "correct", "predict",
           "process_noise"]

Array = NDArray[np.float64]


def predict(system: Any, dt: float, substeps: int, filtered: tuple[int, ...], z: Any, cov: Any, base: Any, u: Any,
            q_mat: Any) -> tuple[Any, Any]:
    """One episode's prediction (pure JAX; batched by vmap) of the state ``z = (x, theta)``: the
    system's state ``x`` moves by ``F_dt(x, u)`` with the parameters ``base`` whose entries
    ``filtered`` are ``theta``; ``theta`` stays (a random walk).  Returns ``z-`` and
    ``A P A^T + Q`` with ``A = dz-/dz`` by forward-mode differentiation."""
    dim = 2 * system.N
    idx = jnp.asarray(filtered, dtype=jnp.int32)

    def step(zz: Any) -> Any:
        p = base.at[idx].set(zz[dim:]) if filtered else base
        return jnp.concatenate([F.rk4_step(system, zz[:dim], p, u, dt, substeps), zz[dim:]])

    a = jax.jacfwd(step)(z)
    return step(z), a @ cov @ a.T + q_mat


def process_noise(n: int, dt: Any, q: float) -> Any:
    """``Q`` of white acceleration noise of intensity ``q^2`` on each of ``n`` coordinates over ``dt``:
    ``q^2 [[dt^3/3, dt^2/2], [dt^2/2, dt]]`` for each (position, velocity) pair, state order ``(q, qd)``
    (a JAX array; ``dt`` may be traced)."""
    block = jnp.stack([jnp.stack([dt**3 / 3, dt**2 / 2]), jnp.stack([dt**2 / 2, dt])])
    return q**2 * jnp.kron(block, jnp.eye(n))


def correct(pred: Any, prior: Any, expected: Any, jac: Any, obs: Any, var: Any) -> tuple[Any, Any]:
    """One episode's Kalman update (pure JAX): ``x = x- + K (z - h(x-))``, ``P = (I - K H) P- (I - K H)^T
    + K R K^T`` (Joseph's form: symmetric and positive however ``K`` rounds), ``K = P- H^T (H P- H^T +
    R)^-1``.

    Parameters
    ----------
    pred, prior : arrays, shapes ``(k,)`` and ``(k, k)``
        The prediction and its covariance.
    expected, jac : arrays, shapes ``(d,)`` and ``(d, k)``
        ``h(x-)`` and ``H``; an entry of ``expected`` that is NaN is not measured.
    obs : array, shape ``(d,)``
        The measurement ``z``.
    var : float
        ``R = var I``.
    """
    measured = jnp.isfinite(expected)
    innovation = jnp.where(measured, obs - expected, 0.0)
    jac = jnp.where(measured[:, None], jac, 0.0)
    d, k = jac.shape
    s = jac @ prior @ jac.T + var * jnp.eye(d)
    gain = jnp.linalg.solve(s, jac @ prior).T  # P- H^T S^-1 (S and P- symmetric)
    rest = jnp.eye(k) - gain @ jac
    return pred + gain @ innovation, rest @ prior @ rest.T + var * gain @ gain.T


class FilterState(NamedTuple):
    """One episode's filter: the estimate ``z = (x, theta)``, its covariance, and the parameters read
    from the last observation (those the filter does not estimate)."""

    z: Any
    cov: Any
    base: Any


class FilterNoise(NamedTuple):
    """What an update of the filter reads besides the episode: the control period ``dt``, the
    observation noise ``sigma``, the process noise ``q`` and the filtered parameters' random walk
    ``q_params`` (a pytree: changing them recompiles nothing)."""

    dt: Any
    sigma: Any
    q: Any
    q_params: Any


@dataclass(frozen=True)
class EKF:
    """`KalmanController`'s filter for one episode as pure JAX functions: `start` on an episode's
    first observation, `update` on each next one (told the force applied since), `estimate` for the
    law.  Batched by ``jax.vmap``, it runs the numpy controllers' rows and, compiled with its
    environment, the compiled backend's residual learners
    (`vnhc_gym.wrappers.residual_jax.kalman_base`).  Jacobians are exact (forward-mode
    differentiation of the task's pure functions).  Build it with `EKF.of`; two filters of the same
    task are equal, so they share their compiled programs.

    ``told`` and ``chart`` (the informed reference, `InformedKalmanController`): parameters that
    replace the filtered ones and those read from the observation, and the parameters the
    observation is computed with (default: the estimate's).
    """

    system: Any  #: the controller model's printed functions
    chart: Callable[..., Any]  #: the task module's ``controller_inputs(obs, p, args)``
    seen: Callable[..., Any]  #: the measurement model, `Task.observation_model`
    move: Callable[..., Any] | None  #: the task module's ``recenter(s, p, args)``, if any
    drift: Callable[..., Any] | None  #: the task module's ``parameter_drift(s, p, args)``, if any
    filtered: tuple[int, ...]  #: the indices of the filtered parameters
    substeps: int

    @classmethod
    def of(cls, task: Task) -> EKF:
        """The filter of a configured task (its controller model, measurement model and frame)."""
        chart = getattr(sys.modules[type(task).__module__], "controller_inputs", None)
        if not callable(chart):
            raise ValueError(f"task {task.name!r}: its module defines no controller_inputs, so no filter can read "
                             f"its observations")
        names = list(task.controller_model().param_names)
        unknown = [p for p in task.filtered_params if p not in names]
        if unknown:
            raise ValueError(f"task {task.name!r}: filtered_params {unknown} are not parameters of the controller "
                             f"model {names}")
        move, drift = task.frame_functions()
        return cls(system=task.controller_functions(), chart=chart, seen=task.observation_model(), move=move,
                   drift=drift, filtered=tuple(names.index(p) for p in task.filtered_params),
                   substeps=int(task.config.substeps))

    @property
    def dim(self) -> int:
        """The controller state's size ``2 n``."""
        return 2 * int(self.system.N)

    def params(self, z: Any, base: Any) -> Any:
        """The controller model's parameters: ``base`` with the filtered entries from ``z``."""
        return base.at[jnp.asarray(self.filtered, dtype=jnp.int32)].set(z[self.dim:]) if self.filtered else base

    def read(self, obs: Any, p_nominal: Any, args: Any, told: Any = None) -> tuple[Any, Any]:
        """``z`` read back from an observation, and the parameters (``told`` ones if given)."""
        y, py = self.chart(obs, p_nominal, args)
        if told is not None:
            py = told
        return jnp.concatenate([y, py[jnp.asarray(self.filtered, dtype=jnp.int32)]]), py

    def start(self, obs: Any, p_nominal: Any, args: Any, sigma: Any, told: Any = None) -> FilterState:
        """The filter at an episode's first observation: ``z`` read back from it, with the covariance
        ``sigma^2 J J^T`` that independent noise ``sigma`` on each entry gives it (``J = dz/dobs``)."""
        z, base = self.read(obs, p_nominal, args, told)
        jac = jax.jacfwd(lambda o: self.read(o, p_nominal, args, told)[0])(obs)
        return FilterState(z, sigma**2 * jac @ jac.T + 1e-12 * jnp.eye(z.shape[0], dtype=z.dtype), base)

    def update(self, f: FilterState, obs: Any, u: Any, p_nominal: Any, args: Any, noise: FilterNoise,
               told: Any = None, chart: Any = None) -> FilterState:
        """Predict one control period with the applied force ``u`` (carried into the frame of the new
        observation, plus the filtered parameters' random walk), then correct with the observation
        (``R = max(sigma, 1e-6)^2 I``).  A non-finite result restarts from the observation."""
        dim, idx = self.dim, jnp.asarray(self.filtered, dtype=jnp.int32)
        k = f.z.shape[0]
        q_mat = jnp.zeros((k, k), f.z.dtype).at[:dim, :dim].set(process_noise(dim // 2, noise.dt, noise.q))
        pred, prior = predict(self.system, noise.dt, self.substeps, self.filtered, f.z, f.cov, f.base, u, q_mat)
        moved = self.params(pred, f.base)
        if self.move is not None:
            move = self.move

            def frame(zz: Any) -> Any:
                x, p = move(zz[:dim], self.params(zz, f.base), args)
                return jnp.concatenate([x, p[idx]])

            jac = jax.jacfwd(frame)(pred)
            moved = move(pred[:dim], moved, args)[1]
            pred, prior = frame(pred), jac @ prior @ jac.T

        def drift(x: Any, p: Any) -> Any:
            return self.drift(x, p, args) if self.drift is not None else jnp.zeros((dim, k - dim), x.dtype)

        if self.filtered and told is not None:
            # Told parameters replace the predicted ones exactly, and carry the state with them as their
            # random walk would (the current at a boat moves its ground velocity); they have no variance.
            x = pred[:dim] + drift(pred[:dim], moved) @ (told[idx] - pred[dim:])
            pred, moved = jnp.concatenate([x, told[idx]]), moved.at[idx].set(told[idx])
            prior = prior.at[dim:, :].set(0.0).at[:, dim:].set(0.0)
        if self.filtered:
            g = jnp.concatenate([drift(pred[:dim], moved), jnp.eye(k - dim, dtype=pred.dtype)])
            prior = prior + noise.q_params**2 * noise.dt * g @ g.T
        fresh = self.start(obs, p_nominal, args, noise.sigma, told)

        def seen(zz: Any) -> Any:
            p = self.params(zz, fresh.base)
            return self.seen(zz[:dim], p, p if chart is None else chart, args)

        z, cov = correct(pred, prior, seen(pred), jax.jacfwd(seen)(pred), obs, jnp.maximum(noise.sigma, 1e-6) ** 2)
        bad = ~(jnp.all(jnp.isfinite(z)) & jnp.all(jnp.isfinite(cov)))
        return FilterState(jnp.where(bad, fresh.z, z), jnp.where(bad, fresh.cov, cov), fresh.base)

    def estimate(self, f: FilterState) -> tuple[Any, Any]:
        """The controller state and parameters the law acts on."""
        return f.z[:self.dim], self.params(f.z, f.base)


@cache
def _batched(ekf: EKF) -> tuple[Any, Any, Any]:
    """`EKF.start`, `update` and `estimate` compiled for a batch of rows, once per filter: every
    controller of the same task shares them (the noise settings are arguments, not constants)."""
    start = jax.jit(jax.vmap(ekf.start, in_axes=(0, 0, None, None, 0)))
    update = jax.jit(jax.vmap(ekf.update, in_axes=(0, 0, 0, 0, None, None, 0, 0)))
    return start, update, jax.jit(jax.vmap(ekf.estimate))


class KalmanController(ObserverController):
    """The stabilising law on an extended Kalman filter's estimate (see the module docstring).

    Parameters
    ----------
    env : gymnasium Env or VectorEnv
        A vnhc_gym environment whose task's controller model is printed
        (`vnhc_gym.systems.printed`).
    gain : float or array_like, default 5
    q : float, default 1.0
        Standard deviation of the white acceleration noise of the process model (units of the
        velocities per second per square-root second).
    q_params : float, default 0.03
        Standard deviation per square-root second of the random walk of the parameters the task
        lists in ``filtered_params`` (the local current model a boat reads from its observation).
    variant : {"plain", "sampled"}
        The law on the estimate: ``u*`` held over the control period, or the sampled-data law (the
        held control that makes ``phi`` after one period of the nominal step map equal
        ``exp(-K dt) phi``; stable at gains where the plain law held over a period is not).

    Notes
    -----
    The estimate of a batch row starts from its first observation, with the covariance that the
    observation noise gives the state read back from it; ``predict(obs, episode_start=...)``
    restarts rows where a new episode begins.
    """

    def __init__(self, env: Any, gain: ArrayLike = DEFAULT_GAIN, q: float = 1.0, q_params: float = 0.03,
                 variant: str = "plain") -> None:
        super().__init__(env, gain)
        if variant not in ("plain", "sampled"):
            raise ValueError(f"variant must be 'plain' or 'sampled', got {variant!r}")
        self.variant = variant
        self.q = check_number("q", q, low=0.0, high=1e6)
        self.q_params = check_number("q_params", q_params, low=0.0, high=1e6)
        self.sigma = float(self.task.config.obs_noise)
        self.name = "kalman"
        self.ekf = EKF.of(self.task)
        self._dim = self.ekf.dim
        self._filter: FilterState | None = None
        self._base: Array | None = None  # the parameters the filter does not estimate (B, n_params)

    def __repr__(self) -> str:
        return (f"KalmanController({self.task.name!r}, gain={self.gain.tolist()}, q={self.q}, "
                f"q_params={self.q_params}, variant={self.variant!r})")

    def _params(self, z: Array, base: Array) -> Array:
        """The controller model's parameters of a batch: ``base`` with the filtered entries from ``z``."""
        p = base.copy()
        p[:, list(self.ekf.filtered)] = z[:, self._dim:]
        return p

    def _told(self, rows: int) -> tuple[Array | None, Array | None]:
        """The parameters told to the filter and the observation's own, per row (none: the filter's)."""
        return None, None

    def law(self, states: Array, params: Array) -> tuple[Array, NDArray[np.bool_]]:
        """The law of the chosen ``variant`` on the estimate (``u = 0`` on flagged rows)."""
        u, singular = super().law(states, params)
        return self.held(u, singular, states, params), singular

    def estimate(self, obs: Array) -> tuple[Array, Array]:
        o = np.asarray(obs, dtype=np.float64)
        b = o.shape[0]
        told, chart = self._told(b)
        start, update, estimate = _batched(self.ekf)
        nominal = np.broadcast_to(np.asarray(self.task.nominal, dtype=np.float64), (b, len(self.task.nominal)))
        noise = FilterNoise(float(self.dt), self.sigma, self.q, self.q_params)
        with jax.enable_x64(True):  # scoped: the filter needs float64, the user's settings stay
            fresh = start(o, nominal, self.task.args, self.sigma, told)
            if self._x is None or self._x.shape[0] != b or self._filter is None or self._u is None \
                    or self._fresh is None:
                f = fresh
                self._u = np.zeros((b, self.act_dim))
                self._fresh = np.zeros(b, dtype=bool)
            else:
                f = update(self._filter, o, self._u, nominal, self.task.args, noise, told, chart)
                restart = self._fresh
                f = jax.tree.map(lambda a, c: np.where(restart.reshape(-1, *([1] * (a.ndim - 1))), a, c), fresh, f)
            x, p = (np.array(v, dtype=np.float64) for v in estimate(f))
        self._filter = f
        self._x, self._base = np.array(f.z, dtype=np.float64), np.array(f.base, dtype=np.float64)
        self._fresh[:] = False
        return x, p


class InformedKalmanController(KalmanController):
    """A headroom reference: the Kalman-filter law told the episode's true parameters, not its state.

    It sees only the observations, as [`KalmanController`][vnhc_gym.baselines.KalmanController] does,
    but its model's parameters are the true ones ([`Task.informed_params`][vnhc_gym.tasks.base.Task.informed_params]:
    the true parameters themselves where the controller model is the environment's own system; for
    the boat, the affine current that matches the true field exactly at the boat).  Between it and
    the oracle (true state and parameters) lies what the observations hide; between it and the best
    classical baseline, what not knowing the model costs.  Like the oracle it reads the environment
    it acts on, so it cannot be fielded.

    Parameters
    ----------
    env : gymnasium Env or VectorEnv
        The vnhc_gym environment it acts on (row ``i`` of a batch is sub-environment ``i``).
    gain, q, variant
        As for [`KalmanController`][vnhc_gym.baselines.KalmanController]; the filtered parameters
        (the boat's local current) are not estimated but told at every step.
    """

    def __init__(self, env: Any, gain: ArrayLike = DEFAULT_GAIN, q: float = 1.0, variant: str = "plain") -> None:
        # No random walk of the told parameters: their change moves the state exactly (`EKF.update`),
        # where the filter's walk spreads it as variance of the parameters and, with them, of the state.
        super().__init__(env, gain, q=q, q_params=0.0, variant=variant)
        self.batch = batch_of(env)
        self.name = "informed_kalman"

    def __repr__(self) -> str:
        return (f"InformedKalmanController({self.task.name!r}, gain={self.gain.tolist()}, q={self.q}, "
                f"variant={self.variant!r})")

    def _told(self, rows: int) -> tuple[Array | None, Array | None]:
        """The true parameters at the true states of the environment's rows, and the nominal ones the
        environment observes with (the boat's chart of the current), which under mismatch differ."""
        buf = self.batch.buf
        if rows != buf.state.shape[0]:
            raise ValueError(f"the informed filter acts on all {buf.state.shape[0]} rows of its environment at once, "
                             f"got {rows} observations")
        return (self.task.informed_params(buf.state, buf.params_true),
                self.task.informed_params(buf.state, buf.params_nominal))
