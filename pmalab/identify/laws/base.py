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

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from pmalab.registry import Registry

if TYPE_CHECKING:
    from pmalab.identify.signals import Signals


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
    """Base class of a hysteresis law (subclass, set the class attributes, write the hooks).

    A law gives the hysteretic force h (N) of the model F = k·x + c0 + h along a path of the
    contraction x (mm, positive = shorter than nominal); F is the tension (N, positive
    pulls).  Friction makes the tension higher while the muscle is stretched (x falling)
    than while it contracts, so along a loop h is larger on the stretching branch: a law
    must reproduce the loop's direction, not only its width.  :meth:`h` integrates a whole
    path, :meth:`step` one segment of it (the same integrator, for 500 Hz loops and the
    forward model).
    """

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

    def cache_key(self) -> tuple:
        """What tells this law's fits of a record apart from another law's in a cache of
        fits: its name (a law built at run time under a name it shares with its base, a
        pressure structure's, adds what makes it another law).

        Returns
        -------
        tuple
            Hashable; equal only for laws whose fits of one record are interchangeable.
        """
        return (self.name,)

    # ------------------------------------------------------------------ start values
    def shape_grid(self, stroke_mm: float) -> list[dict[str, float]]:
        """The shape parameters of the fit's start grid, sized from the stroke.

        Parameters
        ----------
        stroke_mm
            The range of the contraction in the record, mm.

        Returns
        -------
        list of dict
            One start per entry (shape parameter → value); ``[{}]``: a single start.
        """
        return [{}]

    def scale_valid(self, theta: Mapping[str, float]) -> bool:
        """Whether h scales with :attr:`scale_param` at these shape parameters.

        Parameters
        ----------
        theta
            The law's parameters by name, in their units (:attr:`params`).

        Returns
        -------
        bool
            True when h is positively homogeneous in :attr:`scale_param` (h(c·θs) =
            c·h(θs)): the fit may then solve for it linearly.
        """
        return self.scale_param is not None

    def guess(
        self,
        x: np.ndarray,
        force: np.ndarray,
        v: np.ndarray,
        fixed: Mapping[str, float] | None = None,
    ) -> dict[str, float]:
        """Start values of the law's parameters from a measured loop.

        Default: the parameters' ``init`` values.  Laws override this with data-sized
        values (loop half-width from the branch offsets, memory length from the stroke).

        Parameters
        ----------
        x
            Contraction, mm (positive = shorter).
        force
            Tension, N (positive pulls).
        v
            Contraction rate, mm/s.
        fixed
            Parameters this fit holds: their values win over the guess, and a law may size
            the others around them.

        Returns
        -------
        dict of str to float
            A start value per parameter, in its unit.
        """
        return {p.name: p.init for p in self.params}

    def elements(self, theta: Mapping[str, float]) -> tuple[np.ndarray, np.ndarray]:
        """The law's elasto-slide elements (laws that offer :attr:`structures`).

        Parameters
        ----------
        theta
            The law's parameters by name, in their units (:attr:`params`).

        Returns
        -------
        tuple of (numpy.ndarray, numpy.ndarray)
            Each element's stiffness k_i (N/mm) and slip displacement d_i (mm).

        Raises
        ------
        NotImplementedError
            The law has no such elements.
        """
        raise NotImplementedError(f"{self.name} has no elasto-slide elements")

    def element_names(self) -> tuple[tuple[str, ...], tuple[str, ...]]:
        """The names of the elements' parameters.

        Returns
        -------
        tuple of (tuple of str, tuple of str)
            The stiffness parameters and the slip-displacement parameters (empty when the
            law fixes the slip displacements).

        Raises
        ------
        NotImplementedError
            The law has no elasto-slide elements.
        """
        raise NotImplementedError(f"{self.name} has no elasto-slide elements")

    def canonical(self, theta: Mapping[str, float]) -> dict[str, float]:
        """The same parameters with exchangeable elements in a canonical order.

        A campaign's pressure laws then compare one element with the same element.

        Parameters
        ----------
        theta
            The law's parameters by name, in their units (:attr:`params`).

        Returns
        -------
        dict of str to float
            The reordered parameters (a copy of ``theta`` for a law without elements).
        """
        return dict(theta)

    # ------------------------------------------------------------------ evaluation
    def drive_signals(self, sig: Signals) -> Signals:
        """The record's signals as a model with this law is driven by them: ``sig`` itself
        (its position ``x`` filtered in the 60× band); an elasto-slide law overrides it with
        its narrower band (:meth:`pmalab.identify.signals.Signals.slide_drive`).  The linear
        term k·x and the effects see the same position as the law.

        Parameters
        ----------
        sig
            The record's signals.

        Returns
        -------
        Signals
            The signals the model's force is computed from.
        """
        return sig

    def h(
        self, x: np.ndarray, theta: Mapping[str, float], extras: Mapping[str, float] | None = None
    ) -> np.ndarray:
        """The hysteretic force along a path of the contraction.

        Parameters
        ----------
        x
            The contraction at every sample, mm (positive = shorter); a filtered path, as
            the model drives the law (raw 500 Hz noise would bias rate-independent laws).
        theta
            The law's parameters by name, in their units (:attr:`params`).
            ``h0`` is the record's start state, N.
        extras
            Extra inputs effects supply (:attr:`extras`; ``None``: none).

        Returns
        -------
        numpy.ndarray
            h at every sample, N (adds to the tension); ``h[0] = theta["h0"]``.
        """
        raise NotImplementedError

    def h_many(
        self,
        x: np.ndarray,
        thetas: Sequence[Mapping[str, float]],
        extras: Mapping[str, float] | None = None,
    ) -> np.ndarray:
        """:meth:`h` along one path for several parameter sets (the estimator's
        finite-difference columns); row j is ``h(x, thetas[j], extras)``, the same numbers.

        A law whose :meth:`h` is a compiled loop overrides this with one compiled call for
        every row (the per-call overhead is most of the cost on short records).

        Parameters
        ----------
        x
            The contraction at every sample, mm.
        thetas
            Parameter sets, each as :meth:`h` takes it.
        extras
            Extra inputs effects supply (the same for every row).

        Returns
        -------
        numpy.ndarray
            Shape (len(thetas), len(x)), N.
        """
        out = np.empty((len(thetas), np.shape(x)[0]))
        for j, th in enumerate(thetas):
            out[j] = self.h(x, th, extras)
        return out

    def load_compiled(self) -> None:
        """Load this law's compiled code into this process now: :meth:`h` and
        :meth:`h_many` evaluated at the parameters' start values (the law's default fixes
        held) on a short path of the type a fit passes (float64, contiguous), so numba loads
        the machine code a fit uses from its cache, or compiles and caches it once.

        A process that then forks worker processes hands the code to them: without this
        every worker compiled the same kernels side by side on a new numba cache (a fresh
        install's first diagnosis: ~2.5 CPU-s once more), or loaded them each from the
        cache.  Best effort: a law that cannot evaluate here raises nothing (its fits
        report their own errors).
        """
        x = np.linspace(0.0, 1.0, 16)
        theta = {p.name: float(p.init) for p in self.params}
        theta.update({k: float(v) for k, v in self.default_fixed.items() if v is not None})
        try:
            self.h(x, theta)
            self.h_many(x, [theta, theta])
        except Exception:  # a warm-up only: the fits say what is wrong
            pass

    def stepper(
        self, theta: Mapping[str, float], extras: Mapping[str, float] | None = None
    ) -> Callable[[float, float, float], float]:
        """A fast one-segment step with the parameters bound (for 500 Hz loops).

        Parameters
        ----------
        theta
            The law's parameters by name, in their units (:attr:`params`).
        extras
            Extra inputs effects supply (:attr:`extras`; ``None``: none).

        Returns
        -------
        callable
            ``step(state, x_prev, x) -> state``: the state advanced along the segment
            x_prev → x (mm); :meth:`output` gives its h (N).
        """
        raise NotImplementedError

    def initial_state(
        self, theta: Mapping[str, float], h0: float = 0.0, direction: float = 1.0
    ) -> Any:
        """The stepper's state at a record's start (the state :meth:`h` starts from).

        Parameters
        ----------
        theta
            The law's parameters by name, in their units (:attr:`params`).
        h0
            The hysteretic force at the start, N.
        direction
            The first motion: +1 toward contraction, −1 toward stretch.

        Returns
        -------
        object
            The state (a float h for a scalar-state law).
        """
        return float(h0)

    def output(self, state: Any) -> float:
        """The hysteretic force of a stepper state.

        Parameters
        ----------
        state
            A state of :meth:`stepper` or :meth:`initial_state`.

        Returns
        -------
        float
            h, N (the state itself for a scalar-state law).
        """
        return float(state)

    def kernel(self) -> Callable[..., float] | None:
        """The compiled segment, for compiled loops (the forward model of
        :mod:`pmalab.identify.forward`).

        Returns
        -------
        callable or None
            A numba-compiled ``seg(state, x_prev, x, prm) -> state`` for a scalar-state
            law (x in mm, state h in N), ``prm`` = the law's parameters in :attr:`params`
            order followed by :attr:`extras`: the same segment :meth:`h` integrates.
            ``None``: no compiled segment (:meth:`stepper` is used, at Python speed).
        """
        return None

    def step(
        self,
        h: float,
        x_prev: float,
        x: float,
        theta: Mapping[str, float],
        extras: Mapping[str, float] | None = None,
    ) -> float:
        """Advance the state along one segment of the contraction.

        Exactly one segment of the integrator :meth:`h` uses, so running the law forward
        sample by sample reproduces the batch trajectory to round-off.

        Parameters
        ----------
        h
            The state before the segment, N.
        x_prev, x
            The contraction at the segment's start and end, mm (positive = shorter).
        theta
            The law's parameters by name, in their units (:attr:`params`).
        extras
            Extra inputs effects supply (:attr:`extras`; ``None``: none).

        Returns
        -------
        float
            The state after the segment, N.
        """
        return self.stepper(theta, extras)(h, x_prev, x)

    def __repr__(self) -> str:
        return f"<law {self.name}>"
