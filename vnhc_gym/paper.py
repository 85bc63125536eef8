"""Reproduce the figures of the paper's Section IV (``vnhc-gym reproduce --out DIR``).

Every run uses the paper's parameters, initial states, step (``dt = 0.01``) and durations
(flocking 500 s, USV 100 s) from `vnhc_gym.systems.FLOCKING_PRESETS` and
`vnhc_gym.systems.USV_PRESETS`, with the stabilising law re-evaluated at every RK4 stage
(``feedback="continuous"``, the theorem's setting).  Figures written:

==================================  =====================================================
file                                content
==================================  =====================================================
``flocking_trajectories.png``       the 4 particles in the xz-plane, black start points
``flocking_phi3d.png``              the curve ``(phi1, phi2, phi3)(t)``
``usv_<current>_trajectory.png``    the boat in the xy-plane over the current, start point
``usv_<current>_phi.png``           ``phi(t)`` (linear and log scale)
``usv_<current>_energy.png``        kinetic energy ``E(t)``
``usv_printed_law_failure.png``     ``|phi(t)|`` under the paper's printed law vs the derived one
==================================  =====================================================

for ``<current>`` in ``northeast`` and ``anticyclone``.  ``--quick`` shortens every simulation
to 2 % of its duration (for tests).
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure
from numpy.typing import NDArray

from vnhc_gym.mechanics import ConstrainedSystem, simulate
from vnhc_gym.systems import CURRENTS, FLOCKING_PRESETS, USV_OUTPUTS, USV_PRESETS, make_flocking, make_usv

__all__ = ["add_arguments", "run", "main", "reproduce", "FIGURES", "off_manifold_state"]

Array = NDArray[np.float64]

QUICK_FRACTION = 0.02  #: share of every duration simulated with ``quick=True``
MAX_RECORDS = 5000  #: states kept per run (``record_every`` is chosen from it)
PRINTED_LAW_DURATION = 20.0  #: seconds simulated for the printed-law comparison
PRINTED_LAW_OFFSET = 0.3  #: sideways velocity offset added to the paper's start (the docs' errata: the USV law)
USV_CASES = ("paper-northeast", "paper-anticyclone")

#: Every file `reproduce` writes, in order.
FIGURES: tuple[str, ...] = (
    "flocking_trajectories.png",
    "flocking_phi3d.png",
    *(f"usv_{USV_PRESETS[c].current}_{kind}.png" for c in USV_CASES for kind in ("trajectory", "phi", "energy")),
    "usv_printed_law_failure.png",
)

_AGENT_COLOURS = ("tab:blue", "tab:orange", "tab:green", "tab:red")


def _n_steps(duration: float, dt: float, quick: bool) -> int:
    n = round(duration / dt)
    return max(1, round(n * QUICK_FRACTION)) if quick else n


def _save(fig: Figure, path: Path, quick: bool) -> Path:
    fig.savefig(path, dpi=60 if quick else 130)  # quick runs are smoke tests: low resolution renders faster
    return path


# ---------------------------------------------------------------------------------------------- flocking


def _flocking(out: Path, quick: bool) -> list[Path]:
    preset = FLOCKING_PRESETS["paper"]
    model = make_flocking(preset.n_agents)
    n = _n_steps(preset.duration, preset.dt, quick)
    tr = simulate(model, preset.state(), preset.dt, n, feedback="continuous", gains=preset.gain,
                  params=preset.params(), record_every=max(1, n // MAX_RECORDS))
    na = preset.n_agents
    xs, zs = tr.states[:, :na], tr.states[:, na:2 * na]

    fig = Figure(figsize=(8.0, 6.0), layout="constrained")
    ax = fig.add_subplot()
    early = tr.t <= min(20.0, tr.t[-1])  # the alignment transient, shown in an inset
    inset = ax.inset_axes((0.07, 0.07, 0.42, 0.42))
    for target, sel in ((ax, slice(None)), (inset, early)):
        for i in range(na):
            leader = i == na - 1
            role = "leader, uncontrolled" if leader else "controlled"
            target.plot(xs[sel, i], zs[sel, i], color=_AGENT_COLOURS[i % 4], lw=1.2 if leader else 1.6,
                        ls="--" if leader else "-", zorder=3 if leader else 2, label=f"particle {i + 1} ({role})")
        target.scatter(xs[0], zs[0], color="black", s=28, zorder=4, label="initial positions")
        target.grid(alpha=0.3)
    inset.set_title(f"first {tr.t[early][-1]:g} s", fontsize=9)
    inset.tick_params(labelsize=8)
    ax.set_xlabel("x [m]")
    ax.set_ylabel("z [m]")
    ax.set_title(f"Flocking: trajectories of the 4 particles in the xz-plane\n"
                 f"{tr.t[-1]:g} s, dt = {preset.dt:g} s, m_i = {preset.masses[0]:g}, g = {preset.g:g}, K = I")
    ax.legend(loc="upper right", fontsize=9)
    paths = [_save(fig, out / "flocking_trajectories.png", quick)]

    fig = Figure(figsize=(6.5, 6.0), layout="constrained")
    ax3 = fig.add_subplot(projection="3d")
    phi = tr.phi
    ax3.plot(phi[:, 0], phi[:, 1], phi[:, 2], color="tab:blue", lw=1.4, label=r"$\Phi(t)$")
    ax3.scatter(*phi[0], color="black", s=28, label=r"$\Phi(0)$")
    marks = [np.searchsorted(tr.t, tk) for tk in range(1, 6) if tk <= tr.t[-1]]
    if marks:
        ax3.scatter(*phi[marks].T, color="tab:blue", s=14, label=f"t = 1, ..., {len(marks)} s")
    ax3.scatter(0, 0, 0, color="tab:red", marker="x", s=40, label="manifold $\\Phi = 0$")
    ax3.set_xlabel(r"$\phi^1$ [m$^2$/s$^2$]")
    ax3.set_ylabel(r"$\phi^2$ [m$^2$/s$^2$]")
    ax3.set_zlabel(r"$\phi^3$ [m$^2$/s$^2$]")
    ax3.set_title(r"Flocking: constraint values $\Phi = (\phi^1, \phi^2, \phi^3)$"
                  f"\n|Φ| = {np.linalg.norm(phi[0]):.3g} → {np.linalg.norm(phi[-1]):.2g} at t = {tr.t[-1]:g} s")
    ax3.legend(loc="upper left", fontsize=9)
    paths.append(_save(fig, out / "flocking_phi3d.png", quick))
    return paths


# ---------------------------------------------------------------------------------------------- USV


def _current_background(ax, model: ConstrainedSystem, params: Array, xlim: tuple[float, float],
                        ylim: tuple[float, float]) -> None:
    """Quiver of the current field (from the compiled outputs, so current_scale is honoured)."""
    gx, gy = np.meshgrid(np.linspace(*xlim, 17), np.linspace(*ylim, 17))
    grid = np.zeros((gx.size, 2 * model.n))
    grid[:, 0], grid[:, 1] = gx.ravel(), gy.ravel()
    cur = model.outputs(grid, params)
    c1 = cur[:, USV_OUTPUTS.index("C1")].reshape(gx.shape)
    c2 = cur[:, USV_OUTPUTS.index("C2")].reshape(gx.shape)
    ax.quiver(gx, gy, c1, c2, color="0.6", alpha=0.7, width=0.0025, label="current C(x, y)")


def _padded(lo: float, hi: float) -> tuple[float, float]:
    pad = max(0.08 * (hi - lo), 0.5)
    return lo - pad, hi + pad


def _usv(out: Path, case: str, quick: bool) -> list[Path]:
    preset = USV_PRESETS[case]
    model = make_usv(preset.current)
    params = preset.params()
    n = _n_steps(preset.duration, preset.dt, quick)
    tr = simulate(model, preset.state(), preset.dt, n, feedback="continuous", gains=preset.gain, params=params,
                  record_every=max(1, n // MAX_RECORDS))
    name = preset.current
    label = {"northeast": "north-east current C = (1, 1)",
             "anticyclone": "anticyclone C = (y, -x + y)"}.get(name, CURRENTS[name].description)
    setting = f"m = {preset.m:g}, I = {preset.inertia:g}, dt = {preset.dt:g} s, k = {preset.gain:g}"
    x, y = tr.states[:, 0], tr.states[:, 1]
    paths = []

    fig = Figure(figsize=(7.0, 6.0), layout="constrained")
    ax = fig.add_subplot()
    xlim, ylim = _padded(x.min(), x.max()), _padded(y.min(), y.max())
    _current_background(ax, model, params, xlim, ylim)
    ax.plot(x, y, color="tab:blue", lw=1.5, label="boat (closed loop)")
    ax.scatter(x[:1], y[:1], color="black", s=36, zorder=3, label="initial position")
    ax.set_xlim(*xlim)
    ax.set_ylim(*ylim)
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(f"USV, {label}: trajectory in the xy-plane\n{setting}, {tr.t[-1]:g} s")
    ax.grid(alpha=0.3)
    ax.legend(loc="best", fontsize=9)
    paths.append(_save(fig, out / f"usv_{name}_trajectory.png", quick))

    fig = Figure(figsize=(10.0, 4.2), layout="constrained")
    ax1, ax2 = fig.subplots(1, 2)
    phi = tr.phi[:, 0]
    ax1.plot(tr.t, phi, color="tab:blue", lw=1.5)
    ax1.axhline(0.0, color="0.4", lw=0.8, ls="--")
    ax1.set_xlabel("t [s]")
    ax1.set_ylabel(r"$\phi$ [m/s]")
    ax1.set_title(r"Constraint $\phi(t)$")
    ax1.grid(alpha=0.3)
    floor = 1e-17  # below double-precision rounding of O(1) velocities: nothing to see
    nonzero = np.abs(phi) > floor
    ax2.semilogy(tr.t[nonzero], np.abs(phi[nonzero]), color="tab:blue", lw=1.5, label=r"$|\phi(t)|$")
    if abs(phi[0]) > 1e-12:
        ref = abs(phi[0]) * np.exp(-preset.gain * tr.t)
        ax2.semilogy(tr.t[ref > floor], ref[ref > floor], color="tab:red", ls="--", lw=1.0,
                     label=r"$|\phi(0)|\,e^{-kt}$")
    else:
        ax2.text(0.03, 0.97, f"starts on the manifold (|φ(0)| = {abs(phi[0]):.0e}):\nφ stays at rounding level",
                 ha="left", va="top", transform=ax2.transAxes, fontsize=9,
                 bbox={"facecolor": "white", "edgecolor": "0.7", "alpha": 0.9})
    ax2.set_ylim(bottom=floor)
    ax2.legend(loc="upper right", fontsize=9)
    ax2.set_xlabel("t [s]")
    ax2.set_ylabel(r"$|\phi|$ [m/s]")
    ax2.set_title(r"$|\phi(t)|$, log scale")
    ax2.grid(alpha=0.3, which="both")
    fig.suptitle(f"USV, {label}: constraint ({setting})")
    paths.append(_save(fig, out / f"usv_{name}_phi.png", quick))

    fig = Figure(figsize=(7.0, 4.2), layout="constrained")
    ax = fig.add_subplot()
    ax.plot(tr.t, tr.energy, color="tab:purple", lw=1.5)
    ax.set_xlabel("t [s]")
    ax.set_ylabel("E [J]")
    ax.set_title(f"USV, {label}: kinetic energy\n"
                 r"$E = \frac{m}{2}(\dot x^2 + \dot y^2) + \frac{I}{2}\dot\theta^2$" f"  ({setting})")
    ax.grid(alpha=0.3)
    paths.append(_save(fig, out / f"usv_{name}_energy.png", quick))
    return paths


# ---------------------------------------------------------------------------------------------- the erratum


def _printed_usv_law(model: ConstrainedSystem, state: Array, params: Array) -> Array:
    """The USV control law exactly as printed in the paper's Section IV-B -- which is WRONG.

    This is the paper's erratum reproduced on purpose (the docs' errata: the USV law), only to show
    that it does not stabilise the constraint.  Never use it as a controller: the correct law is
    ``model.control`` (``u* = -m [k phi + thetad (xd cos + yd sin)]``).  Batched over rows of
    ``state``; ``W = m dV/dt`` with ``V1 = s^2 C1 - s c C2``, ``V2 = -s c C1 + c^2 C2``::

        u* = -m s [xd + C1 + xd dC1/dx + yd dC1/dy + yd thd + thd C2 + W1]
             -m c [-yd - C2 - xd dC2/dx - yd dC2/dy + xd thd + thd C1 - W2]
    """
    s2 = np.atleast_2d(state)
    m = params[model.param_names.index("m")]
    _, _, th, xd, yd, thd = s2.T
    c1, c2, c1x, c1y, c2x, c2y = model.outputs(s2, params).T  # the (scaled) current and its Jacobian
    sn, cs = np.sin(th), np.cos(th)
    c1_dot, c2_dot = c1x * xd + c1y * yd, c2x * xd + c2y * yd
    w1 = m * ((2 * sn * cs * c1 - (cs**2 - sn**2) * c2) * thd + sn**2 * c1_dot - sn * cs * c2_dot)
    w2 = m * ((-(cs**2 - sn**2) * c1 - 2 * sn * cs * c2) * thd - sn * cs * c1_dot + cs**2 * c2_dot)
    u = (-m * sn * (xd + c1 + xd * c1x + yd * c1y + yd * thd + thd * c2 + w1)
         - m * cs * (-yd - c2 - xd * c2x - yd * c2y + xd * thd + thd * c1 - w2))
    return u[:, None]


def _rk4_with_law(model: ConstrainedSystem, s0: Array, params: Array, dt: float, n_steps: int) -> Array:
    """Plain RK4 with `_printed_usv_law` re-evaluated at every stage (like ``continuous``)."""
    def f(s: Array) -> Array:
        return np.concatenate([s[3:], model.acceleration(s, _printed_usv_law(model, s, params)[0], params)])

    out = np.empty((n_steps + 1, s0.size))
    out[0] = s = s0.astype(np.float64)
    with np.errstate(over="ignore", invalid="ignore"):
        for i in range(n_steps):
            k1 = f(s)
            k2 = f(s + 0.5 * dt * k1)
            k3 = f(s + 0.5 * dt * k2)
            k4 = f(s + dt * k3)
            out[i + 1] = s = s + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    return out


def off_manifold_state(case: str, offset: float = PRINTED_LAW_OFFSET) -> Array:
    """The paper's start for ``case`` with ``offset`` added to the sideways velocity ``(sin, -cos) . (xd, yd)``.

    ``phi`` is affine in that velocity with slope 1, so ``phi`` grows by exactly ``offset``
    (north-east: -0.2 -> 0.1; anticyclone: 0 -> 0.3): the start of the USV-law erratum (the docs' errata page).
    """
    s = USV_PRESETS[case].state()
    th = s[2]
    s[3:5] += offset * np.array([np.sin(th), -np.cos(th)])
    return s


def _printed_law_failure(out: Path, quick: bool) -> tuple[list[Path], dict[str, tuple[float, float]]]:
    fig = Figure(figsize=(8.0, 5.0), layout="constrained")
    ax = fig.add_subplot()
    finals = {}
    for colour, case in zip(("tab:blue", "tab:red"), USV_CASES, strict=True):
        preset = USV_PRESETS[case]
        model = make_usv(preset.current)
        params = preset.params()
        s0 = off_manifold_state(case)
        n = _n_steps(PRINTED_LAW_DURATION, preset.dt, quick)
        t = np.arange(n + 1) * preset.dt
        printed = model.phi(_rk4_with_law(model, s0, params, preset.dt, n), params)[:, 0]
        derived = simulate(model, s0, preset.dt, n, feedback="continuous", gains=preset.gain, params=params)
        ax.semilogy(t, np.abs(printed), color=colour, lw=1.6,
                    label=f"{preset.current}: printed law (φ(0) = {printed[0]:.2g}, final φ = {printed[-1]:.3g})")
        ax.semilogy(derived.t, np.abs(derived.phi[:, 0]), color=colour, lw=1.6, ls="--",
                    label=f"{preset.current}: derived law, k = {preset.gain:g} (final |φ| = "
                          f"{abs(derived.phi[-1, 0]):.1e})")
        finals[preset.current] = (float(printed[-1]), float(derived.phi[-1, 0]))
    ax.set_xlabel("t [s]")
    ax.set_ylabel(r"$|\phi(t)|$ [m/s]")
    ax.set_title("USV: the paper's printed u* does not stabilise φ (erratum), the derived u* does\n"
                 f"paper's start with sideways velocity +{PRINTED_LAW_OFFSET:g} m/s, dt = 0.01 s")
    ax.grid(alpha=0.3, which="both")
    ax.legend(loc="lower left", fontsize=9)
    return [_save(fig, out / "usv_printed_law_failure.png", quick)], finals


# ---------------------------------------------------------------------------------------------- entry points


def reproduce(out_dir: str | Path, quick: bool = False, verbose: bool = False) -> list[Path]:
    """Regenerate every figure of Section IV as PNG in ``out_dir``; return the paths written.

    Parameters
    ----------
    out_dir : str or Path
        Output folder (created if missing).
    quick : bool
        Simulate only 2 % of every duration (for tests and smoke runs).
    verbose : bool
        Print one line per figure group.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths: list[Path] = []
    t0 = time.perf_counter()
    paths += _flocking(out, quick)
    if verbose:
        print(f"flocking: {len(paths)} figures ({time.perf_counter() - t0:.1f} s)")
    for case in USV_CASES:
        t0 = time.perf_counter()
        new = _usv(out, case, quick)
        paths += new
        if verbose:
            print(f"{case}: {len(new)} figures ({time.perf_counter() - t0:.1f} s)")
    t0 = time.perf_counter()
    new, finals = _printed_law_failure(out, quick)
    paths += new
    if verbose:
        summary = ", ".join(f"{k}: printed phi = {p:.3g}, derived phi = {d:.1e}" for k, (p, d) in finals.items())
        print(f"printed-law erratum ({time.perf_counter() - t0:.1f} s): {summary}")
    assert [p.name for p in paths] == list(FIGURES)
    return paths


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of ``vnhc-gym reproduce`` (and ``experiments/reproduce_paper.py``)."""
    parser.add_argument("--out", default="results/paper", metavar="DIR",
                        help="output folder for the PNG figures (default: %(default)s)")
    parser.add_argument("--quick", action="store_true",
                        help=f"simulate only {QUICK_FRACTION * 100:g}%% of every duration (smoke test)")


def run(args: argparse.Namespace) -> int:
    """Run ``reproduce`` from parsed arguments; print the files written."""
    paths = reproduce(args.out, quick=args.quick, verbose=True)
    for p in paths:
        print(p)
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """Stand-alone entry point (``python -m vnhc_gym.paper`` / ``experiments/reproduce_paper.py``)."""
    parser = argparse.ArgumentParser(prog="reproduce_paper", description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    add_arguments(parser)
    return run(parser.parse_args(argv))


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
