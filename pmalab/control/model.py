"""The identified muscle model inside the controller: F = k(p)·x + c0(p) + h, inverted for p.

Read from an ``identification.json`` (``pmalab identify``): ``"model"`` names the
hysteresis law, ``"pressure_fits"`` gives every parameter as θ(p) = q0 + q1·p + q2·p²
(p in MPa).  x is the muscle's *absolute* contraction (mm from nominal length), F the
tension (N), h the hysteretic force (N).

* :meth:`IdentifiedModel.invert` solves k(p)·x + c0(p) + h = F_d for the pressure at the
  current x and h.  Both k and c0 are quadratics in p, so this is one quadratic equation:
  closed form, no iteration (the inner loop needs it 500 times a second).  Outside what the
  muscle can give at this x the answer is clamped to [0, p_max].
* :class:`HysteresisState` advances h by one sample with the law's own per-sample step
  (``pmalab.identify.laws``: the batch integrator for one sample) at the law parameters
  θ(p) of the current pressure — the controller never integrates a law of its own.

Effect terms an identification may carry (``"effects"``) are not inverted: the base law is
what the seeds' controllers use; they are listed in :attr:`IdentifiedModel.ignored_effects`.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

from pmalab.errors import ConfigError
from pmalab.paths import DATA_DIR, shipped

#: the shipped identification of the simulated muscle (pmalab/data/control/README.md says how it was made)
SHIPPED_IDENTIFICATION = DATA_DIR / "control" / "identification-bouc-wen.json"
#: parameters that are not the hysteresis law's
_LINEAR = ("k", "c0")
_STATE = ("h0",)


def _law(name: str) -> Any:
    """The identified law (identify's registry: its ``stepper(theta)`` is the batch
    integrator's segment for one sample)."""
    from pmalab.identify.laws import get_law

    return get_law(name)


class IdentifiedModel:
    """The pressure-parametrised base model of one ``identification.json``."""

    def __init__(self, doc: Mapping[str, Any], source: str = "<memory>") -> None:
        self.source = source
        law = doc.get("model")
        fits = doc.get("pressure_fits")
        if not isinstance(law, str) or not law:
            raise ConfigError(f"{source}: field 'model': missing (not an identification.json?)")
        if not isinstance(fits, Mapping):
            raise ConfigError(f"{source}: field 'pressure_fits': missing or not an object")
        coef: dict[str, tuple[float, float, float]] = {}
        for name, q in fits.items():
            if (
                not isinstance(q, list)
                or len(q) != 3
                or not all(
                    isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v)
                    for v in q
                )
            ):
                raise ConfigError(
                    f"{source}: field 'pressure_fits.{name}': expected three "
                    "finite numbers [q0, q1, q2]"
                )
            coef[str(name)] = (float(q[0]), float(q[1]), float(q[2]))
        for name in _LINEAR:
            if name not in coef:
                raise ConfigError(f"{source}: field 'pressure_fits.{name}': missing")
        law_obj = _law(law)  # an unknown law is one line naming the valid ones
        for lp in law_obj.params:
            if lp.name not in _STATE and lp.name not in coef:
                raise ConfigError(
                    f"{source}: field 'pressure_fits.{lp.name}': missing (the {law} law needs it)"
                )
        self.law = law
        self.coef = coef
        effects = doc.get("effects") or []
        self.ignored_effects = [str(e) for e in effects] if isinstance(effects, list) else []
        # everything but the linear part and the start state goes to the law's step (which
        # reads its own parameters by name; an effect's extra parameters are ignored there)
        self.law_params = [n for n in coef if n not in _LINEAR and n not in _STATE]
        rng = doc.get("pressure_range_MPa")
        self.pressure_range = (
            tuple(float(v) for v in rng) if isinstance(rng, list) and len(rng) == 2 else (0.0, 0.6)
        )
        self._kq = coef["k"]
        self._cq = coef["c0"]

    @classmethod
    def load(cls, path: str | Path | None = None) -> IdentifiedModel:
        """Read an ``identification.json`` (``None``: the shipped one); one-line errors."""
        # a shipped identification by name (identification-duhem) or clone path works anywhere
        p = (
            shipped(path, DATA_DIR / "control", ".json")
            if path is not None
            else SHIPPED_IDENTIFICATION
        )
        if p.is_dir():
            p = p / "identification.json"
        try:
            doc = json.loads(p.read_text(encoding="utf-8"))
        except FileNotFoundError:
            raise ConfigError(f"{p}: no such file") from None
        except (OSError, UnicodeDecodeError) as exc:
            raise ConfigError(f"{p}: unreadable ({exc})") from None
        except json.JSONDecodeError as exc:
            raise ConfigError(f"{p}: not JSON (line {exc.lineno}: {exc.msg})") from None
        if not isinstance(doc, dict):
            raise ConfigError(f"{p}: not an identification.json (top level is not an object)")
        return cls(doc, str(p))

    # ------------------------------------------------------------------ evaluation
    def theta(self, p: float) -> dict[str, float]:
        """The hysteresis law's parameters at pressure ``p`` (MPa)."""
        c = self.coef
        return {n: c[n][0] + c[n][1] * p + c[n][2] * p * p for n in self.law_params}

    def force(self, x: float, p: float, h: float) -> float:
        """Modelled tension (N) at contraction ``x`` (mm), pressure ``p`` (MPa), h (N)."""
        k0, k1, k2 = self._kq
        c0, c1, c2 = self._cq
        return (k0 + k1 * p + k2 * p * p) * x + c0 + c1 * p + c2 * p * p + h

    def invert(self, f_d: float, x: float, h: float, p_max: float) -> float:
        """The pressure (MPa, in [0, p_max]) at which the model gives tension ``f_d`` (N).

        F(p) = a·p² + b·p + c with a = k2·x + c2, b = k1·x + c1, c = k0·x + c0 + h.  If
        ``f_d`` is below F(0) the answer is 0, above F(p_max) it is p_max; otherwise the
        root inside [0, p_max] (the smaller one if the parabola turns back inside it).
        """
        k0, k1, k2 = self._kq
        c0, c1, c2 = self._cq
        a = k2 * x + c2
        b = k1 * x + c1
        c = k0 * x + c0 + h - f_d
        if c >= 0.0:  # F(0) already ≥ f_d
            return 0.0
        if a * p_max * p_max + b * p_max + c <= 0.0:  # even p_max is not enough
            return p_max
        # a sign change inside (0, p_max): the first root, numerically stable form
        if abs(a) < 1e-12:
            return min(max(-c / b, 0.0), p_max)
        disc = b * b - 4.0 * a * c
        sq = math.sqrt(disc) if disc > 0.0 else 0.0
        q = -0.5 * (b + math.copysign(sq, b))
        roots = [r for r in (q / a, (c / q) if q != 0.0 else math.inf) if 0.0 <= r <= p_max]
        return min(roots) if roots else min(max(-c / b, 0.0), p_max)


class HysteresisState:
    """h of the identified law, advanced one sample at a time at the current pressure.

    The law's parameters θ(p) are bound once per 1 kPa of pressure (``law.stepper(θ)``,
    cached): evaluating the quadratics and binding them every sample costs 3× the step
    itself, and θ moves by < 0.2 % within 1 kPa.
    """

    #: pressure bin of the stepper cache (MPa)
    P_BIN = 0.001

    def __init__(self, model: IdentifiedModel, x0: float, h0: float = 0.0) -> None:
        self.model = model
        self.h = float(h0)
        self.x = float(x0)
        self._law = _law(model.law)
        self._cache: dict[int, Callable[[Any, float, float], Any]] = {}
        # the law's own state: h itself (Bouc-Wen, Duhem) or its elements' forces
        # (Prandtl-Ishlinskii, Maxwell-slip), carried across pressure bins
        self.state: Any = float(h0) if self._law.state_size == 1 else [0.0] * self._law.state_size

    def stepper(self, p: float) -> Callable[[float, float, float], float]:
        """``step(h, x_prev, x) -> h`` at pressure ``p`` (MPa, 1 kPa bins)."""
        key = int(round(p / self.P_BIN))
        step = self._cache.get(key)
        if step is None:
            step = self._law.stepper(self.model.theta(key * self.P_BIN))
            self._cache[key] = step
        return step

    def update(self, x: float, p: float) -> float:
        """Move to contraction ``x`` (mm) at pressure ``p`` (MPa); return h (N)."""
        state = self.stepper(p)(self.state, self.x, x)
        h = self._law.output(state)
        if h == h and abs(h) < 1e6:  # a law driven far outside its data must not poison u
            self.state, self.h = state, h
        self.x = x
        return self.h
