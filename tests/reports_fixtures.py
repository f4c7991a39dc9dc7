"""Synthetic result directories in the identify/diagnose output contract, for report tests.

``write_identification_dir`` / ``write_diagnosis_dir`` write exactly the layout the
identification and diagnosis tools produce (identification.json, diagnosis.json,
predictions.h5) from a small closed-form hysteresis so the tests need no fitting.
"""

from __future__ import annotations

import json
from pathlib import Path

import h5py
import numpy as np

PARAMS = ["k", "c0", "A", "beta", "gamma", "n"]
ID_PRESSURES = [0.3102, 0.4762, 0.6]
VAL_RUNS = [("val.h5", "p0498", 0.498, 0.1), ("val.h5", "p0304", 0.304, 0.3)]


def synthetic_trace(p: float, f_hz: float, *, n: int = 600, seed: int = 0,
                    model_error: float = 0.05) -> dict[str, np.ndarray]:
    """A muscle-like loop: tension falls with contraction, is higher while stretching
    (x decreasing); the "model" misses part of the hysteresis by ``model_error``."""
    rng = np.random.default_rng(seed)
    cycles = 2.0
    t = np.linspace(0.0, cycles / f_hz, n)
    x = 12.0 + 8.0 * np.sin(2 * np.pi * f_hz * t)  # mm contraction
    xdot = np.gradient(x, t)
    h = -25.0 * np.tanh(xdot / (0.5 * np.max(np.abs(xdot))))  # friction: higher on stretch
    force = 2500 * p - 20.0 * x + h + rng.normal(0, 1.0, n)
    force_model = 2500 * p - 20.0 * x + (1 - 4 * model_error) * h
    pressure = p + 0.002 * np.sin(2 * np.pi * f_hz * t) + rng.normal(0, 2e-4, n)
    return {"time": t, "position": x, "muscle_pressure": pressure, "force": force,
            "force_model": force_model}


def _nrmse(tr: dict[str, np.ndarray]) -> float:
    e = tr["force_model"] - tr["force"]
    return float(np.sqrt(np.mean(e**2)) / np.std(tr["force"]))


def _metrics(tr: dict[str, np.ndarray]) -> dict:
    e = tr["force_model"] - tr["force"]
    nr = _nrmse(tr)
    return {"rmse": float(np.sqrt(np.mean(e**2))), "nrmse": nr, "fit_percent": 100 * (1 - nr),
            "max_error": float(np.max(np.abs(e))), "energy_error_percent": 3.2,
            "branch_rmse": {"stretch": 2.1, "release": 1.7}}


def write_predictions(path: Path, entries: list[tuple[str, str, str, str, float, float, dict]],
                      model: str) -> None:
    """entries: (key, role, file, run, p, f, trace)."""
    with h5py.File(path, "w") as f:
        f.attrs["format"] = "pmalab.predictions"
        g = f.create_group("runs")
        for key, role, file, run, p, fq, tr in entries:
            r = g.create_group(key)
            for ch, v in tr.items():
                r.create_dataset(ch, data=np.asarray(v, dtype=float))
            r.attrs.update({"role": role, "file": file, "run": run, "muscle_pressure_MPa": p,
                            "frequency_Hz": fq, "waveform": "sine", "model": model})


#: the added effect of the "improved" identification (``identify --add``) and its parameters
ADDED_EFFECT = "asymmetric-hysteresis"
ADDED_PARAMS = ["asym_psi_h", "asym_g"]


def identification_doc(*, pressures=ID_PRESSURES, validation=VAL_RUNS,
                       improved: bool = False) -> tuple[dict, list]:
    """An identification.json document and its prediction entries; ``improved``: the same
    runs identified with :data:`ADDED_EFFECT` (extra parameters, smaller model errors)."""
    err = 0.25 if improved else 1.0  # the improved model misses a quarter of the base's error
    runs, entries = [], []
    rng = np.random.default_rng(1)
    for i, p in enumerate(pressures):
        tr = synthetic_trace(p, 0.15, seed=i, model_error=0.05 * err)
        name = f"p{int(round(p * 1e4)):04d}"
        params = {"k": -40.0 + 5 * p, "c0": 1500 * p, "A": 3.0 + p, "beta": 0.02 + 0.01 * p,
                  "gamma": 0.01 - 0.005 * p, "n": 1.0}
        if improved:
            params.update({"k": params["k"] + 1.5, "asym_psi_h": 0.004 + 0.002 * p,
                           "asym_g": 0.1 - 0.05 * p})
        se = {k: abs(v) * 0.02 for k, v in params.items()}
        se["n"] = None
        corr = np.eye(5)
        corr[3, 4] = corr[4, 3] = 0.998
        corr[2, 3] = corr[3, 2] = -0.6
        runs.append({
            "file": "ident.h5", "run": name, "role": "identification",
            "muscle_pressure_MPa": p, "frequency_Hz": 0.15, "waveform": "sine",
            "parameters": params, "stderr": se,
            "correlation": {"names": PARAMS[:5], "matrix": corr.tolist()},
            "fixed": ["n"], "warnings": ["beta and gamma correlated (rho = 0.998)"] if i == 0 else [],
            **_metrics(tr),
            "quadratic_model": {"nrmse": _nrmse(tr) * 1.1},
        })
        entries.append((f"ident__{name}", "identification", "ident.h5", name, p, 0.15, tr))
        rng.normal()
    ps = np.array(pressures)
    fits, stats = {}, {}
    names = PARAMS + (ADDED_PARAMS if improved else [])
    for n_ in names:
        vals = np.array([r["parameters"][n_] for r in runs])
        q = np.polyfit(ps, vals, 2)[::-1] if len(ps) >= 3 else np.array([vals.mean(), 0, 0])
        fits[n_] = q.tolist()
        stats[n_] = {"r2": 0.99, "residuals": [0.0] * len(ps), "pressures": ps.tolist(),
                     "values": vals.tolist(), "stderr": [abs(v) * 0.02 for v in vals]}
    val = []
    for j, (file, run, p, fq) in enumerate(validation):
        tr = synthetic_trace(p, fq, seed=10 + j, model_error=0.08 * err)
        val.append({"file": file, "run": run, "muscle_pressure_MPa": p, "frequency_Hz": fq,
                    **_metrics(tr)})
        entries.append((f"val__{run}", "validation", file, run, p, fq, tr))
    doc = {
        "model": "bouc-wen", "effects": [ADDED_EFFECT] if improved else [],
        "pmalab_version": "0.1.0",
        "created": "2026-11-21T09:00:00+00:00",
        "inputs": [
            {"file": "ident.h5", "runs": [r["run"] for r in runs],
             "provenance": {
                 "sha256": "ab" * 32, "size_bytes": 1234567,
                 "file_attrs": {"created_utc": "2026-11-21T08:00:00+00:00",
                                "protocol_name": "seed-bouc-wen", "clock": "virtual",
                                "sample_rate_Hz": 500.0, "software_version": "0.1.0",
                                "rig": {"kind": "sim", "rig_file": "sim", "seed": 0,
                                        "truth_values": {"muscle": {"max_force_N": 1500.0}}},
                                "limits": '{"max_force_N": 2000.0}'},
                 "runs": {r["run"]: {"role": "identification", "status": "completed",
                                     "muscle_pressure_MPa": r["muscle_pressure_MPa"],
                                     "frequency_Hz": 0.15, "waveform": "sine", "cycles": 2,
                                     "timing": {"duration_s": 13.3, "n_samples": 6668.0,
                                                "late": 0.0, "missed": 0.0,
                                                "lateness_p99_s": 2e-5,
                                                "lateness_max_s": 1e-4}}
                          for r in runs}}},
            {"file": "val.h5", "runs": [v[1] for v in validation], "provenance": {}},
        ],
        "parameter_names": names, "runs": runs, "pressure_fits": fits,
        "pressure_fit_stats": stats, "validation": val,
        "warnings": ["beta, gamma nearly collinear: n held fixed at 1"],
    }
    return doc, entries


def diagnosis_doc() -> dict:
    rng = np.random.default_rng(3)
    centers = np.linspace(4, 20, 8)

    def binned(unit, c=centers):
        return {"centers": list(map(float, c)), "mean": rng.normal(0, 2, len(c)).tolist(),
                "ci95": [0.8] * (len(c) - 1) + [None], "unit": unit}

    lags = (np.arange(40) * 0.05).tolist()
    acf = np.exp(-np.arange(40) / 8.0)
    ccf_lags = (np.arange(-39, 40) * 0.05).tolist()
    ccf = 0.5 * np.exp(-np.abs(np.arange(-39, 40)) / 8.0) * np.cos(np.arange(-39, 40) / 6)
    doc = {
        "model": "bouc-wen",
        "ranking": [
            {"effect": "viscous-friction", "nrmse_before": 0.12, "nrmse_after": 0.04,
             "significant": True, "gain_x_floor": 12.0, "n_params": 1,
             "explanation": "residual correlates with velocity; a viscous term removes it"},
            {"effect": "asymmetric-hysteresis", "nrmse_before": 0.12, "nrmse_after": 0.11,
             "significant": False, "gain_x_floor": 0.2, "n_params": 2,
             "explanation": "small branch asymmetry"},
            {"effect": "sensor-delay", "nrmse_before": 0.12, "nrmse_after": 0.118,
             "significant": False, "gain_x_floor": -0.1, "n_params": 1,
             "explanation": "no lag in the cross-correlation"},
        ],
        "ambiguous": [],
        "ladder": [
            {"step": 0, "effects": [], "added": None, "nrmse": 0.12, "fit_percent": 88.0},
            {"step": 1, "effects": ["viscous-friction"], "added": "viscous-friction",
             "nrmse": 0.04, "fit_percent": 96.0},
            {"step": 2, "effects": ["viscous-friction", "asymmetric-hysteresis"],
             "added": "asymmetric-hysteresis", "nrmse": 0.037, "fit_percent": 96.3},
        ],
        "diagnostics": {
            "ident.h5:p4762": {
                "binned": {
                    "position": binned("mm"),
                    "velocity": binned("mm/s", np.linspace(-8, 8, 9)),
                    "velocity_sign": binned("-", np.array([-1.0, 1.0])),
                    "acceleration": binned("mm/s²", np.linspace(-5, 5, 7)),
                    "pressure_deviation": binned("MPa", np.linspace(-0.004, 0.004, 6)),
                    "time": binned("s", np.linspace(0, 13, 10)),
                    "branch": binned("-", np.array([-1.0, 1.0])),
                },
                "acf": {"lags_s": lags, "values": acf.tolist(), "bound95": 0.08},
                "ccf_input": {"lags_s": ccf_lags, "values": ccf.tolist(), "bound95": 0.08,
                              "input": "position", "peak_lag_s": 0.0},
                "rmse": 4.2, "nrmse": 0.12, "nrmse_final": 0.037,
                "worst_region": "stretch, high contraction (x 14.7–20.0 mm): rms error 6.1 N "
                                "(1.5× the run's 4.2 N), mean +3.9 N: model tension too low",
                "regions": [
                    {"branch": b, "position": pos, "x_range_mm": [0.0, 1.0], "n": 100,
                     "rms": rms, "mean": mean}
                    for (b, pos), rms, mean in zip(
                        [(b, pos) for b in ("stretch branch (x falling)",
                                            "release branch (x rising)")
                         for pos in ("low contraction", "mid contraction", "high contraction")],
                        [3.1, 4.0, 6.1, 2.5, 3.0, 3.3], [1.0, 2.2, 3.9, -0.4, -1.0, None])
                ],
                "loop_phase": {"centers_deg": [22.5 + 45 * i for i in range(8)],
                               "rms": [3.0, 3.5, 5.0, 6.0, 5.5, 3.8, 3.0, 2.9],
                               "mean": [0.1, 1.0, 3.0, 3.9, 2.5, -0.5, -1.0, None],
                               "note": "0° = maximum contraction"},
            }
        },
        "summary": "viscous-friction explains most of the residual (nrmse 0.12 → 0.04).",
        "final_model": "bouc-wen+viscous-friction+asymmetric-hysteresis",
        "campaign_diagnostics": {
            "pressure_level": {"centers": [0.3102, 0.4762], "mean": [0.5, -0.2],
                               "rms": [5.0, 4.2], "ci95_rms": [None, None], "unit": "MPa"},
            "frequency": {"centers": [0.15], "mean": [0.1], "rms": [4.6], "ci95_rms": [1.0],
                          "unit": "Hz"},
        },
    }
    # a second run with only an autocorrelation: worse, so its page comes first
    doc["diagnostics"]["ident.h5:p3102"] = {
        "rmse": 6.0, "nrmse": 0.2, "nrmse_final": 0.05,
        "acf": {"lags_s": lags, "values": (0.8 * acf).tolist(), "bound95": 0.08},
        "worst_region": "release branch, low contraction"}
    return doc


def write_identification_dir(d: Path, **kw) -> Path:
    d.mkdir(parents=True, exist_ok=True)
    doc, entries = identification_doc(**kw)
    (d / "identification.json").write_text(json.dumps(doc, indent=1))
    write_predictions(d / "predictions.h5", entries, doc["model"])
    return d


def write_improved_dir(d: Path, **kw) -> Path:
    """The "improved" identification (``identify --add asymmetric-hysteresis``) of the same
    runs as :func:`write_identification_dir`."""
    return write_identification_dir(d, improved=True, **kw)


def write_diagnosis_dir(d: Path, *, with_predictions: bool = True) -> Path:
    d.mkdir(parents=True, exist_ok=True)
    (d / "diagnosis.json").write_text(json.dumps(diagnosis_doc(), indent=1))
    if with_predictions:
        entries = []
        for i, p in enumerate([0.3102, 0.4762]):
            name = f"p{int(round(p * 1e4)):04d}"
            entries.append((f"diag__{name}", "diagnosis", "ident.h5", name, p, 0.15,
                            synthetic_trace(p, 0.15, seed=20 + i, model_error=0.1)))
            entries.append((f"diag__{name}-final", "diagnosis-final", "ident.h5", name, p, 0.15,
                            synthetic_trace(p, 0.15, seed=20 + i, model_error=0.01)))
        write_predictions(d / "predictions.h5", entries, "bouc-wen")
    return d


def write_full_dir(d: Path) -> Path:
    """identification.json + diagnosis.json + predictions (identification and validation)."""
    write_identification_dir(d)
    (d / "diagnosis.json").write_text(json.dumps(diagnosis_doc(), indent=1))
    return d
