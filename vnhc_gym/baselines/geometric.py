"""The paper's geometric law as a policy that sees only the observation.

See :mod:`vnhc_gym.baselines` for the overview and the measured residuals.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
from numpy.typing import ArrayLike, NDArray

from vnhc_gym.mechanics import sampled_control
from vnhc_gym.systems import make_flocking, make_usv

__all__ = ["DEFAULT_GAIN", "GeometricController", "ZeroPolicy", "RandomPolicy", "env_spec", "EnvSpec"]

#: Default gain k of the baseline.  The paper uses K = I with dt = 0.01 and continuous
#: feedback; held over the environments' 0.05 s control period, k = 5 (time constant 0.2 s,
#: four control periods, k dt = 0.5 even at the coarse 0.1 s) converges 5x faster and stays
#: well inside the zero-order hold's stability range.  Measured with ``vnhc-gym benchmark``:
#: mean |phi| falls >100-fold against the zero policy on both envs (USV: ~20-fold at k = 1).
DEFAULT_GAIN = 5.0

Array = NDArray[np.float64]

#: Observation scales, as documented in the environments (kept here so the controller can be
#: built without an environment; the tests check them against the env modules).
FLOCKING_LOG_SPEED_SCALE = 5.0
USV_VEL_SCALE = 2.0
USV_RATE_SCALE = 2.0
USV_OBS_DIM = 14


class EnvSpec:
    """What a baseline needs to know about an environment, read once.

    Attributes
    ----------
    system : {"flocking", "usv"}
    obs_dim, act_dim : int
    nominal : ndarray
        Nominal model parameters (flocking ``(m_1..m_N, g)``; USV ``(m, I, current_scale, ...)``).
    force_bound : ndarray, shape (act_dim,)
        Force (N) that action 1 means (already scaled by the scenario).
    dt : float
    substeps : int
    domain : float
        USV only: half-width of the charted square (positions are observed as ``x / domain``).
    vector : bool
        Whether the spec came from a vector environment.
    """

    def __init__(self, system: str, nominal: ArrayLike, force_bound: ArrayLike, dt: float, substeps: int = 1,
                 domain: float = 100.0, vector: bool = False) -> None:
        if system not in ("flocking", "usv"):
            raise ValueError(f"system must be 'flocking' or 'usv', got {system!r}")
        self.system = system
        self.nominal = np.array(nominal, dtype=np.float64).reshape(-1)
        if system == "flocking":
            if self.nominal.size < 3:
                raise ValueError(f"flocking nominal parameters are (m_1..m_N, g) with N >= 2, got {self.nominal}")
            self.n_agents = self.nominal.size - 1
            self.act_dim = self.n_agents - 1
            self.obs_dim = 3 * self.act_dim + 3
        else:
            if self.nominal.size < 2:
                raise ValueError(f"USV nominal parameters start with (m, I), got {self.nominal}")
            self.n_agents = 0
            self.act_dim = 1
            self.obs_dim = USV_OBS_DIM
        fb = np.broadcast_to(np.asarray(force_bound, dtype=np.float64), (self.act_dim,)).copy()
        if not (np.all(np.isfinite(fb)) and np.all(fb > 0)):
            raise ValueError(f"force_bound must be finite and > 0, got {force_bound!r}")
        if not (np.isfinite(dt) and dt > 0):
            raise ValueError(f"dt must be a finite number > 0, got {dt!r}")
        if int(substeps) != substeps or substeps < 1:
            raise ValueError(f"substeps must be an integer >= 1, got {substeps!r}")
        if not (np.isfinite(domain) and domain > 0):
            raise ValueError(f"domain must be a finite number > 0, got {domain!r}")
        self.force_bound = fb
        self.dt = float(dt)
        self.substeps = int(substeps)
        self.domain = float(domain)
        self.vector = bool(vector)

    def __repr__(self) -> str:
        return (f"EnvSpec({self.system!r}, obs_dim={self.obs_dim}, act_dim={self.act_dim}, dt={self.dt}, "
                f"substeps={self.substeps}, force_bound={self.force_bound.tolist()})")


def _task_of(env: Any) -> Any:
    for obj in (env, getattr(env, "unwrapped", None)):
        task = getattr(obj, "task", None)
        if task is not None:
            return task
    # Walk a wrapper chain by hand (some wrappers do not forward attributes).
    obj = env
    for _ in range(64):
        obj = getattr(obj, "env", None)
        if obj is None:
            break
        task = getattr(obj, "task", None)
        if task is not None:
            return task
    raise TypeError(f"{type(env).__name__} has no `.task` (a vnhc_gym environment, single or vector, is needed); "
                    "pass the nominal model explicitly instead (system=..., nominal=..., force_bound=..., dt=...)")


def env_spec(env: Any) -> EnvSpec:
    """Read an :class:`EnvSpec` from a vnhc_gym environment (single, wrapped, or vector)."""
    from vnhc_gym.envs.flocking_align import FlockingTask
    from vnhc_gym.envs.usv_stream import USVTask

    task = _task_of(env)
    cfg = task.config
    vector = isinstance(env, gym.vector.VectorEnv) or isinstance(getattr(env, "unwrapped", None), gym.vector.VectorEnv)
    if isinstance(task, FlockingTask):
        return EnvSpec("flocking", task.nominal, task.force_bound, cfg.dt, cfg.substeps, vector=vector)
    if isinstance(task, USVTask):
        return EnvSpec("usv", task.nominal, task.force_bound, cfg.dt, cfg.substeps, domain=task.domain, vector=vector)
    raise TypeError(f"unsupported task type {type(task).__name__}")


def _spaces(env: Any) -> tuple[gym.Space, gym.Space]:
    if isinstance(env, gym.vector.VectorEnv) or hasattr(env, "single_observation_space"):
        return env.single_observation_space, env.single_action_space
    return env.observation_space, env.action_space


def _flat_dim(space: gym.Space) -> int:
    shape = space.shape
    if shape is None:
        raise TypeError(f"a space with a shape is needed, got {space}")
    return int(np.prod(shape))


class _Policy:
    """Shared observation checking and the SB3-style ``predict``."""

    obs_dim: int
    act_dim: int

    def _set_dims(self, env: Any, obs_dim: int | None, act_dim: int | None) -> None:
        """Observation / action sizes from ``env``'s spaces, or the explicit ones."""
        if env is not None:
            obs_space, act_space = _spaces(env)
            obs_dim, act_dim = _flat_dim(obs_space), _flat_dim(act_space)
        if obs_dim is None or act_dim is None:
            raise TypeError("pass an env or obs_dim= and act_dim=")
        self.obs_dim, self.act_dim = int(obs_dim), int(act_dim)

    def _check_obs(self, obs: ArrayLike) -> tuple[Array, bool]:
        o = np.asarray(obs, dtype=np.float64)
        if o.ndim == 1 and o.shape[0] == self.obs_dim:
            return o[None, :], True
        if o.ndim == 2 and o.shape[1] == self.obs_dim:
            return o, False
        raise ValueError(f"observation must have shape ({self.obs_dim},) or (n, {self.obs_dim}), got {o.shape}")

    def _act(self, obs: Array) -> Array:
        raise NotImplementedError

    def predict(self, obs: ArrayLike, state: Any = None, episode_start: Any = None,
                deterministic: bool = True) -> tuple[NDArray[np.float32], None]:
        """Actions for one observation ``(d,)`` or a batch ``(n, d)``: ``(action, None)``.

        The signature is Stable-Baselines3's; the recurrent ``state`` is unused and returned as None.
        """
        o, single = self._check_obs(obs)
        a = np.asarray(self._act(o), dtype=np.float32)
        return (a[0] if single else a), None

    def reset(self) -> None:
        """Start of a new episode (stateless policies: nothing to do)."""

    def __call__(self, obs: ArrayLike) -> NDArray[np.float32]:
        return self.predict(obs)[0]


class GeometricController(_Policy):
    """The paper's stabilising law computed from the observation (SB3 ``predict`` interface).

    Parameters
    ----------
    env : gymnasium Env or VectorEnv, optional
        A vnhc_gym environment (possibly wrapped); the *nominal* model parameters, the force
        bound, ``dt`` and ``substeps`` are read from it once, here.  Nothing else of the
        environment is used later: the action depends on the observation only.
    gain : float or array_like, default ``DEFAULT_GAIN`` (5)
        ``diag K`` (one value per constraint component, or a scalar); see ``DEFAULT_GAIN``.
    variant : {"plain", "sampled"}
        ``"plain"``: ``u*`` of Theorem 2 at the observed state, held over the control period.
        ``"sampled"``: the held control that makes ``phi`` after one period of the nominal
        RK4 step map equal ``exp(-K dt) phi_now`` (:func:`vnhc_gym.mechanics.sampled_control`),
        on a state rebuilt from the observation.
    system, nominal, force_bound, dt, substeps, domain
        Build without an environment (or override what the environment says):
        ``system`` is ``"flocking"`` or ``"usv"``; ``nominal`` the model's parameter vector.
    iters : int, default 4
        Newton iterations of the sampled variant.
    singular_tol : float, default 1e-9
        Flocking: ``C`` counts as singular where ``|e_x - e_z| <= singular_tol`` (the leader's
        direction of motion on the diagonal); the action is then 0 for that follower.

    Attributes
    ----------
    last_singular : ndarray of bool, shape (n,)
        Per row of the last ``predict`` batch: the law was undefined (singular ``C``) and a
        zero action was returned.
    n_singular : int
        Running count of such rows.
    last_saturated : ndarray of bool, shape (n,)
        Per row: some component of ``u / force_bound`` was outside ``[-1, 1]`` and clipped.
    n_saturated, n_calls_rows : int
        Running counts of saturated rows and of all rows seen.
    last_converged : ndarray of bool or None
        Sampled variant: whether Newton converged, per row of the last batch (a row that did
        not still gets the last finite Newton iterate, at worst ``u*``).
    """

    def __init__(self, env: Any = None, gain: ArrayLike = DEFAULT_GAIN, variant: str = "plain", *,
                 system: str | None = None, nominal: ArrayLike | None = None, force_bound: ArrayLike | None = None,
                 dt: float | None = None, substeps: int | None = None, domain: float | None = None,
                 iters: int = 4, singular_tol: float = 1e-9) -> None:
        if variant not in ("plain", "sampled"):
            raise ValueError(f"variant must be 'plain' or 'sampled', got {variant!r}")
        if env is not None:
            base = env_spec(env)
            spec = EnvSpec(system or base.system, base.nominal if nominal is None else nominal,
                           base.force_bound if force_bound is None else force_bound,
                           base.dt if dt is None else dt, base.substeps if substeps is None else substeps,
                           base.domain if domain is None else domain, vector=base.vector)
            obs_space, act_space = _spaces(env)
            if getattr(obs_space, "shape", None) != (spec.obs_dim,):
                raise ValueError(f"observation space shape {getattr(obs_space, 'shape', None)} does not match the "
                                 f"{spec.system} layout ({spec.obs_dim},)")
            if getattr(act_space, "shape", None) != (spec.act_dim,):
                raise ValueError(f"action space shape {getattr(act_space, 'shape', None)} does not match "
                                 f"({spec.act_dim},)")
        else:
            if system is None or nominal is None or force_bound is None or dt is None:
                raise TypeError("without an env, pass system=, nominal=, force_bound= and dt= "
                                "(and substeps=, domain= for the sampled variant)")
            spec = EnvSpec(system, nominal, force_bound, dt, 1 if substeps is None else substeps,
                           100.0 if domain is None else domain)
        self.spec = spec
        self.variant = variant
        self.name = "geometric" if variant == "plain" else "geometric-sampled"
        self.obs_dim = spec.obs_dim
        self.act_dim = spec.act_dim
        k = np.broadcast_to(np.asarray(gain, dtype=np.float64), (spec.act_dim,)).copy()
        if not (np.all(np.isfinite(k)) and np.all(k >= 0)):
            raise ValueError(f"gain must be finite and >= 0, got {gain!r}")
        self.gain = k
        if int(iters) != iters or iters < 0:
            raise ValueError(f"iters must be an integer >= 0, got {iters!r}")
        self.iters = int(iters)
        if not (np.isfinite(singular_tol) and singular_tol >= 0):
            raise ValueError(f"singular_tol must be a finite number >= 0, got {singular_tol!r}")
        self.singular_tol = float(singular_tol)
        self.force_bound = spec.force_bound
        if spec.system == "flocking":
            self.masses = spec.nominal[: spec.n_agents - 1].copy()
            self.g = float(spec.nominal[-1])
            self.model = make_flocking(spec.n_agents) if variant == "sampled" else None
        else:
            self.mass = float(spec.nominal[0])
            self.inertia = float(spec.nominal[1])
            self.model = make_usv("affine") if variant == "sampled" else None
            if self.model is not None:
                names = self.model.param_names
                self._usv_idx = {name: names.index(name) for name in names}
        self.last_singular = np.zeros(0, dtype=bool)
        self.last_saturated = np.zeros(0, dtype=bool)
        self.last_converged: NDArray[np.bool_] | None = None
        self.n_singular = 0
        self.n_saturated = 0
        self.n_rows = 0

    def __repr__(self) -> str:
        return f"GeometricController({self.spec.system!r}, variant={self.variant!r}, gain={self.gain.tolist()})"

    # ------------------------------------------------------------------ law in force units
    def force(self, obs: ArrayLike) -> tuple[Array, NDArray[np.bool_]]:
        """Unsaturated force ``u`` (N) of the chosen variant and the singular mask, for a batch of observations."""
        o, _ = self._check_obs(obs)
        if self.spec.system == "flocking":
            u, singular = self.flocking_law(o)
            if self.variant == "sampled":
                ok = ~singular
                if ok.any():
                    us, conv = self._flocking_sampled(o[ok], u[ok])
                    u[ok] = us
                    self.last_converged = np.zeros(o.shape[0], dtype=bool)
                    self.last_converged[ok] = conv
                else:
                    self.last_converged = np.zeros(o.shape[0], dtype=bool)
        else:
            u = self.usv_law(o)
            singular = np.zeros(o.shape[0], dtype=bool)
            if self.variant == "sampled":
                u, conv = self._usv_sampled(o)
                self.last_converged = conv
        return u, singular

    def flocking_law(self, o: Array) -> tuple[Array, NDArray[np.bool_]]:
        """``u*_b = m_b [g (e_x - r_bx) - k_b s phi_b/s^2] / (e_x - e_z)`` from observations ``(n, d)``."""
        nf = self.act_dim
        rx = o[:, 0:2 * nf:2]
        ex = o[:, 2 * nf]
        ez = o[:, 2 * nf + 1]
        s = np.exp(FLOCKING_LOG_SPEED_SCALE * o[:, 2 * nf + 2])
        p = o[:, 2 * nf + 3: 3 * nf + 3]
        den = ex - ez
        singular_row = ~(np.abs(den) > self.singular_tol)  # also NaN
        safe = np.where(singular_row, 1.0, den)
        u = self.masses * (self.g * (ex[:, None] - rx) - self.gain * s[:, None] * p) / safe[:, None]
        u[singular_row] = 0.0
        return u, singular_row

    def usv_law(self, o: Array) -> Array:
        """``u* = -m [k phi + thetad (xd cos + yd sin)]`` from observations ``(n, 14)``."""
        c, s = o[:, 0], o[:, 1]
        xd, yd = USV_VEL_SCALE * o[:, 2], USV_VEL_SCALE * o[:, 3]
        thd = USV_RATE_SCALE * o[:, 4]
        phi = USV_VEL_SCALE * o[:, 9]
        return (-self.mass * (self.gain[0] * phi + thd * (xd * c + yd * s)))[:, None]

    # ------------------------------------------------------------------ sampled-data variant
    def flocking_state(self, o: Array) -> tuple[Array, Array]:
        """States (positions 0) and the observed ``phi`` rebuilt from flocking observations."""
        nf = self.act_dim
        n = nf + 1
        s = np.exp(FLOCKING_LOG_SPEED_SCALE * o[:, 2 * nf + 2])
        st = np.zeros((o.shape[0], 4 * n))
        st[:, 2 * n: 2 * n + nf] = s[:, None] * o[:, 0:2 * nf:2]
        st[:, 3 * n: 3 * n + nf] = s[:, None] * o[:, 1:2 * nf:2]
        st[:, 3 * n - 1] = s * o[:, 2 * nf]
        st[:, 4 * n - 1] = s * o[:, 2 * nf + 1]
        phi = (s * s)[:, None] * o[:, 2 * nf + 3: 3 * nf + 3]
        return st, phi

    def usv_state(self, o: Array) -> tuple[Array, Array, Array]:
        """States, affine-current parameters (for ``make_usv("affine")``) and observed ``phi``."""
        d = self.spec.domain
        x0, y0 = o[:, 7] * d, o[:, 8] * d
        th = np.arctan2(o[:, 1], o[:, 0])
        st = np.stack([x0, y0, th, USV_VEL_SCALE * o[:, 2], USV_VEL_SCALE * o[:, 3], USV_RATE_SCALE * o[:, 4]], axis=1)
        c1, c2 = USV_VEL_SCALE * o[:, 5], USV_VEL_SCALE * o[:, 6]
        j11, j12, j21, j22 = o[:, 10], o[:, 11], o[:, 12], o[:, 13]
        assert self.model is not None
        p = np.tile(self.model.default_params, (o.shape[0], 1))
        idx = self._usv_idx
        p[:, idx["m"]] = self.mass
        p[:, idx["I"]] = self.inertia
        p[:, idx["current_scale"]] = 1.0  # the observed current already includes the nominal scale
        p[:, idx["c_c1"]] = c1 - (j11 * x0 + j12 * y0)
        p[:, idx["c_c2"]] = c2 - (j21 * x0 + j22 * y0)
        p[:, idx["c_j11"]] = j11
        p[:, idx["c_j12"]] = j12
        p[:, idx["c_j21"]] = j21
        p[:, idx["c_j22"]] = j22
        phi = (USV_VEL_SCALE * o[:, 9])[:, None]
        return st, p, phi

    def _flocking_sampled(self, o: Array, u_plain: Array) -> tuple[Array, NDArray[np.bool_]]:
        assert self.model is not None
        st, phi = self.flocking_state(o)
        u, conv = sampled_control(self.model, st, self.spec.nominal, self.spec.dt, self.gain, self.spec.substeps,
                                  self.iters, phi_now=phi)
        assert isinstance(conv, np.ndarray)
        return np.where(np.isfinite(u), u, u_plain), conv

    def _usv_sampled(self, o: Array) -> tuple[Array, NDArray[np.bool_]]:
        assert self.model is not None
        st, p, phi = self.usv_state(o)
        u, conv = sampled_control(self.model, st, p, self.spec.dt, self.gain, self.spec.substeps, self.iters,
                                  phi_now=phi)
        assert isinstance(conv, np.ndarray)
        return u, conv

    # ------------------------------------------------------------------ policy
    def _act(self, o: Array) -> Array:
        u, singular = self.force(o)
        a = u / self.force_bound
        bad = ~np.isfinite(a)
        if bad.any():  # cannot happen for finite observations; keep the contract anyway
            a[bad] = 0.0
            singular = singular | bad.any(axis=1)
        saturated = np.any(np.abs(a) > 1.0, axis=1)
        self.last_singular = singular
        self.last_saturated = saturated
        self.n_singular += int(singular.sum())
        self.n_saturated += int(saturated.sum())
        self.n_rows += a.shape[0]
        return np.clip(a, -1.0, 1.0)


class ZeroPolicy(_Policy):
    """Always action 0 (no force): the uncontrolled reference."""

    def __init__(self, env: Any = None, *, obs_dim: int | None = None, act_dim: int | None = None) -> None:
        self._set_dims(env, obs_dim, act_dim)
        self.name = "zero"

    def _act(self, o: Array) -> Array:
        return np.zeros((o.shape[0], self.act_dim))

    def __repr__(self) -> str:
        return "ZeroPolicy()"


class RandomPolicy(_Policy):
    """Uniform random actions in ``[-1, 1]`` from its own seeded generator."""

    def __init__(self, env: Any = None, seed: int | None = 0, *, obs_dim: int | None = None,
                 act_dim: int | None = None) -> None:
        self._set_dims(env, obs_dim, act_dim)
        self.seed = seed
        self.name = "random"
        self.rng = np.random.default_rng(seed)

    def _act(self, o: Array) -> Array:
        return self.rng.uniform(-1.0, 1.0, size=(o.shape[0], self.act_dim))

    def __repr__(self) -> str:
        return f"RandomPolicy(seed={self.seed})"

