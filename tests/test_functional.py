"""The pure JAX core (`vnhc_gym.mechanics.functional` on the printed system modules) against
independent facts: RK4's stability polynomial on an oscillator, exponential decay of ``phi`` under
the law, the exact discretisation of the sampled-data law, hand-derived formulas; and the printed
modules against what printing gives today.

Every check runs under ``jax.enable_x64(True)`` (scoped: the package never changes JAX's global
settings) so that tolerances can be those of float64.
"""

from __future__ import annotations

import subprocess
import sys
import types

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import sympy as sp

from vnhc_gym.mechanics import MechanicalSystem, VelocityConstraint, derive_law
from vnhc_gym.mechanics import functional as F
from vnhc_gym.mechanics.printing import print_module
from vnhc_gym.systems.printed import FOLDER, SOURCES, load
from vnhc_gym.systems.printed.__main__ import BUILDS, text


@pytest.fixture(autouse=True)
def x64() -> object:
    with jax.enable_x64(True):
        yield


def _module(name: str, source: str) -> types.ModuleType:
    """A printed module made importable from its text (as the shipped files are)."""
    module = types.ModuleType(name)
    exec(compile(source, name, "exec"), module.__dict__)  # noqa: S102 - our own printed text
    return module


def _oscillator(k: float = 4.0) -> types.ModuleType:
    """x'' = -k x + u; constraint phi = xd."""
    x, xd = sp.symbols("x xd", real=True)
    ks = sp.Symbol("k", positive=True)
    system = MechanicalSystem(name="osc", q=(x,), qd=(xd,), mass_matrix=sp.eye(1), control_forces=sp.Matrix([1]),
                              potential=ks * x**2 / 2, params={ks: k})
    return _module("osc", print_module(derive_law(system, VelocityConstraint(sp.Matrix([xd]))), "osc", "test"))


def test_rk4_energy_follows_its_stability_polynomial() -> None:
    """On x'' = -omega^2 x, one RK4 step multiplies the energy by |R(i omega h)|^2 with
    R(z) = 1 + z + z^2/2 + z^3/6 + z^4/24, exactly (the step is linear)."""
    osc = _oscillator(4.0)
    omega, h = 2.0, 0.3
    p = jnp.asarray(osc.PARAM_DEFAULTS)
    s = jnp.array([0.7, -1.1])
    steps = 10
    step = jax.jit(lambda x: F.rk4_step(osc, x, p, jnp.zeros(1), h))
    e0 = float(osc.energy(s, p))
    for _ in range(steps):
        s = step(s)
    z = 1j * omega * h
    r = 1 + z + z**2 / 2 + z**3 / 6 + z**4 / 24
    assert float(osc.energy(s, p)) == pytest.approx(e0 * abs(r) ** (2 * steps), rel=1e-12)


def test_substeps_are_steps_of_the_smaller_period() -> None:
    osc = _oscillator(4.0)
    p = jnp.asarray(osc.PARAM_DEFAULTS)
    s = jnp.array([0.7, -1.1])
    u = jnp.array([0.4])
    once = F.rk4_step(osc, s, p, u, 0.2, substeps=4)
    by_hand = s
    for _ in range(4):
        by_hand = F.rk4_step(osc, by_hand, p, u, 0.05)
    np.testing.assert_allclose(once, by_hand, rtol=0, atol=1e-15)


@pytest.mark.parametrize("name", ["sled", "usv_northeast", "cartpole"])
def test_phi_decays_exponentially_under_the_continuous_law(name: str) -> None:
    """With the law inside every RK4 stage, phi(t) = exp(-K t) phi(0) up to RK4's error (dt = 1 ms)."""
    system = load(name)
    p = jnp.asarray(system.PARAM_DEFAULTS)
    s = jnp.asarray(np.random.default_rng(3).uniform(-0.5, 0.5, 2 * system.N))
    gains = jnp.linspace(1.5, 3.0, system.M)
    phi0 = system.phi(s, p)
    step = jax.jit(lambda x: F.rk4_step_controlled(system, x, p, jnp.zeros(system.M), 0.01, 10, feedback="continuous",
                                                         gains=gains)[0])
    for _ in range(50):  # 0.5 s
        s = step(s)
    np.testing.assert_allclose(system.phi(s, p), np.exp(-np.asarray(gains) * 0.5) * np.asarray(phi0), rtol=1e-7,
                               atol=1e-12)


@pytest.mark.parametrize("name", ["sled", "usv_northeast"])
def test_sampled_law_is_the_exact_discretisation(name: str) -> None:
    """Held over one control period, the sampled-data law gives phi(dt) = exp(-K dt) phi(0) on the step
    map itself (to Newton's tolerance), where the held continuous law does not."""
    system = load(name)
    p = jnp.asarray(system.PARAM_DEFAULTS)
    s = jnp.asarray(np.random.default_rng(5).uniform(-1.0, 1.0, 2 * system.N))
    dt, gain = 0.1, 20.0
    target = np.exp(-gain * dt) * np.asarray(system.phi(s, p))
    u, converged = F.sampled_law(system, s, p, dt, gain, substeps=4, iters=6)
    assert bool(converged)
    np.testing.assert_allclose(system.phi(F.rk4_step(system, s, p, u, dt, 4), p), target, rtol=1e-9, atol=1e-12)
    held = F.law(system, s, p, gain)
    assert np.max(np.abs(system.phi(F.rk4_step(system, s, p, held, dt, 4), p) - target)) > 1e-3


def test_usv_pieces_by_hand() -> None:
    """The boat in the north-east current (1, 1) scaled by ``current_scale``: phi = sin(th) xd - cos(th) yd
    + cos(th) c2 - sin(th) c1 (sideways slip through the water); one control, a torque-and-sideways
    force along (sin th / m, -cos th / m, 1 / I)."""
    system = load("usv_northeast")
    p = jnp.asarray(system.PARAM_DEFAULTS)
    m, inertia = system.PARAM_DEFAULTS[:2]
    x, y, th, xd, yd, thd = 0.4, -1.3, 0.7, 0.8, -0.5, 0.3
    s = jnp.array([x, y, th, xd, yd, thd])
    c1 = c2 = system.PARAM_DEFAULTS[2]  # the uniform current (1, 1) times its scale
    expected = np.sin(th) * xd - np.cos(th) * yd + np.cos(th) * c2 - np.sin(th) * c1
    assert float(system.phi(s, p)[0]) == pytest.approx(expected, rel=1e-13)
    np.testing.assert_allclose(system.input_fields(s, p)[:, 0], [np.sin(th) / m, -np.cos(th) / m, 1 / inertia],
                               rtol=1e-13)


def test_law_solves_the_defining_identity_and_batches() -> None:
    """C u* = -K phi - G at every row, and the vmapped law equals the law row by row."""
    system = load("sled")
    p = jnp.asarray(system.PARAM_DEFAULTS)
    states = jnp.asarray(np.random.default_rng(1).uniform(-1, 1, (16, 2 * system.N)))
    gains = jnp.array([2.0, 3.0])
    u = jax.vmap(lambda x: F.law(system, x, p, gains))(states)
    for i in range(16):
        c = system.decoupling_matrix(states[i], p)
        rhs = -gains * system.phi(states[i], p) - system.drift_term(states[i], p)
        np.testing.assert_allclose(c @ u[i], rhs, rtol=1e-12, atol=1e-12)
        np.testing.assert_array_equal(u[i], F.law(system, states[i], p, gains))


@pytest.mark.parametrize("name", [n for n in SOURCES if n != "spacecraft"])
def test_printed_modules_are_what_printing_gives(name: str) -> None:
    """The shipped files are in sync with their sympy definitions (the spacecraft's derivation takes
    minutes: ``python -m vnhc_gym.systems.printed spacecraft --check`` checks it)."""
    assert (FOLDER / f"{name}.py").read_text() == text(name), \
        f"vnhc_gym/systems/printed/{name}.py is out of date: python -m vnhc_gym.systems.printed {name}"


def test_every_printed_module_has_its_sympy_definition() -> None:
    """The command that prints the modules knows the definition of each, and of nothing else."""
    assert list(BUILDS) == list(SOURCES)


def test_every_printed_module_is_shipped_and_loads() -> None:
    assert sorted(p.stem for p in FOLDER.glob("*.py") if not p.stem.startswith("_")) == sorted(SOURCES)
    for name in SOURCES:
        system = load(name)
        p = jnp.asarray(system.PARAM_DEFAULTS)
        s = jnp.zeros(2 * system.N) + 0.1
        assert system.phi(s, p).shape == (system.M,) and system.decoupling_matrix(s, p).shape == (system.M,) * 2


def test_importing_the_core_leaves_jax_settings_and_sympy_alone() -> None:
    code = ("import sys, jax\nbefore = jax.config.jax_enable_x64\n"
            "import vnhc_gym\nfrom vnhc_gym.mechanics import functional\nfrom vnhc_gym.systems.printed import load\n"
            "load('sled'); load('usv_random')\n"
            "print(before == jax.config.jax_enable_x64 == False, 'sympy' in sys.modules)\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == ["True", "False"]
