"""Force laws of the state: F = k·x + c0 + h(x; law) + Σ effect terms.

A :class:`ForceModel` composes a hysteresis law (Bouc-Wen or Duhem) with any number of
:class:`~pmalab.identify.effects.base.Effect` s.  It is written as a law of the state (x, ẋ,
ẍ, p, internal h) evaluated along a trajectory, not as a fitting script, so the same object
predicts force from a measured position (identification, validation) and can be inverted
for controllers later.

Units: x contraction in mm, F tension in N, k in N/mm (negative: tension falls as
contraction grows), c0 in N (tension at x = 0 without hysteresis).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from pmalab.identify.effects.base import Effect
from pmalab.identify.laws import HysteresisLaw, get_law
from pmalab.identify.params import Param, Params
from pmalab.identify.signals import Signals


class ForceModel:
    """The base law plus effects; ``predict(sig, theta)`` gives the force in N."""

    def __init__(self, law: HysteresisLaw | str, effects: Sequence[Effect] = ()) -> None:
        self.law = get_law(law) if isinstance(law, str) else law
        self.effects = list(effects)
        ids = [e.id for e in self.effects]
        if len(set(ids)) != len(ids):
            raise ValueError(f"effect added twice: {ids}")

    # ------------------------------------------------------------------ declared roles
    @property
    def state_params(self) -> tuple[str, ...]:
        """The law's start-state parameters (h0): properties of a record, not the muscle."""
        return tuple(self.law.state_params)

    @property
    def record_params(self) -> tuple[str, ...]:
        """Parameters that belong to one record: the law's start state and the effects'
        ``nuisance_params`` (e.g. a drift rate)."""
        out = list(self.state_params)
        for e in self.effects:
            out += [n for n in e.nuisance_params if n not in out]
        return tuple(out)

    @property
    def tares(self) -> bool:
        """True when an effect says the record's force zero is unknown (``Effect.tare``)."""
        return any(e.tare for e in self.effects)

    @property
    def measured_pressure(self) -> bool:
        """True when an effect takes each run's pressure from its measured mean instead of its
        label (``Effect.pressure_source``)."""
        return any(e.pressure_source == "measured" for e in self.effects)

    @property
    def campaign_shared(self) -> tuple[str, ...]:
        """Parameters with one value for a whole campaign (a rig property)."""
        return tuple(n for e in self.effects for n in e.campaign_shared)

    @property
    def multistart(self) -> dict[str, tuple[float, ...]]:
        """Multi-start grids of the effects' multi-modal parameters."""
        out: dict[str, tuple[float, ...]] = {}
        for e in self.effects:
            out.update(e.multistart)
        return out

    def held_fixed(self) -> dict[str, float | None]:
        """Parameters held by default: the law's degeneracy fixes (value) and effect
        parameters the law does not use (None: held at their start value)."""
        out: dict[str, float | None] = dict(self.law.default_fixed)
        for e in self.effects:
            out.update(dict.fromkeys(e.fixed_for_law(self.law.name)))
        return out

    @property
    def name(self) -> str:
        return "+".join([self.law.name, *[e.id for e in self.effects]])

    def params(self, sig: Signals, force: np.ndarray | None = None) -> Params:
        """Parameters with data-sized start values (refined by the fitter's initial guess)."""
        scale = float(np.std(force)) if force is not None else 100.0
        ps = Params(
            [
                Param(
                    "k",
                    -30.0,
                    -1e4,
                    1e4,
                    "N/mm",
                    doc="linear stiffness (tension per mm of contraction)",
                ),
                Param(
                    "c0",
                    float(np.mean(force)) if force is not None else 0.0,
                    -1e5,
                    1e5,
                    "N",
                    doc="tension offset at zero contraction",
                ),
            ]
        )
        for lp in self.law.params:
            ps.add(Param(lp.name, lp.init, lp.lo, lp.hi, lp.unit, doc=lp.doc))
        for e in self.effects:
            for p in e.params(sig, scale):
                ps.add(p)
        return ps

    @property
    def predicts_by_parts(self) -> bool:
        """Whether :meth:`predict` is this class's parts and assembly (:meth:`drive`,
        :meth:`parts`, :meth:`assemble`, :meth:`assemble_many` as written here): a subclass
        that overrides any of them (a user's own force law) is predicted only through its
        :meth:`predict`, and the fitters neither reuse parts nor assume the linear term's
        derivatives for it (correct, if slower)."""
        cls = type(self)
        return all(
            getattr(cls, m) is getattr(ForceModel, m)
            for m in ("predict", "parts", "assemble", "assemble_many", "drive")
        )

    def unchanged_parts(self, sig: Signals) -> dict[str, str]:
        """Parameters whose change leaves parts of :meth:`parts` as they were.

        ``"law"``: the drive, the law's extras and the linear term stay (a parameter of the
        law: only h and the effect terms change); ``"terms"``: h stays too (a parameter of an
        effect that neither transforms the signals nor feeds the law: only the effect terms
        change).  A parameter not listed may change anything.  Only the built-in law and
        effects are known to read nothing but their own parameters in
        :meth:`Effect.transform` and :meth:`Effect.law_extras`, so a model with a user law or
        effect lists nothing; nor does a subclass with its own prediction
        (:attr:`predicts_by_parts`).

        Parameters
        ----------
        sig
            A run's inputs (only used to list the effects' parameter names).

        Returns
        -------
        dict of str to str
            Parameter name to ``"law"`` or ``"terms"``.
        """
        parts = (self.law, *self.effects)
        if not self.predicts_by_parts:
            return {}
        if not all(type(o).__module__.startswith("pmalab.identify.") for o in parts):
            return {}
        out = {lp.name: "law" for lp in self.law.params}
        for e in self.effects:
            if type(e).transform is Effect.transform and type(e).law_extras is Effect.law_extras:
                out.update({p.name: "terms" for p in e.params(sig, 1.0)})
        return out

    def drive(self, sig: Signals, theta: Mapping[str, float]) -> Signals:
        """The signals the law and the force terms see (after the effects' transforms,
        e.g. a channel delay); ∂F/∂k is this drive's position.  The law chooses the position
        band first (:meth:`~pmalab.identify.laws.base.HysteresisLaw.drive_signals`)."""
        s = self.law.drive_signals(sig)
        for e in self.effects:
            s = e.transform(s, theta)
        return s

    def components(self, sig: Signals, theta: Mapping[str, float]) -> dict[str, np.ndarray]:
        """Each additive part of the force (N): ``linear``, ``hysteresis``, one per effect."""
        s = self.drive(sig, theta)
        extras: dict[str, float] = {}
        for e in self.effects:
            extras.update(e.law_extras(self.law.name, s, theta))
        h = self.law.h(s.x, theta, extras)
        out = {"linear": theta["k"] * s.x + theta["c0"], "hysteresis": h}
        for e in self.effects:
            term = e.force(s, h, theta)
            if np.ndim(term) or term != 0.0:
                out[e.id] = np.broadcast_to(np.asarray(term, dtype=np.float64), s.t.shape)
        return out

    def parts(
        self, sig: Signals, theta: Mapping[str, float]
    ) -> tuple[Signals, dict[str, float], np.ndarray, np.ndarray]:
        """The pieces :meth:`predict` adds up: the drive signals, the law's extras, the
        linear term k·x + c0 (N) and the hysteretic force h (N).

        Parameters
        ----------
        sig
            The run's inputs (time s, filtered contraction x mm, its rates, pressure MPa).
        theta
            Every parameter of the model by name, in its own unit.

        Returns
        -------
        tuple
            ``(drive, extras, linear, h)``; :meth:`assemble` turns them into the force.
        """
        s = self.drive(sig, theta)
        extras: dict[str, float] = {}
        for e in self.effects:
            extras.update(e.law_extras(self.law.name, s, theta))
        h = np.asarray(self.law.h(s.x, theta, extras), dtype=np.float64)
        lin = np.asarray(theta["k"] * s.x + theta["c0"], dtype=np.float64)
        return s, extras, lin, h

    def assemble(
        self, s: Signals, lin: np.ndarray, h: np.ndarray, theta: Mapping[str, float]
    ) -> np.ndarray:
        """The force (N) from :meth:`parts`: linear + hysteresis, then each effect's term
        at ``theta`` (added in that order; ``lin`` and ``h`` are not modified).

        Parameters
        ----------
        s
            The drive signals (:meth:`drive` at ``theta``).
        lin
            k·x + c0 along ``s`` (N).
        h
            The law's hysteretic force along ``s`` (N).
        theta
            Every parameter of the model by name.

        Returns
        -------
        numpy.ndarray
            The predicted tension per sample, N.
        """
        out = lin + h
        for e in self.effects:
            term = e.force(s, h, theta)
            if np.ndim(term) or term != 0.0:
                out = _added(out, np.asarray(term, dtype=np.float64))
        return np.broadcast_to(out, s.t.shape).copy() if out.shape != s.t.shape else out

    def assemble_many(
        self, s: Signals, lin: np.ndarray, H: np.ndarray, theta: Mapping[str, float]
    ) -> np.ndarray:
        """:meth:`assemble` for several hysteretic forces at once (rows of ``H``), every
        effect's term at ``theta`` evaluated once for all rows (the built-in terms broadcast
        over them): row j is ``assemble(s, lin, H[j], theta)``, the same numbers.

        Parameters
        ----------
        s
            The drive signals.
        lin
            k·x + c0 along ``s`` (N).
        H
            Hysteretic forces, shape (rows, samples), N.
        theta
            Every parameter of the model by name.

        Returns
        -------
        numpy.ndarray
            The predicted tension, shape (rows, samples), N.
        """
        out = lin + H
        for e in self.effects:
            term = e.force(s, H, theta)
            if np.ndim(term) or term != 0.0:
                out = _added(out, np.asarray(term, dtype=np.float64))
        return out

    def predict(self, sig: Signals, theta: Mapping[str, float]) -> np.ndarray:
        """Free-run force prediction (N) along the run: the sum of :meth:`components`.

        The fitters call this hundreds of thousands of times on short records, so the parts
        are added in place of being collected: the same additions in the same order
        (linear, hysteresis, each effect's term), hence the same numbers bit for bit, without
        the dict, the broadcast views and the stacked array."""
        s, _, lin, h = self.parts(sig, theta)
        return self.assemble(s, lin, h, theta)

    def __repr__(self) -> str:
        return f"ForceModel({self.name})"


def _added(out: np.ndarray, term: np.ndarray) -> np.ndarray:
    """``out + term``, written into ``out`` (a new array of the caller's own) where the sum
    has its shape: the same additions, element by element, without a new array per term."""
    if isinstance(out, np.ndarray) and out.shape[out.ndim - term.ndim :] == term.shape:
        return np.add(out, term, out=out)
    return out + term
