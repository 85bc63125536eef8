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
  observation noise ``sigma`` (``obs_noise``, which it declares).  The numpy functions of the task
  (the frame change, the observation) are differentiated by central differences.

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
from functools import cache, partial
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from numpy.typing import ArrayLike, NDArray

from vnhc_gym.baselines.geometric import DEFAULT_GAIN
from vnhc_gym.baselines.observer import ObserverController
from vnhc_gym.envs.config import check_number
from vnhc_gym.mechanics import functional as F
from vnhc_gym.tasks.base import Task

__all__ = ["EKF", "FilterState", "InformedKalmanController", "KalmanController", "correct", "predict", "process_noise"]

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


@cache
def _batched_predict(system: Any, dt: float, substeps: int, filtered: tuple[int, ...]) -> Any:
    """`predict` compiled for a batch, once per system and step: every controller of the same task
    and step shares it (JAX compiles a jitted function once per function object)."""
    return jax.jit(jax.vmap(partial(predict, system, dt, substeps, filtered), in_axes=(0, 0, 0, 0, None)))


def _jacobian(f: Any, z: Array, h: float = 1e-6) -> Array:
    """Central differences ``(B, m, k)`` of a batched numpy function ``f: (N, k) -> (N, m)`` at
    ``z (B, k)``, in one call of ``f``."""
    b, k = z.shape
    bumped = np.repeat(z[:, None, :], 2 * k, axis=1)
    idx = np.arange(k)
    bumped[:, idx, idx] += h
    bumped[:, k + idx, idx] -= h
    out = f(bumped.reshape(-1, k)).reshape(b, 2 * k, -1)
    return ((out[:, :k] - out[:, k:]) / (2 * h)).transpose(0, 2, 1)


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


#: `correct` compiled for a batch (the numpy controllers' rows).
_batched_correct = jax.jit(jax.vmap(correct, in_axes=(0, 0, 0, 0, 0, None)))


def _correct_rows(pred: Array, prior: Array, expected: Array, jac: Array, obs: Array, var: float
                  ) -> tuple[Array, Array]:
    """`correct` on every row of a batch, in float64, as writable numpy arrays."""
    with jax.enable_x64(True):
        x, cov = _batched_correct(pred, prior, expected, jac, obs, var)
    return np.array(x, dtype=np.float64), np.array(cov, dtype=np.float64)


class FilterState(NamedTuple):
    """One episode's filter: the estimate ``z = (x, theta)``, its covariance, and the parameters read
    from the last observation (those the filter does not estimate)."""

    z: Any
    cov: Any
    base: Any


@dataclass(frozen=True, eq=False)
class EKF:
    """`KalmanController`'s filter for one episode as pure JAX functions: `start` on an episode's
    first observation, `update` on each next one (told the force applied since), `estimate` for the
    law.  Batched by ``jax.vmap`` and compiled with its environment, it is the base of the compiled
    backend's residual learners (`vnhc_gym.wrappers.residual_jax.kalman_base`).  Jacobians are exact
    (forward-mode differentiation of the task's pure functions).  Build it with `EKF.of`.
    """

    system: Any  #: the controller model's printed functions
    chart: Callable[..., Any]  #: the task module's ``controller_inputs(obs, p, args)``
    seen: Callable[..., Any]  #: the measurement model, `Task.observation_model`
    move: Callable[..., Any] | None  #: the task module's ``recenter(s, p, args)``, if any
    drift: Callable[..., Any] | None  #: the task module's ``parameter_drift(s, p, args)``, if any
    filtered: tuple[int, ...]  #: the indices of the filtered parameters
    substeps: int
    q: float
    q_params: float

    @classmethod
    def of(cls, task: Task, q: float = 1.0, q_params: float = 0.03) -> EKF:
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
                   substeps=int(task.config.substeps), q=check_number("q", q, low=0.0, high=1e6),
                   q_params=check_number("q_params", q_params, low=0.0, high=1e6))

    @property
    def dim(self) -> int:
        """The controller state's size ``2 n``."""
        return 2 * int(self.system.N)

    def params(self, z: Any, base: Any) -> Any:
        """The controller model's parameters: ``base`` with the filtered entries from ``z``."""
        return base.at[jnp.asarray(self.filtered, dtype=jnp.int32)].set(z[self.dim:]) if self.filtered else base

    def read(self, obs: Any, p_nominal: Any, args: Any) -> tuple[Any, Any]:
        """``z`` read back from an observation, and the parameters."""
        y, py = self.chart(obs, p_nominal, args)
        return jnp.concatenate([y, py[jnp.asarray(self.filtered, dtype=jnp.int32)]]), py

    def start(self, obs: Any, p_nominal: Any, sigma: Any, args: Any) -> FilterState:
        """The filter at an episode's first observation: ``z`` read back from it, with the covariance
        ``sigma^2 J J^T`` that independent noise ``sigma`` on each entry gives it (``J = dz/dobs``)."""
        z, base = self.read(obs, p_nominal, args)
        jac = jax.jacfwd(lambda o: self.read(o, p_nominal, args)[0])(obs)
        return FilterState(z, sigma**2 * jac @ jac.T + 1e-12 * jnp.eye(z.shape[0], dtype=z.dtype), base)

    def update(self, f: FilterState, obs: Any, u: Any, p_nominal: Any, dt: Any, sigma: Any, args: Any
               ) -> FilterState:
        """Predict one control period with the applied force ``u`` (carried into the frame of the new
        observation, plus the filtered parameters' random walk), then correct with the observation
        (``R = max(sigma, 1e-6)^2 I``).  A non-finite result restarts from the observation."""
        dim, idx = self.dim, jnp.asarray(self.filtered, dtype=jnp.int32)
        k = f.z.shape[0]
        q_mat = jnp.zeros((k, k), f.z.dtype).at[:dim, :dim].set(process_noise(dim // 2, dt, self.q))
        pred, prior = predict(self.system, dt, self.substeps, self.filtered, f.z, f.cov, f.base, u, q_mat)
        moved = self.params(pred, f.base)
        if self.move is not None:
            move = self.move

            def frame(zz: Any) -> Any:
                x, p = move(zz[:dim], self.params(zz, f.base), args)
                return jnp.concatenate([x, p[idx]])

            jac = jax.jacfwd(frame)(pred)
            moved = move(pred[:dim], moved, args)[1]
            pred, prior = frame(pred), jac @ prior @ jac.T
        if self.filtered:
            drift = (self.drift(pred[:dim], moved, args) if self.drift is not None
                     else jnp.zeros((dim, k - dim), pred.dtype))
            g = jnp.concatenate([drift, jnp.eye(k - dim, dtype=pred.dtype)])
            prior = prior + self.q_params**2 * dt * g @ g.T
        fresh = self.start(obs, p_nominal, sigma, args)

        def seen(zz: Any) -> Any:
            p = self.params(zz, fresh.base)
            return self.seen(zz[:dim], p, p, args)

        z, cov = correct(pred, prior, seen(pred), jax.jacfwd(seen)(pred), obs, jnp.maximum(sigma, 1e-6) ** 2)
        bad = ~(jnp.all(jnp.isfinite(z)) & jnp.all(jnp.isfinite(cov)))
        return FilterState(jnp.where(bad, fresh.z, z), jnp.where(bad, fresh.cov, cov), fresh.base)

    def estimate(self, f: FilterState) -> tuple[Any, Any]:
        """The controller state and parameters the law acts on."""
        return f.z[:self.dim], self.params(f.z, f.base)


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
        self.system = self.model.functions
        self.sigma = float(self.task.config.obs_noise)
        self.name = "kalman"
        names = list(self.model.param_names)
        unknown = [p for p in self.task.filtered_params if p not in names]
        if unknown:
            raise ValueError(f"task {self.task.name!r}: filtered_params {unknown} are not parameters of "
                             f"{self.model.name!r} {names}")
        self._filtered = tuple(names.index(p) for p in self.task.filtered_params)
        self._dim = 2 * self.model.n
        k = self._dim + len(self._filtered)
        self._q_state = np.zeros((k, k))  # the acceleration noise, on the state only
        with jax.enable_x64(True):
            self._q_state[:self._dim, :self._dim] = np.asarray(process_noise(self.model.n, float(self.dt), self.q))
        self._cov: Array | None = None
        self._base: Array | None = None  # the parameters the filter does not estimate (B, n_params)
        self._predict = _batched_predict(self.system, float(self.dt), int(self.substeps), self._filtered)

    def __repr__(self) -> str:
        return (f"KalmanController({self.task.name!r}, gain={self.gain.tolist()}, q={self.q}, "
                f"q_params={self.q_params}, variant={self.variant!r})")

    def _parameter_walk(self, z: Array, params: Array) -> Array:
        """The covariance ``(B, k, k)`` of one step of the filtered parameters' random walk, added in
        the frame of the next observation (where the field differs from its local model): ``q_params^2
        dt G G^T`` with ``G = [D; I]``, ``D`` the state each parameter carries
        ([`parameter_drift`][vnhc_gym.tasks.base.Task.parameter_drift])."""
        b, k = z.shape
        g = np.zeros((b, k, k - self._dim))
        g[:, :self._dim] = self.task.parameter_drift(z[:, :self._dim], params)
        g[:, self._dim:] = np.eye(k - self._dim)
        return self.q_params**2 * self.dt * g @ g.transpose(0, 2, 1)

    # ------------------------------------------------------------------ the filter's state z = (x, theta)
    def _read(self, obs: Array) -> tuple[Array, Array]:
        """``z`` read back from observations, and the parameters."""
        y, py = self.task.controller_inputs(obs)
        return np.concatenate([y, py[:, list(self._filtered)]], axis=1), py

    def _params(self, z: Array, base: Array) -> Array:
        p = base.copy()
        p[:, list(self._filtered)] = z[:, self._dim:]
        return p

    def _read_cov(self, obs: Array) -> Array:
        """The covariance ``sigma^2 J J^T`` of ``z`` read back from an observation with independent
        noise ``sigma`` on every entry."""
        b, d = obs.shape
        k = self._dim + len(self._filtered)
        if self.sigma == 0.0:
            return np.zeros((b, k, k))

        def read(o: Array) -> Array:
            z = self._read(o)[0]
            return z

        jac = _jacobian(read, obs)
        for j in self.task.angles:  # a read-back angle near +-pi may wrap between the two sides
            jac[:, j] = (jac[:, j] * 2e-6 + np.pi) % (2 * np.pi) - np.pi
            jac[:, j] /= 2e-6
        return self.sigma**2 * jac @ jac.transpose(0, 2, 1)

    def _recenter(self, z: Array, cov: Array, base: Array) -> tuple[Array, Array, Array]:
        """``z`` in the frame of the next read-back (`Task.recenter`), its covariance carried through
        the change of frame's Jacobian, and the parameters."""
        if self.task.frame_functions()[0] is None:
            return z, cov, base
        b = z.shape[0]

        def move(zz: Array) -> Array:
            x, p = self.task.recenter(zz[:, :self._dim], self._params(zz, np.repeat(base, zz.shape[0] // b, axis=0)))
            return np.concatenate([x, p[:, list(self._filtered)]], axis=1)

        jac = _jacobian(move, z)
        x, p = self.task.recenter(z[:, :self._dim], self._params(z, base))
        return np.concatenate([x, p[:, list(self._filtered)]], axis=1), jac @ cov @ jac.transpose(0, 2, 1), p

    def _correct(self, z: Array, prior: Array, base: Array, obs: Array) -> tuple[Array, Array]:
        """The Kalman update with the observation itself as the measurement: ``h`` is the task's
        [`observation_of`][vnhc_gym.tasks.base.Task.observation_of], ``H`` its Jacobian (central
        differences of the task's numpy function), ``R = sigma^2 I``."""
        b = z.shape[0]

        def seen(zz: Array) -> Array:
            return self.task.observation_of(zz[:, :self._dim], self._params(zz, np.repeat(base, zz.shape[0] // b, 0)))

        var = max(self.sigma, 1e-6) ** 2  # a floor: with no noise the filter follows the observation
        return _correct_rows(z, prior, seen(z), _jacobian(seen, z), obs, var)

    def law(self, states: Array, params: Array) -> tuple[Array, NDArray[np.bool_]]:
        """The law of the chosen ``variant`` on the estimate (``u = 0`` on flagged rows)."""
        u, singular = super().law(states, params)
        return self.held(u, singular, states, params), singular

    def estimate(self, obs: Array) -> tuple[Array, Array]:
        z_read, base = self._read(obs)
        b = z_read.shape[0]
        fresh_cov = self._read_cov(obs) + 1e-12 * np.eye(z_read.shape[1])
        if self._x is None or self._x.shape[0] != b or self._u is None or self._fresh is None \
                or self._cov is None or self._base is None:
            self._x, self._cov, self._base = z_read.copy(), fresh_cov, base
            self._u = np.zeros((b, self.act_dim))
            self._fresh = np.zeros(b, dtype=bool)
            return self._x[:, :self._dim], self._params(self._x, base)
        with jax.enable_x64(True):  # scoped: the filter needs float64, the user's settings stay
            pred, prior = self._predict(self._x, self._cov, self._base, self._u, self._q_state)
            pred, prior = np.array(pred, dtype=np.float64), np.array(prior, dtype=np.float64)
        pred, prior, moved = self._recenter(pred, prior, self._base)
        prior += self._parameter_walk(pred, moved)
        z, cov = self._correct(pred, prior, base, np.asarray(obs, dtype=np.float64))
        bad = self._fresh | ~np.isfinite(z).all(axis=1) | ~np.isfinite(cov).all(axis=(1, 2))
        z[bad], cov[bad] = z_read[bad], fresh_cov[bad]
        self._x, self._cov, self._base = z, cov, base
        self._fresh[:] = False
        return z[:, :self._dim], self._params(z, base)


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
        from vnhc_gym.baselines.oracle import _batch_of

        # No random walk of the told parameters: their change moves the state exactly (`_recenter`),
        # where the filter's walk spreads it as variance of the parameters and, with them, of the state.
        super().__init__(env, gain, q=q, q_params=0.0, variant=variant)
        self.batch = _batch_of(env)
        self._told = np.zeros((0, len(self.model.param_names)))  # this step's told parameters (B, n_params)
        self._chart = self._told  # and the nominal ones the observation is computed with
        self.name = "informed_kalman"

    def __repr__(self) -> str:
        return (f"InformedKalmanController({self.task.name!r}, gain={self.gain.tolist()}, q={self.q}, "
                f"variant={self.variant!r})")

    def _read(self, obs: Array) -> tuple[Array, Array]:
        """``z`` read back from observations, with the true parameters (and the filtered ones told)."""
        y, _ = self.task.controller_inputs(obs)
        buf = self.batch.buf
        rows = buf.state.shape[0]
        p = self.task.informed_params(buf.state, buf.params_true)
        if y.shape[0] == rows:
            self._told = p
            self._chart = self.task.informed_params(buf.state, buf.params_nominal)
        # Several observations a row: the bumped copies of `_jacobian`, row-major like np.repeat.
        p = np.repeat(p, y.shape[0] // rows, axis=0)
        return np.concatenate([y, p[:, list(self._filtered)]], axis=1), p

    def estimate(self, obs: Array) -> tuple[Array, Array]:
        rows = self.batch.buf.state.shape[0]
        if np.shape(obs)[0] != rows:
            raise ValueError(f"the informed filter acts on all {rows} rows of its environment at once, got "
                             f"{np.shape(obs)[0]} observations")
        return super().estimate(obs)

    def _correct(self, z: Array, prior: Array, base: Array, obs: Array) -> tuple[Array, Array]:
        """As the filter's, with the environment's own measurement: ``phi`` from the true parameters, the
        rest of the observation from the nominal ones it reports (the boat's chart of the current),
        which under mismatch differ."""
        b = z.shape[0]

        def seen(zz: Array) -> Array:
            reps = zz.shape[0] // b
            return self.task.observation_of(zz[:, :self._dim], self._params(zz, np.repeat(base, reps, 0)),
                                            chart=np.repeat(self._chart, reps, 0))

        var = max(self.sigma, 1e-6) ** 2
        return _correct_rows(z, prior, seen(z), _jacobian(seen, z), obs, var)

    def _recenter(self, z: Array, cov: Array, base: Array) -> tuple[Array, Array, Array]:
        """As the filter's, then the told parameters replace the predicted ones, and carry the state
        with them as their random walk would ([`parameter_drift`][vnhc_gym.tasks.base.Task.parameter_drift]:
        the current at a boat moves its ground velocity); told exactly, they have no variance."""
        z, cov, p = super()._recenter(z, cov, base)
        if not self._filtered:
            return z, cov, p
        cols, dim = list(self._filtered), self._dim
        told = self._told[:, cols]
        z, cov, p = z.copy(), cov.copy(), p.copy()
        z[:, :dim] += np.einsum("bik,bk->bi", self.task.parameter_drift(z[:, :dim], p), told - z[:, dim:])
        z[:, dim:] = told
        p[:, cols] = told
        cov[:, dim:, :] = 0.0
        cov[:, :, dim:] = 0.0
        return z, cov, p
