"""The step and reset kernels of one task: its system's RK4 and ``phi``, its hooks, the episode rows.

This file is the template of every task's generated kernel module: `vnhc_gym.envs.runtime`
copies its text with the import between the ``bindings`` markers replaced by the imports of one
compiled system module and one task module.  Imported as it is, it runs the placeholder system
(`vnhc_gym.mechanics._system_template`) with the placeholder task (`vnhc_gym.envs._placeholder_task`).

Why a generated module: numba compiles a kernel together with the functions it calls, but cannot
cache a kernel that receives them as arguments; importing them by name gives one cached kernel
per task, with no Python between the physics and the observation.
"""

from numba import njit

from vnhc_gym.envs.episode import STATUS_NONFINITE, STATUS_OK, finish_rows, kick_row, start_row
from vnhc_gym.mechanics.numerics import FLAG_NONFINITE, SINCOS_MAX_ARG
from vnhc_gym.rng import draw_mismatch

# isort: split
# --- bindings: begin
from vnhc_gym.envs._placeholder_task import draw, observe
from vnhc_gym.mechanics._system_template import N, _aux, _phi, rk4_held_row, rk4_row, work

DRAW_STAGES = 1
MISMATCH_STAGE = 0
# --- bindings: end
# isort: split


@njit(cache=True, inline="always")
def _observe(r, buf, cfg, args):
    """Row ``r``'s observation, status and scale-free ``phi``: the work common to every task around
    the task's own ``observe``.

    ``phi_sf`` starts as ``phi / phi_sf_scale`` (the task may overwrite it); the task writes its
    observation and returns 0 or one of its termination codes; the status is then, in this order,
    ``STATUS_NONFINITE`` for a non-finite state (whatever the task says), the task's code, the code
    of the first state bound exceeded (``Task.limits``), or ``STATUS_NONFINITE`` for an angle beyond
    the inline sine's range (the run blew up); the observation is clipped last.
    """
    phi = buf.phi[r]
    sf = buf.phi_sf[r]
    for b in range(phi.shape[0]):
        sf[b] = phi[b] / cfg.phi_sf_scale
    state = buf.state[r]
    code = observe(state, phi, buf.aux[r], args, buf.obs[r], sf)
    if buf.flags[r] & FLAG_NONFINITE:
        status = STATUS_NONFINITE
    elif code != 0:
        status = STATUS_NONFINITE + code
    else:
        status = STATUS_OK
        for i in range(cfg.limit_index.shape[0]):
            if status == STATUS_OK and abs(state[cfg.limit_index[i]]) > cfg.limit_bound[i]:
                status = STATUS_NONFINITE + cfg.limit_code[i]
        if status == STATUS_OK:
            for j in cfg.angles:
                if not abs(state[j]) <= SINCOS_MAX_ARG:
                    status = STATUS_NONFINITE
    buf.status[r] = status
    obs = buf.obs[r]
    clip = cfg.obs_clip
    for j in range(obs.shape[0]):
        obs[j] = min(max(obs[j], -clip), clip)


@njit(cache=True)
def step(rows, buf, cfg, args):
    """One control period of the episodes ``rows`` with the forces in ``buf.force`` alone (the
    ``OPEN`` mode; `step_feedback` runs the law too).

    Per row: the velocity impulse (if any), RK4 into ``buf.next_state``, the impulse added, the new
    state accepted if finite (a row whose state became non-finite keeps its last finite state),
    ``phi`` with the true parameters, the extra outputs with the nominal ones and the task's
    ``observe``; then, over all rows, reward and bookkeeping (`vnhc_gym.envs.episode.finish_rows`).
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
        # The common work around the task's observe (as in _observe), written out here: a shared
        # function takes the bundles, and numba reference-counts every array of both per row (the
        # flock's 256-row step ran at half the speed).
        for b in range(buf.phi.shape[1]):
            buf.phi_sf[r, b] = buf.phi[r, b] / cfg.phi_sf_scale
        code = observe(buf.state[r], buf.phi[r], buf.aux[r], args, buf.obs[r], buf.phi_sf[r])
        if buf.flags[r] & FLAG_NONFINITE:
            status = STATUS_NONFINITE
        elif code != 0:
            status = STATUS_NONFINITE + code
        else:
            status = STATUS_OK
            for k in range(cfg.limit_index.shape[0]):
                if status == STATUS_OK and abs(buf.state[r, cfg.limit_index[k]]) > cfg.limit_bound[k]:
                    status = STATUS_NONFINITE + cfg.limit_code[k]
            if status == STATUS_OK:
                for k in range(cfg.angles.shape[0]):
                    if not abs(buf.state[r, cfg.angles[k]]) <= SINCOS_MAX_ARG:
                        status = STATUS_NONFINITE
        buf.status[r] = status
        for j in range(buf.obs.shape[1]):
            buf.obs[r, j] = min(max(buf.obs[r, j], -cfg.obs_clip), cfg.obs_clip)
    finish_rows(rows, buf, cfg)


@njit(cache=True)
def step_feedback(rows, buf, cfg, args):
    """`step` with the geometric law inside the integrator (``cfg.mode`` ``CONTINUOUS`` or
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
        # The common work around the task's observe (as in _observe), written out here: a shared
        # function takes the bundles, and numba reference-counts every array of both per row (the
        # flock's 256-row step ran at half the speed).
        for b in range(buf.phi.shape[1]):
            buf.phi_sf[r, b] = buf.phi[r, b] / cfg.phi_sf_scale
        code = observe(buf.state[r], buf.phi[r], buf.aux[r], args, buf.obs[r], buf.phi_sf[r])
        if buf.flags[r] & FLAG_NONFINITE:
            status = STATUS_NONFINITE
        elif code != 0:
            status = STATUS_NONFINITE + code
        else:
            status = STATUS_OK
            for k in range(cfg.limit_index.shape[0]):
                if status == STATUS_OK and abs(buf.state[r, cfg.limit_index[k]]) > cfg.limit_bound[k]:
                    status = STATUS_NONFINITE + cfg.limit_code[k]
            if status == STATUS_OK:
                for k in range(cfg.angles.shape[0]):
                    if not abs(buf.state[r, cfg.angles[k]]) <= SINCOS_MAX_ARG:
                        status = STATUS_NONFINITE
        buf.status[r] = status
        for j in range(buf.obs.shape[1]):
            buf.obs[r, j] = min(max(buf.obs[r, j], -cfg.obs_clip), cfg.obs_clip)
    finish_rows(rows, buf, cfg)


@njit(cache=True)
def reset(rows, buf, cfg, args):
    """New episodes in ``rows``, each drawn from its own stream: the nominal parameters, then the
    task's ``draw`` stage by stage (stage ``k > 0`` sees the true model's extra outputs at the state
    drawn so far), with the true parameters (the mismatch) drawn just before stage ``MISMATCH_STAGE``;
    then ``phi``, the extra outputs, the observation and the start bookkeeping
    (`vnhc_gym.envs.episode.start_row`)."""
    for i in range(rows.shape[0]):
        r = rows[i]
        nominal = buf.params_nominal[r]
        for j in range(nominal.shape[0]):
            nominal[j] = cfg.nominal[j]
        for stage in range(DRAW_STAGES):
            if stage == MISMATCH_STAGE:
                draw_mismatch(buf.rng, r, nominal, cfg.mismatch_mask, cfg.mismatch, buf.params_true[r])
            if stage > 0:
                _aux(buf.state[r], buf.params_true[r], buf.aux[r])
            draw(buf.rng, r, stage, buf.state[r], nominal, buf.aux[r], args)
        if MISMATCH_STAGE >= DRAW_STAGES:
            draw_mismatch(buf.rng, r, nominal, cfg.mismatch_mask, cfg.mismatch, buf.params_true[r])
        buf.flags[r] = 0
        _phi(buf.state[r], buf.params_true[r], buf.phi[r])
        _aux(buf.state[r], buf.params_nominal[r], buf.aux[r])
        _observe(r, buf, cfg, args)
        start_row(r, buf, cfg)
