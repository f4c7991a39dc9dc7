"""N free elasto-slide elements: a bench-only law to score a simulated muscle's own friction.

pmalab's Maxwell-slip law has four elements and its Prandtl-Ishlinskii law fixed thresholds
on a √2 grid, so neither can express a simulated muscle of eight (or six) play operators off
that grid (``data/truth/hysteresis-prandtl-ishlinskii.toml``, ``laws/pi-*.toml``).  The
simulator's braid friction is such elements (:mod:`pmalab.rig.sim.kernel`), and so are both
laws: a play operator of threshold r and weight w is an elasto-slide element of stiffness
k = w and slip displacement d = r (slip force w·r).  :func:`elements_law` is that element
sum with as many elements as the truth has, an
:class:`~pmalab.identify.laws.element_sum.ElementSum` as both laws are (the same integrator,
the same start state from h0 on either branch, the same segment), so a :class:`~pmalab.identify.model.ForceModel` of it predicts a record by
identify's rule (:func:`pmalab.identify.estimation.records.predict_record`) exactly as the
Maxwell-slip law would with that many elements.

It is not a law users can choose (it is never registered) and is never fitted: its
parameters come from :func:`pmalab.rig.sim.reference.maxwell_slip_theta` with
``elements`` = the truth's count.  Units: k_i N/mm, d_i mm, h N; sign as the laws (tension
higher while stretching).
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from pmalab.identify.laws.base import HysteresisLaw, LawParam
from pmalab.identify.laws.element_sum import ElementSum


class _Elements(ElementSum):
    """The element sum; :func:`elements_law` sets its size (class attributes of a subclass,
    so that the base class's registry never sees it)."""

    names_k: tuple[str, ...] = ()
    names_d: tuple[str, ...] = ()

    def _kf(self, theta: Mapping[str, float]) -> tuple[np.ndarray, np.ndarray]:
        # as maxwell_slip._kf: slip force f_i = k_i·d_i
        k, d = self.elements(theta)
        return k, k * d

    def elements(self, theta: Mapping[str, float]) -> tuple[np.ndarray, np.ndarray]:
        """Stiffnesses (N/mm) and slip displacements (mm) of the elements (negative values
        act as zero)."""
        k = np.array([max(float(theta[n]), 0.0) for n in self.names_k])
        return k, np.array([max(float(theta[n]), 0.0) for n in self.names_d])

    def element_names(self) -> tuple[tuple[str, ...], tuple[str, ...]]:
        return self.names_k, self.names_d


def elements_law(n: int) -> HysteresisLaw:
    """A law of ``n`` elasto-slide elements with free stiffness ``k1…kn`` (N/mm) and slip
    displacement ``d1…dn`` (mm), plus the start state ``h0`` (N).

    Parameters
    ----------
    n : int
        Number of elements (≥ 1).

    Returns
    -------
    HysteresisLaw
        An instance named ``elasto-slide-<n>``, not registered as a user law.
    """
    if n < 1:
        raise ValueError(f"elements_law: n must be >= 1, not {n}")
    ks = tuple(f"k{i + 1}" for i in range(n))
    ds = tuple(f"d{i + 1}" for i in range(n))
    params = (
        *(
            LawParam(k, 10.0, 0.0, 1e4, "N/mm", f"stiffness of element {i + 1}")
            for i, k in enumerate(ks)
        ),
        *(
            LawParam(d, 1.0, 1e-3, 50.0, "mm", f"slip displacement of element {i + 1}")
            for i, d in enumerate(ds)
        ),
        LawParam("h0", 0.0, -1e4, 1e4, "N", "initial hysteretic force"),
    )
    cls = type(
        f"ElastoSlide{n}",
        (_Elements,),
        {"params": params, "state_size": n, "names_k": ks, "names_d": ds},
    )
    # named after creation: a class whose own dict holds a name registers as a user law
    cls.name = f"elasto-slide-{n}"
    cls.title = f"{n} elasto-slide elements (bench reference)"
    return cls()
