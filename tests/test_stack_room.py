"""pmalab.lazy.with_stack_room: a command's work without CPython's frame-stack chunk churn.

CPython (3.11 on) keeps frames in 16 KiB chunks and frees a chunk when the frame at its
base returns; a loop whose calls cross a chunk's end maps, touches (one page fault) and
unmaps a chunk per call.  The loop below is started at every 8-byte offset of a chunk (its
own frame padded slot by slot), so some offset makes it churn where the interpreter has
that behaviour; inside ``with_stack_room`` no offset may."""

from __future__ import annotations

import resource
import sys
import types

import pytest
from identify_synth import make_run

from pmalab.lazy import STACK_ROOM, with_stack_room
from pmalab.runfile import write_runs

CALLS = 200
#: this thread's page faults only (a test runner's other threads fault too)
WHO = getattr(resource, "RUSAGE_THREAD", resource.RUSAGE_SELF)


def _leaf() -> int:
    return 1


def _loop() -> int:
    """Minor page faults of CALLS calls of a small function from this frame."""
    before = resource.getrusage(WHO).ru_minflt
    for _ in range(CALLS):
        _leaf()
    return resource.getrusage(WHO).ru_minflt - before


def _padded(slots: int):
    """:func:`_loop` with a frame ``slots`` × 8 bytes larger (unused stack slots)."""
    code = _loop.__code__
    return types.FunctionType(code.replace(co_stacksize=code.co_stacksize + slots), globals())


LOOPS = [_padded(s) for s in range(2 * 16 * 1024 // 8 + 64)]  # two chunks' worth of offsets


def _faults() -> list[int]:
    return [f() for f in LOOPS]


def test_the_call_passes_arguments_results_and_errors():
    assert with_stack_room(lambda a, b=0: (a, b), 1, b=2) == (1, 2)
    with pytest.raises(KeyError, match="x"):
        with_stack_room({}.__getitem__, "x")
    # deep work inside: far beyond the room, it still runs (the stack just grows as usual)
    def down(n: int) -> int:
        return 0 if n == 0 else 1 + down(n - 1)

    assert with_stack_room(down, 500) == 500


@pytest.mark.skipif(sys.implementation.name != "cpython", reason="CPython's frame stack")
def test_no_offset_churns_chunks_inside_the_room():
    outside = _faults()
    churn = [s for s, f in enumerate(outside) if f >= CALLS]
    if not churn:
        pytest.skip("this interpreter keeps a spare frame-stack chunk: no churn to remove")
    inside = with_stack_room(_faults)
    assert max(inside) < CALLS // 4, [s for s, f in enumerate(inside) if f >= CALLS // 4]
    assert STACK_ROOM > len(LOOPS) * 8  # every padded frame lies within the room


@pytest.mark.parametrize(
    ("verb", "options", "written"),
    [
        ("identify", [], "identification.json"),
        ("diagnose", ["--only", "viscous-friction", "--laws", "none", "--max-steps", "0",
                      "--jobs", "1"], "diagnosis.json"),
    ],
)  # fmt: skip
def test_the_command_runs_its_work_in_the_room(verb, options, written, tmp_path, monkeypatch):
    from pmalab.cli import main
    from pmalab.identify import cli

    runs = [make_run("duhem", p, seed=i, n=3000, f=0.3, name=f"p{i}")[0]
            for i, p in enumerate((0.2, 0.4, 0.6))]
    f = write_runs(tmp_path / "c.h5", runs)
    seen = []

    def spy(fn, *args, **kwargs):
        seen.append(fn)
        return with_stack_room(fn, *args, **kwargs)

    monkeypatch.setattr(cli, "with_stack_room", spy)
    out = tmp_path / "o"
    assert main([verb, str(f), "--model", "duhem", "--out", str(out), "-q", *options]) == 0
    assert seen == [getattr(cli, f"{verb}_command")]
    assert (out / written).is_file()


def test_a_frame_size_the_runtime_refuses_leaves_a_plain_call():
    """A code object the interpreter will not rebuild with that much room (here more than
    its C int holds) costs the room, never the command: the work runs as a plain call."""
    from pmalab import lazy

    assert lazy._roomy_call(room=8 * 2**31) is lazy._call
    if sys.implementation.name == "cpython":
        assert lazy._roomy_call() is not lazy._call  # CPython rebuilds it at the usual room
