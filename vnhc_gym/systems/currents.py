"""A library of sea-current fields ``C(x, y) = (C1, C2)`` for the USV.

Each field is a symbolic expression in ``(x, y)`` and named parameters, so the USV's law and
dynamics are derived and compiled with it; :meth:`CurrentField.value` and
:meth:`CurrentField.jacobian` evaluate it with numpy (rendering, analysis).

=============  ============================================  ==================================
name           C(x, y)                                       parameters (default)
=============  ============================================  ==================================
northeast      (c1, c2)                                      c1 = 1, c2 = 1  (paper)
anticyclone    a (y, -x + y)                                 a = 1  (paper)
affine         (c1 + j11 x + j12 y, c2 + j21 x + j22 y)       all 0
vortex         G/(2 pi) (-(y - y0), x - x0) / (r^2 + rc^2)   G = 4 pi, x0 = y0 = 0, rc = 1
shear          (u0 + s y, 0)                                 u0 = 0.5, s = 0.2
random         (d psi/dy, -d psi/dx),                        6 modes drawn from a seed
               psi = sum_k a_k sin(kx_k x + ky_k y + ph_k)   (divergence-free, |C| ~ 1)
=============  ============================================  ==================================

Every field is multiplied by the USV parameter ``current_scale`` (default 1), which the
``mismatch`` scenario perturbs.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import cached_property
from typing import Any

import numpy as np
import sympy as sp
from numpy.typing import ArrayLike, NDArray

__all__ = ["CurrentField", "CURRENTS", "get_current", "random_field_params", "RANDOM_MODES"]

RANDOM_MODES = 6


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
        return {k: sp.Symbol(f"c_{k}", real=True) for k in self.defaults}

    def expressions(self, x: sp.Symbol, y: sp.Symbol) -> tuple[sp.Expr, sp.Expr]:
        return self.build(x, y, self.symbols())

    @cached_property
    def _numeric(self) -> tuple[Callable[..., Any], Callable[..., Any]]:
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


def _random_build(x: sp.Symbol, y: sp.Symbol, p: dict[str, sp.Symbol]) -> tuple[sp.Expr, sp.Expr]:
    psi = sum(p[f"a{k}"] * sp.sin(p[f"kx{k}"] * x + p[f"ky{k}"] * y + p[f"ph{k}"]) for k in range(RANDOM_MODES))
    return sp.diff(psi, y), -sp.diff(psi, x)


def _vortex(x: sp.Symbol, y: sp.Symbol, p: dict[str, sp.Symbol]) -> tuple[sp.Expr, sp.Expr]:
    dx, dy = x - p["x0"], y - p["y0"]
    strength = p["gamma"] / (2 * sp.pi) / (dx**2 + dy**2 + p["rc"] ** 2)
    return -strength * dy, strength * dx


def random_field_params(seed: int | np.random.Generator, n_modes: int = RANDOM_MODES, wavelength: float = 8.0,
                        speed: float = 1.0) -> dict[str, float]:
    """Parameters of the ``random`` field for ``seed``: a divergence-free field of RMS speed ~``speed``.

    ``seed`` is an integer or a ``numpy.random.Generator`` to draw from (the environments pass
    their own, which is cheaper than seeding a new generator every episode).  Wave vectors have
    random directions and lengths around ``2 pi / wavelength``.
    """
    rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
    k0 = 2 * np.pi / wavelength
    angles = rng.uniform(0, 2 * np.pi, n_modes)
    norms = k0 * rng.uniform(0.5, 1.5, n_modes)
    amps = rng.normal(0.0, 1.0, n_modes)
    # RMS of C is sqrt(sum a_k^2 |k|^2 / 2): normalise it to `speed`.
    amps *= speed / np.sqrt(0.5 * np.sum(amps**2 * norms**2))
    phases = rng.uniform(0, 2 * np.pi, n_modes)
    out: dict[str, float] = {}
    for k in range(n_modes):
        out[f"a{k}"] = float(amps[k])
        out[f"kx{k}"] = float(norms[k] * np.cos(angles[k]))
        out[f"ky{k}"] = float(norms[k] * np.sin(angles[k]))
        out[f"ph{k}"] = float(phases[k])
    return out


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
    "shear": CurrentField("shear", {"u0": 0.5, "s": 0.2}, lambda x, y, p: (p["u0"] + p["s"] * y, sp.Integer(0)),
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
