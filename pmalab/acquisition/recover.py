"""``pmalab recover``: turn a run file whose writer died into a plainly closed HDF5 file.

:func:`pmalab.runfile.read_runs` already reads such a file (it opens it in SWMR-read mode),
but other tools (HDFView, MATLAB ``h5read``, a plain ``h5py.File(path, "r")``) refuse it
while its "open for write" flag is set.  ``recover`` copies everything into a fresh file
(temporary name, then an atomic rename), marks each run that was cut mid-recording
(status ``running``) as ``aborted: recording interrupted (writer killed; recovered)``, and
leaves finished and never-started runs as they were.

A healthy file (it opens without SWMR, no run is cut mid-recording) is left alone: there
is nothing to recover, and rewriting a good file in place only risks it; ``force``
rewrites it anyway.
"""

from __future__ import annotations

import os
import warnings
from pathlib import Path
from typing import cast

import numpy as np

from pmalab.errors import RunFileError, RunFileWarning
from pmalab.paths import output_failure
from pmalab.runfile import (
    CHECKSUM,
    FORMAT,
    create_run_group,
    open_h5,
    read_samples,
    recording_by,
)


def is_healthy(path: Path) -> bool:
    """True when ``path`` opens as a plain HDF5 file (no "open for write" flag left by a
    killed writer) and none of its runs has the status ``running``."""
    import h5py

    try:
        f = h5py.File(path, "r")
    except OSError:
        return False
    try:
        if f.attrs.get("format") not in (FORMAT, FORMAT.encode()):
            return False  # not ours: recover() names the problem
        runs = f.get("runs")
        if runs is None:
            return True
        if not isinstance(runs, h5py.Group):
            return False  # damaged: recover() names the problem
        for name in runs:
            g = runs[name]
            if not isinstance(g, h5py.Group):
                return False
            status_ds = g.get("status")
            if isinstance(status_ds, h5py.Dataset):
                status = status_ds[()]
                if isinstance(status, bytes) and status.rstrip(b"\x00 ") == b"running":
                    return False
        return True
    finally:
        f.close()


def _is_channel(obj) -> bool:
    """A per-sample dataset: 1-D, resizable, with units (subgroups' too: ``gains/...``)."""
    import h5py

    return (
        isinstance(obj, h5py.Dataset)
        and obj.ndim == 1
        and obj.maxshape == (None,)
        and "units" in obj.attrs
    )


def _channel_values(path: Path, run: str, g) -> tuple[dict[str, np.ndarray], list[str]]:
    """Every channel of run group ``g`` read whole (by its path in the group), and the words
    of any loss: a killed writer's torn last chunk keeps the samples its old checksum
    verifies, else the run is cut at that chunk (:func:`pmalab.runfile.read_samples`)."""
    killed = _is_running(g)
    values: dict[str, np.ndarray] = {}
    losses: list[str] = []

    def visit(name: str, obj) -> None:
        if _is_channel(obj):
            v, lost = read_samples(path, run, name, obj, killed=killed)
            values[name] = v
            if lost:
                losses.append(lost)

    g.visititems(visit)
    return values, losses


def _is_running(g) -> bool:
    import h5py

    st = g.get("status")
    return (
        isinstance(st, h5py.Dataset)
        and st.shape == ()
        and isinstance(st[()], bytes)
        and st[()].rstrip(b"\x00 ") == b"running"
    )


def _copy_group(src, dst, n: int, values: dict[str, np.ndarray], prefix: str = "") -> None:
    """Copy ``src``'s datasets and subgroups into ``dst``; channels (``values``, read by
    :func:`_channel_values`, keyed by path in the run group) cut to ``n`` samples."""
    import h5py

    for c in src:
        obj = src[c]
        if isinstance(obj, h5py.Group):
            sub = dst.create_group(c)
            for k, v in obj.attrs.items():
                sub.attrs[k] = v
            _copy_group(obj, sub, n, values, f"{prefix}{c}/")
            continue
        if obj.chunks is not None:  # samples: chunked as recorded, each chunk checksummed
            data = values[prefix + c][:n] if _is_channel(obj) else obj[()]
            new = dst.create_dataset(
                c,
                data=data,
                dtype=obj.dtype,
                chunks=obj.chunks,
                maxshape=obj.maxshape,
                **CHECKSUM,
            )
        else:
            new = dst.create_dataset(c, data=obj[()], dtype=obj.dtype)
        for k, v in obj.attrs.items():
            new.attrs[k] = v


def recover(
    path: str | Path, out: str | Path | None = None, *, force: bool = False
) -> list[str] | None:
    """Rewrite ``path`` (or into ``out``) as a closed file; return the runs marked aborted,
    or None when the file is healthy and ``force`` is not given (nothing is written)."""
    import h5py

    from pmalab.paths import check_output

    src_path = Path(path)
    if not src_path.exists():
        raise RunFileError(f"{src_path}: no such file")
    if src_path.is_dir():
        raise RunFileError(f"{src_path}: is a directory, not a run file")
    dst_path = Path(out) if out is not None else src_path
    if out is not None:
        check_output(dst_path, force)
    if not force and is_healthy(src_path):
        return None
    # plain read first; SWMR-read only for the "already open for write" flag a killed
    # writer leaves (a damaged file opened in SWMR mode makes HDF5 retry its reads forever)
    src = open_h5(src_path)
    writer = recording_by(src)
    if writer is not None:  # its writer is alive: there is nothing to recover
        src.close()
        raise RunFileError(
            f"{src_path}: still being recorded by {writer}: nothing to recover (recover a "
            "file whose writer was killed; this one is closed when its recording ends)"
        )
    tmp = dst_path.with_name(dst_path.name + ".recovering")
    try:  # --out may name a new directory, as every other verb's output may
        dst_path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        src.close()
        raise output_failure(dst_path, exc, f"be written from {src_path}") from None
    fixed: list[str] = []
    losses: list[str] = []
    try:
        if src.attrs.get("format") not in (FORMAT, FORMAT.encode()):
            raise RunFileError(f"{src_path}: not a pmalab run file")
        with h5py.File(tmp, "w") as dst:
            for k, v in src.attrs.items():
                dst.attrs[k] = v
            runs = dst.create_group("runs", track_order=True)
            src_runs = src["runs"]
            if not isinstance(src_runs, h5py.Group):
                raise RunFileError(f"{src_path}: damaged run file ('/runs' is not a group)")
            for name in src_runs.keys():
                g = src_runs[name]
                if not isinstance(g, h5py.Group):
                    raise RunFileError(
                        f"{src_path}: damaged run file (run '{name}' is not a group)"
                    )
                d = create_run_group(runs, name)
                for k, v in g.attrs.items():
                    d.attrs[k] = v
                values, lost = _channel_values(src_path, name, g)
                losses.extend(lost)
                _copy_group(g, d, min((v.size for v in values.values()), default=0), values)
                if "status" in g:
                    status_ds = g["status"]
                    if not isinstance(status_ds, h5py.Dataset):
                        raise RunFileError(
                            f"{src_path}: damaged run file (run '{name}': "
                            "'status' is not a dataset)"
                        )
                    status = status_ds[()].decode("utf-8", "replace").rstrip("\x00 ")
                    if status == "running":
                        # _copy_group copied the status dataset into d
                        cast(h5py.Dataset, d["status"])[()] = np.bytes_(
                            b"aborted: recording interrupted (writer killed; recovered)"
                        )
                        fixed.append(name)
        src.close()
        os.replace(tmp, dst_path)
    except BaseException as exc:
        src.close()
        tmp.unlink(missing_ok=True)
        if isinstance(exc, KeyError):
            raise RunFileError(f"{src_path}: damaged run file (missing {exc})") from None
        if isinstance(exc, OSError):  # unwritable destination, full disk, damaged source
            what = "be recovered" if out is None else f"be written from {src_path}"
            raise output_failure(dst_path, exc, what) from None
        raise
    for words in losses:  # a torn last chunk's cut samples: never silently
        warnings.warn(RunFileWarning(words), stacklevel=2)
    return fixed
