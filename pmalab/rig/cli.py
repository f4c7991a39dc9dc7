"""CLI verbs of the rig area: ``pmalab emulate``.

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

from pmalab.errors import ConfigError

if TYPE_CHECKING:
    from pmalab.rig.emulators.launcher import EmulatorSet


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``emulate`` and ``benchmark`` to the ``pmalab`` parser."""
    _register_benchmark(sub)
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
        "--seed", type=int, default=None, help="sensor-noise seed (default: [rig.emulator] seed)"
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
    p.add_argument("--seed", type=int, default=0, help="multisine phases and noise (default 0)")
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
