"""The hysteresis-law contract: everything the estimation engine and the controllers need.

A law is the h in F = k·x + c0 + h (+ effect terms).  Each law is one small class (one
file in this folder) that owns all knowledge about itself, in the spirit of lmfit's
``Model.guess()`` and PySINDy's feature-library base class:

* ``params``: its parameters with start values, bounds, units and meaning;
* ``default_fixed`` / ``default_fixed_why``: parameters held by default (a known
  degeneracy), and why — the user frees them with ``--free NAME``;
* ``collinear_fixes``: parameters the fitter may fix when they are collinear with another
  on a run (value to fix at), accepted only when that costs < 1 % of nrmse;
* ``scale_param`` and :meth:`shape_grid`: the start search.  With the state at zero and
  the shape fixed, h is affine and positively homogeneous in one scale parameter
  (h(c·s) − h(0) = c·(h(s) − h(0)) for c ≥ 0), so the fitter scans the shape on a small
  grid sized from the stroke and solves (k, c0, scale) by linear least squares at every
  point, one sign of the scale at a time (variable projection); :meth:`scale_valid` says
  when that holds;
* :meth:`guess`: start values from the measured loop (lmfit's ``guess``), sized around
  any parameters the fit holds fixed;
* ``shared_shape``: parameters that describe the material, not the pressure (an element's
  slip displacement): the campaign holds them at one reference run's values on every run,
  so the other parameters' pressure laws compare like with like (see
  :func:`pmalab.identify.campaign.fit.fit_campaign`), and the joint fit refines them as
  constants;
* ``state_params``: the internal state at the first sample (h0) — a property of the
  record, never of the muscle;
* :meth:`h` (a whole trajectory) and :meth:`step` (one sample, for controllers that run
  the law forward): the SAME integrator, one segment of position at a time; a law with an
  element state (``state_size`` > 1) steps that state, :meth:`initial_state` and
  :meth:`output` map it from and to h.

Units: x contraction in mm (positive = shorter), h in N.  A physical loop (tension higher
while the muscle is stretched, x falling) needs h > 0 while dx < 0.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from pmalab.registry import Registry


@dataclass(frozen=True)
class LawParam:
    """Default start value and bounds of a law parameter (units in ``unit``)."""

    name: str
    init: float
    lo: float
    hi: float
    unit: str
    doc: str


#: every law by the id users type (``--model``), in its declared order: a subclass that
#: sets ``name`` registers itself (one file in this folder is a new law)
LAWS: Registry[type[HysteresisLaw]] = Registry("model")


class HysteresisLaw:
    """Base class of a hysteresis law (subclass, set the class attributes, write the hooks)."""

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        if cls.__dict__.get("name") and not cls.__dict__.get("structure_of"):
            LAWS.register(cls.name, cls, title=cls.title or cls.name, order=cls.order)

    #: the id users type (``--model bouc-wen``)
    name: ClassVar[str] = ""
    #: parameters, in the order they are reported
    params: ClassVar[tuple[LawParam, ...]] = ()
    #: optional extra inputs effects may supply (e.g. asymmetric-hysteresis coefficients)
    extras: ClassVar[tuple[str, ...]] = ()
    #: parameters describing the record's start state (never a pressure law)
    state_params: ClassVar[tuple[str, ...]] = ("h0",)
    #: parameters held by default (a structural degeneracy) and their values
    default_fixed: ClassVar[dict[str, float]] = {}
    #: why each default fix is there (shown to the user once per identification)
    default_fixed_why: ClassVar[dict[str, str]] = {}
    #: (name, value) a fit may fix when the name is collinear with another parameter
    collinear_fixes: ClassVar[tuple[tuple[str, float], ...]] = ()
    #: the parameter h is linear in (state at zero, shape fixed); None: no such parameter
    scale_param: ClassVar[str | None] = None
    #: a one-line title for tables and reports
    title: ClassVar[str] = ""
    #: place in lists, tables and ``diagnose``'s scoring (lower first)
    order: ClassVar[float] = 100.0
    #: size of the internal state the stepper carries: 1 for a law whose state is h itself
    #: (Bouc-Wen, Duhem); n for laws of n elements (Prandtl-Ishlinskii, Maxwell-slip), whose
    #: stepper takes and returns the element state and :meth:`output` sums it to h
    state_size: ClassVar[int] = 1
    #: parameters the same at every pressure (a material property); with more than one
    #: they describe exchangeable elements and :meth:`canonical` orders them
    shared_shape: ClassVar[tuple[str, ...]] = ()
    #: pressure structures a campaign may choose for this law besides ``"free"`` (every
    #: parameter its own pressure law): ``"scaled"`` (one element profile, its magnitude a
    #: pressure law) and ``"scaled-thresholds"`` (the same, and every slip displacement
    #: times one pressure law) — see :mod:`pmalab.identify.laws.structures`; a law that
    #: offers them implements :meth:`elements`
    structures: ClassVar[tuple[str, ...]] = ()
    #: set on a law built by :mod:`~pmalab.identify.laws.structures` (the law it
    #: restructures): such a class is never registered as a law of its own
    structure_of: ClassVar[str] = ""

    # ------------------------------------------------------------------ start values
    def shape_grid(self, stroke_mm: float) -> list[dict[str, float]]:
        """Shape parameters of the start grid, sized from the stroke (mm)."""
        return [{}]

    def scale_valid(self, theta: Mapping[str, float]) -> bool:
        """True when h is positively homogeneous in :attr:`scale_param` at these shape parameters."""
        return self.scale_param is not None

    def guess(
        self,
        x: np.ndarray,
        force: np.ndarray,
        v: np.ndarray,
        fixed: Mapping[str, float] | None = None,
    ) -> dict[str, float]:
        """Start values of the law's parameters from a measured loop (x mm, force N, v mm/s).

        ``fixed``: parameters this fit holds (their values win over the guess; a law may
        size the others around them).  Default: the parameters' ``init`` values.  Laws
        override this with data-sized values (loop half-width from the branch offsets,
        memory length from the stroke).
        """
        return {p.name: p.init for p in self.params}

    def elements(self, theta: Mapping[str, float]) -> tuple[np.ndarray, np.ndarray]:
        """(stiffness k_i N/mm, slip displacement d_i mm) of the law's elasto-slide elements
        at ``theta`` — for laws that offer :attr:`structures`."""
        raise NotImplementedError(f"{self.name} has no elasto-slide elements")

    def element_names(self) -> tuple[tuple[str, ...], tuple[str, ...]]:
        """(stiffness parameter names, slip-displacement parameter names) of the elements;
        the second is empty when the slip displacements are fixed by the law."""
        raise NotImplementedError(f"{self.name} has no elasto-slide elements")

    def canonical(self, theta: Mapping[str, float]) -> dict[str, float]:
        """The same law with its exchangeable elements in a canonical order (identity for
        a law without elements): a campaign compares one element with the same element."""
        return dict(theta)

    # ------------------------------------------------------------------ evaluation
    def h(
        self, x: np.ndarray, theta: Mapping[str, float], extras: Mapping[str, float] | None = None
    ) -> np.ndarray:
        """h (N) at every sample of the position path ``x`` (mm); h[0] = theta['h0']."""
        raise NotImplementedError

    def stepper(
        self, theta: Mapping[str, float], extras: Mapping[str, float] | None = None
    ) -> Callable[[float, float, float], float]:
        """A fast ``step(h, x_prev, x) -> h`` with the parameters bound (for 500 Hz loops)."""
        raise NotImplementedError

    def initial_state(
        self, theta: Mapping[str, float], h0: float = 0.0, direction: float = 1.0
    ) -> Any:
        """The stepper's state at a record's start with hysteretic force ``h0`` (N) whose
        first motion is toward contraction (``direction`` +1) or stretch (−1) — the state
        :meth:`h` starts from."""
        return float(h0)

    def output(self, state: Any) -> float:
        """h (N) of a stepper state (the state itself for a scalar-state law)."""
        return float(state)

    def kernel(self) -> Callable[..., float] | None:
        """A numba-compiled ``seg(state, x_prev, x, prm) -> state`` for scalar-state laws,
        ``prm`` = the law's parameters in :attr:`params` order followed by :attr:`extras`
        — the same segment :meth:`h` integrates, for compiled loops (the forward model of
        :mod:`pmalab.identify.forward`).  None: the law has no compiled segment (its
        :meth:`stepper` is used instead, at Python speed)."""
        return None

    def step(
        self,
        h: float,
        x_prev: float,
        x: float,
        theta: Mapping[str, float],
        extras: Mapping[str, float] | None = None,
    ) -> float:
        """Advance the state h (N) along one position segment x_prev → x (mm).

        Exactly one segment of the integrator :meth:`h` uses, so running the law forward
        sample by sample reproduces the batch trajectory to round-off.
        """
        return self.stepper(theta, extras)(h, x_prev, x)

    def __repr__(self) -> str:
        return f"<law {self.name}>"
