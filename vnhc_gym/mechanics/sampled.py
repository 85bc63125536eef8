"""A sampled-data (zero-order hold) version of the stabilising law.

The law of Theorem 2 makes ``d phi/dt = -K phi`` when it is re-evaluated continuously.  An
RL environment (and any digital controller) instead holds one control value over a control
period ``dt``; held, ``u*`` no longer gives ``phi(t + dt) = exp(-K dt) phi(t)`` because the
drift changes inside the period, and ``phi`` levels off at a small but nonzero value (see
the docs' math page, "the sampled-data fact").

[`sampled_control`][vnhc_gym.mechanics.sampled_control] chooses the held control so that the
*discrete* closed loop is the exact discretisation of the continuous one,

.. math::

    \\phi\\big(F_{dt}(x, u)\\big) = e^{-K\\,dt}\\,\\phi(x),

where ``F_dt`` is the RK4 step map of the model over one control period (open loop, ``u``
held; the same map an environment integrates with).  The ``m`` equations in ``m`` unknowns are
solved by Newton's method, started from ``u*``, with a central finite-difference Jacobian;
every candidate control and its ``2m`` perturbations of every batch row are integrated in one
batched call of the model's RK4 step.  For the flocking system the equation is
affine in ``u`` (the held motion is a polynomial of degree two in time, which RK4 integrates
exactly), so a single Newton step solves it to rounding error.

Nothing here imports Gymnasium.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from vnhc_gym.mechanics.model import FLAG_NONFINITE, ConstrainedSystem

__all__ = ["sampled_control"]

Array = NDArray[np.float64]


def sampled_control(model: ConstrainedSystem, states: ArrayLike, params: ArrayLike | None, dt: float,
                    gains: ArrayLike | None = 1.0, substeps: int = 1, iters: int = 4, *,
                    phi_now: ArrayLike | None = None, fd_step: float = 1e-4, xtol: float = 1e-10,
                    ) -> tuple[Array, NDArray[np.bool_] | bool]:
    """Held control that makes ``phi`` after one control period equal ``exp(-K dt) phi_now``.

    Parameters
    ----------
    model : ConstrainedSystem
        A system with a *velocity* constraint (holonomic constraints are not supported).
    states : array_like, shape (2n,) or (B, 2n)
        Finite.
    params : array_like or None
        Model parameters, ``(n_params,)`` or ``(B, n_params)`` (``None``: defaults); finite, and
        > 0 where declared positive (``model.param_positive``).
    dt : float
        Control period over which the control is held (> 0).
    gains : scalar or array_like, default 1
        ``diag K`` (``m`` values, or a scalar), each >= 0.
    substeps : int, default 1
        RK4 steps per control period (use the environment's value).
    iters : int, default 4
        Largest number of Newton updates.
    phi_now : array_like, optional, shape (m,) or (B, m)
        A measured value of ``phi`` at ``states``.  The target is then ``exp(-K dt) phi_now``
        and the model is used for the *increment*: the equation solved is
        ``phi(F(x, u)) - phi(x) = (exp(-K dt) - 1) phi_now``, so a bias between the model's
        ``phi(x)`` and the measurement (a state rebuilt from rounded observations, a local
        model of a current) cancels.  Default: ``phi(states)`` (then both forms coincide).
    fd_step : float, default 1e-4
        Relative step ``h = fd_step * max(1, |u_a|)`` of the central differences.
    xtol : float, default 1e-10
        A row has converged when its residual is exactly zero or its last Newton step is at
        most ``xtol * max(1, |u|)`` in every component.

    Returns
    -------
    (u, converged)
        ``u`` of shape ``(m,)`` or ``(B, m)``; ``converged`` a bool or ``(B,)`` bool array.
        Where Newton fails (singular Jacobian, non-finite values, a singular ``C`` at the
        start, or no convergence within ``iters``) ``converged`` is False; ``u`` is then the
        last finite iterate (at worst ``u*``, or 0 where ``C`` is singular).
        No saturation is applied: clip ``u`` to the actuator bounds yourself.

    Raises
    ------
    ValueError
        If a parameter, a state or ``phi_now`` is not finite (or a parameter declared positive is
        not > 0); the message names the row and the entry.
    """
    if model.holonomic:
        raise ValueError("sampled_control supports velocity constraints only (the model's constraint is holonomic)")
    if not (np.isfinite(dt) and dt > 0):
        raise ValueError(f"dt must be a finite number > 0, got {dt}")
    if int(substeps) != substeps or substeps < 1:
        raise ValueError(f"substeps must be an integer >= 1, got {substeps}")
    if int(iters) != iters or iters < 0:
        raise ValueError(f"iters must be an integer >= 0, got {iters}")
    if not (np.isfinite(fd_step) and fd_step > 0):
        raise ValueError(f"fd_step must be a finite number > 0, got {fd_step}")
    s, single = model._states(states)
    b, m = s.shape[0], model.m
    p = model._params(params, b)
    k = model._gains(gains, b)
    model._law_states(s, single)

    # Start: the continuous-time law at the start of the period.
    u, singular = model.control(s, k, p, on_singular="flag")
    u = np.array(u)
    ok = ~np.asarray(singular)
    phi0 = model.phi(s, p)
    if phi_now is None:
        measured = phi0
    else:
        given = np.asarray(phi_now, dtype=np.float64)
        measured = np.ascontiguousarray(np.broadcast_to(given.reshape(1, -1) if given.ndim == 1 else given, (b, m)))
        if not np.all(np.isfinite(measured)):
            row = int(np.argwhere(~np.isfinite(measured))[0][0])
            where = f"phi_now row {row}" if given.ndim == 2 else "phi_now"
            raise ValueError(f"{where} = {measured[row].tolist()}: expected finite values")
    # Residual r(u) = phi(F(x, u)) - phi(x) - (exp(-K dt) - 1) phi_now.
    offset = phi0 + np.expm1(-k * dt) * measured

    # One kernel call per Newton iteration: rows [u, u + h e_a, u - h e_a] for every batch row.
    w = 1 + 2 * m
    big_s = np.ascontiguousarray(np.repeat(s, w, axis=0))
    big_p = np.ascontiguousarray(np.repeat(p, w, axis=0))
    big_k = np.zeros((b * w, model.n_gains))
    big_u = np.empty((b * w, m))
    lo, hi = np.full(m, -np.inf), np.full(m, np.inf)
    eye = np.eye(m)

    active = ok.copy()
    converged = np.zeros(b, dtype=bool)
    for it in range(iters + 1):
        if not active.any():
            break
        h = fd_step * np.maximum(1.0, np.abs(u))  # (b, m)
        cand = big_u.reshape(b, w, m)
        cand[:] = u[:, None, :]
        cand[:, 1:1 + m, :] += h[:, None, :] * eye[None]
        cand[:, 1 + m:, :] -= h[:, None, :] * eye[None]
        out, _, big_flags = model._advance(big_s, big_p, big_u, big_k, float(dt), int(substeps), "open", lo, hi)
        big_phi = model._run(("phi",), lambda: model.functions.phi, (out, big_p))
        ph = big_phi.reshape(b, w, m)
        bad = ((big_flags.reshape(b, w) & FLAG_NONFINITE) != 0).any(axis=1) | ~np.isfinite(ph).all(axis=(1, 2))
        active &= ~bad
        r = ph[:, 0, :] - offset
        zero = np.all(r == 0.0, axis=1)
        converged |= active & zero
        active &= ~zero
        if it == iters or not active.any():
            break
        # J[row, c, a] = d phi_c / d u_a
        jac = (ph[:, 1:1 + m, :] - ph[:, 1 + m:, :]).transpose(0, 2, 1) / (2.0 * h[:, None, :])
        rows = np.flatnonzero(active)
        du = _solve(jac[rows], r[rows])
        good = np.isfinite(du).all(axis=1)
        rows_bad = rows[~good]
        active[rows_bad] = False
        rows, du = rows[good], du[good]
        u[rows] -= du
        small = np.all(np.abs(du) <= xtol * np.maximum(1.0, np.abs(u[rows])), axis=1)
        converged[rows[small]] = True
        active[rows[small]] = False
    if single:
        return u[0], bool(converged[0])
    return u, converged


def _solve(a: Array, rhs: Array) -> Array:
    """Batched ``a x = rhs``; rows with a singular ``a`` get NaN."""
    if a.shape[1] == 1:
        with np.errstate(divide="ignore", invalid="ignore"):
            x = rhs / a[:, :, 0]
        return np.asarray(np.where(a[:, :, 0] != 0.0, x, np.nan), dtype=np.float64)
    try:
        return np.asarray(np.linalg.solve(a, rhs[..., None])[..., 0], dtype=np.float64)
    except np.linalg.LinAlgError:
        x = np.full_like(rhs, np.nan)
        for i in range(a.shape[0]):
            try:
                x[i] = np.linalg.solve(a[i], rhs[i])
            except np.linalg.LinAlgError:
                pass
        return x
