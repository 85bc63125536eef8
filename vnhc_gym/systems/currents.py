"""A library of sea-current fields ``C(x, y) = (C1, C2)`` for the USV.

Each field is a symbolic expression in ``(x, y)`` and named parameters, so the USV's law and
dynamics are derived and compiled with it; `CurrentField.value` and
`CurrentField.jacobian` evaluate it with numpy (rendering, analysis).

=============  ============================================  ==================================
name           C(x, y)                                       parameters (default)
=============  ============================================  ==================================
northeast      (c1, c2)                                      c1 = 1, c2 = 1  (paper)
anticyclone    a (y, -x + y)                                 a = 1  (paper)
affine         (c1 + j11 x + j12 y, c2 + j21 x + j22 y)       all 0
vortex         G/(2 pi) (-(y - y0), x - x0) / (r^2 + rc^2)   G = 4 pi, x0 = y0 = 0, rc = 1
shear          (u0 + s y, 0)                                 u0 = 0.5, s = 0.2
random         (d psi/dy, -d psi/dx),                        A, B = a_<i>_<j>, b_<i>_<j> (m for
               psi = sum_(i, j) A cos(k0 (i x + j y))        a minus sign) for the 14 (i, j) in
                                + B sin(k0 (i x + j y)),     RANDOM_MODES: random_field_params(0)
               k0 = 2 pi / 16 m, 1 <= |(i, j)| <= 3          (divergence-free, 16 m-periodic,
                                                             RMS |C| = 1, peak wavelength 8 m)
=============  ============================================  ==================================

Every field is multiplied by the USV parameter ``current_scale`` (default 1), which the
``mismatch`` scenario perturbs.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import cached_property
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

if TYPE_CHECKING:  # sympy is imported where an expression is built, never on a warm start
    import sympy as sp

__all__ = ["CurrentField", "CURRENTS", "get_current", "random_field_params", "random_field_weights", "RANDOM_MODES",
           "RANDOM_PARAM_NAMES", "RANDOM_WEIGHTS", "RANDOM_K0", "RANDOM_PERIOD"]


@dataclass(frozen=True)
class CurrentField:
    """A current field ``C(x, y; params)``.

    Parameters
    ----------
    name : str
    defaults : dict of str to float
        Parameter names (without the ``c_`` prefix used in the system) and default values.
    build : callable
        ``build(x, y, P) -> (C1, C2)`` with ``P`` a dict of sympy symbols by parameter name.
    description : str
    """

    name: str
    defaults: dict[str, float]
    build: Callable[[sp.Symbol, sp.Symbol, dict[str, sp.Symbol]], tuple[sp.Expr, sp.Expr]]
    description: str = ""

    def symbols(self) -> dict[str, sp.Symbol]:
        """Parameter symbols, prefixed ``c_`` so they never clash with the boat's."""
        import sympy as sp

        return {k: sp.Symbol(f"c_{k}", real=True) for k in self.defaults}

    def expressions(self, x: sp.Symbol, y: sp.Symbol) -> tuple[sp.Expr, sp.Expr]:
        return self.build(x, y, self.symbols())

    @cached_property
    def _numeric(self) -> tuple[Callable[..., Any], Callable[..., Any]]:
        import sympy as sp

        x, y = sp.symbols("x y", real=True)
        syms = list(self.symbols().values())
        c1, c2 = self.expressions(x, y)
        value = sp.lambdify([x, y, *syms], [c1, c2], "numpy")
        jac = sp.lambdify([x, y, *syms], [sp.diff(c1, x), sp.diff(c1, y), sp.diff(c2, x), sp.diff(c2, y)], "numpy")
        return value, jac

    def _args(self, params: dict[str, float] | None) -> list[float]:
        vals = dict(self.defaults)
        for k, v in (params or {}).items():
            if k not in vals:
                raise ValueError(f"unknown parameter {k!r} for current {self.name!r}; valid: {sorted(vals)}")
            vals[k] = float(v)
        return [vals[k] for k in self.defaults]

    def value(self, x: ArrayLike, y: ArrayLike, params: dict[str, float] | None = None) -> NDArray[np.float64]:
        """``C(x, y)``, shape ``(..., 2)``."""
        xa, ya = np.broadcast_arrays(np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64))
        c1, c2 = self._numeric[0](xa, ya, *self._args(params))
        return np.stack(np.broadcast_arrays(c1, c2, xa)[:2], axis=-1).astype(np.float64)

    def jacobian(self, x: ArrayLike, y: ArrayLike, params: dict[str, float] | None = None) -> NDArray[np.float64]:
        """``dC/d(x, y)``, shape ``(..., 2, 2)`` with ``[..., i, j] = d C_i / d x_j``."""
        xa, ya = np.broadcast_arrays(np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64))
        parts = np.broadcast_arrays(*self._numeric[1](xa, ya, *self._args(params)), xa)[:4]
        return np.stack(parts, axis=-1).reshape(*xa.shape, 2, 2).astype(np.float64)


#: Lattice period (m) of the ``random`` field in x and in y, its fundamental wave number
#: ``k0 = 2 pi / period`` and the radius of its mode set.  Wave vectors are ``k0 (i, j)`` with
#: ``1 <= |(i, j)| <= 3``: wavelengths ``16 m / |(i, j)|`` from 5.3 m to 16 m, the band of the former
#: 6-mode field (``|k|`` uniform in ``[0.5, 1.5] 2 pi / 8 m``), with the 8 m spectral peak at
#: ``|(i, j)| = 2``.  A longer period (less visible periodicity) needs a larger radius for the same
#: band, and the cost grows with the number of modes (~R^2); a shorter one leaves too few modes
#: around the peak to look random.
RANDOM_PERIOD = 16
RANDOM_K0 = 2 * np.pi / RANDOM_PERIOD
RANDOM_RADIUS = 3
#: Integer wave vectors ``(i, j)`` of the ``random`` field: half-plane ``i > 0`` or ``(i == 0, j > 0)``,
#: ``1 <= i^2 + j^2 <= RANDOM_RADIUS^2`` (14 modes).
RANDOM_MODES: tuple[tuple[int, int], ...] = tuple(
    (i, j) for i in range(RANDOM_RADIUS + 1) for j in range(-RANDOM_RADIUS, RANDOM_RADIUS + 1)
    if (i > 0 or j > 0) and 1 <= i * i + j * j <= RANDOM_RADIUS**2)


def _mode_label(i: int, j: int) -> str:
    return f"{i}_{j}" if j >= 0 else f"{i}_m{-j}"


#: Parameter names of the ``random`` field (without the ``c_`` prefix): ``a_<i>_<j>``, ``b_<i>_<j>`` per
#: mode in ``RANDOM_MODES`` order (``m`` for a minus sign: ``a_1_m2`` is the cosine amplitude of (1, -2)).
RANDOM_PARAM_NAMES: tuple[str, ...] = tuple(f"{ab}_{_mode_label(i, j)}" for i, j in RANDOM_MODES for ab in "ab")


def random_field_weights(wavelength: float = 8.0, speed: float = 1.0) -> NDArray[np.float64]:
    """Standard deviations of the ``random`` field's amplitudes, in ``RANDOM_PARAM_NAMES`` order.

    Passot-Pouquet energy spectrum ``E(k) ~ (k / kp)^4 exp(-2 (k / kp)^2)``, ``kp = 2 pi / wavelength``
    (the spectrum peaks at ``wavelength``).  In 2-D a mode of wave number ``k`` carries ``E(k) / k`` of
    the mean-square speed, so a mode ``n = (i, j)`` gets ``e_n ~ |n|^3 exp(-2 |n|^2 / np^2)`` with
    ``np = period / wavelength``, normalised to ``sum e_n = speed^2``; its amplitudes ``A, B ~ N(0, w_n^2)``
    contribute ``E[(A^2 + B^2) / 2] k0^2 |n|^2 = w_n^2 k0^2 |n|^2 = e_n``, so ``E|C|^2 = speed^2`` at every point.
    """
    if not wavelength > 0:
        raise ValueError(f"wavelength must be positive, got {wavelength}")
    norms = np.array([np.hypot(i, j) for i, j in RANDOM_MODES])
    n_peak = RANDOM_PERIOD / float(wavelength)
    energy = norms**3 * np.exp(-2.0 * (norms / n_peak) ** 2)
    energy *= speed**2 / energy.sum()
    w = np.sqrt(energy) / (RANDOM_K0 * norms)
    return np.repeat(w, 2)


#: Default amplitude standard deviations (8 m peak wavelength, RMS speed 1 m/s), in
#: ``RANDOM_PARAM_NAMES`` order.  ``random_field_params`` draws ``z * RANDOM_WEIGHTS``, ``z`` standard normal.
RANDOM_WEIGHTS: NDArray[np.float64] = random_field_weights()
RANDOM_WEIGHTS.setflags(write=False)


def _harmonics(t: Any, n_max: int) -> tuple[list[Any], list[Any]]:
    """``cos(n k0 t)``, ``sin(n k0 t)`` for ``n = 0..n_max`` as polynomials in ``cos(k0 t)``, ``sin(k0 t)``.

    Chebyshev recurrences ``X_{n+1} = 2 cos(k0 t) X_n - X_{n-1}``: the only trig left in the compiled
    code (after differentiation and CSE) is ``cos(k0 t)`` and ``sin(k0 t)``.  Sympy never folds the
    polynomials back into multiple-angle trig (it does not auto-simplify).
    """
    import sympy as sp

    k0 = 2 * sp.pi / RANDOM_PERIOD
    c, s = sp.cos(k0 * t), sp.sin(k0 * t)
    cos_n: list[Any] = [sp.Integer(1), c]
    sin_n: list[Any] = [sp.Integer(0), s]
    for _ in range(2, n_max + 1):
        cos_n.append(2 * c * cos_n[-1] - cos_n[-2])
        sin_n.append(2 * c * sin_n[-1] - sin_n[-2])
    return cos_n, sin_n


def _random_build(x: sp.Symbol, y: sp.Symbol, p: dict[str, sp.Symbol]) -> tuple[sp.Expr, sp.Expr]:
    """``psi = sum_(i, j) A cos(k0 (i x + j y)) + B sin(k0 (i x + j y))``, ``C = (dpsi/dy, -dpsi/dx)``.

    Separated by angle addition as ``psi = sum_i cos(i k0 x) F_i(y) + sin(i k0 x) G_i(y)``, with
    ``F_i, G_i`` sums of ``cos(n k0 y)``, ``sin(n k0 y)``, ``n = |j|`` (``j`` and ``-j`` by parity): each
    derivative only touches one factor of a product, and each harmonic of ``y`` is multiplied by one
    combination of amplitudes (``A_(i, n) + A_(i, -n)`` etc.), which CSE computes once.
    """
    import sympy as sp

    cx, sx = _harmonics(x, RANDOM_RADIUS)
    cy, sy = _harmonics(y, RANDOM_RADIUS)
    psi = sp.Integer(0)
    for i in range(RANDOM_RADIUS + 1):
        f, g = sp.Integer(0), sp.Integer(0)
        for n in range(RANDOM_RADIUS + 1):
            # A cos(u + v) + B sin(u + v) = cos u (A cos v + B sin v) + sin u (B cos v - A sin v),
            # with cos v = cos(n k0 y), sin v = sign(j) sin(n k0 y).
            fc = fs = gc = gs = sp.Integer(0)
            for j in (n, -n) if n else (0,):
                if (i, j) in RANDOM_MODES:
                    a, b = p[f"a_{_mode_label(i, j)}"], p[f"b_{_mode_label(i, j)}"]
                    sign = 1 if j >= 0 else -1
                    fc, fs, gc, gs = fc + a, fs + sign * b, gc + b, gs - sign * a
            f += fc * cy[n] + fs * sy[n]
            g += gc * cy[n] + gs * sy[n]
        psi += cx[i] * f + sx[i] * g
    return sp.diff(psi, y), -sp.diff(psi, x)


def _vortex(x: sp.Symbol, y: sp.Symbol, p: dict[str, sp.Symbol]) -> tuple[sp.Expr, sp.Expr]:
    import sympy as sp

    dx, dy = x - p["x0"], y - p["y0"]
    strength = p["gamma"] / (2 * sp.pi) / (dx**2 + dy**2 + p["rc"] ** 2)
    return -strength * dy, strength * dx


def _shear(x: sp.Symbol, y: sp.Symbol, p: dict[str, sp.Symbol]) -> tuple[sp.Expr, sp.Expr]:
    import sympy as sp

    return p["u0"] + p["s"] * y, sp.Integer(0)


def random_field_params(seed: int | np.random.Generator, speed: float = 1.0,
                        wavelength: float = 8.0) -> dict[str, float]:
    """Parameters of the ``random`` field for ``seed``: a divergence-free field of RMS speed ``speed``.

    ``seed`` is an integer or a ``numpy.random.Generator`` to draw from (the environments pass
    their own, which is cheaper than seeding a new generator every episode).  The amplitudes are
    ``z * random_field_weights(wavelength, speed)`` with ``z = rng.standard_normal(len(RANDOM_PARAM_NAMES))``
    (28 numbers) in ``RANDOM_PARAM_NAMES`` order; by default the weights are ``RANDOM_WEIGHTS``, so a caller may draw
    ``z * RANDOM_WEIGHTS`` itself (same distribution, same numbers for the same generator state).
    The expected mean-square speed ``E|C|^2`` is ``speed^2`` at every point.
    """
    rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
    weights = RANDOM_WEIGHTS if (speed, wavelength) == (1.0, 8.0) else random_field_weights(wavelength, speed)
    amps = rng.standard_normal(len(RANDOM_PARAM_NAMES)) * weights
    return dict(zip(RANDOM_PARAM_NAMES, amps.tolist(), strict=True))


#: Public current names (keep them stable).
CURRENTS: dict[str, CurrentField] = {
    "northeast": CurrentField("northeast", {"c1": 1.0, "c2": 1.0}, lambda x, y, p: (p["c1"], p["c2"]),
                              "uniform current (c1, c2); the paper's north-east case is (1, 1)"),
    "anticyclone": CurrentField("anticyclone", {"a": 1.0}, lambda x, y, p: (p["a"] * y, p["a"] * (-x + y)),
                                "linear anticyclone a (y, -x + y) (paper); spirals outward"),
    "affine": CurrentField(
        "affine", {"c1": 0.0, "c2": 0.0, "j11": 0.0, "j12": 0.0, "j21": 0.0, "j22": 0.0},
        lambda x, y, p: (p["c1"] + p["j11"] * x + p["j12"] * y, p["c2"] + p["j21"] * x + p["j22"] * y),
        "general affine field c + J (x, y); a local model of any field (used by the sampled-data baseline)"),
    "vortex": CurrentField(
        "vortex", {"gamma": float(4 * np.pi), "x0": 0.0, "y0": 0.0, "rc": 1.0},
        lambda x, y, p: _vortex(x, y, p),
        "point vortex of circulation gamma with a smooth core rc (peak speed gamma / (4 pi rc))"),
    "shear": CurrentField("shear", {"u0": 0.5, "s": 0.2}, lambda x, y, p: _shear(x, y, p),
                          "plane shear flow (u0 + s y, 0)"),
    "random": CurrentField("random", random_field_params(0), _random_build,
                           "smooth divergence-free random field; parameters from random_field_params(seed)"),
}


def get_current(name: str) -> CurrentField:
    """Look up a current by name, with an error that lists the valid names."""
    try:
        return CURRENTS[name]
    except KeyError:
        raise ValueError(f"unknown current {name!r}; valid names: {sorted(CURRENTS)}") from None
