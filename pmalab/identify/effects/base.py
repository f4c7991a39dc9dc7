"""The effect base class: one small class per physical effect the base model lacks.

In the spirit of PySINDy's feature library: adding an effect is writing one small class.
An effect can do any of three things to the base law F = k·x + c0 + h:

* ``transform`` the signals before the law sees them (e.g. a sensor delay shifts the
  position channel in time);
* supply ``law_extras`` that change the hysteresis law itself (e.g. asymmetric Bouc-Wen
  coefficients; see :mod:`pmalab.identify.laws` for the extras each law accepts);
* add a ``force`` term in N (e.g. viscous friction −c·ẋ, inertia, drift).

Each effect states its physics (``explanation``) and the residual pattern that points to it
(``signature``), which diagnosis shows to the user next to the ranking.

Record nuisance parameters.  Some effects describe the *record* (the sensor, the start of
one run), not the muscle: a load-cell zero that drifts over a campaign differs from run to
run by the drift accumulated since switch-on, whatever the pressure.  Such an effect lists
those parameters in ``nuisance_params``: the campaign fit then gives them one value per run
in the joint refinement of the pressure laws (like the start state h0, never a pressure law
θ(p)), and a prediction of *another* run sets them to 0.  ``tare = True`` says the record's
force zero is unknown: a validation prediction with ``initial="estimate"`` then also
estimates the run's force offset with its other record parameters, on the early part of
the record (:mod:`pmalab.identify.estimation.records`).

User effects: put subclasses in a Python file and pass ``--effects my_effects.py``; every
``Effect`` subclass with an ``id`` found there is registered.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import ClassVar

import numpy as np

from pmalab.errors import PmalabError
from pmalab.identify.params import Param
from pmalab.identify.signals import Signals
from pmalab.registry import Registry


class EffectError(PmalabError):
    """An unknown effect id or a broken user effects file."""


#: the catalogue, id -> class, in the effects' declared order: a subclass in this package
#: that sets ``id`` registers itself (one file is a new effect); user files loaded with
#: :func:`pmalab.identify.effects.load_user_effects` follow
EFFECTS: Registry[type[Effect]] = Registry("effect", EffectError)


class Effect:
    """A pluggable physical effect (subclass and set the class attributes).

    An effect acts on the model F = k·x + c0 + h in up to three ways: it changes the
    signals the law and the force terms see (:meth:`transform`: a channel delay, a pressure
    that moves), it gives the law extra inputs (:meth:`law_extras`), and it adds a force
    term (:meth:`force`: viscous friction −c·ẋ, inertia, a drifting zero).  Signs follow the
    model: F is the tension in N (positive pulls), x the contraction in mm (positive =
    shorter), so a force term that raises the tension while the muscle is stretched
    (ẋ < 0) is positive there.  The class attributes below say what the diagnosis and the
    forward model need to know.
    """

    def __init_subclass__(cls, **kwargs) -> None:
        super().__init_subclass__(**kwargs)
        if cls.__dict__.get("id") and cls.__module__.startswith("pmalab.identify.effects."):
            EFFECTS.register(cls.id, cls, title=cls.title, order=cls.order)

    #: the id users type (``--add viscous-friction``); docs/explanation/physics.md lists the built-in ids
    id: ClassVar[str] = ""
    #: one-line title
    title: ClassVar[str] = ""
    #: place in the catalogue's lists (lower first)
    order: ClassVar[float] = 100.0
    #: the physics in two or three sentences
    explanation: ClassVar[str] = ""
    #: the residual signature that points to this effect
    signature: ClassVar[str] = ""
    #: the experiment that would tell this effect apart from look-alikes (diagnosis shows it
    #: when the ranking is ambiguous)
    experiment: ClassVar[str] = ""
    #: True when the effect's force grows with the rate of motion (velocity, acceleration,
    #: a time shift): identification runs all at ONE frequency cannot tell such effects
    #: from each other (nor from the loop's width), so diagnosis calls two of them that are
    #: both significant ambiguous there, whatever their falls
    rate_dependent: ClassVar[bool] = False
    #: the parameter values at which the effect's force vanishes (the model without the
    #: effect), or None.  Diagnosis removes the effect's term from an identified model with
    #: them — every other parameter as identified — to see how much of a held-out fall the
    #: effect's own force carries (docs/explanation/significance.md, "The fall must be the
    #: effect's own"); an effect without them is judged by its fall alone
    absent: ClassVar[dict[str, float] | None] = None

    #: parameters of this effect that belong to one record (one value per run in the joint
    #: pressure-law fit; 0 when another run is predicted) — see the module docstring
    nuisance_params: ClassVar[tuple[str, ...]] = ()
    #: True when the record's force zero is unknown (a drifting sensor): predicting another
    #: run with ``initial="estimate"`` tares the force on its first ~50 ms
    tare: ClassVar[bool] = False

    #: multi-start values of parameters whose cost is multi-modal (e.g. a channel delay: a
    #: local minimum wherever a shift lines up one feature of the loop); the fitter tries
    #: each value as a start and keeps the best
    multistart: ClassVar[dict[str, tuple[float, ...]]] = {}
    #: parameters that describe the rig, not the muscle (e.g. a channel skew): one value for
    #: every run of a campaign (pressure order 0 in the joint fit)
    campaign_shared: ClassVar[tuple[str, ...]] = ()
    #: where a run's pressure for the pressure laws θ(p) comes from: ``"nominal"`` (its label)
    #: or ``"measured"`` (its measured mean; an effect saying so makes every run of the
    #: identification and of its validation use it, as ``--pressure measured`` does)
    pressure_source: ClassVar[str] = "nominal"

    #: the effect in the forward (plant) model of :mod:`pmalab.identify.forward`: which term
    #: of its force law each parameter is — ``mass`` (kg: the load cell reads F − m·ẍ),
    #: ``damping`` (N·s/mm: −c·ẋ), ``k2``/``k3`` (+k2·x² + k3·x³), ``p0``/``p1``
    #: ((p0 + p1·x)·(p − p_nom)), ``hx`` (h·hx·x); law extras come from :meth:`law_extras`.
    #: None: the effect has no forward form (a sensor delay, a drifting zero) and a forward
    #: simulation refuses it by name
    plant: ClassVar[dict[str, str] | None] = None

    def params(self, sig: Signals, force_scale: float) -> list[Param]:
        """The effect's parameters, with start values and bounds sized from the data.

        Parameters
        ----------
        sig
            The run's inputs (:class:`~pmalab.identify.signals.Signals`: time s, filtered
            contraction x mm, its rates mm/s and mm/s², pressure MPa).
        force_scale
            The standard deviation of the measured force, N, to size bounds with.

        Returns
        -------
        list of Param
            Name (unique across effects: prefix them, ``visc_c``), start, bounds and unit
            of each parameter.
        """
        return []

    def transform(self, sig: Signals, theta: Mapping[str, float]) -> Signals:
        """The signals the hysteresis law and the force terms see.

        Parameters
        ----------
        sig
            The run's inputs (:class:`~pmalab.identify.signals.Signals`: time s, filtered
            contraction x mm, its rates mm/s and mm/s², pressure MPa).
        theta
            Every parameter of the model by name (the law's, k, c0 and the effects'), in
            its own unit.

        Returns
        -------
        Signals
            The signals as the effect changes them (a shifted channel, a varying
            pressure); the default returns ``sig`` unchanged.
        """
        return sig

    def law_extras(
        self, law_name: str, sig: Signals, theta: Mapping[str, float]
    ) -> dict[str, float]:
        """Extra inputs for the hysteresis law.

        Parameters
        ----------
        law_name
            The law in force (``bouc-wen``, ``duhem``, ...): an effect may feed laws
            differently.
        sig
            The run's inputs (:class:`~pmalab.identify.signals.Signals`: time s, filtered
            contraction x mm, its rates mm/s and mm/s², pressure MPa).
        theta
            Every parameter of the model by name (the law's, k, c0 and the effects'), in
            its own unit.

        Returns
        -------
        dict of str to float
            Named inputs the law's step reads (e.g. an asymmetry factor); default none.
        """
        return {}

    def force(self, sig: Signals, h: np.ndarray, theta: Mapping[str, float]) -> np.ndarray | float:
        """The effect's additive force term.

        Parameters
        ----------
        sig
            The run's inputs (:class:`~pmalab.identify.signals.Signals`: time s, filtered
            contraction x mm, its rates mm/s and mm/s², pressure MPa).
        h
            The hysteresis law's state per sample, N.
        theta
            Every parameter of the model by name (the law's, k, c0 and the effects'), in
            its own unit.

        Returns
        -------
        numpy.ndarray or float
            The term added to the tension, N, per sample (or one value); positive raises
            the tension.  Default 0.
        """
        return 0.0

    def fixed_for_law(self, law_name: str) -> tuple[str, ...]:
        """This effect's parameters that a law does not use.

        Parameters
        ----------
        law_name
            The law in force.

        Returns
        -------
        tuple of str
            Names held fixed at their start value when this law is fitted; default none.
        """
        return ()

    def __repr__(self) -> str:
        return f"<effect {self.id}>"
