"""The step and reset kernels of one task: its system's RK4 and ``phi``, its hooks, the episode rows.

This file is the template of every task's generated kernel module: :mod:`vnhc_gym.envs.runtime`
copies its text with the import between the ``bindings`` markers replaced by the imports of one
compiled system module and one task module.  Imported as it is, it runs the placeholder system
(:mod:`vnhc_gym.mechanics._template`) with the placeholder task (:mod:`vnhc_gym.envs._placeholder`).

Why a generated module: numba compiles a kernel together with the functions it calls, but cannot
cache a kernel that receives them as arguments; importing them by name gives one cached kernel
per task, with no Python between the physics and the observation.
"""

from numba import njit

from vnhc_gym.envs.episode import finish_rows, kick_row, start_row
from vnhc_gym.mechanics.kernels import FLAG_NONFINITE

# isort: split
# --- bindings: begin
from vnhc_gym.envs._placeholder import DRAW_STAGES, draw, observe
from vnhc_gym.mechanics._template import N, _aux, _phi, rk4_held_row, rk4_row, work

# --- bindings: end
# isort: split


@njit(cache=True)
def step(rows, buf, cfg, args):
    """One control period of the episodes ``rows`` with the forces in ``buf.force`` alone (the
    ``OPEN`` mode; :func:`step_feedback` runs the law too).

    Per row: the velocity impulse (if any), RK4 into ``buf.next_state``, the impulse added, the new
    state accepted if finite (a row whose state became non-finite keeps its last finite state),
    ``phi`` with the true parameters, the extra outputs with the nominal ones and the task's
    ``observe``; then, over all rows, reward and bookkeeping (:func:`~vnhc_gym.envs.episode.finish_rows`).
    """
    w = work()
    kicks = cfg.impulse_prob > 0
    for i in range(rows.shape[0]):
        r = rows[i]
        if kicks:
            kick_row(r, buf, cfg)
        flag = rk4_held_row(buf.state[r], buf.params_true[r], buf.force[r], cfg.lo, cfg.hi, cfg.dt, cfg.substeps,
                            buf.next_state[r], buf.force_applied[r], w)
        buf.flags[r] = flag
        if kicks:
            for j in range(N):
                buf.next_state[r, N + j] += buf.kick[r, j]
        if not flag & FLAG_NONFINITE:
            for j in range(2 * N):
                buf.state[r, j] = buf.next_state[r, j]
        _phi(buf.state[r], buf.params_true[r], buf.phi[r])
        _aux(buf.state[r], buf.params_nominal[r], buf.aux[r])
        observe(r, buf, cfg, args)
    finish_rows(rows, buf, cfg)


@njit(cache=True)
def step_feedback(rows, buf, cfg, args):
    """:func:`step` with the geometric law inside the integrator (``cfg.mode`` ``CONTINUOUS`` or
    ``SAMPLED``, see ``rk4_row``).  A kernel of its own, so that environments that never run the
    law in the loop never compile it.  (The rows' bookkeeping after RK4 is written out in both
    kernels: a shared function inlined by numba reference-counts the bundles per row, 25 % slower.)"""
    w = work()
    kicks = cfg.impulse_prob > 0
    for i in range(rows.shape[0]):
        r = rows[i]
        if kicks:
            kick_row(r, buf, cfg)
        flag = rk4_row(buf.state[r], buf.params_true[r], buf.params_nominal[r], buf.force[r], cfg.gains, cfg.mode,
                       cfg.lo, cfg.hi, cfg.dt, cfg.substeps, cfg.singular_tol, buf.next_state[r], buf.force_applied[r],
                       w)
        buf.flags[r] = flag
        if kicks:
            for j in range(N):
                buf.next_state[r, N + j] += buf.kick[r, j]
        if not flag & FLAG_NONFINITE:
            for j in range(2 * N):
                buf.state[r, j] = buf.next_state[r, j]
        _phi(buf.state[r], buf.params_true[r], buf.phi[r])
        _aux(buf.state[r], buf.params_nominal[r], buf.aux[r])
        observe(r, buf, cfg, args)
    finish_rows(rows, buf, cfg)


@njit(cache=True)
def reset(rows, buf, cfg, args):
    """New episodes in ``rows``, each drawn from its own stream by the task's ``draw`` (stage ``k > 0``
    sees the true model's extra outputs at the state drawn so far), then ``phi``, the extra outputs,
    the task's ``observe`` and the start bookkeeping (:func:`~vnhc_gym.envs.episode.start_row`)."""
    for i in range(rows.shape[0]):
        r = rows[i]
        for stage in range(DRAW_STAGES):
            if stage > 0:
                _aux(buf.state[r], buf.params_true[r], buf.aux[r])
            draw(r, stage, buf, cfg, args)
        buf.flags[r] = 0
        _phi(buf.state[r], buf.params_true[r], buf.phi[r])
        _aux(buf.state[r], buf.params_nominal[r], buf.aux[r])
        observe(r, buf, cfg, args)
        start_row(r, buf, cfg)
