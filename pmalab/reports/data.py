"""Reading an identification/diagnosis output directory for the report.

The directory contract (written by ``pmalab identify`` / ``pmalab diagnose``):

* ``identification.json`` — model, runs with parameters/stderr/correlation/metrics,
  pressure quadratics, validation metrics, warnings;
* ``diagnosis.json`` — effect ranking, ladder, residual diagnostics, summary;
* ``predictions.h5`` — root attr ``format = "pmalab.predictions"``; one group
  ``/runs/<key>`` per run with 1-D float datasets ``time`` (s), ``position`` (mm,
  contraction, positive = shorter), ``muscle_pressure`` (MPa), ``force`` (N tension,
  measured), ``force_model`` (N, model prediction) and attrs ``role``
  (identification|validation|diagnosis), ``file``, ``run``, ``muscle_pressure_MPa``,
  ``frequency_Hz``, ``waveform``, ``model``.

Every malformed input becomes one :class:`ReportError` line naming the file and the key
(``DIR/identification.json: runs[1].parameters: missing key``).  Keys the report needs
are required; the optional ones (metrics, correlation, diagnostics...) may be absent and
their pages or cells are then skipped.
"""

from __future__ import annotations

import math
import re
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, cast

import numpy as np

from pmalab.config import load_json
from pmalab.identify.predictions import PREDICTIONS_FORMAT  # the one declaration
from pmalab.reports.errors import ReportError
from pmalab.runfile import decode_attr

IDENTIFICATION_JSON = "identification.json"
DIAGNOSIS_JSON = "diagnosis.json"
PREDICTIONS_H5 = "predictions.h5"
TRACE_CHANNELS = ("time", "position", "muscle_pressure", "force", "force_model")
#: roles the report draws; a trace with another (string) role is read but not drawn.
#: ``diagnosis-final`` is the diagnosis's final model (base + the effects the ladder added).
ROLES = ("identification", "validation", "diagnosis", "diagnosis-final")
#: role prefix of the traces of a second (improved) identification directory
IMPROVED = "improved-"


# --------------------------------------------------------------------------- traces
@dataclass
class Trace:
    """One run's measured and modelled signals (canonical units: s, mm, MPa, N).

    ``position`` is the contraction (positive = shorter than nominal) and ``force`` the
    tension; ``force_model`` is the model's prediction of ``force`` for the same input.
    """

    key: str
    role: str
    time: np.ndarray
    position: np.ndarray
    muscle_pressure: np.ndarray
    force: np.ndarray
    force_model: np.ndarray
    file: str = ""
    run: str = ""
    muscle_pressure_MPa: float = float("nan")
    frequency_Hz: float | None = None
    waveform: str = ""
    model: str = ""
    #: the free-run simulated position (mm) of a model fitted on position (output error)
    position_model: np.ndarray | None = None

    @property
    def label(self) -> str:
        """``file:run`` with the file's base name (or the group key)."""
        if self.run:
            return f"{Path(self.file).name}:{self.run}" if self.file else self.run
        return self.key

    @property
    def error(self) -> np.ndarray:
        """Residual: measured minus model tension (N), as in diagnosis.json (positive =
        model tension too low)."""
        return self.force - self.force_model

    @property
    def nrmse(self) -> float:
        """RMS error / standard deviation of the measured force (docs/reference/json.md)."""
        sd = float(np.std(self.force))
        return float(np.sqrt(np.mean(self.error**2)) / sd) if sd > 0 else float("nan")

    @property
    def fit_percent(self) -> float:
        return 100.0 * (1.0 - self.nrmse)

    def describe(self) -> str:
        """``p = 0.476 MPa, 0.15 Hz sine`` (what a panel title needs)."""
        parts = [f"p = {self.muscle_pressure_MPa:.3f} MPa"]
        if self.frequency_Hz is not None and math.isfinite(self.frequency_Hz):
            parts.append(f"{self.frequency_Hz:g} Hz {self.waveform}".rstrip())
        elif self.waveform:
            parts.append(self.waveform)
        return ", ".join(parts)


@dataclass
class ReportData:
    """Everything a report is made of; ``identification``/``diagnosis`` are the parsed
    (and checked) JSON documents or None when absent."""

    directory: Path
    #: every directory the data came from (several when identify and diagnose wrote apart)
    directories: list[Path] = field(default_factory=list)
    identification: dict[str, Any] | None = None
    diagnosis: dict[str, Any] | None = None
    traces: list[Trace] = field(default_factory=list)
    #: a second identification (e.g. ``identify --add EFFECT``) drawn beside the first; its
    #: traces carry the roles ``improved-identification`` / ``improved-validation``
    improved: dict[str, Any] | None = None

    def traces_with_role(self, role: str) -> list[Trace]:
        return [t for t in self.traces if t.role == role]

    @property
    def model(self) -> str:
        doc = self.identification or self.diagnosis or {}
        return str(doc.get("model", ""))


# --------------------------------------------------------------------------- JSON checks
class _Doc:
    """Typed key access into one JSON document; failures name file and key path."""

    def __init__(self, path: Path):
        self.path = path

    def fail(self, where: str, msg: str) -> ReportError:
        return ReportError(f"{self.path}: {where}: {msg}" if where else f"{self.path}: {msg}")

    def get(
        self,
        obj: dict,
        key: str,
        where: str,
        kind: str,
        *,
        required: bool = True,
        nullable: bool = False,
    ) -> Any:
        at = f"{where}.{key}" if where else key
        if not isinstance(obj, dict):
            raise self.fail(where, "expected an object")
        if key not in obj:
            if required:
                raise self.fail(at, "missing key")
            return None
        v = obj[key]
        if v is None and (nullable or not required):
            return None
        self.check(v, at, kind)
        return v

    def check(self, v: Any, at: str, kind: str) -> None:
        ok = {
            "number": isinstance(v, int | float) and not isinstance(v, bool),
            "str": isinstance(v, str),
            "list": isinstance(v, list),
            "dict": isinstance(v, dict),
            "bool": isinstance(v, bool),
            "any": True,
        }[kind]
        if not ok:
            raise self.fail(at, f"expected {kind}, got {type(v).__name__}")

    def numbers(self, v: Any, at: str, *, nullable: bool = False) -> list[float]:
        self.check(v, at, "list")
        out = []
        for i, x in enumerate(v):
            if x is None and nullable:
                out.append(float("nan"))
                continue
            self.check(x, f"{at}[{i}]", "number")
            out.append(float(cast(float, x)))
        return out

    def number_map(self, v: Any, at: str, *, nullable: bool = False) -> dict[str, float]:
        self.check(v, at, "dict")
        out = {}
        for k, x in v.items():
            if x is None and nullable:
                out[k] = float("nan")
                continue
            self.check(x, f"{at}.{k}", "number")
            out[k] = float(cast(float, x))
        return out


def _load_json(path: Path) -> tuple[dict, _Doc]:
    doc = _Doc(path)
    obj = load_json(path, "result file", error=ReportError)
    if not isinstance(obj, dict):
        raise doc.fail("", "expected a JSON object at the top level")
    return obj, doc


_METRICS = ("rmse", "nrmse", "fit_percent", "max_error", "energy_error_percent")


def _check_metrics(doc: _Doc, r: dict, where: str) -> None:
    doc.get(r, "nrmse", where, "number")
    for k in _METRICS:
        doc.get(r, k, where, "number", required=False)
    br = doc.get(r, "branch_rmse", where, "dict", required=False)
    if br is not None:
        doc.number_map(br, f"{where}.branch_rmse", nullable=True)
    doc.get(r, "file", where, "str")
    doc.get(r, "run", where, "str")
    doc.get(r, "muscle_pressure_MPa", where, "number")
    doc.get(r, "frequency_Hz", where, "number", required=False)
    doc.get(r, "waveform", where, "str", required=False)


def check_identification(obj: dict, path: Path) -> dict:
    """Check an ``identification.json`` document; return it (unchanged) or raise."""
    doc = _Doc(path)
    doc.get(obj, "model", "", "str")
    names = doc.get(obj, "parameter_names", "", "list")
    for i, n in enumerate(names):
        doc.check(n, f"parameter_names[{i}]", "str")
    doc.get(obj, "effects", "", "list", required=False)
    runs = doc.get(obj, "runs", "", "list")
    for i, r in enumerate(runs):
        w = f"runs[{i}]"
        doc.check(r, w, "dict")
        _check_metrics(doc, r, w)
        params = doc.number_map(doc.get(r, "parameters", w, "dict"), f"{w}.parameters")
        for n in names:
            if n not in params and n not in (r.get("fixed") or []):
                raise doc.fail(f"{w}.parameters.{n}", "missing key")
        se = doc.get(r, "stderr", w, "dict", required=False)
        if se is not None:
            doc.number_map(se, f"{w}.stderr", nullable=True)
        corr = doc.get(r, "correlation", w, "dict", required=False)
        if corr is not None:
            cn = doc.get(corr, "names", f"{w}.correlation", "list")
            m = doc.get(corr, "matrix", f"{w}.correlation", "list")
            if len(m) != len(cn):
                raise doc.fail(f"{w}.correlation.matrix", f"has {len(m)} rows for {len(cn)} names")
            for j, row in enumerate(m):
                vals = doc.numbers(row, f"{w}.correlation.matrix[{j}]", nullable=True)
                if len(vals) != len(cn):
                    raise doc.fail(
                        f"{w}.correlation.matrix[{j}]",
                        f"has {len(vals)} entries for {len(cn)} names",
                    )
        for k in ("fixed", "warnings"):
            v = doc.get(r, k, w, "list", required=False)
            for j, x in enumerate(v or []):
                doc.check(x, f"{w}.{k}[{j}]", "str")
    fits = doc.get(obj, "pressure_fits", "", "dict", required=False) or {}
    for n, q in fits.items():
        doc.numbers(q, f"pressure_fits.{n}", nullable=True)
    stats = doc.get(obj, "pressure_fit_stats", "", "dict", required=False) or {}
    for n, s in stats.items():
        w = f"pressure_fit_stats.{n}"
        doc.check(s, w, "dict")
        doc.get(s, "r2", w, "number", required=False, nullable=True)
    val = doc.get(obj, "validation", "", "list", required=False) or []
    for i, v in enumerate(val):
        doc.check(v, f"validation[{i}]", "dict")
        _check_metrics(doc, v, f"validation[{i}]")
    for i, x in enumerate(doc.get(obj, "warnings", "", "list", required=False) or []):
        doc.check(x, f"warnings[{i}]", "str")
    inputs = doc.get(obj, "inputs", "", "list", required=False) or []
    for i, inp in enumerate(inputs):
        doc.check(inp, f"inputs[{i}]", "dict")
        doc.get(inp, "file", f"inputs[{i}]", "str")
        doc.get(inp, "provenance", f"inputs[{i}]", "dict", required=False)
    return obj


def check_diagnosis(obj: dict, path: Path) -> dict:
    """Check a ``diagnosis.json`` document; return it (unchanged) or raise."""
    doc = _Doc(path)
    doc.get(obj, "model", "", "str")
    ranking = doc.get(obj, "ranking", "", "list")
    for i, r in enumerate(ranking):
        w = f"ranking[{i}]"
        doc.check(r, w, "dict")
        doc.get(r, "effect", w, "str")
        doc.get(r, "nrmse_before", w, "number")
        doc.get(r, "nrmse_after", w, "number")
        doc.get(r, "significant", w, "bool")
        doc.get(r, "gain_x_floor", w, "number", required=False)
        doc.get(r, "explanation", w, "str", required=False)
    amb = doc.get(obj, "ambiguous", "", "list", required=False) or []
    for i, x in enumerate(amb):
        doc.check(x, f"ambiguous[{i}]", "str")
    doc.get(obj, "suggested_experiment", "", "str", required=False)
    doc.get(obj, "summary", "", "str", required=False)
    ladder = doc.get(obj, "ladder", "", "list", required=False) or []
    for i, s in enumerate(ladder):
        w = f"ladder[{i}]"
        doc.check(s, w, "dict")
        doc.get(s, "step", w, "number")
        doc.get(s, "nrmse", w, "number")
        doc.get(s, "fit_percent", w, "number", required=False)
        doc.get(s, "added", w, "str", required=False, nullable=True)
    diags = doc.get(obj, "diagnostics", "", "dict", required=False) or {}
    for key, d in diags.items():
        w = f"diagnostics.{key}"
        doc.check(d, w, "dict")
        binned = doc.get(d, "binned", w, "dict", required=False) or {}
        for var, b in binned.items():
            wb = f"{w}.binned.{var}"
            doc.check(b, wb, "dict")
            centers = doc.get(b, "centers", wb, "list")
            mean = doc.numbers(doc.get(b, "mean", wb, "list"), f"{wb}.mean", nullable=True)
            if len(centers) != len(mean):
                raise doc.fail(f"{wb}.mean", f"has {len(mean)} values for {len(centers)} centers")
            ci = doc.get(b, "ci95", wb, "list", required=False)
            if ci is not None and len(ci) != len(centers):
                raise doc.fail(f"{wb}.ci95", f"has {len(ci)} values for {len(centers)} centers")
            doc.get(b, "unit", wb, "str", required=False)
        for kind in ("acf", "ccf_input"):
            c = doc.get(d, kind, w, "dict", required=False)
            if c is None:
                continue
            lags = doc.numbers(doc.get(c, "lags_s", f"{w}.{kind}", "list"), f"{w}.{kind}.lags_s")
            vals = doc.numbers(
                doc.get(c, "values", f"{w}.{kind}", "list"), f"{w}.{kind}.values", nullable=True
            )
            if len(lags) != len(vals):
                raise doc.fail(f"{w}.{kind}.values", f"has {len(vals)} values for {len(lags)} lags")
            doc.get(c, "bound95", f"{w}.{kind}", "number", required=False)
        doc.get(d, "worst_region", w, "str", required=False)
        doc.get(d, "nrmse", w, "number", required=False, nullable=True)
        doc.get(d, "nrmse_final", w, "number", required=False, nullable=True)
        for i, c in enumerate(doc.get(d, "regions", w, "list", required=False) or []):
            wr = f"{w}.regions[{i}]"
            doc.check(c, wr, "dict")
            doc.get(c, "branch", wr, "str")
            doc.get(c, "position", wr, "str")
            doc.get(c, "rms", wr, "number", nullable=True)
            doc.get(c, "mean", wr, "number", required=False, nullable=True)
        ph = doc.get(d, "loop_phase", w, "dict", required=False)
        if ph is not None:
            wp = f"{w}.loop_phase"
            c = doc.numbers(doc.get(ph, "centers_deg", wp, "list"), f"{wp}.centers_deg")
            for k in ("mean", "rms"):
                v = doc.get(ph, k, wp, "list", required=False)
                if v is not None and len(doc.numbers(v, f"{wp}.{k}", nullable=True)) != len(c):
                    raise doc.fail(f"{wp}.{k}", f"has {len(v)} values for {len(c)} centers")
    camp = doc.get(obj, "campaign_diagnostics", "", "dict", required=False) or {}
    for var, c in camp.items():
        wc = f"campaign_diagnostics.{var}"
        doc.check(c, wc, "dict")
        centers = doc.numbers(doc.get(c, "centers", wc, "list"), f"{wc}.centers")
        for k in ("rms", "mean", "ci95_rms"):
            v = doc.get(c, k, wc, "list", required=False)
            if v is not None and len(doc.numbers(v, f"{wc}.{k}", nullable=True)) != len(centers):
                raise doc.fail(f"{wc}.{k}", f"has {len(v)} values for {len(centers)} centers")
        doc.get(c, "unit", wc, "str", required=False)
    doc.get(obj, "final_model", "", "str", required=False)
    return obj


# --------------------------------------------------------------------------- predictions
def read_predictions(path: Path) -> list[Trace]:
    """Read ``predictions.h5``; one :class:`Trace` per ``/runs/<key>`` group, in file order."""
    import h5py

    try:
        f = h5py.File(path, "r")
    except OSError:
        raise ReportError(f"{path}: not a readable HDF5 file") from None
    with f:
        fmt = decode_attr(f.attrs.get("format"))
        if fmt != PREDICTIONS_FORMAT:
            raise ReportError(f"{path}: format: expected {PREDICTIONS_FORMAT!r}, got {fmt!r}")
        if "runs" not in f:
            raise ReportError(f"{path}: no '/runs' group")
        out = []
        runs = f["runs"]
        if not isinstance(runs, h5py.Group):
            raise ReportError(f"{path}: '/runs' is not a group")
        for key in runs:
            g = runs[key]
            where = f"{path}: /runs/{key}"
            if not isinstance(g, h5py.Group):
                raise ReportError(f"{where}: not a group")
            chans: dict[str, np.ndarray] = {}
            for ch in TRACE_CHANNELS:
                if ch not in g:
                    raise ReportError(f"{where}/{ch}: missing dataset")
                a = np.asarray(cast(h5py.Dataset, g[ch])[()], dtype=np.float64)
                if a.ndim != 1:
                    raise ReportError(f"{where}/{ch}: expected 1-D, got shape {a.shape}")
                chans[ch] = a
            n = {c: a.shape[0] for c, a in chans.items()}
            if len(set(n.values())) != 1:
                desc = ", ".join(f"{c}={m}" for c, m in n.items())
                raise ReportError(f"{where}: datasets have unequal lengths ({desc})")
            if n["time"] < 2:
                raise ReportError(f"{where}/time: too few samples ({n['time']})")
            attrs = {k: decode_attr(v) for k, v in g.attrs.items()}
            role = attrs.get("role")
            if not isinstance(role, str) or not role:
                raise ReportError(
                    f"{where}: attr 'role': expected a string such as "
                    f"{', '.join(ROLES)}, got {role!r}"
                )
            freq = attrs.get("frequency_Hz")
            xm = None
            if "position_model" in g:
                xm = np.asarray(cast(h5py.Dataset, g["position_model"])[()], dtype=np.float64)
                if xm.shape != chans["time"].shape:
                    raise ReportError(
                        f"{where}/position_model: {xm.shape[0] if xm.ndim else 0} "
                        f"samples, time has {n['time']}"
                    )
            out.append(
                Trace(
                    position_model=xm,
                    key=str(key),
                    role=str(role),
                    file=str(attrs.get("file", "")),
                    run=str(attrs.get("run", key)),
                    muscle_pressure_MPa=float(
                        attrs.get("muscle_pressure_MPa", np.mean(chans["muscle_pressure"]))
                    ),
                    frequency_Hz=None if freq is None else float(freq),
                    waveform=str(attrs.get("waveform", "")),
                    model=str(attrs.get("model", "")),
                    **chans,
                )
            )
        return out


def load_report_dir(directory: str | Path | Sequence[str | Path]) -> ReportData:
    """Read and check one result directory, or several merged into one report; raise
    :class:`ReportError` on any problem.

    At most two directories may hold an ``identification.json``: the first is the base
    model, the second the improved one (``identify --add``), drawn side by side; at most
    one may hold a ``diagnosis.json``."""
    dirs = [Path(directory)] if isinstance(directory, str | Path) else [Path(d) for d in directory]
    if not dirs:
        raise ReportError("no result directory given")
    data = ReportData(directory=dirs[0], directories=dirs)
    seen: dict[str, Path] = {}
    given: dict[Path, Path] = {}
    for d in dirs:
        if not d.exists():
            raise ReportError(f"{d}: no such directory")
        if not d.is_dir():
            raise ReportError(f"{d}: not a directory")
        if d.resolve() in given:
            first = given[d.resolve()]
            same = "" if str(first) == str(d) else f" (the same directory as {first})"
            raise ReportError(f"{d}: directory given twice{same}: give each once")
        given[d.resolve()] = d
        ident, diag = d / IDENTIFICATION_JSON, d / DIAGNOSIS_JSON
        if not ident.exists() and not diag.exists():
            raise ReportError(
                f"{d}: holds neither {IDENTIFICATION_JSON} nor {DIAGNOSIS_JSON} "
                "(run 'pmalab identify' or 'pmalab diagnose' with --out there)"
            )
        if diag.exists() and DIAGNOSIS_JSON in seen:
            raise ReportError(
                f"{diag}: a second {DIAGNOSIS_JSON} (the first is in "
                f"{seen[DIAGNOSIS_JSON]}); give one diagnosis directory"
            )
        second = ident.exists() and IDENTIFICATION_JSON in seen
        if second and data.improved is not None:
            raise ReportError(
                f"{ident}: a third {IDENTIFICATION_JSON}; give at most two "
                "identification directories (BASE_DIR IMPROVED_DIR)"
            )
        if second and diag.exists():
            raise ReportError(
                f"{d}: holds the second {IDENTIFICATION_JSON} and a "
                f"{DIAGNOSIS_JSON}; give the improved identification its own "
                "directory"
            )
        if ident.exists():
            obj, _ = _load_json(ident)
            if second:
                data.improved = check_identification(obj, ident)
            else:
                data.identification = check_identification(obj, ident)
                seen[IDENTIFICATION_JSON] = d
        if diag.exists():
            obj, _ = _load_json(diag)
            data.diagnosis = check_diagnosis(obj, diag)
            seen[DIAGNOSIS_JSON] = d
        pred = d / PREDICTIONS_H5
        if pred.exists():
            traces = read_predictions(pred)
            if second:
                for t in traces:
                    t.role = IMPROVED + t.role
            data.traces.extend(traces)
    _check_same_runs(data, seen)
    return data


def _ident_runs(doc: dict) -> set[tuple[str, str]]:
    """(file name, run) of every identification and validation row of a document."""
    return {
        (Path(str(r.get("file") or "")).name, str(r.get("run", "")))
        for r in [*doc.get("runs", []), *doc.get("validation", [])]
    }


def _check_same_runs(data: ReportData, seen: dict[str, Path]) -> None:
    """Refuse directories that describe different recordings: an improved identification
    or a diagnosis sharing no run with the base identification would be drawn side by side
    with it as if they were one campaign (most likely a wrong directory was given)."""
    base = data.identification
    if base is None:
        return
    keys = _ident_runs(base)
    where = seen[IDENTIFICATION_JSON]
    if data.improved is not None and not keys & _ident_runs(data.improved):
        other = next(
            d for d in data.directories if d != where and (d / IDENTIFICATION_JSON).exists()
        )
        raise ReportError(
            f"{other}: its identification shares no run with {where}'s (files "
            f"{', '.join(sorted({f for f, _ in _ident_runs(data.improved)}))} against "
            f"{', '.join(sorted({f for f, _ in keys}))}): BASE_DIR and IMPROVED_DIR must "
            "identify the same runs"
        )
    diag = (data.diagnosis or {}).get("diagnostics") or {}
    if diag:
        dkeys = set()
        for label in diag:  # "file:run", or "run" for a run that was never in a file
            file, sep, run = str(label).partition(":")
            if not sep:
                file, run = "", file
            dkeys.add((file, re.sub(r"\[held-out\]$", "", run)))
        if not keys & dkeys:
            raise ReportError(
                f"{seen[DIAGNOSIS_JSON]}: its diagnosis shares no run with {where}'s "
                f"identification (files {', '.join(sorted({f for f, _ in dkeys}))} against "
                f"{', '.join(sorted({f for f, _ in keys}))}): give directories of the same "
                "runs"
            )
