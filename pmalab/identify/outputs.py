"""Writing an identification: ``identification.json`` and ``predictions.h5``.

``identification.json`` (the keys of docs/reference/json.md; more keys are welcome to readers)::

    {"model", "effects": [ids], "pmalab_version", "created",
     "inputs": [{"file", "runs": [...], "provenance": {...}}],
     "parameter_names": [...],
     "runs": [{"file", "run", "role": "identification", "muscle_pressure_MPa", "frequency_Hz",
               "waveform", "parameters": {name: value}, "stderr": {name: value|null},
               "correlation": {"names": [...], "matrix": [[...]]}, "fixed": [...],
               "warnings": [...], "rmse", "nrmse", "fit_percent", "max_error",
               "energy_error_percent", "branch_rmse": {"stretch", "release"}}],
     "pressure_model": "joint" | "per-run",
     "pressure_fits": {name: [q0, q1, q2]},            # the model's laws (refined if joint)
     "pressure_fits_per_run": {name: [q0, q1, q2]},    # the seeds' per-run quadratics
     "pressure_fit_stats": {name: {"r2", "degree", "residuals", "pressures", "values",
                                   "stderr", "method", "per_run_quadratic", "per_run_r2"}},
     "pressure_range_MPa": [lo, hi],
     "joint_fit": {"nrmse", "mean_nrmse", "mean_nrmse_per_run_quadratics", "orders",
                   "h0", "per_run": {nuisance name: [value per run]}, ...} | null,
     "validation": [{"file", "run", "muscle_pressure_MPa", "frequency_Hz", "status"
                     ("ok" | "extrapolated" | "diverged"), "message", "extrapolated",
                     "rmse", "nrmse", "fit_percent", "max_error", "energy_error_percent",
                     "branch_rmse"}],       # metrics null when the prediction diverged
     "warnings": [...]}

NaN/inf values are written as ``null`` (strict JSON).

``predictions.h5``: root attrs ``format = "pmalab.predictions"``, ``format_version = 1``,
``model``; one group ``/runs/<key>`` per identification and validation run with datasets
``time`` (s), ``position`` (mm, measured), ``muscle_pressure`` (MPa), ``force`` (N,
measured), ``force_model`` (N) and attrs ``role``, ``file``, ``run``,
``muscle_pressure_MPa``, ``frequency_Hz``, ``waveform``, ``model``.  For identification
runs ``force_model`` is the run's own fit; ``force_model_quadratic`` adds the
pressure-quadratic model's prediction.
"""

from __future__ import annotations

import datetime as _dt
import hashlib
import json
import math
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from pmalab import __version__
from pmalab.errors import PmalabError
from pmalab.identify.campaign import CampaignFit, ModelSpec, Validation, validate_runs
from pmalab.identify.estimation.joint import joint_stride
from pmalab.identify.estimation.solver import SOLVER_METHOD, STDERR_METHOD
from pmalab.identify.messages import as_message
from pmalab.identify.metrics import metrics
from pmalab.identify.model import ForceModel
from pmalab.identify.predictions import (  # noqa: F401  (the format's names, re-exported)
    PREDICTIONS_FORMAT,
    PREDICTIONS_VERSION,
    PredictionItem,
    write_predictions_file,
)
from pmalab.identify.schema import IdentificationDoc
from pmalab.identify.signals import Signals
from pmalab.paths import check_output, write_together
from pmalab.runfile import Run, decode_attr


def _clean(v: Any) -> Any:
    """JSON-safe: numpy → Python, NaN/inf → None."""
    if isinstance(v, dict):
        return {str(k): _clean(x) for k, x in v.items()}
    if isinstance(v, list | tuple):
        return [_clean(x) for x in v]
    if isinstance(v, np.ndarray):
        return _clean(v.tolist())
    if isinstance(v, np.generic):
        v = v.item()
    if isinstance(v, float) and not math.isfinite(v):
        return None
    return v


def _sha256(path: Path) -> str | None:
    try:
        h = hashlib.sha256()
        with open(path, "rb") as f:
            for chunk in iter(lambda: f.read(1 << 20), b""):
                h.update(chunk)
        return h.hexdigest()
    except OSError:
        return None


def _file_attrs(path: Path) -> dict:
    try:
        import h5py

        with h5py.File(path, "r") as f:
            return {k: decode_attr(v, parse_json=True) for k, v in f.attrs.items()}
    except (OSError, ImportError):
        return {}


def _run_provenance(run: Run) -> dict:
    keep = {}
    for k, v in run.attrs.items():
        keep[k] = decode_attr(v, parse_json=True)
    return keep


def _inputs(runs: list[tuple[Run, str]]) -> list[dict]:
    by_file: dict[str, dict] = {}
    for run, role in runs:
        key = run.file or "<memory>"
        d = by_file.setdefault(key, {"file": key, "runs": [], "roles": {}, "provenance": {}})
        d["runs"].append(run.name)
        d["roles"][run.name] = role
        d["provenance"].setdefault("runs", {})[run.name] = _run_provenance(run)
    for key, d in by_file.items():
        if key != "<memory>":
            p = Path(key)
            d["provenance"]["sha256"] = _sha256(p)
            d["provenance"]["size_bytes"] = p.stat().st_size if p.exists() else None
            d["provenance"]["file_attrs"] = _file_attrs(p)
    return list(by_file.values())


def _metric_block(m: dict) -> dict:
    return {
        "rmse": m["rmse"],
        "nrmse": m["nrmse"],
        "fit_percent": m["fit_percent"],
        "max_error": m["max_error"],
        "energy_error_percent": m["energy_error_percent"],
        "energy_measured_mJ_per_cycle": m.get("energy_measured_mJ_per_cycle"),
        "energy_model_mJ_per_cycle": m.get("energy_model_mJ_per_cycle"),
        "branch_rmse": dict(m["branch_rmse"]),
        # output error (--output position): the simulated position's errors, in m and mm
        **{k: m[k] for k in POSITION_KEYS if k in m},
    }


#: the position-error keys of a validation row when the model was fitted on position
POSITION_KEYS = ("rmse_position_m", "rmse_position_mm", "nrmse_position", "fit_percent_position")


def _output_error_block(cf) -> dict | None:
    """The ``output_error`` JSON block (None when the model was fitted on force)."""
    oe = cf.output_error
    if oe is None:
        return None
    return {
        "runs": list(oe.labels),
        "rmse_position_m": [v * 1e-3 for v in oe.rmse_mm],
        "nrmse_position": list(oe.nrmse),
        "rmse_position_m_start": [v * 1e-3 for v in oe.rmse_mm_start],
        "initial_state": {
            "x0_mm": oe.state["x0"],
            "v0_mm_per_s": oe.state["v0"],
            "h0_N": oe.state["h0"],
        },
        "substeps_per_sample": list(oe.n_sub),
        "orders": dict(oe.degree),
        "stderr_at_mean_pressure": dict(oe.stderr),
        "nfev": oe.nfev,
        "success": oe.success,
        "message": oe.message,
        "note": (
            "free-run simulation of the position from the measured force and pressure "
            "(velocity Verlet, implicit damping, exact hysteresis segments, inputs "
            "linear between samples); start state estimated per run"
        ),
    }


def identification_dict(res: Identification) -> IdentificationDoc:
    """The ``identification.json`` content of an :class:`Identification`
    (:class:`pmalab.identify.schema.IdentificationDoc`)."""
    cf = res.campaign
    model = cf.model
    names = cf.parameter_names
    units = {p.name: p.unit for p in cf.runs[0].result.params} if cf.runs else {}
    docs = {p.name: p.doc for p in cf.runs[0].result.params} if cf.runs else {}
    runs_out = []
    for rf, (_, q) in zip(cf.runs, res.quadratic_predictions()):
        r = rf.result
        runs_out.append(
            {
                "file": rf.file,
                "run": rf.run,
                "role": "identification",
                "muscle_pressure_MPa": rf.p_nom,
                "frequency_Hz": rf.frequency_Hz,
                "waveform": rf.waveform,
                "parameters": r.values,
                "stderr": r.stderr,
                "correlation": {
                    "names": list(r.names),
                    "matrix": np.asarray(r.correlation).tolist(),
                },
                "fixed": list(r.fixed),
                "warnings": list(r.warnings),
                "notes": list(r.notes),
                "messages": [as_message(m).to_dict() for m in [*r.warnings, *r.notes]],
                **_metric_block(r.metrics),
                "n_samples": r.n_samples,
                "n_eff": r.n_eff,
                "n_free": r.n_free,
                "aic": r.aic,
                "bic": r.bic,
                "condition_number": r.condition_number,
                "quadratic_model": {
                    "fit_percent": q["fit_percent"],
                    "nrmse": q["nrmse"],
                    "rmse": q["rmse"],
                },
            }
        )
    val_out = []
    for v in res.validation:
        run = v.run
        val_out.append(
            {
                "file": run.file,
                "run": run.name,
                "role": "validation",
                "muscle_pressure_MPa": run.nominal_pressure,
                "frequency_Hz": run.frequency,
                "waveform": str(run.attrs.get("waveform", "")),
                "status": v.status,
                "message": v.message,
                "extrapolated": cf.extrapolates(float(run.nominal_pressure)),
                "scored_from_s": float(run.time[v.scored_from] - run.time[0])
                if v.scored_from < len(run)
                else None,
                "noise_floor_nrmse": _floor(run, v.scored_from),
                **_metric_block(v.metrics),
            }
        )
    warnings = list(res.warnings)
    for rf in cf.runs:
        warnings += [f"{rf.label}: {w}" for w in rf.result.warnings]
    all_runs = [(r, "identification") for r in res.runs] + [
        (v.run, "validation") for v in res.validation
    ]
    out: dict[str, Any] = {
        "model": model.law.name,
        "model_full": model.name,
        "effects": [e.id for e in model.effects],
        "pmalab_version": __version__,
        "created": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"),
        "inputs": _inputs(all_runs),
        "parameter_names": names,
        "parameter_units": units,
        "parameter_docs": docs,
        "state_parameters": ["h0"],
        "runs": runs_out,
        "pressure_model": cf.pressure_model,
        "pressure_fits": {n: list(pf.coef) for n, pf in cf.pressure.items()},
        "pressure_fits_per_run": {n: list(pf.coef) for n, pf in cf.per_run_pressure.items()},
        "pressure_fit_stats": {n: pf.stats() for n, pf in cf.pressure.items()},
        "pressure_range_MPa": list(cf.pressure_range),
        "joint_fit": _joint_block(cf),
        # which pressure structure an element law's elements took, chosen how, by how much
        "pressure_structure": None if cf.structure is None else cf.structure.as_json(),
        "output": cf.output,
        "output_error": _output_error_block(cf),
        "parameter_bounds": {n: [float(lo), float(hi)] for n, (lo, hi) in cf.bounds.items()},
        "validation": val_out,
        "decimation": _decimation_block(res),
        "trajectory": list(res.trajectory),
        # each run's nominal pressure against its measured mean (label offsets named)
        "pressure_labels": _pressure_labels(all_runs),
        "warnings": warnings,
        "notes": list(res.notes),
        # every campaign message typed: kind (note | detail | warning), code, text, data
        "messages": [as_message(m).to_dict() for m in [*res.notes, *res.warnings]],
        "method": {
            "fit": "two-stage (linear LS for k, c0; grid over hysteresis shape with linear "
            f"scale) then joint least squares on free-run error by {SOLVER_METHOD}",
            "drive": "zero-phase Butterworth-filtered measured position, measured time stamps",
            "derivatives": derivatives_method(),
            "validation_scoring": (
                "record parameters (start state, record nuisances) estimated on each "
                "validation run's early part (whole cycles, about a third), metrics of the "
                "rest (validation[i].scored_from_s on)"
                if res.initial == "estimate"
                else "metrics of the whole run (no record parameter estimated on it)"
            ),
            "stderr": STDERR_METHOD,
            "initial_state_validation": res.initial,
            "pressure_fits": (
                "theta(p) = q0 + q1 p + q2 p^2 (p in MPa); start: per-run values weighted by "
                "1/stderr; joint: coefficients refined by least squares of the free-run error "
                "of all identification runs at once (per-run h0, each run's residual / (its "
                "per-run rmse * sqrt(N))), order 0-2 per parameter from the per-run fits and "
                "a Wald/BIC test on the joint fit; theta clipped into the law's bounds"
                if cf.pressure_model == "joint"
                else "theta(p) = q0 + q1 p + q2 p^2 (p in MPa), weighted by 1/stderr"
            ),
        },
    }
    return _clean(out)


def _pressure_labels(all_runs: list[tuple[Run, str]]) -> list[dict[str, Any]]:
    """Per run: nominal vs measured mean pressure, the tolerance and whether it is offset;
    ``label_MPa`` when the run's pressure was replaced by its measured mean."""
    from pmalab.identify.labels import check_runs

    rows = []
    for (run, role), c in zip(all_runs, check_runs([r for r, _ in all_runs], whole_run=True)):
        row: dict[str, Any] = {"file": run.file, "role": role, **c.as_json()}
        lab = run.attrs.get("muscle_pressure_label_MPa")
        if lab is not None:
            row["label_MPa"] = float(lab)
        rows.append(row)
    return rows


def derivatives_method() -> dict[str, Any]:
    """How velocity and acceleration are estimated (``method.derivatives``)."""
    from pmalab.identify.signals import DERIVATIVE_HARMONICS, DERIVATIVE_MIN_HZ

    return {
        "method": "zero-phase 4th-order Butterworth low-pass of the measured position, then "
        "central differences against the measured time stamps; one estimator for every "
        "velocity/acceleration term (identify, validate, diagnose, reports); the forward "
        "simulation and the controllers integrate velocity as a state",
        "cutoff": f"{DERIVATIVE_HARMONICS:g} x the excitation frequency, >= "
        f"{DERIVATIVE_MIN_HZ:g} Hz, <= sample rate / 5",
        "harmonics": DERIVATIVE_HARMONICS,
        "min_Hz": DERIVATIVE_MIN_HZ,
    }


def validation_floor(v: Validation) -> float | None:
    """The noise floor (nrmse) of a validation run as it is scored (None when undefined)."""
    return _floor(v.run, v.scored_from)


def validation_headline(validation: Iterable[Validation]) -> str:
    """One line: the mean validation nrmse and its multiple of the mean noise floor — the
    number ``pmalab diagnose`` quotes for the same model and held-out runs ("" when no run
    was validated or every prediction diverged)."""
    vals = [v for v in validation if not v.diverged and math.isfinite(float(v.metrics["nrmse"]))]
    if not vals:
        return ""
    nr = float(np.mean([float(v.metrics["nrmse"]) for v in vals]))
    fl = [f for f in (validation_floor(v) for v in vals) if f is not None and f > 0]
    if not fl:
        return f"validation: mean nrmse {nr:.4f} over {len(vals)} run(s)"
    floor = float(np.mean(fl))
    return (
        f"validation: mean nrmse {nr:.4f} over {len(vals)} run(s), {nr / floor:.1f}× the "
        f"noise floor {floor:.4f}"
    )


def _floor(run: Run, start: int) -> float | None:
    """The noise floor (nrmse) of a validation run's scored part (None when undefined)."""
    from pmalab.identify.noise import noise_sigma

    f = np.asarray(run.force, dtype=float)
    sd = float(np.std(f[start:])) if start < f.size else 0.0
    try:
        return noise_sigma(f, run.time) / sd if sd > 0 else None
    except ValueError:
        return None


def _decimation_block(res: Identification) -> list[dict]:
    """Per run, how many of its samples each stage used: ``read`` (a long record is read
    decimated, :mod:`pmalab.identify.long_records`; else whole), and the subsampling of the
    joint fit of the pressure laws (identification runs; never below 100 per cycle)."""
    out = []
    roles = [(r, "identification") for r in res.runs] + [
        (v.run, "validation") for v in res.validation
    ]
    for run, role in roles:
        n = len(run)
        dt = float(np.median(np.diff(run.time[: min(n, 4096)]))) if n > 1 else float("nan")
        fs = 1.0 / dt if dt > 0 else float("nan")
        f = run.frequency
        read = run.attrs.get("decimation") or {"stride": 1, "note": "read whole"}
        row: dict[str, Any] = {
            "file": run.file,
            "run": run.name,
            "role": role,
            "frequency_Hz": f,
            "samples": n,
            "sample_rate_Hz": fs,
            "read": read,
        }
        if run.attrs.get("fit_part"):  # a long record: the run-level fit's part of it
            row["fit_part"] = run.attrs["fit_part"]
        if role == "identification" and res.campaign.joint is not None and np.isfinite(fs):
            k = joint_stride(n, fs, f)
            row["joint_fit"] = {
                "stride": k,
                "samples": -(-n // k),
                "samples_per_cycle": (fs / k / f) if f else None,
            }
        out.append(row)
    return out


def _joint_block(cf) -> dict | None:
    """The ``joint_fit`` JSON block (None when the pressure laws were not refined jointly)."""
    j = cf.joint
    if j is None:
        return None
    return {
        "runs": [rf.label for rf in cf.runs],
        "nrmse": list(j.nrmse),
        "mean_nrmse": j.mean_nrmse,
        "nrmse_per_run_quadratics": list(cf.per_run_nrmse),
        "mean_nrmse_per_run_quadratics": (
            float(np.mean(cf.per_run_nrmse)) if cf.per_run_nrmse else None
        ),
        "nrmse_start": list(j.nrmse_start),
        "mean_nrmse_start": j.mean_nrmse_start,
        "orders": dict(j.degree),
        "constants": dict(j.constants),
        "h0": list(j.h0),
        # record nuisances (e.g. a load cell's drift rate): one value per run, in "runs" order
        "per_run": {n: [float(v) for v in vals] for n, vals in j.nuisance.items()},
        "legendre": {n: np.asarray(c).tolist() for n, c in j.legendre.items()},
        "legendre_stderr": {n: np.asarray(c).tolist() for n, c in j.legendre_stderr.items()},
        "n_eff": j.n_eff,
        "bic": j.bic,
        "nfev": j.nfev,
        "success": j.success,
        "message": j.message,
        "note": "nrmse of the free-run prediction on the subsampled identification runs",
    }


def _unique_key(grp, base: str) -> str:
    key = base.replace("/", "_")
    i = 2
    while key in grp:
        key = f"{base}__{i}"
        i += 1
    return key


def write_predictions(res: Identification, path: Path) -> None:
    """The identification's ``predictions.h5`` (:mod:`pmalab.identify.predictions`)."""
    cf = res.campaign
    name = cf.model.name
    items = [
        PredictionItem(run, "identification", rf.result.predict(run), name, fq)
        for rf, run, (fq, _) in zip(cf.runs, res.runs, res.quadratic_predictions())
    ]
    oe = cf.output_error
    if oe is not None:
        for it, xm in zip(items, oe.positions):
            it.position_model = xm
    items += [
        PredictionItem(v.run, "validation", v.force_model, name, position_model=v.position_model)
        for v in res.validation
    ]
    write_predictions_file(path, items, name)


def write_outputs(
    res: Identification, out_dir: str | Path, force: bool = False
) -> tuple[Path, Path]:
    """Write ``out_dir/identification.json`` and ``out_dir/predictions.h5``."""
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise PmalabError(f"{out}: exists and is not a directory")
    jpath = check_output(out / "identification.json", force)
    hpath = check_output(out / "predictions.h5", force)
    doc = identification_dict(res)
    out.mkdir(parents=True, exist_ok=True)
    write_together(
        {
            jpath: lambda p: p.write_text(json.dumps(doc, indent=1, allow_nan=False) + "\n"),
            hpath: lambda p: write_predictions(res, p),
        }
    )
    return jpath, hpath


# --------------------------------------------------------------------------- the result
@dataclass
class Identification:
    """Result of :func:`~pmalab.identify.api.identify`: per-run fits, pressure quadratics,
    validation.

    The model is F = k·x + c0 + h (+ the effects' terms), F the tension in N (positive
    pulls), x the contraction in mm (positive = shorter than nominal), h the hysteresis
    law's state in N; every parameter θ is fitted per run and then as a quadratic in the
    nominal muscle pressure p (MPa gauge): θ(p) = q0 + q1·p + q2·p².
    Tables: :attr:`parameters`, :attr:`pressure_table`, :attr:`validation_table`;
    figures: :meth:`plot_loops`; files: :meth:`save`.

    Attributes
    ----------
    campaign
        The campaign fit: per-run fits, the pressure laws, warnings.
    runs
        The identification runs, in canonical units.
    validation
        One :class:`Validation` per held-out run (its free-run prediction and metrics).
    spec
        The model's specification (law, effects, fixes).
    initial
        How a predicted record's own states are set (``"estimate"``: on its early part,
        every muscle parameter held).
    notes, validation_warnings
        Notes and warnings for the user, one line each.
    trajectory
        Long records: the model refitted window by window along each long run.
    """

    campaign: CampaignFit
    runs: list[Run]
    validation: list[Validation] = field(default_factory=list)
    spec: ModelSpec | None = None
    initial: str = "estimate"
    notes: list[str] = field(default_factory=list)
    #: warnings raised while validating (extrapolation, divergence)
    validation_warnings: list[str] = field(default_factory=list)
    #: long records: the model refitted window by window along each long run
    #: (:mod:`pmalab.identify.campaign.trajectory`); empty for a campaign of short runs
    trajectory: list[dict] = field(default_factory=list)

    # ---- model
    @property
    def model(self) -> ForceModel:
        """The force model identified: the hysteresis law and the effects added to it."""
        return self.campaign.model

    @property
    def warnings(self) -> list[str]:
        """Every warning of the identification and the validation, one line each."""
        return list(self.campaign.warnings) + list(self.validation_warnings)

    def theta(self, p_MPa: float) -> dict[str, float]:
        """The parameters at a nominal muscle pressure, from the pressure quadratics.

        Parameters
        ----------
        p_MPa
            Nominal muscle pressure, MPa gauge (extrapolating outside the identified
            pressures is unreliable).

        Returns
        -------
        dict of str to float
            θ(p) = q0 + q1·p + q2·p² per parameter name, in the parameter's own unit
            (``k`` N/mm, ``c0`` N, a law's shape parameters as the law states them).
        """
        return self.campaign.theta(p_MPa)

    def predict(self, run: Run, p_MPa: float | None = None) -> np.ndarray:
        """The model's free-run force on any run, driven by its position and pressure.

        Parameters
        ----------
        run
            A run (identification, held-out or new) in canonical units.
        p_MPa
            The nominal pressure whose parameters are used, MPa gauge; ``None``: the run's
            own nominal pressure.

        Returns
        -------
        numpy.ndarray
            The predicted tension, N (positive pulls), one value per sample of ``run``; the
            record's own states (initial h, an effect's nuisances) are estimated on it with
            every muscle parameter held.
        """
        return self.campaign.predict(run, p_MPa, initial=self.initial)

    def quadratic_predictions(self) -> list[tuple[np.ndarray, dict]]:
        """The pressure-quadratic model's prediction of each identification run.

        Returns
        -------
        list of (numpy.ndarray, dict)
            Per identification run, in order: the predicted tension (N) and its metrics
            (``rmse`` N, ``nrmse``, ``fit_percent``, ...), computed once and kept.
        """
        cache = getattr(self, "_quad_cache", None)
        if cache is None:
            cache = []
            for run in self.runs:
                sig = Signals.from_run(run)
                fq = self.campaign.predict(sig, force=run.force, initial=self.initial)
                cache.append((fq, metrics(run.force, fq, sig.x)))
            self._quad_cache = cache
        return cache

    def validate(self, runs: Iterable[Run]) -> list[Validation]:
        """Predict held-out runs with the pressure-quadratic model.

        Parameters
        ----------
        runs
            The held-out runs (never used in the fit).

        Returns
        -------
        list of Validation
            One per run: its free-run prediction (N) and metrics (``nrmse`` = RMS error /
            SD of the measured force); they are also appended to :attr:`validation`, and
            any warning (extrapolation, divergence) to :attr:`warnings`.
        """
        new, warns = validate_runs(self.campaign, runs, self.initial)
        self.validation.extend(new)
        self.validation_warnings.extend(warns)
        return new

    # ---- tables (pandas, imported lazily)
    @property
    def parameters(self):
        """One row per identification run: its own fitted parameters.

        Returns
        -------
        pandas.DataFrame
            Index ``run``; ``p_MPa`` (nominal pressure, MPa gauge), ``f_Hz``,
            ``fit_percent``, ``nrmse``, each parameter and its standard error
            (``<name>_stderr``), in the parameter's unit.
        """
        import pandas as pd

        rows = []
        for rf in self.campaign.runs:
            row = {
                "run": rf.label,
                "p_MPa": rf.p_nom,
                "f_Hz": rf.frequency_Hz,
                "fit_percent": rf.result.fit_percent,
                "nrmse": rf.result.nrmse,
            }
            for p in rf.result.params:
                row[p.name] = p.value
                row[f"{p.name}_stderr"] = p.stderr
            rows.append(row)
        return pd.DataFrame(rows).set_index("run")

    @property
    def pressure_table(self):
        """The pressure quadratics θ(p) = q0 + q1·p + q2·p², p in MPa gauge.

        Returns
        -------
        pandas.DataFrame
            Index ``parameter``; ``q0``, ``q1``, ``q2`` (units: the parameter's, per MPa,
            per MPa²), ``degree`` (0–2: reduced with fewer pressure levels), ``r2`` and
            ``method`` ("joint" = refined on all runs at once,
            :mod:`pmalab.identify.estimation.joint`).
        """
        import pandas as pd

        return pd.DataFrame(
            [
                {
                    "parameter": n,
                    "q0": pf.coef[0],
                    "q1": pf.coef[1],
                    "q2": pf.coef[2],
                    "degree": pf.degree,
                    "r2": pf.r2,
                    "method": pf.method,
                }
                for n, pf in self.campaign.pressure.items()
            ]
        ).set_index("parameter")

    @property
    def validation_table(self):
        """The validation metrics of each held-out run.

        Returns
        -------
        pandas.DataFrame
            Index ``run``; ``p_MPa``, ``f_Hz``, ``status``, ``fit_percent``, ``nrmse``,
            ``rmse_N``, ``max_error_N``, ``energy_error_percent`` (loop area, model vs
            measured), ``stretch_rmse_N`` and ``release_rmse_N`` (per loop branch); empty
            without validation runs.
        """
        import pandas as pd

        rows = []
        for v in self.validation:
            m = v.metrics
            rows.append(
                {
                    "run": v.run.label,
                    "p_MPa": v.run.nominal_pressure,
                    "f_Hz": v.run.frequency,
                    "status": v.status,
                    "fit_percent": m["fit_percent"],
                    "nrmse": m["nrmse"],
                    "rmse_N": m["rmse"],
                    "max_error_N": m["max_error"],
                    "energy_error_percent": m["energy_error_percent"],
                    "stretch_rmse_N": m["branch_rmse"]["stretch"],
                    "release_rmse_N": m["branch_rmse"]["release"],
                }
            )
        return pd.DataFrame(rows).set_index("run") if rows else pd.DataFrame()

    # ---- plots (matplotlib only)
    def plot_loops(self, which: str = "all", ncols: int = 3):
        """Force–position loops: measured (wide grey band) and model (thin blue line).

        Parameters
        ----------
        which
            ``"identification"``, ``"validation"`` or ``"all"`` runs.
        ncols
            Panels per row.

        Returns
        -------
        matplotlib.figure.Figure
            One panel per run: tension F (N) against contraction x (mm), with its fit %.
        """
        import matplotlib.pyplot as plt

        panels: list[tuple[str, np.ndarray, np.ndarray, np.ndarray]] = []
        if which in ("all", "identification"):
            for rf, run in zip(self.campaign.runs, self.runs):
                fm = rf.result.predict(run)
                panels.append(
                    (f"{rf.label}\nfit {rf.result.fit_percent:.1f} %", run.position, run.force, fm)
                )
        if which in ("all", "validation"):
            for v in self.validation:
                panels.append(
                    (
                        f"{v.run.label} (validation)\nfit {v.fit_percent:.1f} %",
                        v.run.position,
                        v.run.force,
                        v.force_model,
                    )
                )
        n = max(len(panels), 1)
        nc = min(ncols, n)
        nr = int(np.ceil(n / nc))
        fig, axes = plt.subplots(nr, nc, figsize=(4.2 * nc, 3.4 * nr), squeeze=False)
        for ax, (title, x, f, fm) in zip(axes.flat, panels):
            # the measurement as a wide band underneath, the model thinner on top: both
            # stay visible where they agree, and the band shows where the model leaves it
            ax.plot(
                x,
                f,
                color="0.55",
                lw=2.4,
                alpha=0.8,
                label="measured",
                solid_capstyle="round",
                zorder=1,
            )
            ax.plot(x, fm, color="#1f77b4", lw=0.9, label=self.model.name, zorder=2)
            ax.set_title(title, fontsize=8)
            ax.set_xlabel("contraction x (mm)")
            ax.set_ylabel("tension F (N)")
        for ax in list(axes.flat)[len(panels) :]:
            ax.set_visible(False)
        if panels:
            axes.flat[0].legend(fontsize=7)
        fig.tight_layout()
        return fig

    def plot_parameters(self):
        """Each parameter against pressure with ±stderr bars and its quadratic."""
        import matplotlib.pyplot as plt

        names = [n for n in self.campaign.parameter_names]
        nc = 3
        nr = int(np.ceil(len(names) / nc))
        fig, axes = plt.subplots(nr, nc, figsize=(4.0 * nc, 3.0 * nr), squeeze=False)
        for ax, name in zip(axes.flat, names):
            pf = self.campaign.pressure[name]
            se = [np.nan if s is None else s for s in pf.stderr]
            ax.errorbar(pf.pressures, pf.values, yerr=se, fmt="o", ms=4)
            pp = np.linspace(min(pf.pressures), max(pf.pressures), 50)
            ax.plot(pp, pf(pp), lw=1)
            ax.set_title(f"{name}  (R² {pf.r2:.3f})", fontsize=9)
            ax.set_xlabel("muscle pressure (MPa)")
        for ax in list(axes.flat)[len(names) :]:
            ax.set_visible(False)
        fig.tight_layout()
        return fig

    # ---- output
    def save(self, out_dir: str | Path, force: bool = False) -> tuple[Path, Path]:
        """Write ``identification.json`` and ``predictions.h5``, as ``pmalab identify`` does.

        Parameters
        ----------
        out_dir
            The directory to write (made when missing).
        force
            Overwrite existing outputs; without it an existing file is refused and nothing
            is written.

        Returns
        -------
        tuple of (Path, Path)
            The paths of ``identification.json`` and ``predictions.h5``.

        Raises
        ------
        pmalab.errors.OutputExistsError
            An output exists and ``force`` is false.
        """
        return write_outputs(self, out_dir, force=force)

    def __repr__(self) -> str:
        lines = [
            f"Identification({self.model.name}: {len(self.campaign.runs)} runs, "
            f"{len(self.validation)} validation)"
        ]
        for rf in self.campaign.runs:
            lines.append(
                f"  identify  {rf.label:40s} p={rf.p_nom:.4g} MPa  fit {rf.result.fit_percent:6.2f} %"
            )
        for v in self.validation:
            lines.append(
                f"  validate  {v.run.label:40s} p={v.run.nominal_pressure:.4g} MPa  "
                + ("DIVERGED" if v.diverged else f"fit {v.fit_percent:6.2f} %")
                + ("" if v.status == "ok" else f"  ({v.status})")
            )
        lines += [f"  warning: {w}" for w in self.warnings]
        return "\n".join(lines)
