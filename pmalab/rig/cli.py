"""CLI verbs of the rig area: ``pmalab emulate``, ``pmalab benchmark``, ``pmalab stand``.

``pmalab stand --test isometric --held 0,12,24,36 --out iso.h5`` runs the simulated static
test stand (:mod:`pmalab.rig.sim.static_stand`): one run per held length (isometric), load
(isotonic), pressure (isobaric) or centre length (free), into one run file; ``--text DIR``
also writes each run as a real isometric logger's headerless text file.

``pmalab emulate --rig data/rigs/labjack-t7.toml`` starts wire-level emulators of every
device the rig file names (Modbus TCP/RTU I/O module, SMC ITV on RS-232C, load-cell
indicator), all driven by one simulated rig, prints their endpoints and runs until Ctrl-C.
In another shell, ``pmalab run --rig data/rigs/labjack-t7.toml ...`` then records through
the real drivers; with ``--port P`` the printed command carries ``--port P`` too.
"""

from __future__ import annotations

import argparse
import shlex
import signal
import sys
import threading
import time
from typing import TYPE_CHECKING

from pmalab.arguments import seed as seed_arg
from pmalab.errors import ConfigError

if TYPE_CHECKING:
    from pmalab.rig.emulators.launcher import EmulatorSet


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``emulate``, ``benchmark`` and ``stand`` to the ``pmalab`` parser."""
    _register_benchmark(sub)
    _register_stand(sub)
    p = sub.add_parser(
        "emulate",
        help="emulate a rig file's devices (Modbus, serial) on the simulated rig",
        description=(
            "Start wire-level emulators for every device of a kind = 'modbus' rig file, "
            "driven by the simulated rig's physics in real time; runs until Ctrl-C."
        ),
    )
    p.add_argument("--rig", required=True, help="rig TOML file (kind = 'modbus')")
    p.add_argument(
        "--truth",
        default=None,
        help="truth TOML of the simulated rig (default: the rig file's [rig.emulator] truth)",
    )
    p.add_argument(
        "--seed",
        type=seed_arg,
        default=None,
        help="sensor-noise seed (default: [rig.emulator] seed)",
    )
    p.add_argument(
        "--port", type=int, default=None, help="TCP port to listen on instead of the rig file's"
    )
    p.add_argument(
        "--no-baud-pacing",
        action="store_true",
        help="RTU: deliver bytes at once instead of at the baud rate",
    )
    p.add_argument(
        "--duration", type=float, default=None, help=argparse.SUPPRESS
    )  # tests: stop after N s
    p.set_defaults(func=run_emulate)


def run_command(rig: str, emus: EmulatorSet) -> str:
    """The ``pmalab run`` command line that reaches these emulators: ``--port`` when the
    Modbus TCP module listens elsewhere than the rig file says (``emulate --port``)."""
    spec = emus.spec
    port = ""
    if spec.transport.type == "tcp" and int(spec.transport.port) != emus.modbus.port:
        port = f" --port {emus.modbus.port}"
    return f"pmalab run --rig {shlex.quote(rig)}{port} --protocol PROTOCOL.toml --out FILE.h5"


def run_emulate(args: argparse.Namespace) -> int:
    from pmalab.rig.emulators.launcher import start_emulators

    if args.seed is not None and args.seed < 0:
        raise ConfigError(f"--seed: must be an integer ≥ 0, got {args.seed}")
    if args.port is not None and not 0 <= args.port <= 65535:
        raise ConfigError(f"--port: must be a TCP port 0…65535, got {args.port}")
    try:
        emus = start_emulators(
            args.rig,
            tcp_port=args.port,
            truth=args.truth,
            seed=args.seed,
            baud_pacing=False if args.no_baud_pacing else None,
        )
    except FileExistsError as exc:
        raise ConfigError(f"{args.rig}: {exc}") from None
    except OSError as exc:
        raise ConfigError(f"{args.rig}: cannot start the emulators ({exc})") from None
    stop = threading.Event()

    def on_term(*_: object) -> None:
        stop.set()

    old = signal.signal(signal.SIGTERM, on_term)
    try:
        print(f"pmalab emulate: {emus.spec.name} — simulated rig in real time", flush=True)
        for line in emus.endpoints():
            print(f"  {line}", flush=True)
        print(f"  now: {run_command(args.rig, emus)}", flush=True)
        print("  Ctrl-C to stop", flush=True)
        t_end = None if args.duration is None else time.monotonic() + args.duration
        while not stop.is_set() and (t_end is None or time.monotonic() < t_end):
            stop.wait(0.2)
    except KeyboardInterrupt:
        pass
    finally:
        signal.signal(signal.SIGTERM, old)
        emus.stop()
        m = emus.modbus.model
        print(
            f"pmalab emulate: stopped ({m.reads} block reads, {m.writes} writes served)",
            file=sys.stderr,
            flush=True,
        )
    return 0


# --------------------------------------------------------------------------- stand
def _register_stand(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "stand",
        help="simulate a static test stand: isometric, isotonic, isobaric or free runs",
        description=(
            "Run the simulated static test stand (a McKibben muscle with Chou-Hannaford's "
            "geometric force and braid friction in the pressure and contraction domains, "
            "its truth in a TOML file) through one test type: isometric (length held at "
            "each --held value in mm, pressure ramped 0 -> --p-max -> 0), isotonic (a "
            "--held load in N, the pressure cycled), isobaric (pressure held at each --held "
            "value in MPa, the length cycled) or free (both vary).  One run per value, in "
            "one run file; --text DIR also writes each run as a headerless text file of "
            "the shape real isometric loggers write (force N, pressure kPa, time s in "
            "whole ms with one repeated stamp, state 1/2)."
        ),
    )
    p.add_argument(
        "--truth",
        default="geometric",
        metavar="TOML",
        help="static truth file or shipped name: geometric (default), geometric-both",
    )
    p.add_argument(
        "--test",
        required=True,
        choices=("isometric", "isotonic", "isobaric", "free"),
        help="the test type",
    )
    p.add_argument(
        "--held",
        required=True,
        metavar="V[,V...]",
        help="one run per value: held contraction mm (isometric, free: the centre), load N "
        "(isotonic) or pressure MPa (isobaric)",
    )
    p.add_argument("--p-max", type=float, default=0.62, metavar="MPA", help="top of the ramp")
    p.add_argument(
        "--waveform",
        default="ramp",
        choices=("ramp", "steps", "sine"),
        help="pressure waveform (default ramp)",
    )
    p.add_argument("--period", type=float, default=20.0, metavar="S", help="pressure period (s)")
    p.add_argument("--cycles", type=float, default=1.0, help="periods recorded (default 1)")
    p.add_argument(
        "--stroke", type=float, default=10.0, metavar="MM", help="length swing (isobaric, free)"
    )
    p.add_argument("--seed", type=seed_arg, default=0, help="sensor noise (default 0)")
    p.add_argument("--out", required=True, metavar="FILE.h5", help="the run file to write")
    p.add_argument("--text", metavar="DIR", help="also write headerless text files here")
    p.add_argument("--force", action="store_true", help="overwrite existing outputs")
    p.set_defaults(func=run_stand)


def run_stand(args: argparse.Namespace) -> int:
    from pathlib import Path

    from pmalab.paths import check_output
    from pmalab.rig.sim.static_stand import load_static_truth, run_test, write_headerless
    from pmalab.runfile import write_runs

    try:
        values = [float(v) for v in args.held.split(",") if v.strip()]
    except ValueError:
        raise ConfigError(f"--held {args.held!r}: numbers separated by commas") from None
    if not values:
        raise ConfigError("--held: give at least one value")
    import math

    if not (0 < args.p_max <= 1.0):
        raise ConfigError(f"--p-max {args.p_max:g}: must be a pressure in (0, 1] MPa")
    for opt, v, hi in (("--period", args.period, 3600.0), ("--cycles", args.cycles, 100.0)):
        if not (math.isfinite(v) and 0 < v <= hi):
            raise ConfigError(f"{opt} {v:g}: must be > 0 and ≤ {hi:g}")
    if not (math.isfinite(args.stroke) and 0 <= args.stroke <= 50.0):
        raise ConfigError(f"--stroke {args.stroke:g}: must be 0 … 50 mm")
    if not all(math.isfinite(v) for v in values):
        raise ConfigError(f"--held {args.held!r}: finite numbers only")
    truth = load_static_truth(args.truth)
    unit, key = {
        "isometric": ("mm", "held_mm"),
        "free": ("mm", "held_mm"),
        "isotonic": ("N", "load_N"),
        "isobaric": ("MPa", "pressure_MPa"),
    }[args.test]
    text_dir = Path(args.text) if args.text else None
    names = [f"{args.test}_{v:g}{unit}" for v in values]
    outs = [check_output(args.out, args.force)]
    if text_dir is not None:
        outs += [check_output(text_dir / f"{n}.txt", args.force) for n in names]
    runs = []
    for i, (v, name) in enumerate(zip(values, names, strict=True)):
        kw = {key: v}
        if args.test == "isobaric":
            kw["held_mm"] = 15.0
        rec = run_test(
            truth,
            args.test,
            p_max=args.p_max,
            period_s=args.period,
            cycles=args.cycles,
            waveform=args.waveform,
            stroke_mm=args.stroke,
            seed=args.seed + i,
            **kw,
        )
        runs.append(rec.to_run(name, waveform=args.waveform))
        if text_dir is not None:
            text_dir.mkdir(parents=True, exist_ok=True)
            write_headerless(rec, text_dir / f"{name}.txt")
    write_runs(args.out, runs, force=args.force)
    print(
        f"{args.out}: {len(runs)} {args.test} run(s) of the simulated stand "
        f"({truth.source or 'defaults'}), {len(runs[0])} samples each"
        + (f"; text files in {text_dir}" if text_dir is not None else "")
    )
    return 0


# --------------------------------------------------------------------------- benchmark
def _register_benchmark(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "benchmark",
        help="write the Bouc-Wen benchmark's data (Noël & Schoukens 2016), regenerated",
        description=(
            "Integrate the Bouc-Wen benchmark system from its published equations and write "
            "OUT/train.h5 (multisine, output noise 8e-6 m rms), OUT/test-multisine.h5 and "
            "OUT/test-sweep.h5 (noise-free) as pmalab run files (contraction x = -y in mm, "
            "tension = the input force u in N).  Then: pmalab identify OUT/train.h5 --output "
            "position --model bouc-wen --add inertia --add viscous-friction --validate "
            "OUT/test-multisine.h5 OUT/test-sweep.h5 --out DIR"
        ),
    )
    p.add_argument("name", choices=("bouc-wen",), help="which benchmark")
    p.add_argument("--out", required=True, metavar="DIR", help="directory for the three files")
    p.add_argument(
        "--seed", type=seed_arg, default=0, help="multisine phases and noise (default 0)"
    )
    p.add_argument("--force", action="store_true", help="overwrite existing files")
    p.set_defaults(func=run_benchmark)


def run_benchmark(args: argparse.Namespace) -> int:
    from pathlib import Path

    from pmalab.paths import check_output
    from pmalab.rig.sim import bouc_wen_benchmark as bwb

    out = Path(args.out)
    for name in ("train.h5", "test-multisine.h5", "test-sweep.h5"):
        check_output(out / name, args.force)  # refuse before any work
    files = bwb.generate(out, seed=args.seed, force=args.force)
    print(f"Bouc-Wen benchmark ({bwb.describe()})")
    for what, path in files.items():
        print(f"  {what:<15} {path}")
    return 0
