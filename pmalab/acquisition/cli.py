"""CLI verbs of the acquisition area: ``pmalab run``, ``pmalab import``, ``pmalab recover``,
``pmalab view``.

``pmalab run --rig sim|RIG.toml --protocol P.toml --out F.h5 [--force] [--seed N]
[--realtime] [-q] [--only ROLE_OR_RUN ...] [--host H] [--port P] [--live [HOST:]PORT]``
records a protocol (the simulated rig runs on its virtual clock unless ``--realtime``;
``--host/--port`` override a Modbus TCP rig file's endpoint; ``--live`` serves the live
page while it runs); ``pmalab import CSV --out F.h5 ...`` converts another DAQ's CSV into
a contract file; ``pmalab view F.h5`` serves the live page on a run file.
"""

from __future__ import annotations

import argparse
import os
import signal
import sys
import time

from pmalab.arguments import seed as seed_arg
from pmalab.errors import ConfigError, PmalabError, RunFileError, SafetyAbort


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``run`` and ``import`` to the ``pmalab`` parser."""
    p = sub.add_parser(
        "run",
        help="run a test protocol on a rig and record it to HDF5",
        description="Run a protocol on a rig (or the simulated one) and record "
        "every run at 500 Hz into a crash-proof HDF5 run file.  Ctrl-C or "
        "SIGTERM vents, closes the file and exits non-zero; after a kill -9 or "
        "power cut pmalab still reads the file, but h5dump/HDFView open it only "
        "after 'pmalab recover FILE' (or 'h5clear -s FILE').",
    )
    p.add_argument(
        "--rig", required=True, help="'sim', a rig TOML file or a shipped rig's name: {rigs}"
    )
    p.add_argument(
        "--protocol",
        required=True,
        help="protocol TOML file, or the name of a shipped one: {protocols}",
    )
    p.add_argument("--out", required=True, help="output HDF5 run file")
    p.add_argument("--force", action="store_true", help="overwrite an existing output")
    p.add_argument(
        "--seed",
        type=seed_arg,
        default=None,
        help="sensor-noise seed of a simulated rig (default: the rig file's, else 0)",
    )
    p.add_argument(
        "--realtime",
        action="store_true",
        help="simulated rig: run on the real clock instead of the virtual one",
    )
    p.add_argument(
        "-q",
        "--quiet",
        action="store_true",
        help="print only the line naming the output file, warnings and errors: no progress "
        "bar, no per-run lines, no vent confirmation (a regulator the software did not vent "
        "is always reported, on stderr)",
    )
    p.add_argument(
        "--host",
        default=None,
        help="Modbus TCP rig: connect to this host instead of the rig file's",
    )
    p.add_argument(
        "--port",
        type=int,
        default=None,
        help="Modbus TCP rig: connect to this TCP port instead of the rig file's "
        "(e.g. the one 'pmalab emulate --port' listens on)",
    )
    p.add_argument(
        "--only",
        nargs="+",
        metavar="ROLE_OR_RUN",
        help="record only runs with these roles (identification, validation) or names",
    )
    p.add_argument(
        "--live",
        metavar="[HOST:]PORT",
        help="serve a live page of the recording on HOST:PORT (HOST defaults to "
        "127.0.0.1; port 0 picks a free one); its stop button works from "
        "127.0.0.1 only",
    )
    p.set_defaults(func=cmd_run)

    v = sub.add_parser(
        "view",
        help="show a run file (finished or still recording) in the live page",
        description="Serve the live page on a run file: a finished one, or one "
        "still being recorded (followed as it grows).  Ctrl-C to quit.",
    )
    v.add_argument("file", help="the HDF5 run file")
    v.add_argument(
        "--port",
        metavar="[HOST:]PORT",
        default="0",
        help="where to serve (default: a free port on 127.0.0.1)",
    )
    v.add_argument(
        "--no-browser",
        action="store_true",
        help="only print the address (default: open it where a desktop is running)",
    )
    v.set_defaults(func=cmd_view)

    q = sub.add_parser(
        "import",
        help="convert other DAQs' exports (text, TDMS, .mat) into a run file",
        description="Convert exports of another DAQ into one pmalab HDF5 run "
        "file: text/CSV (one run per file), TDMS (.tdms: one run per group; "
        "units from unit_string, time from the waveform timing when there is "
        "no time channel) and MATLAB .mat v5/v7.3 (a struct per run, a vector "
        "per channel, or one matrix named by --columns). "
        "Columns default to time, position, force, muscle_pressure.  Exports "
        "with a metadata block (--header-rows), a units row (--units-row), "
        "';' and a decimal comma (--delimiter ';' --decimal ,) or Windows text "
        "(--encoding cp1252) are understood; values no PMA test can produce "
        "(gauge pressure above 1.2 MPa, |force| above 20 kN, |position| above "
        "500 mm) are refused with the unit they probably are in.",
    )
    q.add_argument(
        "csv",
        nargs="+",
        metavar="FILE",
        help="input export(s): .csv/.txt (a row of column names, then data rows; "
        "--no-header for numbers only), .tdms or .mat; several files make one "
        "campaign",
    )
    q.add_argument("--out", required=True, help="output HDF5 run file")
    q.add_argument("--force", action="store_true", help="overwrite an existing output")
    for ch in ("time", "position", "force"):
        q.add_argument(f"--{ch}-col", metavar="NAME", help=f"column holding {ch} (default '{ch}')")
    q.add_argument(
        "--pressure-col",
        metavar="NAME",
        help="column holding the muscle pressure (default 'muscle_pressure')",
    )
    q.add_argument(
        "--cylinder-col", metavar="NAME", help="column holding the cylinder pressure (optional)"
    )
    q.add_argument(
        "--units",
        metavar="Q=U,...",
        help="units of the columns, e.g. position=m,force=kN,time=ms,pressure=kPa "
        "(override the units row and units in column names; defaults: s, mm, N, "
        "MPa); also written [mm], (mm), µm, um",
    )
    q.add_argument(
        "--pressure",
        type=float,
        metavar="MPA",
        help="nominal muscle pressure in MPa (required without a pressure column)",
    )
    q.add_argument(
        "--position",
        type=float,
        metavar="MM",
        help="contraction in mm an isometric test held (a file without a position column)",
    )
    q.add_argument(
        "--position-from-name",
        metavar="REGEX",
        help="held contraction from each file's name, the number in the first group and "
        "the unit after it, e.g. '(\\d+)mm', or '(\\d+)pct' with --max-contraction",
    )
    q.add_argument(
        "--max-contraction",
        type=float,
        metavar="MM",
        help="the muscle's maximum contraction in mm (turns a percentage in a file name into mm)",
    )
    q.add_argument(
        "--load",
        type=float,
        metavar="N",
        help="the constant load in N of an isotonic test (recorded; makes the test isotonic)",
    )
    q.add_argument(
        "--test-type",
        choices=["auto", "isobaric", "isometric", "isotonic", "free"],
        default="auto",
        help="what the test held: the pressure (isobaric), the length (isometric), the "
        "load (isotonic) or nothing (free); default auto: recognised from the channels",
    )
    q.add_argument("--run", metavar="NAME", help="run name (default: the CSV's stem)")
    q.add_argument(
        "--delimiter",
        default=",",
        metavar="D",
        help="field separator: ',' (default), ';', '\\t' (tab) or any one character",
    )
    q.add_argument(
        "--decimal",
        default=".",
        choices=(".", ","),
        metavar="MARK",
        help="decimal mark of the numbers: '.' (default) or ','",
    )
    q.add_argument(
        "--header-rows",
        type=int,
        default=0,
        metavar="N",
        help="lines before the row of column names (a metadata block; default 0)",
    )
    q.add_argument(
        "--units-row",
        action="store_true",
        help="the row under the names holds each column's unit ([s], mm, µm, kPa...)",
    )
    q.add_argument(
        "--encoding",
        default="utf-8",
        metavar="NAME",
        help="text encoding (default utf-8; cp1252 for most Windows exports)",
    )
    q.add_argument(
        "--negate",
        nargs="+",
        default=[],
        choices=["position", "force"],
        help="flip the sign of these channels (e.g. a DAQ recording elongation)",
    )
    q.add_argument(
        "--no-header",
        action="store_true",
        help="the file has no row of column names (LabVIEW's spreadsheet export): "
        "name the fields with --columns",
    )
    q.add_argument(
        "--columns",
        metavar="F1,F2,...",
        help="the fields by position: time, position, force, pressure (or t, x, f, "
        "p), cylinder_pressure; '-' skips a field, e.g. time,-,-,-,position,"
        "pressure,force",
    )
    q.add_argument(
        "--pressure-from-name",
        metavar="REGEX",
        help="nominal pressure from each file's name, the number in the first "
        "group and the unit after it, e.g. '(\\d+)bar' or '(\\d+)kPa'",
    )
    q.add_argument(
        "--split-halves",
        action="store_true",
        help="each record becomes two runs: the first half for identification, "
        "the second held out for validation",
    )
    q.add_argument(
        "--drop-duplicate-times",
        action="store_true",
        help="drop a sample whose time stamp repeats the one before (some DAQ exports "
        "write a stamp twice); the count dropped is reported and stored with the run",
    )
    q.add_argument("--waveform", default="unknown", help="waveform tag stored with the run")
    q.add_argument(
        "--frequency",
        metavar="HZ|auto",
        help="excitation frequency tag (Hz), or 'auto': from the position's spectrum",
    )
    q.set_defaults(func=cmd_import)

    r = sub.add_parser(
        "recover",
        help="close a run file whose recording was killed",
        description="A recording killed mid-run (kill -9, power cut) leaves "
        "its HDF5 file flagged 'open for write': h5dump, h5ls, HDFView and "
        "MATLAB refuse to open it until it is recovered (this command, or "
        "HDF5's 'h5clear -s FILE').  recover rewrites it as a plainly closed "
        "file that any tool opens; runs cut mid-recording are marked "
        "aborted.  pmalab's own readers do not need this.  A healthy file is "
        "left as it is (exit 0) unless --force.",
    )
    r.add_argument("file", help="the run file")
    r.add_argument("--out", help="write here instead of replacing FILE")
    r.add_argument(
        "--force",
        action="store_true",
        help="overwrite --out if it exists; rewrite even a healthy file",
    )
    r.set_defaults(func=cmd_recover)

    c = sub.add_parser(
        "check",
        help="report which runs and channels of a run file are intact",
        description="Reads every chunk of every dataset against its checksum and every "
        "run's attributes against their digest, then reads the file as identify does. "
        "Prints what is intact and what is damaged (run, channel, samples); exit 0 when "
        "everything is intact, 2 otherwise.",
    )
    c.add_argument("file", nargs="+", help="run files")
    c.set_defaults(func=cmd_check)


def load_rig_spec(
    spec: str,
    *,
    seed: int | None = None,
    realtime: bool = False,
    host: str | None = None,
    port: int | None = None,
):
    """``sim`` or a rig TOML path → a Rig; ``--realtime`` puts a simulated rig on the wall
    clock; ``host``/``port`` replace a Modbus TCP rig's endpoint."""
    from pmalab.rig.base import RealClock
    from pmalab.rig.loader import load_rig

    return load_rig(spec, seed=seed, clock=RealClock() if realtime else None, host=host, port=port)


def cmd_run(args: argparse.Namespace) -> int:
    from pmalab.acquisition.protocol import load_protocol
    from pmalab.acquisition.runner import (
        VENT_SLOT,
        RunnerOptions,
        Terminated,
        abort_error,
        run_protocol,
        update_abort_vent,
    )
    from pmalab.paths import check_output

    if args.seed is not None and args.seed < 0:
        raise ConfigError(f"--seed: must be an integer ≥ 0, got {args.seed}")
    if args.port is not None and not 1 <= args.port <= 65535:
        raise ConfigError(f"--port: must be a TCP port 1…65535, got {args.port}")
    if args.host is not None and not args.host.strip():
        raise ConfigError("--host: must not be empty")
    protocol = load_protocol(args.protocol)
    if args.only:
        roles = [o for o in args.only if o in ("identification", "validation", "other")]
        names = [o for o in args.only if o not in roles]
        protocol = _select_either(protocol, roles, names)
    check_output(args.out, args.force)  # before the rig is even opened
    live = None
    if args.live is not None:
        from pmalab.acquisition.live.address import parse_address

        live = parse_address(args.live, "--live")
    rig = load_rig_spec(
        args.rig, seed=args.seed, realtime=args.realtime, host=args.host, port=args.port
    )

    def on_term(signum, frame):  # SIGTERM aborts like Ctrl-C: vent, close, exit non-zero
        raise Terminated()

    old = signal.signal(signal.SIGTERM, on_term)
    opts = RunnerOptions(
        progress=not args.quiet,
        extra_attrs={
            "command_line": " ".join(sys.argv),
            "seed": rig.info.get("seed", args.seed),
            "rig_spec": args.rig,
        },
    )
    try:
        with rig:
            if live is None:
                results = run_protocol(rig, protocol, args.out, force=args.force, options=opts)
            else:
                from pmalab.acquisition.live.session import LiveSession

                with LiveSession(rig, protocol, args.out, opts, *live):
                    if rig.clock.virtual:
                        print(
                            "pmalab: note: the simulated rig runs on its virtual clock, "
                            "faster than real time; add --realtime to watch it at its pace",
                            file=sys.stderr,
                        )
                    results = run_protocol(rig, protocol, args.out, force=args.force, options=opts)
    except SafetyAbort as exc:
        # closing the rig vented once more: a regulator that answers again is confirmed
        update_abort_vent(exc, rig.last_vent)
        _with_recover_hint(exc, args.out)
        raise
    except PmalabError as exc:  # e.g. a refused protocol: say so if a vent failed too
        vent = rig.last_vent
        if vent is None or vent.ok:
            _with_recover_hint(exc, args.out)
            raise
        err = abort_error(f"{exc}; {VENT_SLOT}", vent)
        err.hard_exit = exc.hard_exit
        raise _with_recover_hint(err, args.out) from None
    finally:
        signal.signal(signal.SIGTERM, old)
    if not args.quiet:
        for r in results:
            print(r.summary())
    total = sum(r.n_samples for r in results)
    print(f"{args.out}: {len(results)} runs, {total} samples")
    for (
        r
    ) in results:  # after the summaries: a run that did not keep its rate is not just "completed"
        if r.warning:
            print(f"pmalab run: warning: {args.out}: {r.warning}", file=sys.stderr)
    vent = rig.last_vent
    if vent is not None and not vent.ok:  # the data are safe; the rig may not be
        raise abort_error(f"{args.out}: all {len(results)} runs recorded, but {VENT_SLOT}", vent)
    if vent is not None and not args.quiet:
        print(f"regulators: {vent.line()}")
    elif vent is not None and any(not r.ok for _, r in vent.items):  # a manual regulator
        print(f"pmalab run: warning: regulators: {vent.line()}", file=sys.stderr)
    return 0


def _with_recover_hint(exc: PmalabError, out: str) -> PmalabError:
    """An error after which the process ends without closing the run file (``hard_exit``:
    HDF5 could not flush it) leaves HDF5's "open for write" flag: say what opens it."""
    if exc.hard_exit:
        from pmalab.runfile import recover_hint

        exc.args = (f"{exc}; {recover_hint(out)}",)
    return exc


def _select_either(protocol, roles, names):
    from pmalab.acquisition.protocol import Protocol

    runs = [r for r in protocol.runs if r.role in roles or r.name in names]
    if not runs:
        raise ConfigError(f"{protocol.path}: no run matches --only")
    return Protocol(
        protocol.name,
        runs,
        protocol.path,
        protocol.description,
        protocol.sample_rate_Hz,
        protocol.text,
    )


def cmd_import(args: argparse.Namespace) -> int:
    from pmalab.acquisition.csv_import import (
        CsvImportOptions,
        import_files,
        parse_delimiter,
        parse_layout,
        parse_units,
    )

    cols = {}
    for ch, val in (
        ("time", args.time_col),
        ("position", args.position_col),
        ("force", args.force_col),
        ("muscle_pressure", args.pressure_col),
        ("cylinder_pressure", args.cylinder_col),
    ):
        if val:
            cols[ch] = val
    auto = args.frequency is not None and args.frequency.strip().lower() == "auto"
    freq = None
    if args.frequency is not None and not auto:
        try:
            freq = float(args.frequency)
        except ValueError:
            raise ConfigError(
                f"--frequency: '{args.frequency}' is not a number of Hz or 'auto'"
            ) from None
        if not (freq > 0 and freq < 1e4):
            raise ConfigError(f"--frequency: must be > 0 Hz, got {args.frequency}")
    opts = CsvImportOptions(
        columns=cols,
        units=parse_units(args.units),
        pressure_MPa=args.pressure,
        position_mm=args.position,
        load_N=args.load,
        test_type=None if args.test_type == "auto" else args.test_type,
        run=args.run,
        delimiter=parse_delimiter(args.delimiter),
        negate=tuple(args.negate),
        waveform=args.waveform,
        frequency_Hz=freq,
        header_rows=args.header_rows,
        units_row=args.units_row,
        decimal=args.decimal,
        encoding=args.encoding,
        no_header=args.no_header,
        drop_duplicate_times=args.drop_duplicate_times,
        layout=parse_layout(
            args.columns,
            held_position=args.position is not None or bool(args.position_from_name),
        ),
    )
    opts.check()  # option mistakes before the input is read
    if args.position is not None and args.position_from_name:
        raise ConfigError("--position and --position-from-name: give one of them")
    if args.max_contraction is not None and not (0 < args.max_contraction <= 500):
        raise ConfigError(
            f"--max-contraction: must be a contraction > 0 and ≤ 500 mm, got {args.max_contraction:g}"
        )
    if args.load is not None and not (0 < args.load <= 20e3):
        raise ConfigError(f"--load: must be a load > 0 and ≤ 20000 N, got {args.load:g}")
    many = len(args.csv) > 1

    def progress(path, run) -> None:
        if many:
            print(f"  {path}: {_run_summary(run)}", file=sys.stderr)

    runs = import_files(
        args.csv,
        args.out,
        opts,
        force=args.force,
        pressure_pattern=args.pressure_from_name,
        position_pattern=args.position_from_name,
        max_contraction_mm=args.max_contraction,
        halves=args.split_halves,
        auto_frequency=auto,
        progress=progress,
    )
    if len(runs) == 1:
        run = runs[0]
        print(f"{args.out}: run '{run.name}', {_run_summary(run)}")
    else:
        held = sum(r.attrs.get("role") == "validation" for r in runs)
        types = sorted({r.test_type for r in runs})
        print(
            f"{args.out}: {len(runs)} runs from {len(args.csv)} file(s), "
            f"{sum(len(r) for r in runs)} samples, {'/'.join(types)} test"
            + ("s" if len(types) > 1 else "")
            + ", "
            + _campaign_levels(runs)
            + (f", {held} held out for validation" if held else "")
            + _dropped_summary(runs)
        )
    _warn_pressure_labels(runs)
    return 0


def _warn_pressure_labels(runs) -> None:
    """Name the runs whose measured mean pressure differs from their nominal label (a
    file name, ``--pressure``) beyond the gauge noise and the regulator's resolution."""
    import numpy as np

    from pmalab.pressure_labels import check_labels, label_warning

    labelled = [r for r in runs if r.attrs.get("muscle_pressure_MPa") is not None]
    line = label_warning(
        check_labels(
            (r.name, float(r.nominal_pressure), np.asarray(r.muscle_pressure, float))
            for r in labelled
        ),
        "identify's pressure laws",
    )
    if line:
        print(f"warning: {line}", file=sys.stderr, flush=True)


def _dropped_summary(runs) -> str:
    """``--drop-duplicate-times``' count over a campaign (each file counted once: the
    halves of a split record carry their record's count)."""
    per_file = {r.file: int(r.attrs.get("dropped_duplicate_times") or 0) for r in runs}
    n = sum(per_file.values())
    return f", {n} duplicate time stamps dropped" if n else ""


def _run_summary(run) -> str:
    """One run as the import reports it: samples, duration, force, what the test held."""
    import numpy as np

    head = (
        f"{len(run)} samples, {run.time[-1] - run.time[0]:.2f} s, force "
        f"{run.force.min():.0f}…{run.force.max():.0f} N, {run.test_type} "
        f"({run.attrs.get('test_type_from', 'recorded')})"
    )
    p = run.muscle_pressure
    if run.test_type == "isobaric":
        head += f", muscle pressure {run.nominal_pressure:.4g} MPa"
    else:
        head += f", muscle pressure {p.min():.3g}…{p.max():.3g} MPa (not held)"
    if run.test_type == "isometric":
        head += f", contraction held at {float(run.attrs.get('held_position_mm', 0.0)):.3g} mm"
    if run.test_type == "isotonic" and run.attrs.get("load_N") is not None:
        head += f", load {float(run.attrs['load_N']):g} N"
    if run.branch is not None:
        codes = sorted({int(c) for c in np.unique(run.branch)})
        head += f", state column kept (codes {', '.join(map(str, codes))})"
    dropped = run.attrs.get("dropped_duplicate_times")
    if dropped:
        head += f", {int(dropped)} duplicate time stamps dropped"
    return head


def _campaign_levels(runs) -> str:
    """The levels a campaign's runs held: pressures (isobaric) and/or contractions."""
    parts = []
    iso = [r for r in runs if r.test_type == "isobaric"]
    if iso:
        levels = sorted({round(r.nominal_pressure, 4) for r in iso})
        parts.append(f"pressures {', '.join(f'{p:g}' for p in levels)} MPa")
    held = [r for r in runs if r.test_type == "isometric"]
    if held:
        xs = sorted({round(float(r.attrs.get("held_position_mm", 0.0)), 3) for r in held})
        parts.append(f"contractions held at {', '.join(f'{x:g}' for x in xs)} mm")
        pmin = min(float(r.muscle_pressure.min()) for r in held)
        pmax = max(float(r.muscle_pressure.max()) for r in held)
        parts.append(f"pressure {pmin:.3g}…{pmax:.3g} MPa")
    other = [r for r in runs if r.test_type in ("isotonic", "free")]
    if other:
        parts.append(f"{len(other)} run(s) with pressure and length both varying")
    n_branch = sum(r.branch is not None for r in runs)
    if n_branch:
        parts.append(f"state column kept in {n_branch}")
    return ", ".join(parts)


def cmd_recover(args: argparse.Namespace) -> int:
    from pmalab.acquisition.recover import recover

    fixed = recover(args.file, args.out, force=args.force)
    if fixed is None:
        print(
            f"{args.file}: nothing to recover (closed cleanly, no run cut mid-recording); "
            "left as it is"
            + (f", {args.out} not written" if args.out else "")
            + " (--force rewrites it anyway)"
        )
        return 0
    where = args.out or args.file
    print(
        f"{where}: closed; "
        + (f"marked aborted: {', '.join(fixed)}" if fixed else "no run was cut mid-recording")
    )
    return 0


def cmd_check(args: argparse.Namespace) -> int:
    from pmalab.acquisition.check import report

    bad = []
    for path in args.file:
        lines, ok = report(path)
        print("\n".join(lines))
        if not ok:
            bad.append(path)
    if bad:
        raise RunFileError(f"{', '.join(bad)}: damaged or refused (see the report above)")
    return 0


def cmd_view(args: argparse.Namespace) -> int:
    from pathlib import Path

    from pmalab.acquisition.live import FileFollower, Hub, LiveServer, open_run_file
    from pmalab.acquisition.live.address import parse_address
    from pmalab.runfile import decode_attr

    host, port = parse_address(args.port, "--port")
    path = Path(args.file)
    with open_run_file(path) as f:
        protocol = decode_attr(f.attrs.get("protocol_name", ""))
    hub = Hub({"mode": "view", "file": str(path), "protocol": protocol})
    follower = FileFollower(path, hub)
    follower.poll()  # a file it cannot read fails here, before anything is served
    server = LiveServer(hub, host, port, on_stop=None, option="--port")
    url = server.start()
    follower.start()

    def on_term(signum, frame):  # SIGTERM quits like Ctrl-C
        raise KeyboardInterrupt

    # in place before the line that says the page is served: whoever reads that line may
    # stop the viewer at once (on a busy machine this thread can lag the server's threads)
    old = signal.signal(signal.SIGTERM, on_term)
    try:
        print(f"pmalab: viewing {path} on {url} (Ctrl-C to quit)", file=sys.stderr, flush=True)
        if not args.no_browser and _has_desktop():
            import webbrowser

            webbrowser.open(url)
        while True:
            time.sleep(0.5)
    except KeyboardInterrupt:
        pass
    finally:
        signal.signal(signal.SIGTERM, old)
        follower.close()
        follower.join(5.0)  # never leave it inside HDF5 while the interpreter exits
        server.close(grace_s=0.2)
    return 0


def _has_desktop() -> bool:
    """A graphical session to open a browser in (not a terminal browser over ssh)."""
    return sys.platform in ("darwin", "win32") or bool(
        os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")
    )
