"""Output-error identification: fit the model's *simulated position* to the measured one.

``pmalab identify --output position``.  The force-direction fit (measured position in,
force out; :mod:`.single`, :mod:`.joint`) gives the start; this refines the same
parameters so that the model, driven by the measured force (and pressure) alone and
integrated forward by :func:`pmalab.identify.forward.simulate`, reproduces the measured
position (free run, no measured position fed back).  It is the same estimation problem
(:class:`~.problem.Problem`: shared parameters through the pressure basis at the orders the
force fit chose, per-run blocks, one solver, one uncertainty) with another output:

* residual of run i: (x_sim − x_measured)·w_i in mm, w_i = 1/(sd_i·√N_i) so every run
  counts equally (sd_i the run's position standard deviation);
* per-run parameters: the record's start state — position x0 (mm), velocity v0 (mm/s) and
  the hysteretic force h0 (N) — estimated with the muscle parameters;
* k and c0 enter the simulated position nonlinearly: every column is a forward difference.

The sub-steps per sample are fixed per run at the start (so the cost is a smooth function
of the parameters) from the start parameters with a 1.5× margin on the fastest mode.

Predicting another record (validation, ``pmalab simulate``) estimates its start state the
same way on its first :data:`INITIAL_WINDOW_S` seconds with every muscle parameter held,
then simulates the whole record from the input alone.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from pmalab.identify.estimation.basis import PressureBasis
from pmalab.identify.estimation.problem import Problem, Record
from pmalab.identify.estimation.solver import solve, uncertainty
from pmalab.identify.forward import Coefficients, Load, plant_slots, simulate, substeps
from pmalab.identify.messages import Message, note
from pmalab.identify.model import ForceModel
from pmalab.identify.signals import Signals

#: the start state of a predicted record is estimated on its first this many seconds
INITIAL_WINDOW_S = 0.2
#: start-state parameters of a forward simulation (per run)
STATE = ("x0", "v0", "h0")
#: least-squares tolerance and evaluations per free variable
TOL = 1e-8
NFEV_PER_VAR = 20


@dataclass
class PositionData:
    """One run for the output-error fit: signals (time, pressure), the input force (N) and
    the measured position (mm)."""

    label: str
    p_nom: float
    sig: Signals
    force: np.ndarray
    position: np.ndarray


class PositionProblem(Problem):
    """:class:`~.problem.Problem` whose output is the simulated position (mm)."""

    analytic_linear = False

    def __init__(
        self, model: ForceModel, data: Sequence[PositionData], *, n_sub: Sequence[int], **kw
    ) -> None:
        recs = [
            Record(d.label, d.p_nom, d.sig, np.asarray(d.position, dtype=np.float64)) for d in data
        ]
        super().__init__(model, recs, **kw)
        self.inputs = [np.asarray(d.force, dtype=np.float64) for d in data]
        self.n_sub = list(n_sub)

    def output(self, i: int, th: Mapping[str, float]) -> np.ndarray:
        r = self.records[i]
        s = simulate(
            self.model,
            th,
            r.sig.t,
            self.inputs[i],
            r.sig.p,
            p_nom=r.p_nom,
            x0=th["x0"],
            v0=th["v0"],
            h0=th["h0"],
            n_sub=self.n_sub[i],
        )
        return s.position


@dataclass
class OutputErrorFit:
    """The refined pressure laws and what the refinement measured."""

    coef: dict[str, tuple[float, float, float]]  # monomial q per parameter (free and held)
    degree: dict[str, int]
    stderr: dict[str, float | None]  # of θ at the mean identified pressure
    labels: list[str]
    state: dict[str, list[float]]  # x0, v0, h0 per run
    rmse_mm: list[float]
    nrmse: list[float]
    rmse_mm_start: list[float]
    n_sub: list[int]
    nfev: int
    success: bool
    message: str
    positions: list[np.ndarray] = field(default_factory=list)  # simulated, per run
    notes: list[Message] = field(default_factory=list)

    def theta(self, p: float) -> dict[str, float]:
        return {n: _at(q, p) for n, q in self.coef.items()}


def _at(q: Sequence[float], p: float) -> float:
    """A monomial pressure law θ(p) = q0 + q1·p + q2·p² at ``p`` (MPa)."""
    q0, q1, q2 = (float(v) for v in (*q, 0.0, 0.0)[:3])
    return q0 + q1 * p + q2 * p * p


def state_names(model: ForceModel, theta: Mapping[str, float]) -> tuple[str, ...]:
    """The start-state parameters: (x0, v0, h0) with a moving mass, (x0, h0) for the
    quasi-static (massless) forward model, where the velocity is no state."""
    slots = plant_slots(model)
    m = float(theta.get(slots["mass"], 0.0)) if "mass" in slots else 0.0
    return STATE if m > 0 else ("x0", "h0")


def position_data(
    label: str, sig: Signals, force: np.ndarray, position: np.ndarray
) -> PositionData:
    return PositionData(
        label,
        float(sig.p_nom),
        sig,
        np.asarray(force, dtype=np.float64),
        np.asarray(position, dtype=np.float64),
    )


def _n_sub(
    model: ForceModel,
    theta: Mapping[str, float],
    d: PositionData,
    bounds: Mapping[str, tuple[float, float]] | None,
) -> int:
    coef = Coefficients(model, theta, bounds)
    dt = float(np.median(np.diff(d.sig.t)))
    n = substeps(model, coef, d.sig.p, dt, Load())
    return max(1, int(math.ceil(1.5 * n)))


def _state_bounds(
    data: Sequence[PositionData], hb: tuple[float, float]
) -> dict[str, tuple[float, float]]:
    xs = np.concatenate([d.position for d in data])
    span = float(np.ptp(xs)) + 1e-3
    vmax = max(float(np.max(np.abs(d.sig.v))) for d in data) + 1.0
    return {
        "x0": (float(np.min(xs)) - span, float(np.max(xs)) + span),
        "v0": (-5.0 * vmax, 5.0 * vmax),
        "h0": hb,
    }


def start_state(d: PositionData, h0: float = 0.0) -> dict[str, float]:
    """Start values of (x0, v0, h0): the record's first filtered position and velocity."""
    return {"x0": float(d.sig.x[0]), "v0": float(d.sig.v[0]), "h0": float(h0)}


def fit_output_error(
    model: ForceModel,
    data: Sequence[PositionData],
    start: Mapping[str, Sequence[float]],
    degree: Mapping[str, int],
    held: Mapping[str, Sequence[float]],
    h0: Sequence[float],
    bounds: Mapping[str, tuple[float, float]],
) -> OutputErrorFit:
    """Refine the pressure laws ``start`` (monomial q per free parameter, orders ``degree``;
    ``held``: fixed parameters' laws) on the simulated position of ``data``."""
    pressures = [d.p_nom for d in data]
    basis = PressureBasis.over(pressures)
    free = [n for n in start if n not in STATE]
    b = dict(bounds)
    notes: list[Message] = []
    mass = plant_slots(model).get("mass")
    if mass in free:
        m0 = min(_at(start[mass], p) for p in pressures)
        if m0 <= 0:
            # no positive mass at the start: the quasi-static forward model, m held at 0
            held = {**held, mass: (0.0, 0.0, 0.0)}
            free.remove(mass)
            start = {n: q for n, q in start.items() if n != mass}
            notes.append(
                note(
                    "oe-massless",
                    f"{mass} held at 0 in the output-error fit: the force-direction "
                    f"fit found no positive moving mass ({m0:.3g} kg), so the position is "
                    "simulated quasi-statically (force balance per sample)",
                    mass_kg=m0,
                )
            )
        else:
            # a mass far below the start would need more sub-steps than were sized
            lo_m, hi_m = b.get(mass, (-np.inf, np.inf))
            b[mass] = (max(lo_m, 0.25 * m0), hi_m)
    b.update(_state_bounds(data, b.get("h0", (-1e4, 1e4))))
    th_start = []
    for d in data:
        th = {n: _at(q, d.p_nom) for n, q in {**start, **held}.items()}
        th_start.append(th)
    n_sub = [_n_sub(model, {**th, **start_state(d)}, d, b) for th, d in zip(th_start, data)]
    constants = {n: float(held[n][0]) for n in held}  # held laws are constants (order 0)
    states = state_names(model, th_start[0])
    constants.update({s: 0.0 for s in STATE if s not in states})
    prob = PositionProblem(
        model,
        data,
        n_sub=n_sub,
        free=free,
        degree=dict(degree),
        constants=constants,
        bounds=b,
        run_params=list(states),
        basis=basis,
    )
    for rec, d in zip(prob.records, data):
        rec.weight = 1.0 / (max(float(np.std(d.position)), 1e-9) * math.sqrt(rec.n))
    st = [start_state(d, h) for d, h in zip(data, h0)]
    z0 = prob.z_from(
        {n: basis.from_monomial(start[n], int(degree[n])) for n in free},
        {s: [v[s] for v in st] for s in states},
    )
    lo, hi = prob.z_bounds()
    z0 = np.clip(z0, lo, hi)
    rm0 = prob.per_run_rmse(z0)
    sol = solve(
        prob.residual, prob.jac, z0, lo, hi, tol=TOL, max_nfev=NFEV_PER_VAR * (prob.n_var + 1)
    )
    z = sol.x if sol.cost <= 0.5 * float(prob.residual(z0) @ prob.residual(z0)) else z0
    u = uncertainty(prob.jac(z), prob.residual(z), prob.rows)
    coef = {n: basis.to_monomial(z[prob.slices[n]]) for n in free}
    coef.update({n: (float(held[n][0]), 0.0, 0.0) for n in held})
    pm = float(np.mean(pressures))
    se: dict[str, float | None] = {}
    for n in free:
        sl = prob.slices[n]
        row = basis.matrix(pm, int(degree[n]))[0]
        s = u.stderr[sl]
        cov = u.correlation[sl, sl] * np.outer(s, s)
        v = float(row @ cov @ row)
        se[n] = math.sqrt(v) if np.isfinite(v) and v >= 0 else None
    ths = prob.thetas(z)
    rm = prob.per_run_rmse(z)
    return OutputErrorFit(
        coef=coef,
        degree={n: int(degree[n]) for n in free},
        stderr=se,
        labels=[d.label for d in data],
        state={s: [float(th.get(s, 0.0)) for th in ths] for s in STATE},
        rmse_mm=rm,
        nrmse=[r / max(float(np.std(d.position)), 1e-12) for r, d in zip(rm, data)],
        rmse_mm_start=rm0,
        n_sub=n_sub,
        nfev=int(sol.nfev),
        success=bool(sol.success),
        message=str(sol.message),
        positions=[prob.output(i, th) for i, th in enumerate(ths)],
        notes=notes,
    )


def estimate_state(
    model: ForceModel,
    theta: Mapping[str, float],
    d: PositionData,
    bounds: Mapping[str, tuple[float, float]] | None = None,
    n_sub: int | None = None,
) -> tuple[dict[str, float], int]:
    """(x0, v0, h0) of a record fitted on its first :data:`INITIAL_WINDOW_S` with the muscle
    parameters ``theta`` held, and the sub-steps used."""
    dt = float(np.median(np.diff(d.sig.t)))
    m = max(20, min(d.sig.t.shape[0], int(round(INITIAL_WINDOW_S / dt))))
    win = PositionData(d.label, d.p_nom, _head(d.sig, m), d.force[:m], d.position[:m])
    b = dict(bounds or {})
    b.update(_state_bounds([d], b.get("h0", (-1e4, 1e4))))
    th = {k: v for k, v in theta.items() if k not in STATE}
    ns = n_sub or _n_sub(model, {**th, **start_state(d)}, d, b)
    states = state_names(model, th)
    th.update({s: 0.0 for s in STATE if s not in states})
    prob = PositionProblem(
        model,
        [win],
        n_sub=[ns],
        free=[],
        degree={},
        constants=th,
        bounds=b,
        run_params=list(states),
    )
    st = start_state(d)
    z0 = np.clip(prob.z_from({}, {s: [st[s]] for s in states}), *prob.z_bounds())
    lo, hi = prob.z_bounds()
    sol = solve(prob.residual, prob.jac, z0, lo, hi, tol=TOL, max_nfev=200)
    vals = prob.run_values(sol.x)
    out = {s: 0.0 for s in STATE}
    out.update({s: float(vals[s][0]) for s in states})
    return out, ns


def predict_position(
    model: ForceModel,
    theta: Mapping[str, float],
    d: PositionData,
    bounds: Mapping[str, tuple[float, float]] | None = None,
) -> tuple[np.ndarray, dict[str, float]]:
    """Free-run position (mm) of a record from its force input, its start state estimated
    (:func:`estimate_state`); returns (position, start state)."""
    st, ns = estimate_state(model, theta, d, bounds)
    th = {**theta, **st}
    s = simulate(
        model,
        th,
        d.sig.t,
        d.force,
        d.sig.p,
        p_nom=d.p_nom,
        x0=st["x0"],
        v0=st["v0"],
        h0=st["h0"],
        n_sub=ns,
        bounds=bounds,
    )
    return s.position, st


def position_metrics(measured: np.ndarray, simulated: np.ndarray) -> dict[str, float]:
    """rms error of a simulated position in mm and m, nrmse and fit % (NaN if it diverged)."""
    e = np.asarray(simulated, dtype=np.float64) - np.asarray(measured, dtype=np.float64)
    rmse = float(np.sqrt(np.mean(e * e))) if np.all(np.isfinite(e)) else float("nan")
    sd = max(float(np.std(measured)), 1e-12)
    dev = float(np.linalg.norm(measured - np.mean(measured))) or 1e-12
    fit = 100.0 * (1.0 - float(np.linalg.norm(e)) / dev) if np.isfinite(rmse) else float("nan")
    return {
        "rmse_position_mm": rmse,
        "rmse_position_m": rmse * 1e-3,
        "nrmse_position": rmse / sd,
        "fit_percent_position": fit,
    }


def _head(sig: Signals, m: int) -> Signals:
    from dataclasses import replace

    return replace(
        sig,
        t=sig.t[:m],
        x=sig.x[:m],
        v=sig.v[:m],
        a=sig.a[:m],
        p=sig.p[:m],
        x_raw=sig.x_raw[:m],
        x_slide=None if sig.x_slide is None else sig.x_slide[:m],
    )
