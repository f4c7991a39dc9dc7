"""Damage a run file the ways storage and transfers do, and classify what the reader does.

Used by the suite's Hypothesis tests (``test_runfile_trust.py``) and by ``python -m bench
trust`` (counts by outcome over many copies).  Kinds of damage:

* ``truncate``: the file cut at a byte (a copy or transfer that stopped);
* ``bitflip``: one bit flipped anywhere (a bad sector, RAM, a network);
* ``zero-block``: a 512-byte aligned block of zeros (a sector lost by the file system);
* ``metadata``: one byte changed outside every chunk of samples (object headers,
  attributes, B-trees, the superblock).

Outcomes: ``refused`` (one :class:`~pmalab.errors.PmalabError` line), ``identical`` (every
run's channels and attributes as in the original, so any fit is the original's),
``changed`` (read without complaint but different: the failure this guards against) and
``traceback`` (any other exception).
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from pathlib import Path

import h5py
import numpy as np

from pmalab.errors import PmalabError
from pmalab.runfile import Run, read_runs

KINDS = ("truncate", "bitflip", "zero-block", "metadata")
BLOCK = 512


def data_ranges(path: Path) -> list[tuple[int, int]]:
    """Byte ranges [start, stop) of every stored chunk or contiguous dataset of ``path``."""
    out: list[tuple[int, int]] = []

    def visit(_name: str, obj: object) -> None:
        if not isinstance(obj, h5py.Dataset):
            return
        if obj.chunks is None:
            off = obj.id.get_offset()
            if off is not None:
                out.append((int(off), int(off) + int(obj.id.get_storage_size())))
            return
        for i in range(obj.id.get_num_chunks()):
            info = obj.id.get_chunk_info(i)
            out.append((int(info.byte_offset), int(info.byte_offset) + int(info.size)))

    with h5py.File(path, "r") as f:
        f.visititems(visit)
    return sorted(out)


def corrupt(data: bytes, kind: str, where: float, bit: int, ranges: Sequence[tuple[int, int]]
            ) -> bytes:
    """``data`` damaged by ``kind`` at relative position ``where`` (0…1); ``bit`` 0…7."""
    n = len(data)
    buf = bytearray(data)
    if kind == "truncate":
        return bytes(buf[: int(where * (n - 1))])
    if kind == "bitflip":
        i = min(n - 1, int(where * n))
        buf[i] ^= 1 << bit
        return bytes(buf)
    if kind == "zero-block":
        i = min(n - 1, int(where * n)) // BLOCK * BLOCK
        buf[i : i + BLOCK] = bytes(len(buf[i : i + BLOCK]))
        return bytes(buf)
    if kind == "metadata":
        inside = np.zeros(n, dtype=bool)
        for a, b in ranges:
            inside[a:b] = True
        meta = np.flatnonzero(~inside)
        i = int(meta[min(meta.size - 1, int(where * meta.size))])
        buf[i] ^= 1 << bit
        return bytes(buf)
    raise ValueError(kind)


def _same(a: Sequence[Run], b: Sequence[Run]) -> bool:
    if [r.name for r in a] != [r.name for r in b]:
        return False
    for ra, rb in zip(a, b):
        ca, cb = ra.channels(), rb.channels()
        if ca.keys() != cb.keys():
            return False
        if not all(np.array_equal(ca[k], cb[k]) for k in ca):
            return False
        if repr(sorted(ra.attrs.items())) != repr(sorted(rb.attrs.items())):
            return False
    return True


def outcome(original: Sequence[Run], path: Path) -> tuple[str, str]:
    """(outcome, detail) of reading the damaged copy ``path`` (see the module docstring)."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            runs = read_runs(path)
    except PmalabError as exc:
        msg = str(exc)
        return ("refused" if "\n" not in msg else "traceback"), msg
    except Exception as exc:
        return "traceback", f"{type(exc).__name__}: {exc}"
    for r in runs:
        r.file = ""
    orig = []
    for r in original:
        c = Run(**{**r.__dict__, "file": "", "attrs": dict(r.attrs)})
        orig.append(c)
    if _same(orig, runs):
        return "identical", ""
    flagged = [r.name for r in runs if r.attrs.get("device_stats", {}).get("error")]
    for r in runs:
        r.attrs.pop("device_stats", None)
    for r in orig:
        r.attrs.pop("device_stats", None)
    if flagged and _same(orig, runs):
        return "flagged", f"device_stats of {flagged} unreadable"
    return "changed", "values differ"


def _child(conn, fn, args) -> None:  # pragma: no cover - runs in a child process
    conn.send(fn(*args))
    conn.close()


def in_child(fn, args: tuple, who: str, timeout_s: float = 60.0) -> tuple[str, str]:
    """``fn(*args)`` (an outcome pair) in a forked child process: an answer that never comes
    (damaged HDF5 metadata can send the library round a loop) is the outcome ``hang``, a
    child that dies is ``traceback`` naming ``who`` — never a stuck or crashed harness."""
    import multiprocessing

    ctx = multiprocessing.get_context("fork")
    recv, send = ctx.Pipe(duplex=False)
    p = ctx.Process(target=_child, args=(send, fn, args))
    p.start()
    send.close()
    if recv.poll(timeout_s):
        try:
            res = recv.recv()
        except EOFError:
            res = ("traceback", f"{who} process died (exit {p.exitcode})")
        p.join()
        return res
    p.kill()
    p.join()
    return "hang", f"no answer in {timeout_s:g} s"


def outcome_guarded(original: Sequence[Run], path: Path, timeout_s: float = 60.0
                    ) -> tuple[str, str]:
    """:func:`outcome` in a child process (:func:`in_child`)."""
    return in_child(outcome, (list(original), path), "reader", timeout_s)
