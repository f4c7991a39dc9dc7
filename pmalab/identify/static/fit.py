"""Static characterization: F = F_s(x, p) + h(drive), fitted over every run of any test type.

The model (:class:`StaticModel`) is a static map (:mod:`.maps`) plus, optionally, one of the
hysteresis laws of :mod:`pmalab.identify.laws` driven by

* ``pressure`` — the law integrates along the (zero-phase filtered) muscle pressure: the
  inflation and deflation branches of an isometric ramp (rate-independent laws need only
  the path, so the same integrator runs in MPa instead of mm; a parameter's unit then reads
  ``MPa`` where the law's says ``mm``);
* ``position`` — today's drive, the filtered contraction (isobaric tests);
* ``both`` — one law on each input, summed (free tests, where both vary).

A law parameter's name ends in its input: ``_p`` (pressure), ``_x`` (contraction).

Every parameter is one value for the whole campaign (the static map carries the pressure
dependence); each run has its own start state h0 of each law (a property of the record).
The fit is two-stage like the isobaric one: the static map alone by least squares (closed
form start, :meth:`~.maps.StaticMap.guess`), then the law from its data-sized guess, then
everything jointly (``scipy.optimize.least_squares``, trust region with bounds).  Standard
errors come from the Jacobian at the optimum, scaled by the residual variance and by the
residual's autocorrelation (an effective sample count, as a white-noise formula would
understate them on a smooth misfit).

A run that holds one drive (the contraction of an isometric run beside isobaric ones) keeps
that law at its start state: a constant of the run, as free as the force offset.  Such a
mixed campaign fits each run well, but the offset and those constants trade against each
other, so a prediction of a free run (both laws saturating) can carry that trade; free runs
in the identification pin it.

A held-out run (``--validate``) is predicted with every muscle parameter held and only its
start state h0 refitted — the same initial-state policy as the isobaric validation — so a
model identified on isometric runs can be scored on isobaric ones (the map meets x that
varies, the pressure law meets a pressure that does not).

Units: x contraction mm, p MPa, F tension N.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from pmalab.errors import PmalabError
from pmalab.identify.laws import HysteresisLaw, get_law
from pmalab.identify.noise import noise_floor_nrmse
from pmalab.identify.signals import zero_phase_lowpass
from pmalab.identify.static.maps import StaticMap
from pmalab.runfile import Run

DRIVES = ("pressure", "position", "both")
#: how the pressure law's loop scales with the pressure
LOOP_SCALES = ("none", "pressure")
#: default drive per test type: what moves the muscle's friction
DEFAULT_DRIVE = {"isometric": "pressure", "isotonic": "pressure", "isobaric": "position"}
#: zero-phase cut-off of the drives (Hz): a static test's ramps are slow
CUTOFF_HZ = 5.0
#: samples of one run the fit uses at most (every k-th of the filtered signals)
FIT_SAMPLES = 1500


def default_drive(runs: Sequence[Run]) -> str:
    """``pressure`` for isometric/isotonic campaigns, ``position`` for isobaric ones,
    ``both`` when free runs or several kinds are mixed."""
    kinds = {r.test_type for r in runs}
    drives = {DEFAULT_DRIVE.get(k, "both") for k in kinds}
    return drives.pop() if len(drives) == 1 else "both"


@dataclass
class StaticRecord:
    """One run ready for the static fit: filtered drives, measured force (full rate)."""

    run: Run
    x: np.ndarray  # mm, filtered contraction (the held value for an isometric run)
    p: np.ndarray  # MPa, filtered pressure
    force: np.ndarray  # N, measured
    stride: int  # every stride-th sample enters the fit

    @property
    def label(self) -> str:
        return self.run.label


def prepare(run: Run, cutoff_Hz: float = CUTOFF_HZ) -> StaticRecord:
    """Filter the run's contraction and pressure (zero phase) for the static fit."""
    t = run.time
    x = run.position
    if float(np.ptp(x)) > 0.0:
        x = zero_phase_lowpass(t, x, cutoff_Hz)
    p = zero_phase_lowpass(t, run.muscle_pressure, cutoff_Hz)
    stride = max(1, len(t) // FIT_SAMPLES)
    return StaticRecord(run, np.asarray(x, float), np.asarray(p, float), run.force, stride)


class StaticModel:
    """A static map plus an optional law on a drive; parameters in :attr:`names` order."""

    def __init__(
        self,
        smap: StaticMap,
        law: HysteresisLaw | str | None,
        drive: str,
        loop_scale: str = "none",
    ) -> None:
        if drive not in DRIVES:
            raise PmalabError(f"--drive: unknown '{drive}' (one of {', '.join(DRIVES)})")
        if loop_scale not in LOOP_SCALES:
            raise PmalabError(
                f"--loop-scale: unknown '{loop_scale}' (one of {', '.join(LOOP_SCALES)})"
            )
        #: ``pressure``: the pressure law's output times p/p_ref (friction ∝ contact
        #: pressure, Tondu & Lopez), ``none``: as the law gives it
        self.loop_scale = loop_scale
        #: the reference pressure (MPa) of a pressure-scaled loop: the campaign's largest,
        #: set by the fit; the law's parameters describe the loop there
        self.p_ref: float | None = None
        self.map = smap
        self.law = get_law(law) if isinstance(law, str) else law
        self.drive = drive
        #: the law inputs: "p" (pressure), "x" (contraction)
        self.inputs: tuple[str, ...] = (
            ()
            if self.law is None
            else {"pressure": ("p",), "position": ("x",)}.get(drive, ("p", "x"))
        )

    # ------------------------------------------------------------------ names
    def _suffix(self, inp: str) -> str:
        """Law parameters carry their input (``alpha_p``, ``b_x``): a law's names never
        meet a map's (Duhem's ``a``, ``b`` and Tondu–Lopez's)."""
        return f"_{inp}"

    @property
    def law_fixed(self) -> dict[str, float]:
        """Law parameters held (the law's degeneracy fixes), with suffixes."""
        if self.law is None:
            return {}
        return {
            f"{n}{self._suffix(i)}": float(v)
            for i in self.inputs
            for n, v in self.law.default_fixed.items()
        }

    @property
    def map_names(self) -> list[str]:
        return [q.name for q in self.map.params]

    @property
    def law_names(self) -> list[str]:
        """Free law parameters (not h0, not held), with suffixes."""
        if self.law is None:
            return []
        state = set(self.law.state_params)
        fixed = set(self.law.default_fixed)
        return [
            f"{q.name}{self._suffix(i)}"
            for i in self.inputs
            for q in self.law.params
            if q.name not in state and q.name not in fixed
        ]

    @property
    def state_names(self) -> list[str]:
        """Per-run start states: ``h0_p`` and/or ``h0_x``."""
        return [f"h0{self._suffix(i)}" for i in self.inputs]

    @property
    def names(self) -> list[str]:
        return self.map_names + self.law_names

    @property
    def name(self) -> str:
        if self.law is None:
            return self.map.name
        scaled = "·p" if self.loop_scale == "pressure" else ""
        return f"{self.map.name}+{self.law.name}({self.drive}){scaled}"

    def units(self) -> dict[str, str]:
        """Unit of every parameter; a law's ``mm`` reads ``MPa`` on the pressure drive."""
        out = {q.name: q.unit for q in self.map.params}
        if self.law is not None:
            for i in self.inputs:
                for q in self.law.params:
                    unit = q.unit.replace("mm", "MPa") if i == "p" else q.unit
                    out[f"{q.name}{self._suffix(i)}"] = unit
        return out

    def docs(self) -> dict[str, str]:
        out = {q.name: q.doc for q in self.map.params}
        if self.law is not None:
            for i in self.inputs:
                what = "pressure" if i == "p" else "contraction"
                for q in self.law.params:
                    out[f"{q.name}{self._suffix(i)}"] = f"{q.doc} (driven by the {what})"
        return out

    def bounds(self) -> dict[str, tuple[float, float]]:
        out = {q.name: (q.lo, q.hi) for q in self.map.params}
        if self.law is not None:
            for i in self.inputs:
                for q in self.law.params:
                    out[f"{q.name}{self._suffix(i)}"] = (q.lo, q.hi)
        return out

    # ------------------------------------------------------------------ evaluation
    def _law_theta(self, theta: Mapping[str, float], inp: str, h0: float) -> dict[str, float]:
        assert self.law is not None
        sfx = self._suffix(inp)
        th = {q.name: float(theta.get(f"{q.name}{sfx}", q.init)) for q in self.law.params}
        th.update({n: float(v) for n, v in self.law.default_fixed.items()})
        th["h0"] = float(h0)
        return th

    def components(
        self,
        rec: StaticRecord,
        theta: Mapping[str, float],
        h0: Sequence[float] | np.ndarray,
        stride: int = 1,
    ) -> dict[str, np.ndarray]:
        """The force's parts (N) on every ``stride``-th sample: ``static`` and one
        ``hysteresis_<input>`` per law."""
        x, p = rec.x[::stride], rec.p[::stride]
        out = {"static": self.map.force(x, p, theta)}
        for inp, h in zip(self.inputs, h0, strict=True):
            assert self.law is not None
            path = p if inp == "p" else x
            out[f"hysteresis_{inp}"] = self.law.h(path, self._law_theta(theta, inp, h)) * (
                self.scale(p) if inp == "p" else 1.0
            )
        return out

    def scale(self, p: np.ndarray) -> np.ndarray | float:
        """The pressure law's output factor: p/p_ref for a pressure-scaled loop, else 1."""
        if self.loop_scale != "pressure":
            return 1.0
        return np.asarray(p, dtype=float) / float(self.p_ref or 1.0)

    def predict(
        self,
        rec: StaticRecord,
        theta: Mapping[str, float],
        h0: Sequence[float] | np.ndarray,
        stride: int = 1,
    ) -> np.ndarray:
        return np.sum(list(self.components(rec, theta, h0, stride).values()), axis=0)

    def loop_half_width(self, theta: Mapping[str, float], inp: str, span: float) -> float:
        """Half the vertical width (N) of the law's loop over a drive swing of ``span``
        (MPa or mm) and back, at mid-swing: the hysteresis width the data show."""
        if self.law is None:
            return 0.0
        n = 2001
        path = np.concatenate([np.linspace(0.0, span, n), np.linspace(span, 0.0, n)[1:]])
        # two swings, so the second starts from a state the first left (no h0 memory)
        path = np.concatenate([path, path[1:]])
        h = self.law.h(path, self._law_theta(theta, inp, 0.0))
        second = h[2 * (n - 1) :]
        up, down = second[: n // 2 + 1], second[n - 1 :][::-1]
        mid = n // 2
        return 0.5 * abs(float(down[mid] - up[mid]))


@dataclass
class RunFit:
    """A run's result: its start state(s) and fit metrics on every sample."""

    rec: StaticRecord
    h0: list[float]
    rmse: float
    nrmse: float
    noise_floor_nrmse: float
    prediction: np.ndarray
    role: str = "identification"


@dataclass
class StaticFit:
    """The campaign's static identification."""

    model: StaticModel
    theta: dict[str, float]
    stderr: dict[str, float | None]
    runs: list[RunFit]
    validation: list[RunFit] = field(default_factory=list)
    messages: list[str] = field(default_factory=list)

    def hysteresis_widths(self) -> dict[str, float]:
        """Loop half-width (N) of each law over the campaign's drive span."""
        out: dict[str, float] = {}
        for inp in self.model.inputs:
            span = max(float(np.ptp(r.rec.p if inp == "p" else r.rec.x)) for r in self.runs)
            if span > 0:
                out[inp] = self.model.loop_half_width(self.theta, inp, span)
        return out


def _metrics(rec: StaticRecord, pred: np.ndarray) -> tuple[float, float, float]:
    e = pred - rec.force
    rmse = float(np.sqrt(np.mean(e**2)))
    sd = max(float(np.std(rec.force)), 1e-9)
    return rmse, rmse / sd, float(noise_floor_nrmse(rec.force, rec.run.time))


def _effective_n(r: np.ndarray) -> float:
    """Samples / (1 + 2·Σρ_k) of a residual (Bartlett, lags while ρ > 0.05)."""
    r = r - r.mean()
    v = float(np.dot(r, r))
    if v <= 0 or r.size < 10:
        return float(r.size)
    s = 0.0
    for k in range(1, min(r.size // 4, 400)):
        rho = float(np.dot(r[:-k], r[k:])) / v
        if rho < 0.05:
            break
        s += rho
    return r.size / (1.0 + 2.0 * s)


def fit_static(
    model: StaticModel,
    runs: Sequence[Run],
    validate: Sequence[Run] = (),
    *,
    fixed: Mapping[str, float] | None = None,
) -> StaticFit:
    """Fit ``model`` to ``runs`` jointly; predict ``validate`` (h0 refitted per run).

    Parameters
    ----------
    fixed
        Parameters held at a value (``--fix NAME=VALUE``), besides the law's own fixes.

    Returns
    -------
    StaticFit
        Parameters, standard errors, per-run and validation metrics.
    """
    from scipy.optimize import least_squares

    if not runs:
        raise PmalabError("identify: no identification run")
    fixed = dict(fixed or {})
    for n in fixed:
        if n not in model.names:
            raise PmalabError(
                f"--fix {n}: not a parameter of {model.name} (parameters: {', '.join(model.names)})"
            )
    recs = [prepare(r) for r in runs]
    if model.loop_scale == "pressure" and model.p_ref is None:
        model.p_ref = max(float(np.max(r.p)) for r in recs)
        if not model.p_ref > 0:
            raise PmalabError("--loop-scale pressure: the runs never reach a positive pressure")
    # a law needs its drive to move in some run (runs of other test types may hold it: an
    # isometric run beside isobaric ones keeps the contraction law at its start state)
    for inp in model.inputs:
        if all(
            float(np.ptp(r.x if inp == "x" else r.p)) < (0.05 if inp == "x" else 0.01) for r in recs
        ):
            what = "contraction" if inp == "x" else "pressure"
            other = "pressure" if inp == "x" else "position"
            raise PmalabError(
                f"--drive {model.drive}: the {what} is held in every run "
                f"({', '.join(sorted({r.run.test_type for r in recs}))}), so a law on the "
                f"{what} has nothing to fit; use --drive {other}"
            )
    # ---- stage 1: the static map alone (closed-form start, then least squares)
    xs = np.concatenate([r.x[:: r.stride] for r in recs])
    ps = np.concatenate([r.p[:: r.stride] for r in recs])
    fs = np.concatenate([r.force[:: r.stride] for r in recs])
    bounds = model.bounds()
    theta = dict(model.map.guess(xs, ps, fs))
    theta.update({n: v for n, v in fixed.items() if n in theta})
    free_map = [n for n in model.map_names if n not in fixed]

    def pack(names: list[str], th: Mapping[str, float]) -> np.ndarray:
        return np.array([th[n] for n in names], dtype=float)

    def lohi(names: list[str]) -> tuple[np.ndarray, np.ndarray]:
        lo = np.array([bounds[n][0] for n in names])
        hi = np.array([bounds[n][1] for n in names])
        return lo, hi

    def inside(z: np.ndarray, names: list[str]) -> np.ndarray:
        lo, hi = lohi(names)
        span = hi - lo
        return np.clip(z, lo + 1e-9 * span, hi - 1e-9 * span)

    if free_map:

        def r_map(z: np.ndarray) -> np.ndarray:
            th = dict(theta, **dict(zip(free_map, z, strict=True)))
            return model.map.force(xs, ps, th) - fs

        sol = least_squares(
            r_map, inside(pack(free_map, theta), free_map), bounds=lohi(free_map), x_scale="jac"
        )
        theta.update(dict(zip(free_map, map(float, sol.x), strict=True)))

    # ---- stage 2: the law's start from the static residual's loop
    nrun, nst = len(recs), len(model.state_names)
    h0 = np.zeros((nrun, nst))
    if model.law is not None:
        resid = [r.force - model.map.force(r.x, r.p, theta) for r in recs]
        for j, inp in enumerate(model.inputs):
            path = np.concatenate([(r.p if inp == "p" else r.x)[:: r.stride] for r in recs])
            res = np.concatenate([e[:: r.stride] for e, r in zip(resid, recs, strict=True)])
            v = np.gradient(path)
            g = model.law.guess(path, res, v, fixed=model.law.default_fixed)
            sfx = model._suffix(inp)
            for q in model.law.params:
                key = f"{q.name}{sfx}"
                if key in model.law_names:
                    lo, hi = bounds[key]
                    theta[key] = float(min(max(g.get(q.name, q.init), lo), hi))
            for i, e in enumerate(resid):
                h0[i, j] = float(np.median(e[: max(5, len(e) // 50)]))
    theta.update(fixed)

    # ---- stage 3: everything jointly
    free = [n for n in model.names if n not in fixed]
    nf = len(free)

    def unpack(z: np.ndarray) -> tuple[dict[str, float], np.ndarray]:
        th = dict(theta, **dict(zip(free, map(float, z[:nf]), strict=True)))
        return th, z[nf:].reshape(nrun, nst)

    def resid_all(z: np.ndarray) -> np.ndarray:
        th, hs = unpack(z)
        out = []
        for i, r in enumerate(recs):
            with np.errstate(all="ignore"):
                e = model.predict(r, th, hs[i], r.stride) - r.force[:: r.stride]
            out.append(np.nan_to_num(e, nan=1e6, posinf=1e6, neginf=-1e6))
        return np.concatenate(out)

    # a law whose memory outlasts the whole swing is a straight line in its drive, the
    # static map's own pressure (or contraction) term: the rate parameters of the law's
    # start grid (Duhem's alpha, Bouc-Wen's beta) are held to loops that saturate within
    # the campaign's swing (memory ≤ the swing), which keeps the two apart
    if model.law is not None:
        for inp in model.inputs:
            span = max(float(np.ptp(r.p if inp == "p" else r.x)) for r in recs)
            grid = model.law.shape_grid(max(span, 1e-6))
            for key in {k for g in grid for k in g if k != "n"}:
                vals = [g[key] for g in grid if key in g]
                name = f"{key}{model._suffix(inp)}"
                if name in bounds and min(vals) > 0:
                    lo_k, hi_k = bounds[name]
                    bounds[name] = (min(max(lo_k, 4.0 * min(vals)), 0.5 * hi_k), hi_k)
                    theta[name] = min(max(theta[name], bounds[name][0]), hi_k)
    h_lo, h_hi = -1e4, 1e4
    if model.law is not None and model.law_names:
        theta, h0 = _law_start(
            model, recs, theta, h0, bounds, [n for n in model.law_names if n not in fixed]
        )
    lo_f, hi_f = lohi(free)
    lo = np.concatenate([lo_f, np.full(nrun * nst, h_lo)])
    hi = np.concatenate([hi_f, np.full(nrun * nst, h_hi)])
    z0 = np.concatenate([inside(pack(free, theta), free), np.clip(h0.ravel(), h_lo, h_hi)])
    sol = least_squares(resid_all, z0, bounds=(lo, hi), x_scale="jac", max_nfev=400)
    theta, hs = unpack(sol.x)
    messages: list[str] = []
    if not sol.success:
        messages.append(f"the joint fit stopped before converging ({sol.message})")

    # ---- standard errors: (JᵀJ)⁻¹ scaled by the residual variance and, for a residual
    # correlated over many samples, by samples / effective samples
    stderr: dict[str, float | None] = dict.fromkeys(model.names)
    res = sol.fun
    n = len(res)
    n_eff = sum(
        _effective_n(res[a:b]) for a, b in _spans([len(r.force[:: r.stride]) for r in recs])
    )
    s2 = float(np.dot(res, res)) / max(n - sol.x.size, 1)
    try:
        cov = np.linalg.pinv(sol.jac.T @ sol.jac) * s2 * (n / max(n_eff, 1.0))
        for k, name in enumerate(free):
            v = float(cov[k, k])
            stderr[name] = math.sqrt(v) if v >= 0 and math.isfinite(v) else None
    except np.linalg.LinAlgError:
        pass
    fits = []
    for i, r in enumerate(recs):
        pred = model.predict(r, theta, hs[i])
        rmse, nrmse, floor = _metrics(r, pred)
        fits.append(RunFit(r, [float(v) for v in hs[i]], rmse, nrmse, floor, pred))
    out = StaticFit(model, theta, stderr, fits, messages=messages)
    out.validation = [predict_run(out, run) for run in validate]
    return out


def _law_start(
    model: StaticModel,
    recs: Sequence[StaticRecord],
    theta: dict[str, float],
    h0: np.ndarray,
    bounds: Mapping[str, tuple[float, float]],
    names: list[str],
) -> tuple[dict[str, float], np.ndarray]:
    """The law's start with the static map held, by variable projection: at every point of
    the law's start grid (shape parameters sized from the swing) h is linear in the law's
    scale parameter once the state starts at zero, so the scale and a constant per run
    (the start state's share) are solved by linear least squares; the best point wins.
    A law without a scale parameter keeps its data-sized guess."""
    law = model.law
    assert law is not None
    if law.scale_param is None or len(model.inputs) != 1:
        return theta, h0
    inp = model.inputs[0]
    sfx = model._suffix(inp)
    scale = f"{law.scale_param}{sfx}"
    if scale not in names:
        return theta, h0
    span = max(float(np.ptp(r.p if inp == "p" else r.x)) for r in recs)
    paths = [(r.p if inp == "p" else r.x)[:: r.stride] for r in recs]
    resid = [
        r.force[:: r.stride] - model.map.force(r.x[:: r.stride], r.p[:: r.stride], theta)
        for r in recs
    ]
    y = np.concatenate(resid)
    lens = [len(e) for e in resid]
    best: tuple[float, dict[str, float], np.ndarray] | None = None
    for g in [{}, *law.shape_grid(max(span, 1e-6))]:
        th = dict(theta)
        for k, v in g.items():
            name = f"{k}{sfx}"
            if name in names:
                lo, hi = bounds[name]
                th[name] = float(min(max(v, lo), hi))
        lth = model._law_theta(th, inp, 0.0)
        lth[law.scale_param] = 1.0
        if not law.scale_valid(lth):
            continue
        pss = [r.p[:: r.stride] for r in recs]
        cols = [
            np.concatenate(
                [
                    law.h(pth, lth) * (model.scale(pp) if inp == "p" else 1.0)
                    for pth, pp in zip(paths, pss, strict=True)
                ]
            )
        ]
        for i, n in enumerate(lens):  # one constant per run
            c = np.zeros(len(y))
            c[sum(lens[:i]) : sum(lens[:i]) + n] = 1.0
            cols.append(c)
        A = np.column_stack(cols)
        if not np.all(np.isfinite(A)):
            continue
        coef, *_ = np.linalg.lstsq(A, y, rcond=None)
        lo, hi = bounds[scale]
        coef[0] = min(max(coef[0], lo), hi)
        cost = float(np.sum((A @ coef - y) ** 2))
        if best is None or cost < best[0]:
            th[scale] = float(coef[0])
            best = (cost, th, np.asarray(coef[1:], dtype=float).reshape(-1, 1))
    if best is None:
        return theta, h0
    return best[1], best[2]


def _spans(lengths: Sequence[int]) -> list[tuple[int, int]]:
    offs = np.cumsum([0, *lengths])
    return [(int(a), int(b)) for a, b in itertools.pairwise(offs)]


def predict_run(fit: StaticFit, run: Run) -> RunFit:
    """A held-out run predicted with the muscle's parameters held, its start state(s) h0
    refitted (the record's, not the muscle's)."""
    from scipy.optimize import least_squares

    model = fit.model
    rec = prepare(run)
    nst = len(model.state_names)
    h = np.zeros(nst)
    if nst:
        base = rec.force - model.map.force(rec.x, rec.p, fit.theta)
        h[:] = float(np.median(base[: max(5, len(base) // 50)])) / nst

        def r_h(z: np.ndarray) -> np.ndarray:
            return model.predict(rec, fit.theta, z, rec.stride) - rec.force[:: rec.stride]

        h = least_squares(r_h, h, bounds=(-1e4, 1e4)).x
    pred = model.predict(rec, fit.theta, h)
    rmse, nrmse, floor = _metrics(rec, pred)
    return RunFit(rec, [float(v) for v in h], rmse, nrmse, floor, pred, role="validation")


def summary_doc(fit: StaticFit, geometry: Mapping[str, Any]) -> dict[str, Any]:
    """The static identification as ``identification.json`` (the contract's keys, plus
    ``static_map``, ``hysteresis`` and per-run test types)."""
    m = fit.model
    units, docs = m.units(), m.docs()
    params = {
        n: {
            "value": fit.theta[n],
            "unit": units.get(n),
            "stderr": fit.stderr.get(n),
            "doc": docs.get(n),
            "fixed": n not in m.names or fit.stderr.get(n) is None,
        }
        for n in m.map_names
    }
    derived = {
        k: {"value": v, "unit": u, "doc": d} for k, (v, u, d) in m.map.derived(fit.theta).items()
    }
    law_block: dict[str, Any] | None = None
    if m.law is not None:
        widths = fit.hysteresis_widths()
        law_block = {
            "law": m.law.name,
            "drive": m.drive,
            "parameters": {
                n: {
                    "value": fit.theta[n],
                    "unit": units.get(n),
                    "stderr": fit.stderr.get(n),
                    "doc": docs.get(n),
                }
                for n in m.law_names
            },
            "held": m.law_fixed,
            "loop_half_width_N": {
                ("pressure" if k == "p" else "position"): v for k, v in widths.items()
            },
            "loop_half_width_doc": "half the force gap between the rising and falling "
            "branches at mid-swing, over the campaign's largest drive swing (N)"
            + (
                f"; the pressure loop at the reference pressure {m.p_ref:.4g} MPa, "
                "scaled by p/p_ref elsewhere"
                if m.loop_scale == "pressure"
                else ""
            ),
            "loop_scale": m.loop_scale,
            "loop_reference_MPa": m.p_ref,
        }

    def row(rf: RunFit) -> dict[str, Any]:
        run = rf.rec.run
        p = run.muscle_pressure
        d: dict[str, Any] = {
            "file": run.file or None,
            "run": run.name,
            "role": rf.role,
            "test_type": run.test_type,
            "muscle_pressure_MPa": float(run.nominal_pressure),
            "pressure_measured_MPa": [float(p.min()), float(np.mean(p)), float(p.max())],
            "rmse": rf.rmse,
            "nrmse": rf.nrmse,
            "fit_percent": 100.0 * (1.0 - rf.nrmse),
            "noise_floor_nrmse": rf.noise_floor_nrmse,
            "n_samples": len(run),
        }
        if run.test_type == "isometric":
            d["held_position_mm"] = float(
                run.attrs.get("held_position_mm", np.median(run.position))
            )
        if run.attrs.get("load_N") is not None:
            d["load_N"] = float(run.attrs["load_N"])
        return d

    runs = []
    for rf in fit.runs:
        d = row(rf)
        d["parameters"] = {n: fit.theta[n] for n in m.names} | dict(
            zip(m.state_names, rf.h0, strict=True)
        )
        d["stderr"] = {n: fit.stderr.get(n) for n in m.names}
        runs.append(d)
    validation = []
    for rf in fit.validation:
        d = row(rf)
        d["status"] = "ok"
        d["refitted"] = dict(zip(m.state_names, rf.h0, strict=True))
        validation.append(d)
    return {
        "model": m.law.name if m.law is not None else "none",
        "model_full": m.name,
        "kind": "static",
        "parameter_names": m.names,
        "parameter_units": {n: units.get(n) for n in m.names},
        "parameter_docs": {n: docs.get(n) for n in m.names},
        "state_parameters": m.state_names,
        "static_map": {
            "id": m.map.name,
            "title": m.map.title,
            "geometry": dict(geometry),
            "parameters": params,
            "derived": derived,
        },
        "hysteresis": law_block,
        "test_types": sorted({r.rec.run.test_type for r in fit.runs}),
        "runs": runs,
        "pressure_model": "static map",
        "pressure_fits": {},
        "validation": validation,
        "messages": [
            {"kind": "warning", "code": "static-fit", "text": t, "data": {}} for t in fit.messages
        ],
        "method": {
            "static": "the static map alone by least squares from its closed-form start, "
            "then the law from its guess on the static residual, then all jointly "
            "(scipy least_squares, trust region, bounds)",
            "drive": f"the law(s) integrate the zero-phase filtered "
            f"{'pressure' if m.drive == 'pressure' else m.drive} ({CUTOFF_HZ:g} Hz)",
            "stderr": "Jacobian at the optimum, residual variance, effective sample count "
            "of the autocorrelated residual",
            "validation": "muscle parameters held, each held-out run's start state refitted",
        },
    }
