"""Pressure structures of an element law: how its elements may change with pressure.

An element law (Prandtl-Ishlinskii, Maxwell-slip) is a sum of elasto-slide elements, element
i with stiffness k_i (N/mm) and slip displacement d_i (mm).  How those change with the muscle
pressure p is a property of the muscle, not of the law, so a campaign chooses among
candidate *structures* by held-out evidence across pressure
(:mod:`pmalab.identify.campaign.structure`):

* ``"free"`` — every parameter its own pressure law (orders 0–2 chosen by the joint fit):
  the law's own file, nothing assumed, most parameters (Prandtl-Ishlinskii: 15 weights);
* ``"scaled"`` — one element profile κ_i (Σκ_i = 1) and slip displacements δ_i, the same at
  every pressure; only the magnitude s(p) changes:  k_i(p) = s(p)·κ_i,  d_i = δ_i.  Friction
  and element stiffness scale alike (the picture of a braid whose contacts all press harder);
* ``"scaled-thresholds"`` — the same, and every slip displacement scales with one pressure
  law t(p):  d_i(p) = t(p)·δ_i (slip forces rise faster than stiffnesses when t grows).

The structured law (:func:`structured_law`) has two or three parameters — ``s``, ``t`` and
the start state ``h0`` — and runs through the one estimation engine like any law.  Its
profile (κ, δ) is taken from the free structure's pressure laws over the campaign's runs
(:func:`profile`), so it pools every run.  Its pressure laws map back onto the base law's
parameters exactly (:func:`base_laws`: k_i's coefficients are κ_i times s's, d_i's δ_i times
t's), so the model a campaign reports is always the base law's, whatever structure won.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any, ClassVar

import numpy as np

from pmalab.identify.laws._slide import (
    column,
    nonneg,
    slide_h_rows,
)
from pmalab.identify.laws.base import HysteresisLaw, LawParam
from pmalab.identify.laws.element_sum import ElementSum

#: every structure a law may offer, in order of decreasing parameter count
ALL_STRUCTURES = ("free", "scaled-thresholds", "scaled")
#: the threshold-scale grid of the start search (dimensionless)
T_GRID = (0.35, 0.5, 0.7, 1.0, 1.4, 2.0, 2.8)


class ProfileElements(ElementSum):
    """Elements of one profile: k_i = s·κ_i·c_i, d_i = t·δ_i·r_i (see module doc).

    (κ, δ) is the start profile the law is built with; the corrections c_i (stiffness shares)
    and r_i (slip displacements) are its ``shared_shape`` — the same at every pressure, held
    at 1 on every run and refined jointly on all runs as constants.  The element with the
    largest share is the anchor (c = 1, and r = 1 where t scales the slip displacements), so
    s and t are not collinear with the corrections.  Not registered as a law:
    :func:`structured_law` builds one per campaign with the base law's ``name`` (effects that
    know a law by name treat it as the base law)."""

    structure_of = "elements"
    params = (
        LawParam("s", 10.0, 0.0, 1e5, "N/mm", "element stiffness magnitude"),
        LawParam("t", 1.0, 0.1, 10.0, "1", "slip-displacement scale: d_i = t·δ_i·r_i"),
        LawParam("h0", 0.0, -1e4, 1e4, "N", "initial hysteretic force"),
    )
    scale_param = "s"
    #: the structure's id
    structure: ClassVar[str] = "scaled"
    #: element indices with a stiffness / slip-displacement correction parameter
    c_index: ClassVar[tuple[int, ...]] = ()
    r_index: ClassVar[tuple[int, ...]] = ()

    def __init__(
        self, kappa: Sequence[float] | np.ndarray, delta: Sequence[float] | np.ndarray
    ) -> None:
        k = np.clip(np.asarray(kappa, dtype=np.float64), 0.0, None)
        tot = float(k.sum())
        #: element shares κ_i (Σ = 1) of the start profile
        self.kappa = k / tot if tot > 0 else np.full(k.size, 1.0 / max(k.size, 1))
        #: slip displacements δ_i (mm) of the start profile at t = 1
        self.delta = np.asarray(delta, dtype=np.float64)

    #: the law restructured (set by :func:`structured_law`; what a copy is rebuilt from)
    base: HysteresisLaw | None = None

    def __reduce__(self) -> tuple:
        # the class is built at run time (:func:`structured_law`), so a copy sent to a worker
        # process is rebuilt the same way: from the base law, the structure and the profile
        if self.base is None:
            raise TypeError(f"{type(self).__name__} was not built by structured_law()")
        return (_rebuilt, (self.base, self.structure, self.kappa, self.delta))

    def cache_key(self) -> tuple:
        # the base law's name is shared: the structure and its profile make it another law
        return (self.name, self.structure, self.kappa.tobytes(), self.delta.tobytes())

    def corrections(self, theta: Mapping[str, float]) -> tuple[np.ndarray, np.ndarray]:
        """(c_i, r_i) at ``theta`` (1 for an element without a correction parameter)."""
        m = int(np.size(self.kappa))
        c = np.ones(m)
        r = np.ones(m)
        for i in self.c_index:
            c[i] = max(float(theta[f"c{i + 1}"]), 0.0)
        for i in self.r_index:
            r[i] = max(float(theta[f"r{i + 1}"]), 0.0)
        return c, r

    def _kd(self, theta: Mapping[str, float]) -> tuple[np.ndarray, np.ndarray]:
        c, r = self.corrections(theta)
        k = max(float(theta["s"]), 0.0) * self.kappa * c
        return k, self.delta * r * max(float(theta.get("t", 1.0)), 0.0)

    def _kf(self, theta: Mapping[str, float]) -> tuple[np.ndarray, np.ndarray]:
        k, d = self._kd(theta)
        return k, k * d

    def shape_grid(self, stroke_mm: float) -> list[dict[str, float]]:
        if "t" in self.default_fixed:
            return [{}]
        return [{"t": t} for t in T_GRID]

    def guess(self, x, force, v, fixed=None) -> dict[str, float]:
        out = {p.name: p.init for p in self.params}
        out.update({k: float(v) for k, v in (fixed or {}).items() if v is not None})
        return out

    def h_many(self, x, thetas, extras=None):
        # every row's _kd at once: k = (max(s, 0)·κ)·c, d = (δ·r)·max(t, 0), f = k·d,
        # the same operations as _kd's, elementwise
        m, n = int(np.size(self.kappa)), len(thetas)
        C = np.ones((n, m))
        Rr = np.ones((n, m))
        if self.c_index:
            C[:, list(self.c_index)] = nonneg(column(thetas, [f"c{i + 1}" for i in self.c_index]))
        if self.r_index:
            Rr[:, list(self.r_index)] = nonneg(column(thetas, [f"r{i + 1}" for i in self.r_index]))
        S = nonneg(column(thetas, ["s"]))
        T = nonneg(np.array([[float(th.get("t", 1.0))] for th in thetas]).reshape(n, 1))
        K = S * self.kappa[None, :] * C
        return slide_h_rows(x, K, K * (self.delta[None, :] * Rr * T), thetas)

    def elements(self, theta: Mapping[str, float]) -> tuple[np.ndarray, np.ndarray]:
        return self._kd(theta)


def structured_law(
    base: HysteresisLaw,
    structure: str,
    kappa: Sequence[float] | np.ndarray,
    delta: Sequence[float] | np.ndarray,
) -> ProfileElements:
    """The law ``base`` restructured: ``"scaled"`` or ``"scaled-thresholds"`` elements
    starting from the profile (κ, δ) (κ is normalised; δ in mm)."""
    if structure not in base.structures:
        raise ValueError(f"{base.name} offers no pressure structure {structure!r}")
    m = len(kappa)
    anchor = int(np.argmax(np.asarray(kappa, dtype=np.float64)))
    c_index = tuple(i for i in range(m) if i != anchor and float(kappa[i]) > 0.0)
    _, d_names = base.element_names()
    if not d_names:  # slip displacements fixed by the law (Prandtl-Ishlinskii's grid)
        r_index: tuple[int, ...] = ()
    elif structure == "scaled":  # an element of zero share has no slip displacement to fit
        r_index = tuple(i for i in range(m) if float(kappa[i]) > 0.0)
    else:
        r_index = tuple(i for i in range(m) if i != anchor and float(kappa[i]) > 0.0)
    shape = (
        *(
            LawParam(
                f"c{i + 1}", 1.0, 0.0, 100.0, "1", f"stiffness share of element {i + 1} ÷ its start"
            )
            for i in c_index
        ),
        *(
            LawParam(
                f"r{i + 1}",
                1.0,
                0.02,
                50.0,
                "1",
                f"slip displacement of element {i + 1} ÷ its start",
            )
            for i in r_index
        ),
    )
    attrs: dict[str, Any] = {
        "name": base.name,
        "title": f"{base.title or base.name} ({structure})",
        "structure_of": base.name,
        "structure": structure,
        "order": base.order,
        "state_size": m,
        "params": (*ProfileElements.params[:2], *shape, ProfileElements.params[2]),
        "shared_shape": tuple(p.name for p in shape),
        "c_index": c_index,
        "r_index": r_index,
        "default_fixed": {"t": 1.0} if structure == "scaled" else {},
        "default_fixed_why": (
            {"t": "the 'scaled' structure holds the slip displacements the same at every pressure"}
            if structure == "scaled"
            else {}
        ),
    }
    cls = type(
        f"{type(base).__name__}{structure.title().replace('-', '')}", (ProfileElements,), attrs
    )
    law = cls(kappa, delta)
    law.base = base
    return law


def _rebuilt(
    base: HysteresisLaw, structure: str, kappa: np.ndarray, delta: np.ndarray
) -> ProfileElements:
    """A pickled structured law, rebuilt bit for bit: its shares as they were (normalising
    them again could move their last bit, and a worker's fit would then differ from this
    process's)."""
    law = structured_law(base, structure, kappa, delta)
    law.kappa = np.array(kappa, dtype=np.float64)
    return law


def profile(
    base: HysteresisLaw, thetas: Sequence[Mapping[str, float]]
) -> tuple[np.ndarray, np.ndarray]:
    """(κ, δ) pooled over a campaign's parameter sets ``thetas`` (one per run, from the free
    structure's pressure laws): κ_i = Σ_r k_ri / Σ_r Σ_j k_rj (the runs' summed stiffness
    shares, so stiffer runs count more), δ_i the stiffness-weighted mean slip displacement."""
    ks, ds = zip(*(base.elements(th) for th in thetas))
    K = np.asarray(ks, dtype=np.float64)
    D = np.asarray(ds, dtype=np.float64)
    tot = K.sum(axis=0)
    delta = np.where(tot > 0, (K * D).sum(axis=0) / np.where(tot > 0, tot, 1.0), D.mean(axis=0))
    return tot / max(float(tot.sum()), 1e-300), delta


def base_laws(
    base: HysteresisLaw, law: ProfileElements, coef: Mapping[str, Sequence[float]]
) -> dict[str, tuple[float, float, float]]:
    """The base law's element parameters' pressure laws (monomial (q0, q1, q2) in MPa) from
    the structured law's: k_i = κ_i·c_i·s(p), d_i = δ_i·r_i·t(p) (``coef``: monomial q of
    ``s``, ``t`` and of every correction, a constant)."""
    qs = np.asarray(coef["s"], dtype=np.float64)
    held_t = law.default_fixed.get("t")
    qt = np.asarray(
        (held_t, 0.0, 0.0) if held_t is not None else coef.get("t", (1.0, 0.0, 0.0)),
        dtype=np.float64,
    )
    c, r = law.corrections({n: float(q[0]) for n, q in coef.items()})
    k_names, d_names = base.element_names()
    out: dict[str, tuple[float, float, float]] = {}
    for i, n in enumerate(k_names):
        q = law.kappa[i] * c[i] * qs
        out[n] = (float(q[0]), float(q[1]), float(q[2]))
    for i, n in enumerate(d_names):
        q = law.delta[i] * r[i] * qt
        out[n] = (float(q[0]), float(q[1]), float(q[2]))
    return out
