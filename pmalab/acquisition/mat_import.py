"""MATLAB ``.mat`` → runs: v5/v7 (scipy.io) and v7.3 (an HDF5 file behind a 512-byte
MATLAB header, read with h5py).

Three layouts are understood, tried in this order:

* **one struct per run**: every struct variable whose fields include the channels becomes a
  run named after the variable (``run1.time``, ``run1.position`` ...);
* **one variable per channel**: vectors named as the CSV importer's columns (``time``,
  ``position``, ``force``, ``muscle_pressure``, or ``--time-col`` ...): one run named after
  the file;
* **one matrix**: a 2-D numeric variable (``--columns`` names its columns by position,
  ``-`` skipping one; with several matrices ``--run`` is not enough, give the layout and
  keep one matrix per file).

MATLAB has no units: ``--units`` says them (default s, mm, N, MPa).  v7.3 stores arrays
transposed (column-major); vectors are flattened and an N×k matrix is read as N rows.
Sign convention: position = contraction; ``--negate position`` flips elongation.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from pmalab.acquisition.csv_import import CsvImportOptions, finish_run, match_named, read_head
from pmalab.errors import RunFileError
from pmalab.runfile import CANONICAL_UNITS, Run

#: what a v7.3 file starts with (its HDF5 superblock follows at byte 512)
_V73_TEXT = b"MATLAB 7.3 MAT-file"


def _load(path: Path) -> dict[str, Any]:
    """{variable: numpy array or {field: array}} of a .mat file of any version."""
    head = read_head(path, "MATLAB", 128)
    if head.startswith(_V73_TEXT) or head[:8] == b"\x89HDF\r\n\x1a\n":
        return _load_v73(path)
    if not head.startswith(b"MATLAB 5.0 MAT-file"):
        if head[:4] == b"\x00\x00\x00\x00" or len(head) < 128:
            pass  # v4 files have no text header: let scipy decide
        else:
            raise RunFileError(
                f"{path}: not a MATLAB .mat file (no 'MATLAB 5.0' or 'MATLAB 7.3' header)"
            )
    import scipy.io

    try:
        doc = scipy.io.loadmat(str(path), squeeze_me=True, struct_as_record=False)
    except Exception as exc:  # scipy raises ValueError/TypeError/MatReadError on damage
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise RunFileError(f"{path}: not a readable MATLAB file ({first[:120]})") from None
    out: dict[str, Any] = {}
    for k, v in doc.items():
        if k.startswith("__"):
            continue
        if hasattr(v, "_fieldnames"):  # a struct
            out[k] = {f: np.asarray(getattr(v, f)) for f in v._fieldnames}
        else:
            out[k] = np.asarray(v)
    return out


def _load_v73(path: Path) -> dict[str, Any]:
    import h5py

    def arr(ds) -> np.ndarray:
        a = np.asarray(ds[()])
        return a.T if a.ndim == 2 else a  # MATLAB is column-major: (k, N) on disk is N×k

    out: dict[str, Any] = {}
    try:
        with h5py.File(path, "r") as f:
            for k, obj in f.items():
                if k.startswith("#"):  # '#refs#' and '#subsystem#': MATLAB's internals
                    continue
                if isinstance(obj, h5py.Group):
                    out[k] = {fk: arr(fv) for fk, fv in obj.items() if isinstance(fv, h5py.Dataset)}
                elif isinstance(obj, h5py.Dataset):
                    out[k] = arr(obj)
    except (OSError, RuntimeError, KeyError, ValueError, TypeError) as exc:
        # h5py: OSError for an unreadable file, RuntimeError/KeyError for damaged links
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise RunFileError(f"{path}: not a readable MATLAB 7.3 file ({first[:120]})") from None
    return out


def _numeric(path: Path, where: str, a: Any) -> np.ndarray:
    a = np.asarray(a)
    if a.dtype.kind not in "iuf":
        raise RunFileError(f"{path}: {where}: not numbers ({a.dtype})")
    return a.astype(np.float64)


def _run_from_vectors(
    path: Path, name: str, vecs: dict[str, Any], opts: CsvImportOptions, where: str
) -> Run:
    found = match_named(
        [k for k, v in vecs.items() if np.asarray(v).dtype.kind in "iuf"],
        opts,
        where,
        what="variable",
    )
    raw: dict[str, tuple[np.ndarray, str]] = {}
    for ch, var in found.items():
        v = _numeric(path, f"variable '{var}'", vecs[var])
        if v.ndim > 1 and min(v.shape) != 1:
            raise RunFileError(
                f"{where}: variable '{var}' is a {v.shape[0]}×{v.shape[1]} matrix, not a vector"
            )
        v = v.ravel()
        if ch in opts.negate:
            v = -v
        raw[ch] = (v, opts.units.get(ch, CANONICAL_UNITS[ch]))
    lengths = {found[ch]: len(v) for ch, (v, _) in raw.items()}
    if len(set(lengths.values())) > 1:
        raise RunFileError(
            f"{where}: variables of different lengths "
            f"({', '.join(f'{k}={n}' for k, n in lengths.items())})"
        )
    return finish_run(path, name, raw, opts, "mat import", {"variables": found})


def _run_from_matrix(path: Path, name: str, var: str, m: np.ndarray, opts: CsvImportOptions) -> Run:
    m = _numeric(path, f"variable '{var}'", m)
    layout = opts.layout or []
    if m.ndim != 2:
        raise RunFileError(f"{path}: variable '{var}': a {m.ndim}-D array, not a matrix")
    if m.shape[1] != len(layout) and m.shape[0] == len(layout):
        m = m.T  # channels in rows
    if m.shape[1] != len(layout):
        raise RunFileError(
            f"{path}: variable '{var}': {m.shape[1]} columns but --columns names "
            f"{len(layout)}; name every column ('-' skips one)"
        )
    raw: dict[str, tuple[np.ndarray, str]] = {}
    for i, ch in enumerate(layout):
        if ch is None:
            continue
        v = m[:, i]
        raw[ch] = (-v if ch in opts.negate else v, opts.units.get(ch, CANONICAL_UNITS[ch]))
    return finish_run(path, name, raw, opts, "mat import", {"variable": var, "layout": layout})


def read_mat_runs(path: str | Path, opts: CsvImportOptions) -> list[Run]:
    """The runs of a MATLAB file (v5 or v7.3; the module doc gives the layouts).

    Parameters
    ----------
    path
        The .mat file.
    opts
        Which variable is which channel, units, ``negate``, and for one matrix the names
        of its columns (:class:`~pmalab.acquisition.csv_import.CsvImportOptions`).

    Returns
    -------
    list of Run
        One run per struct holding position and force vectors, else one run of the file's
        vectors or matrix (named ``opts.run`` or the file's stem), in canonical units:
        time s, position mm (contraction positive), force N (tension positive), pressure
        MPa gauge.

    Raises
    ------
    pmalab.errors.RunFileError
        One line naming the file, struct or variable.
    """
    path = Path(path)
    doc = _load(path)
    if not doc:
        raise RunFileError(f"{path}: no variables")
    structs = {k: v for k, v in doc.items() if isinstance(v, dict)}
    wanted = {opts.columns.get(c, c).lower() for c in ("position", "force")}
    run_structs = {k: v for k, v in structs.items() if wanted <= {f.lower() for f in v}}
    if run_structs:
        if opts.run and len(run_structs) > 1:
            raise RunFileError(
                f"--run: names one run, but {path} has {len(run_structs)} run structs"
            )
        return [
            _run_from_vectors(path, opts.run or k, v, opts, f"{path}: struct '{k}'")
            for k, v in run_structs.items()
        ]
    arrays = {k: v for k, v in doc.items() if not isinstance(v, dict)}
    if opts.layout is not None:
        mats = [
            k for k, v in arrays.items() if np.asarray(v).ndim == 2 and min(np.asarray(v).shape) > 1
        ]
        if len(mats) != 1:
            raise RunFileError(
                f"{path}: --columns names a matrix's columns, but the file has "
                f"{len(mats)} matrices ({', '.join(mats) or 'none'})"
            )
        return [_run_from_matrix(path, opts.run or path.stem, mats[0], arrays[mats[0]], opts)]
    return [_run_from_vectors(path, opts.run or path.stem, arrays, opts, str(path))]
