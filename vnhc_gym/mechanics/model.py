"""Numeric, batched evaluation of a constrained mechanical system.

[`ConstrainedSystem`][vnhc_gym.mechanics.ConstrainedSystem] is the checked numpy face of the core: it
evaluates ``phi``, ``C``, ``G(phi)``, ``u*``, ``u_hat``, the energy and RK4 steps for one state
(shape ``(2n,)``) or a batch (shape ``(B, 2n)``), by running the pure ``jax.numpy`` functions of
`vnhc_gym.mechanics.functional` on the system's functions (a printed module, a lambdified law or a
fleet) under ``jax.vmap`` and ``jax.jit``, in float64 inside ``jax.enable_x64`` (a user's global JAX
settings stay as they were).  Like python-control's checked ``dynamics`` beside a fast ``_rhs``, the
methods check their arguments; the environments and the JAX baselines call the functions directly.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Mapping
from typing import TYPE_CHECKING, Any, Literal

import jax
import numpy as np
from numpy.typing import ArrayLike, NDArray

from vnhc_gym.mechanics import functional as F
from vnhc_gym.mechanics._checks import check_param, check_param_rows, check_state_rows, lower_bounds

if TYPE_CHECKING:  # the symbolic layer (sympy) is imported only when a model needs it
    import sympy as sp

    from vnhc_gym.mechanics.constraint import HolonomicConstraint, SymbolicLaw, VelocityConstraint
    from vnhc_gym.mechanics.fleet import FleetLayout
    from vnhc_gym.mechanics.system import MechanicalSystem

__all__ = ["ConstrainedSystem", "SingularControlError", "Feedback", "FLAG_SINGULAR", "FLAG_NONFINITE"]

Feedback = Literal["open", "continuous", "sampled"]

# Bits of the per-row status flag of `ConstrainedSystem.step`.
FLAG_SINGULAR = 1  #: the input fields were (nearly) tangent to the constraint at some evaluation (u* set to 0).
FLAG_NONFINITE = 2  #: the state became non-finite.

Array = NDArray[np.float64]

#: The smallest padded batch: batches are padded to a power of two, so that a program compiled for
#: one size serves every batch up to it (a new size costs a compilation, ~0.1-1 s).
_MIN_ROWS = 8

Parts = tuple["MechanicalSystem", "VelocityConstraint | HolonomicConstraint", "dict[str, sp.Expr]"]
#: A recipe's builder: returns ``(system, constraint)`` or ``(system, constraint, outputs)``.
Builder = Callable[[], tuple[Any, ...]]


class SingularControlError(ArithmeticError):
    """The state is singular for the law: there the input fields are (nearly) tangent to the constraint.

    Theorem 2 needs the input fields transversal to the constraint (``C`` invertible); where the
    transversality measure
    ([`ConstrainedSystem.transversality`][vnhc_gym.mechanics.ConstrainedSystem.transversality]) is
    at most ``singular_tol``, ``u*`` does not exist or is dominated by rounding.  Raised by
    [`ConstrainedSystem.control`][vnhc_gym.mechanics.ConstrainedSystem.control] with
    ``on_singular="raise"`` (the default), after the parameters and the states have been checked: a
    bad parameter or a non-finite state raises ``ValueError`` instead.

    Attributes
    ----------
    rows : ndarray of int
        The offending batch rows.
    measure : ndarray of float or None
        The transversality measure at those rows.
    """

    def __init__(self, rows: NDArray[np.intp], measure: NDArray[np.float64] | None = None,
                 singular_tol: float | None = None) -> None:
        self.rows = rows
        self.measure = measure
        shown = rows[:10].tolist()
        more = f" and {rows.size - 10} more" if rows.size > 10 else ""
        detail = ""
        if measure is not None:
            vals = ", ".join(f"{v:.3g}" for v in measure[:10])
            tol = f" <= singular_tol = {singular_tol:g}" if singular_tol is not None else ""
            detail = f" (transversality measure {vals}{tol})"
        super().__init__(f"singular state at batch rows {shown}{more}: the input fields are tangent or nearly "
                         f"tangent to the constraint{detail}, so the decoupling matrix C is singular and the "
                         "stabilising law is undefined there (see ConstrainedSystem.transversality)")


def _check_tol(singular_tol: float) -> float:
    if not (np.isfinite(singular_tol) and singular_tol > 0):
        raise ValueError(f"singular_tol must be a finite number > 0, got {singular_tol}")
    return float(singular_tol)


class ConstrainedSystem:
    """A mechanical control system with a virtual constraint, evaluated in batches.

    Parameters
    ----------
    system : MechanicalSystem
        The symbolic system.
    constraint : VelocityConstraint or HolonomicConstraint
        The virtual constraint, with ``system.m`` components.
    outputs : mapping of str to sympy expression, optional
        Extra functions of the state and parameters (for example the sea current at the boat),
        evaluated by [`outputs`][vnhc_gym.mechanics.ConstrainedSystem.outputs].
    singular_tol : float, default 1e-10
        The law's singular test: a state is singular when its transversality measure
        ([`transversality`][vnhc_gym.mechanics.ConstrainedSystem.transversality]) is at most
        ``singular_tol``, or is not finite.  The measure is the smallest singular value of
        ``C^{ba} / (|J_b| |Y^a|)``, ``C`` normalised by the sizes, in the metric, of the rows
        ``J_b = d phi^b/d qd`` and of the input fields ``Y^a`` it is built from: a number in
        ``[0, 1]`` that rescaling masses, units, constraint components or controls never changes,
        and that is small where the constraint's gradient is nearly orthogonal to every input.

    Attributes
    ----------
    functions : module or object
        The system's pure ``jax.numpy`` functions of one state and one parameter vector (a printed
        module of `vnhc_gym.systems.printed`, a
        [`LambdifiedSystem`][vnhc_gym.mechanics.lambdified.LambdifiedSystem] or a
        ``FleetSystem`` of `vnhc_gym.mechanics.functional_fleet`); what the environments
        and the JAX baselines run.

    Notes
    -----
    States are ``s = (q, qd)`` of length ``2n``.  Parameters are a vector in the order of
    ``param_names``; every method takes ``params=None`` (defaults), a vector, or a
    ``(B, n_params)`` batch.  Every method refuses a non-finite parameter, and a parameter
    declared positive (``param_positive``) that is not > 0, with a ``ValueError`` that names it
    and its row; the methods that evaluate the law
    ([`control`][vnhc_gym.mechanics.ConstrainedSystem.control],
    [`step`][vnhc_gym.mechanics.ConstrainedSystem.step] and
    [`simulate`][vnhc_gym.mechanics.simulate] with the law in the loop) refuse a non-finite state
    likewise.  In the open loop a non-finite state is integrated and flagged ``FLAG_NONFINITE``.

    The constructor derives the law with sympy and lambdifies it (a second or two for a small
    system).  [`from_recipe`][vnhc_gym.mechanics.ConstrainedSystem.from_recipe] (used by the
    package's systems) imports the system's printed module instead and builds the symbolic side only
    when it is asked for: a start neither imports sympy nor derives anything.
    """

    name: str
    n: int
    m: int
    n_gains: int
    holonomic: bool
    param_names: tuple[str, ...]
    param_positive: tuple[bool, ...]
    default_params: Array
    output_names: tuple[str, ...]
    functions: Any

    def __init__(self, system: MechanicalSystem, constraint: VelocityConstraint | HolonomicConstraint,
                 outputs: Mapping[str, sp.Expr] | None = None, singular_tol: float = 1e-10) -> None:
        self._recipe: tuple[object, ...] | None = None
        self._build: Builder | None = None
        self._printed: str | None = None
        self._unit_layout: tuple[ConstrainedSystem, FleetLayout, tuple[str, ...] | None] | None = None
        self._parts: Parts | None = (system, constraint, dict(outputs or {}))
        self._law: SymbolicLaw | None = None
        self._setup(singular_tol)

    @classmethod
    def from_recipe(cls, recipe: tuple[object, ...], build: Builder, *, printed: str | None = None,
                    singular_tol: float = 1e-10) -> ConstrainedSystem:
        """A system named by ``recipe``, run from its printed module; ``build()`` runs only if the
        symbolic side is needed.

        Parameters
        ----------
        recipe : tuple of str, int, float or bool
            Names the system, e.g. ``("usv", "affine")``.
        build : callable
            ``build() -> (system, constraint)`` or ``(system, constraint, outputs)``, the
            arguments of the constructor.  It is stored (and pickled with the model), so it must
            be picklable: a module-level function or a ``functools.partial`` of one, not a lambda.
        printed : str, optional
            The import path of the system's printed module (``"vnhc_gym.systems.printed.sled"``);
            a test holds it to what printing ``build()`` gives.  Without one the law is derived and
            lambdified on first use.
        singular_tol : float, default 1e-10
        """
        self = cls.__new__(cls)
        self._recipe = tuple(recipe)
        self._build = build
        self._printed = printed
        self._unit_layout = None
        self._parts = None
        self._law = None
        self._setup(singular_tol)
        return self

    @classmethod
    def fleet(cls, unit: ConstrainedSystem, layout: FleetLayout, *, build: Builder | None = None,
              state_names: tuple[str, ...] | None = None, singular_tol: float = 1e-10) -> ConstrainedSystem:
        """A fleet of ``layout.replicas`` copies of ``unit`` sharing an autonomous part, run as
        ``jax.vmap`` over the unit (see `vnhc_gym.mechanics.fleet`), for any number of copies.

        Parameters
        ----------
        unit : ConstrainedSystem
            The unit system (with its constraint).
        layout : FleetLayout
            Where each copy sits in the fleet's state and parameters.
        build : callable, optional
            ``build() -> (system, constraint)`` of the whole fleet written out, for ``system``,
            ``constraint`` and ``symbolic`` (display and tests); not needed to run anything.
        state_names : tuple of str, optional
            The fleet's state names (``q`` then ``qd``); default ``s_0, s_1, ...``.
        singular_tol : float, default 1e-10
        """
        if layout.state_map.shape[1] != 2 * unit.n or layout.own.shape[0] != unit.n or \
                layout.param_map.shape[1] != len(unit.param_names):
            raise ValueError(f"the layout does not fit the unit {unit.name!r}: state_map needs {2 * unit.n} columns "
                             f"(got {layout.state_map.shape[1]}), own {unit.n} entries (got {layout.own.shape[0]}), "
                             f"param_map {len(unit.param_names)} columns (got {layout.param_map.shape[1]})")
        self = cls.__new__(cls)
        self._recipe = ("fleet", layout.name, layout.replicas)
        self._build = build
        self._printed = None
        self._parts = None
        self._law = None
        self._unit_layout = (unit, layout, state_names)
        if unit._law is not None:  # a derived unit (a printed one is held to its derivation by a test)
            from vnhc_gym.mechanics.fleet import check_autonomous

            check_autonomous(unit._law, layout.own)
        self._setup(singular_tol)
        for name, value, positive in zip(layout.param_names, layout.param_defaults, self.param_positive,
                                         strict=True):
            check_param(name, value, positive, f"the defaults of fleet {layout.name!r}")
        return self

    def _setup(self, singular_tol: float) -> None:
        """The functions, and the sizes, names and defaults read from them (no sympy for a printed module)."""
        self.singular_tol = _check_tol(singular_tol)
        self.functions = self._make_functions()
        f = self.functions
        self.name = str(f.NAME)
        self.n = int(f.N)
        self.m = int(f.M)
        self.holonomic = bool(f.HOLONOMIC)
        self.n_gains = 2 * self.m if self.holonomic else self.m
        self.param_names = tuple(f.PARAM_NAMES)
        self.param_positive = tuple(bool(v) for v in f.PARAM_POSITIVE)
        self.default_params = np.array(f.PARAM_DEFAULTS, dtype=np.float64)
        self.output_names = tuple(getattr(f, "OUTPUT_NAMES", ()))
        self._lower = lower_bounds(self.param_positive)
        self._programs: dict[tuple[object, ...], Callable[..., Any]] = {}

    def _make_functions(self) -> Any:
        if self._printed is not None:
            return importlib.import_module(self._printed)
        if self._unit_layout is not None:
            from vnhc_gym.mechanics.functional_fleet import FleetSystem

            unit, layout, names = self._unit_layout
            return FleetSystem(unit.functions, layout, names)
        from vnhc_gym.mechanics.lambdified import LambdifiedSystem

        return LambdifiedSystem(self.symbolic, self._outputs)

    def __getstate__(self) -> dict[str, object]:
        # Functions and compiled programs are rebuilt on load (a printed module by its name); a
        # recipe-built model pickles its recipe and builder, not the sympy objects.
        state = self.__dict__.copy()
        for key in ("functions", "_programs", "_law"):
            state.pop(key, None)
        if state["_build"] is not None:
            state["_parts"] = None
        return state

    def __setstate__(self, state: dict[str, object]) -> None:
        self.__dict__.update(state)
        self._law = None
        self._programs = {}
        self.functions = self._make_functions()

    # ------------------------------------------------------------------ symbolic side
    def _symbolic_parts(self) -> Parts:
        if self._parts is None:
            if self._build is None:
                raise ValueError(f"{self!r} has no symbolic form: it was built without one (pass build= to "
                                 "ConstrainedSystem.fleet)")
            system, constraint, *rest = self._build()
            outputs = dict(rest[0] or {}) if rest else {}
            seen = (system.name, system.n, system.m, tuple(str(p) for p in system.params), tuple(outputs))
            expected = tuple(getattr(self, a, None) for a in ("name", "n", "m", "param_names", "output_names"))
            if "name" in self.__dict__ and seen != expected:
                raise RuntimeError(f"the builder of recipe {self._recipe!r} returned a system {seen} that does not "
                                   f"match its functions {expected}; is the builder deterministic?")
            self._parts = (system, constraint, outputs)
        return self._parts

    @property
    def system(self) -> MechanicalSystem:
        """The symbolic system (built on first access for a recipe-built model)."""
        return self._symbolic_parts()[0]

    @property
    def constraint(self) -> VelocityConstraint | HolonomicConstraint:
        """The virtual constraint (built on first access for a recipe-built model)."""
        return self._symbolic_parts()[1]

    @property
    def _outputs(self) -> dict[str, sp.Expr]:
        return self._symbolic_parts()[2]

    @property
    def recipe(self) -> tuple[object, ...] | None:
        """The recipe of a model made by
        [`from_recipe`][vnhc_gym.mechanics.ConstrainedSystem.from_recipe] or
        [`fleet`][vnhc_gym.mechanics.ConstrainedSystem.fleet], else ``None``."""
        return self._recipe

    @property
    def symbolic(self) -> SymbolicLaw:
        """The symbolic law (derived on first access)."""
        if self._law is None:
            from vnhc_gym.mechanics.constraint import derive_law

            self._law = derive_law(self.system, self.constraint)
        return self._law

    def params(self, **overrides: float) -> Array:
        """Parameter vector with named overrides, e.g. ``params(m=3.0)``.

        Same checks and messages as
        [`MechanicalSystem.default_param_values`][vnhc_gym.mechanics.system.MechanicalSystem.default_param_values], from
        the functions' parameter names, defaults and signs (no sympy).

        Raises
        ------
        ValueError
            If a name is unknown, or a value is not finite (or not > 0 for a parameter declared
            positive, see ``param_positive``).
        """
        values = dict(zip(self.param_names, self.default_params.tolist(), strict=True))
        positive = dict(zip(self.param_names, self.param_positive, strict=True))
        for key, val in overrides.items():
            if key not in values:
                raise ValueError(f"unknown parameter {key!r}; valid names: {sorted(values)}")
            values[key] = check_param(key, val, positive[key], "params()")
        return np.array([values[k] for k in self.param_names], dtype=np.float64)

    # ------------------------------------------------------------------ argument checks
    def _states(self, state: ArrayLike) -> tuple[Array, bool]:
        s = np.asarray(state, dtype=np.float64)
        single = s.ndim == 1
        s2 = np.ascontiguousarray(s.reshape(1, -1) if single else s)
        if s2.ndim != 2 or s2.shape[1] != 2 * self.n:
            raise ValueError(f"state must have shape (2n,) or (B, 2n) with 2n = {2 * self.n}, got {s.shape}")
        return s2, single

    def _rows(self, value: ArrayLike | None, batch: int, width: int, name: str, default: Array) -> Array:
        v = default if value is None else np.asarray(value, dtype=np.float64)
        if v.ndim == 0:
            v = np.full(width, float(v))
        if v.ndim == 1:
            if v.shape[0] != width:
                raise ValueError(f"{name} must have {width} entries (or shape (B, {width})), got {v.shape}")
            return np.ascontiguousarray(np.broadcast_to(v, (batch, width)))
        if v.shape != (batch, width):
            raise ValueError(f"{name} must have shape ({width},) or ({batch}, {width}), got {v.shape}")
        return np.ascontiguousarray(v)

    def _params(self, params: ArrayLike | None, batch: int) -> Array:
        p = self._rows(params, batch, len(self.param_names), "params", self.default_params)
        if params is not None:  # the defaults were checked when the model was made
            check_param_rows(p, self.param_names, self._lower, batched=np.ndim(params) == 2)
        return p

    def _law_states(self, s: Array, single: bool) -> None:
        """Refuse non-finite states where the law is evaluated: there ``C`` would be NaN and the state
        reported as singular, which it is not."""
        check_state_rows(s, self.n, not single, "the law is defined at finite states only")

    def _gains(self, gains: ArrayLike | None, batch: int) -> Array:
        k = self._rows(gains, batch, self.n_gains, "gains", np.ones(self.n_gains))
        if not np.all(np.isfinite(k)) or np.any(k < 0):
            raise ValueError("gains must be finite and >= 0")
        return k

    @staticmethod
    def _out(x: Array, single: bool) -> Array:
        return x[0] if single else x

    def _run(self, key: tuple[object, ...], make: Callable[[], Callable[..., Any]], rows: tuple[Array, ...],
             shared: tuple[Any, ...] = ()) -> Any:
        """``make()`` (a function of one row) on every row of ``rows`` (each ``(B, ...)``), with the
        arguments ``shared`` common to all rows: one compiled call in float64, numpy results."""
        program = self._programs.get(key)
        if program is None:
            fn = make()
            program = jax.jit(jax.vmap(fn, in_axes=(0,) * len(rows) + (None,) * len(shared)))
            self._programs[key] = program
        b = rows[0].shape[0]
        size = max(_MIN_ROWS, 1 << max(b - 1, 0).bit_length())
        if b == 0:
            padded = tuple(np.zeros((size, *r.shape[1:])) for r in rows)
        else:  # padded with copies of the last row: finite wherever the rows are
            padded = tuple(np.concatenate([r, np.repeat(r[-1:], size - b, axis=0)]) if size > b else r for r in rows)
        with jax.enable_x64(True):
            out = program(*padded, *shared)
            return jax.tree.map(lambda a: np.array(a)[:b], out)

    def _each(self, name: str, state: ArrayLike, params: ArrayLike | None) -> tuple[Any, bool]:
        """The functions' ``name`` on every row: ``(values, single)``."""
        s, single = self._states(state)
        p = self._params(params, s.shape[0])
        return self._run((name,), lambda: getattr(self.functions, name), (s, p)), single

    # ------------------------------------------------------------------ evaluation
    def phi(self, state: ArrayLike, params: ArrayLike | None = None) -> Array:
        """Velocity constraint ``phi(q, qd)`` (``psi = d phi_h/dt`` if holonomic), shape ``(..., m)``."""
        out, single = self._each("phi", state, params)
        return self._out(out, single)

    def phi_h(self, state: ArrayLike, params: ArrayLike | None = None) -> Array:
        """Holonomic constraint values ``phi_h(q)``; only for a holonomic constraint."""
        if not self.holonomic:
            raise ValueError("phi_h is only defined for a HolonomicConstraint")
        out, single = self._each("phi_h", state, params)
        return self._out(out, single)

    def transversality(self, state: ArrayLike, params: ArrayLike | None = None) -> Array | float:
        """How far the input fields are from tangent to the constraint: the measure of the singular test.

        With ``J_b = d phi^b/d qd`` (a covector) and the input fields ``Y^a`` (vectors),
        ``C^{ba} = J_b Y^a``.  The measure is the smallest singular value of the normalised matrix
        ``C^{ba} / (|J_b| |Y^a|)``, where ``|J_b|^2 = J_b M^-1 J_b^T`` and ``|Y^a|^2 = Y^a . M Y^a``
        are sizes in the metric ``M`` (for a block-diagonal ``C``: the smallest over its blocks).
        Each normalised entry is the cosine of the angle between the gradient of ``phi^b`` and
        ``Y^a``, so the measure lies in ``[0, 1]``: 1 where each constraint component is steered by
        its own input head-on, 0 where some combination of components cannot be changed by any
        control.  Rescaling masses, units, constraint components or controls does not change it.

        The law counts a state as singular where the measure is at most ``singular_tol`` (or is
        not finite); see the docs' math page.

        Returns
        -------
        float or ndarray, shape (B,)
            0 where a row of ``J`` or an input field vanishes; NaN where ``C`` or a size is not
            finite.
        """
        s, single = self._states(state)
        out = self._measure(s, self._params(params, s.shape[0]))
        return float(out[0]) if single else out

    def _measure(self, s: Array, p: Array) -> Array:
        return np.asarray(self._run(("transversality",), lambda: lambda x, q: F.transversality(self.functions, x, q),
                                    (s, p)))

    def decoupling(self, state: ArrayLike, params: ArrayLike | None = None) -> tuple[Array, Array]:
        """``(C, G(phi))``: ``C[b, a] = d phi^b/d qd . Y^a`` and the Lie derivative along the drift."""
        c, single = self._each("decoupling_matrix", state, params)
        g, _ = self._each("drift_term", state, params)
        return self._out(c, single), self._out(g, single)

    def dynamics(self, state: ArrayLike, params: ArrayLike | None = None) -> tuple[Array, Array]:
        """``(a0, Y)``: drift acceleration ``(..., n)`` and input fields ``(..., n, m)``."""
        a0, single = self._each("drift", state, params)
        y, _ = self._each("input_fields", state, params)
        return self._out(a0, single), self._out(y, single)

    def acceleration(self, state: ArrayLike, u: ArrayLike, params: ArrayLike | None = None) -> Array:
        """``qdd = a0 + Y u`` for a given control."""
        a0, y = self.dynamics(state, params)
        return a0 + np.einsum("...ia,...a->...i", y, np.asarray(u, dtype=np.float64))

    def energy(self, state: ArrayLike, params: ArrayLike | None = None) -> Array | float:
        """Mechanical energy ``1/2 qd^T M qd + V(q)``."""
        out, single = self._each("energy", state, params)
        return float(out[0]) if single else out

    def outputs(self, state: ArrayLike, params: ArrayLike | None = None) -> Array:
        """The extra outputs, in the order of ``output_names``."""
        if not self.output_names:
            s, single = self._states(state)
            self._params(params, s.shape[0])
            return self._out(np.empty((s.shape[0], 0)), single)
        out, single = self._each("outputs", state, params)
        return self._out(out, single)

    def control(self, state: ArrayLike, gains: ArrayLike | None = None, params: ArrayLike | None = None,
                on_singular: Literal["raise", "flag"] = "raise") -> Array | tuple[Array, NDArray[np.bool_]]:
        """The stabilising law ``u* = C^-1 (-K phi - G(phi))``.

        Parameters
        ----------
        state : array_like, shape (2n,) or (B, 2n)
        gains : array_like, optional
            ``diag K`` (``m`` values; ``2m`` values ``diag K1, diag K2`` for a holonomic
            constraint); a scalar applies to all.  Default 1.  ``gains=0`` gives ``u_hat``.
        params : array_like, optional
            Finite; > 0 where declared positive.
        on_singular : {"raise", "flag"}
            ``"raise"``: raise [`SingularControlError`][vnhc_gym.mechanics.SingularControlError] if
            the state is singular at any row (its
            [`transversality`][vnhc_gym.mechanics.ConstrainedSystem.transversality] is at most
            ``singular_tol``).
            ``"flag"``: return ``(u, singular)``, with ``u = 0`` on singular rows.

        Raises
        ------
        ValueError
            If a parameter is not finite (or not > 0 where declared positive) or a state is not
            finite: the message names the row and the entry.  These are checked first, so a
            [`SingularControlError`][vnhc_gym.mechanics.SingularControlError] always means a singular state.
        """
        if on_singular not in ("raise", "flag"):
            raise ValueError(f"on_singular must be 'raise' or 'flag', got {on_singular!r}")
        s, single = self._states(state)
        b = s.shape[0]
        p = self._params(params, b)
        k = self._gains(gains, b)
        self._law_states(s, single)
        tol = self.singular_tol
        u, singular = self._run(("law",), lambda: lambda x, q, g: F.checked_law(self.functions, x, q, g, tol),
                                (s, p, k))
        if on_singular == "raise":
            if singular.any():
                rows = np.flatnonzero(singular)
                raise SingularControlError(rows, self._measure(s[rows], p[rows]), tol)
            return self._out(u, single)
        return self._out(u, single), (singular[0] if single else singular)

    def invariance_control(self, state: ArrayLike, params: ArrayLike | None = None) -> Array:
        """The invariance control ``u_hat = -C^-1 G(phi)`` (``u*`` with ``K = 0``)."""
        out = self.control(state, gains=0.0, params=params)
        assert isinstance(out, np.ndarray)  # on_singular="raise" returns an array
        return out

    # ------------------------------------------------------------------ integration
    def step(self, state: ArrayLike, dt: float, *, u: ArrayLike | None = None, feedback: Feedback = "open",
             gains: ArrayLike | None = None, params: ArrayLike | None = None, substeps: int = 1,
             u_bounds: tuple[ArrayLike, ArrayLike] | None = None) -> tuple[Array, Array, NDArray[np.int64]]:
        """Advance by one control period ``dt`` with ``substeps`` RK4 steps.

        Parameters
        ----------
        state : array_like, shape (2n,) or (B, 2n)
        dt : float
            Control period (seconds), > 0.
        u : array_like, optional
            Held control (``open``) or held addition to the law (``continuous``/``sampled``).
        feedback : {"open", "continuous", "sampled"}
            ``open``: apply ``u`` only.  ``continuous``: re-evaluate ``u*`` at every RK4 stage
            (the theorem's setting).  ``sampled``: evaluate ``u*`` once at the start of the
            period and hold it (zero-order hold, as an RL environment applies an action).
        u_bounds : (lower, upper), optional
            Saturation applied to the total control at every stage.

        Returns
        -------
        (new_state, u_applied, flags)
            ``u_applied`` is the applied control averaged over the substeps' first stages.
            ``flags`` per row: bit ``FLAG_SINGULAR`` if the law met a singular state at some
            evaluation (``u*`` then taken as 0 there), bit ``FLAG_NONFINITE`` if the state became
            non-finite.

        Raises
        ------
        ValueError
            If a parameter is not finite (or not > 0 where declared positive), or, with the law
            in the loop (``continuous``, ``sampled``), a state is not finite; the message names the
            row and the entry.  In the ``open`` mode a non-finite state is integrated and flagged.
        """
        if feedback not in F.FEEDBACK_MODES:
            raise ValueError(f"feedback must be one of {sorted(F.FEEDBACK_MODES)}, got {feedback!r}")
        if not (np.isfinite(dt) and dt > 0):
            raise ValueError(f"dt must be a finite number > 0, got {dt}")
        if int(substeps) != substeps or substeps < 1:
            raise ValueError(f"substeps must be an integer >= 1, got {substeps}")
        s, single = self._states(state)
        b = s.shape[0]
        uh = self._rows(u, b, self.m, "u", np.zeros(self.m))
        if u_bounds is None:
            lo, hi = np.full(self.m, -np.inf), np.full(self.m, np.inf)
        else:
            lo = np.broadcast_to(np.asarray(u_bounds[0], dtype=np.float64), (self.m,)).copy()
            hi = np.broadcast_to(np.asarray(u_bounds[1], dtype=np.float64), (self.m,)).copy()
            if np.any(lo > hi):
                raise ValueError("u_bounds: lower bound exceeds upper bound")
        p = self._params(params, b)
        k = self._gains(gains, b)
        if feedback != "open":
            self._law_states(s, single)
        out, u_out, flags = self._advance(s, p, uh, k, float(dt), int(substeps), feedback, lo, hi)
        return self._out(out, single), self._out(u_out, single), (flags[0] if single else flags)

    def _advance(self, s: Array, p: Array, u: Array, k: Array, dt: float, substeps: int, feedback: str,
                 lo: Array, hi: Array) -> tuple[Array, Array, NDArray[np.int64]]:
        """`step` on checked rows: ``(new states, applied forces, flags)``."""
        functions, tol = self.functions, self.singular_tol

        def make() -> Callable[..., Any]:
            def one(x: Any, q: Any, force: Any, g: Any, h: Any, lower: Any, upper: Any) -> Any:
                new, applied, singular = F.rk4_step_controlled(functions, x, q, force, h, substeps, feedback=feedback,
                                                               gains=g, lower=lower, upper=upper, singular_tol=tol)
                return new, applied, singular

            return one

        new, applied, singular = self._run(("step", feedback, substeps), make, (s, p, u, k), (dt, lo, hi))
        flags = np.where(singular, FLAG_SINGULAR, 0) | np.where(np.isfinite(new).all(axis=1), 0, FLAG_NONFINITE)
        return new, applied, flags.astype(np.int64)

    def __repr__(self) -> str:
        kind = "holonomic" if self.holonomic else "velocity"
        return f"ConstrainedSystem({self.name!r}, n={self.n}, m={self.m}, {kind} constraint)"
