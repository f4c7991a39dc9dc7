"""Reading an identification/diagnosis output directory for the report.

The directory contract (written by ``pmalab identify`` / ``pmalab diagnose``):

* ``identification.json`` — model, runs with parameters/stderr/correlation/metrics,
  pressure quadratics, validation metrics, warnings;
* ``diagnosis.json`` — effect ranking, ladder, residual diagnostics, summary;
* ``laws.json`` (``pmalab identify --model a,b,c``) — the laws ranked, each law's
  identification in the sub-directory named after it; the best law is the report's
  identification and every law's held-out predictions are drawn side by side;
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
from typing import Any

import numpy as np

from pmalab.config import load_json
from pmalab.identify import schema  # the files' structure and readers (one declaration)
from pmalab.identify.schema import DIAGNOSIS_JSON, IDENTIFICATION_JSON, PREDICTIONS_H5
from pmalab.reports.errors import ReportError

TRACE_CHANNELS = schema.PREDICTION_CHANNELS
#: roles the report draws; a trace with another (string) role is read but not drawn.
#: ``diagnosis-final`` is the diagnosis's final model (base + the effects the ladder added).
ROLES = ("identification", "validation", "diagnosis", "diagnosis-final")
#: role prefix of the traces of a second (improved) identification directory
IMPROVED = "improved-"
#: the ranked laws of ``pmalab identify --model a,b,c`` (one sub-directory per law)
LAWS_JSON = "laws.json"


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
class LawEntry:
    """One law of a ``laws.json`` directory: its row, its identification and its traces."""

    row: dict[str, Any]
    identification: dict[str, Any]
    traces: list[Trace]

    @property
    def law(self) -> str:
        return str(self.row["law"])

    def validation(self) -> list[Trace]:
        return [t for t in self.traces if t.role == "validation"]


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
    #: the laws of a ``laws.json`` directory, best first (empty otherwise)
    laws: list[LawEntry] = field(default_factory=list)
    #: the held-out runs' noise floor (nrmse) the laws were ranked against
    laws_noise_floor: float | None = None

    def traces_with_role(self, role: str) -> list[Trace]:
        return [t for t in self.traces if t.role == role]

    @property
    def model(self) -> str:
        doc = self.identification or self.diagnosis or {}
        return str(doc.get("model", ""))


# --------------------------------------------------------------------------- JSON checks
# The key-and-type checks are the schema's (:mod:`pmalab.identify.schema`, one source);
# what is left here are the report's cross-checks (lengths that must agree, names that
# must be there).
class _Doc:
    """Failures naming file and key path."""

    def __init__(self, path: Path):
        self.path = path

    def fail(self, where: str, msg: str) -> ReportError:
        return ReportError(f"{self.path}: {where}: {msg}" if where else f"{self.path}: {msg}")

    def same_length(self, v: Any, at: str, n: int, what: str) -> None:
        if isinstance(v, list) and len(v) != n:
            raise self.fail(at, f"has {len(v)} values for {n} {what}")


def _load_json(path: Path) -> dict:
    obj = load_json(path, "result file", error=ReportError)
    if not isinstance(obj, dict):
        raise _Doc(path).fail("", "expected a JSON object at the top level")
    return obj


def check_identification(obj: dict, path: Path) -> dict:
    """Check an ``identification.json`` document; return it (unchanged) or raise."""
    ident = schema.check_identification(obj, path, error=ReportError)
    doc = _Doc(path)
    names = ident["parameter_names"]
    for i, r in enumerate(ident["runs"]):
        w = f"runs[{i}]"
        for n in names:
            if n not in r["parameters"] and n not in (r.get("fixed") or []):
                raise doc.fail(f"{w}.parameters.{n}", "missing key")
        corr = r.get("correlation")
        if corr is not None:
            cn, m = corr["names"], corr["matrix"]
            if len(m) != len(cn):
                raise doc.fail(f"{w}.correlation.matrix", f"has {len(m)} rows for {len(cn)} names")
            for j, row in enumerate(m):
                if len(row) != len(cn):
                    raise doc.fail(
                        f"{w}.correlation.matrix[{j}]",
                        f"has {len(row)} entries for {len(cn)} names",
                    )
    return obj


def check_diagnosis(obj: dict, path: Path) -> dict:
    """Check a ``diagnosis.json`` document; return it (unchanged) or raise."""
    diag = schema.check_diagnosis(obj, path, error=ReportError)
    doc = _Doc(path)
    for key, d in (diag.get("diagnostics") or {}).items():
        w = f"diagnostics.{key}"
        for var, b in (d.get("binned") or {}).items():
            wb = f"{w}.binned.{var}"
            n = len(b["centers"])
            doc.same_length(b["mean"], f"{wb}.mean", n, "centers")
            doc.same_length(b.get("ci95"), f"{wb}.ci95", n, "centers")
        for kind in ("acf", "ccf_input"):
            c = d.get(kind)
            if c is not None:
                doc.same_length(c["values"], f"{w}.{kind}.values", len(c["lags_s"]), "lags")
        ph = d.get("loop_phase")
        if ph is not None:
            for k in ("mean", "rms"):
                doc.same_length(ph.get(k), f"{w}.loop_phase.{k}", len(ph["centers_deg"]), "centers")
    for var, c in (diag.get("campaign_diagnostics") or {}).items():
        wc = f"campaign_diagnostics.{var}"
        for k in ("rms", "mean", "ci95_rms"):
            doc.same_length(c.get(k), f"{wc}.{k}", len(c["centers"]), "centers")
    return obj


# --------------------------------------------------------------------------- predictions
def read_predictions(path: Path) -> list[Trace]:
    """Read ``predictions.h5``; one :class:`Trace` per ``/runs/<key>`` group, in file order
    (the reading and checks are :func:`pmalab.identify.schema.read_predictions`)."""
    out = []
    for r in schema.read_predictions(path, error=ReportError).runs:
        a, attrs = r.arrays, r.attrs
        freq = attrs.get("frequency_Hz")
        out.append(
            Trace(
                key=r.key,
                role=r.role,
                time=a["time"],
                position=a["position"],
                muscle_pressure=a["muscle_pressure"],
                force=a["force"],
                force_model=a["force_model"],
                position_model=a.get("position_model"),
                file=str(attrs.get("file", "")),
                run=str(attrs.get("run", r.key)),
                muscle_pressure_MPa=float(
                    attrs.get("muscle_pressure_MPa", np.mean(a["muscle_pressure"]))
                ),
                frequency_Hz=None if freq is None else float(freq),
                waveform=str(attrs.get("waveform", "")),
                model=str(attrs.get("model", "")),
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
    dirs = _expand_laws(dirs, data)
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
            obj = _load_json(ident)
            if second:
                data.improved = check_identification(obj, ident)
            else:
                data.identification = check_identification(obj, ident)
                seen[IDENTIFICATION_JSON] = d
        if diag.exists():
            obj = _load_json(diag)
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


def _expand_laws(dirs: list[Path], data: ReportData) -> list[Path]:
    """Read a ``laws.json`` directory into ``data.laws``; return ``dirs`` with it replaced
    by its best law's directory (the report's identification).  A laws directory is given
    alone or with one diagnosis directory: its best law is the base of the report."""
    laws_dirs = [d for d in dirs if (d / LAWS_JSON).is_file()]
    if not laws_dirs:
        return dirs
    if len(laws_dirs) > 1:
        raise ReportError(f"{laws_dirs[1]}: a second {LAWS_JSON}; give one laws directory")
    ld = laws_dirs[0]
    for d in dirs:
        if d != ld and (d / IDENTIFICATION_JSON).exists():
            raise ReportError(
                f"{d}: an identification beside the laws directory {ld}: give the laws "
                "directory alone (its best law is the report's identification)"
            )
    path = ld / LAWS_JSON
    doc = schema.read_laws(path, error=ReportError)
    if not doc["laws"]:
        raise ReportError(f"{path}: laws: empty list (no law to report)")
    data.laws_noise_floor = doc["noise_floor_nrmse"]
    for i, row in enumerate(doc["laws"]):
        sub = ld / row["law"]  # identify --model a,b,c writes OUT/<law>/
        ident = sub / IDENTIFICATION_JSON
        if not ident.exists():
            raise ReportError(
                f"{path}: laws[{i}] ({row['law']}): {ident} is missing (the directory was "
                "moved or pruned; re-run pmalab identify --model ...)"
            )
        pred = sub / PREDICTIONS_H5
        data.laws.append(
            LawEntry(
                row=dict(row),
                identification=check_identification(_load_json(ident), ident),
                traces=read_predictions(pred) if pred.exists() else [],
            )
        )
    best = ld / doc["laws"][0]["law"]
    return [best if d == ld else d for d in dirs]


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
