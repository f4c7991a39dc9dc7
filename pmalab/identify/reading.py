"""Reading a campaign's run files for identification, here or in a child process.

:func:`read_files` is what :func:`pmalab.identify.api.load` does: every complete run of
the given files, canonical units, long runs read decimated
(:mod:`pmalab.identify.long_records`).  It needs NumPy and h5py only.

:func:`start_reading` runs it in a forked child while this process goes on importing the
fitting code (SciPy, numba: half a second that reading HDF5 does not need), so on two
cores the two overlap; :meth:`Reading.result` takes the runs back through a pipe.  The
runs are pickled, so every sample arrives bit for bit, and the warnings the child's
reading raised (a skipped aborted run...) are shown here, in order, as they would have
been.  Whatever goes wrong in the child (an unreadable file, a broken pipe, a signal),
:meth:`Reading.result` returns None and the caller reads the files itself, so errors and
their messages are exactly those of reading in process.

The child is forked only where that is safe and pays: on Linux with two cores or more,
before NumPy (and with it BLAS's threads) is loaded, in a process running one thread, and
for files of modest size
(:data:`MAX_BYTES`; a long record is read here, a window at a time, rather than copied
through a pipe).
"""

from __future__ import annotations

import os
import pickle
import signal
import sys
import threading
import warnings
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from pmalab.runfile import Run

#: the child reads only when the files hold at most this many bytes in all (larger runs
#: are long records: read here, a window at a time)
MAX_BYTES = 256 * 2**20


def read_files(
    paths: Sequence[str | Path],
    runs: Iterable[str] | None = None,
    include_aborted: bool = False,
    muscle: str | None = None,
) -> list[Run]:
    """Every complete run of the files ``paths`` (or the named ``runs``), canonical units.

    Parameters
    ----------
    paths
        Run files (HDF5, ``pmalab.run`` contract).
    runs
        Names of the runs to read (default: every complete run).
    include_aborted
        Also read aborted and interrupted runs (the samples they hold).
    muscle
        Which muscle of a file recording several (an antagonistic pair).

    Returns
    -------
    list of Run
        The runs, file by file in the order given.

    Raises
    ------
    pmalab.errors.RunFileError
        One line naming file, run and channel (a missing file or channel, unequal lengths,
        time not increasing, NaNs, a file given twice).
    """
    from pmalab.identify.long_records import long_runs
    from pmalab.runfile import check_distinct, check_distinct_runs, read_runs

    check_distinct(list(paths))
    wanted = None if runs is None else list(runs)
    out: list[Run] = []
    for p in paths:
        out.extend(
            read_runs(
                p,
                wanted,
                skip_incomplete=not include_aborted,
                long_runs=long_runs(),
                muscle=muscle,
            )
        )
    check_distinct_runs(out)
    return out


class Reading:
    """The child process reading the files (:func:`start_reading`)."""

    def __init__(self, pid: int, fd: int):
        self._pid = pid
        self._fd = fd

    def discard(self) -> None:
        """Stop the child and reap it, its runs not taken (the command gave up before it
        asked for them: interrupted, or failing while it imported).  Otherwise the child
        would wait, blocked on the full pipe, for as long as this process lives."""
        if self._pid < 0:
            return
        pid, self._pid = self._pid, -1
        try:
            os.kill(pid, signal.SIGKILL)
        except ProcessLookupError:  # pragma: no cover - a reaped child keeps its pid
            pass
        os.close(self._fd)
        os.waitpid(pid, 0)

    def result(self) -> tuple[list[Run], list[Run]] | None:
        """``(runs, validation runs)``, or None when the child did not deliver them (read
        them in this process then: the same runs, the same errors).

        Waits for the child.  The warnings its reading raised are shown now, in order."""
        pid, self._pid = self._pid, -1
        try:
            with os.fdopen(self._fd, "rb") as f:
                data = f.read()
        finally:
            _, status = os.waitpid(pid, 0)
        if not data or not os.WIFEXITED(status) or os.WEXITSTATUS(status) != 0:
            return None
        try:
            runs, val, caught = pickle.loads(data)
        except Exception:
            return None
        for w in caught:
            replay_warning(w)
        return runs, val


def replay_warning(m: warnings.WarningMessage) -> None:
    """Issue a warning a forked child recorded as if raised here: through the filters and
    the raising module's registry, so one shown here already is not shown twice."""
    mod = next(
        (v for v in list(sys.modules.values()) if getattr(v, "__file__", None) == m.filename),
        None,
    )
    registry = vars(mod).setdefault("__warningregistry__", {}) if mod is not None else None
    warnings.warn_explicit(m.message, m.category, m.filename, m.lineno, registry=registry)


def _worth_a_child(files: Sequence[str | Path]) -> bool:
    if not sys.platform.startswith("linux") or not hasattr(os, "fork"):
        return False
    if len(os.sched_getaffinity(0)) < 2:
        return False  # one core: nothing to overlap
    if "numpy" in sys.modules or threading.active_count() > 1:
        return False  # a fork after BLAS has started its threads is not safe everywhere
    try:
        size = sum(os.stat(p).st_size for p in files)
    except OSError:
        return False  # a missing file: reading here says which
    return 0 < size <= MAX_BYTES


def start_reading(
    files: Sequence[str | Path],
    validate: Sequence[str | Path] = (),
    *,
    include_aborted: bool = False,
    muscle: str | None = None,
) -> Reading | None:
    """Fork a child that reads the identification and validation files, or None.

    The child does what reading them here does, in the same order: the check that no file
    is given twice (:func:`~pmalab.runfile.check_distinct`), then :func:`read_files` of
    ``files``, then of ``validate``.

    Parameters
    ----------
    files, validate
        The identification files and the held-out (validation) files.
    include_aborted, muscle
        As for :func:`read_files`.

    Returns
    -------
    Reading or None
        The reading child (:meth:`Reading.result` takes its runs); None where no child is
        started (not Linux, NumPy already loaded, several threads running, large or missing
        files): read in process then.
    """
    if not _worth_a_child([*files, *validate]):
        return None
    sys.stdout.flush()
    sys.stderr.flush()
    r, w = os.pipe()
    pid = os.fork()
    if pid:
        os.close(w)
        return Reading(pid, r)
    # the child: read, send, leave without running the parent's exit handlers
    code = 1
    try:
        os.close(r)
        from pmalab.runfile import check_distinct

        with warnings.catch_warnings(record=True) as caught:
            check_distinct(files, validate)
            runs = read_files(files, include_aborted=include_aborted, muscle=muscle)
            val = read_files(validate, include_aborted=include_aborted, muscle=muscle)
        data = pickle.dumps((runs, val, caught), protocol=pickle.HIGHEST_PROTOCOL)
        with os.fdopen(w, "wb") as f:
            f.write(data)
        code = 0
    except BaseException:  # the parent reads the files itself and reports any error
        pass
    finally:
        os._exit(code)
