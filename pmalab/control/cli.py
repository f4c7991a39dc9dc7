"""``pmalab control``: the seeds' cascade controllers on the simulated 1-DOF manipulator.

One run::

    pmalab control --controller pid|sn-pid|rbf-pid --reference square:0.1Hz:15mm
                   [--loop position|pressure] [--model ID.json] --duration S --out F.h5

Every seed experiment with every controller::

    pmalab control --experiments data/control/seed-experiments.toml --out DIR
"""

from __future__ import annotations

import argparse
import signal
import sys
from collections.abc import Callable

from pmalab.arguments import seed as seed_arg
from pmalab.errors import ConfigError


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``control`` to the ``pmalab`` parser."""
    p = sub.add_parser(
        "control",
        help="cascade position control of the simulated PMA manipulator",
        description="Run the seed papers' cascade controllers (classic PID, single-neuron "
        "adaptive PID, RBF-network-tuned PID) on the simulated 1-DOF manipulator driven by "
        "one DMSP-20-120 muscle, on a virtual clock; record a run file with the response, "
        "pressures and gains, and print step/tracking metrics.",
    )
    # no argparse choices: the registry (pmalab.control.pid.CONTROLLERS) is the list, and
    # importing it here would load numpy at every start-up; an unknown id is one line, and
    # the help names the registered ids when it is printed ({controllers})
    p.add_argument(
        "--controller",
        metavar="ID",
        help="the controller, both loops use it: {controllers}",
    )
    p.add_argument(
        "--reference",
        metavar="KIND:FHz:M",
        help="square|sine, frequency, magnitude in mm (position loop) or MPa "
        "(pressure loop), e.g. square:0.1Hz:15mm, sine:0.1Hz:20mm, "
        "square:0.1Hz:0.5MPa; runs from 0 to the magnitude",
    )
    p.add_argument(
        "--loop",
        choices=["position", "pressure"],
        help="the loop to close (default: from the reference's unit)",
    )
    p.add_argument(
        "--model",
        metavar="ID.json",
        help="identification.json (or its directory) of the muscle, from 'pmalab "
        "identify' (default: the shipped identification of the simulated muscle)",
    )
    p.add_argument("--duration", type=float, metavar="S", help="run length in s (≤ 600)")
    p.add_argument(
        "--experiments",
        metavar="FILE.toml",
        help="run every experiment of this file with each of its controllers "
        "(data/control/seed-experiments.toml: the seeds' set); --out is a directory",
    )
    p.add_argument("--out", required=True, help="output run file (a directory with --experiments)")
    p.add_argument("--force", action="store_true", help="overwrite existing outputs")
    p.add_argument(
        "--truth",
        metavar="TRUTH.toml",
        help="simulated muscle truth (e.g. data/truth/hidden-viscous-friction.toml "
        "for a plant/model mismatch; default: every effect off)",
    )
    p.add_argument(
        "--hysteresis-compensation",
        choices=("on", "off"),
        default=None,
        help="invert the identified law's hysteretic force h (on, the default) or "
        "the static curve alone (off); for pid, sn-pid and rbf-pid alike",
    )
    p.add_argument(
        "--plant",
        metavar="MODEL_DIR",
        help="model in the loop: the manipulator's muscle is this identification "
        "(identification.json) run forward instead of the simulated truth; "
        "mechanics and regulator as the simulated manipulator's",
    )
    p.add_argument(
        "--rig",
        metavar="RIG",
        help="an antagonistic pair (rig kind sim-pair: data/rigs/sim-pair.toml) for a joint-"
        "angle reference in deg, e.g. square:0.1Hz:20deg",
    )
    p.add_argument(
        "--cocontraction",
        type=float,
        metavar="MPA",
        default=None,
        help="joint control: both muscles' common pressure p0, which sets the joint's "
        "stiffness (default 0.25 MPa)",
    )
    p.add_argument("--seed", type=seed_arg, default=None, help="sensor-noise seed (default 0)")
    p.add_argument(
        "--real-time",
        action="store_true",
        help="run the simulation at the wall clock's pace (the loop timing of a "
        "real rig; default: a virtual clock, as fast as it computes)",
    )
    p.set_defaults(func=cmd_control)


def _make_rig_factory(
    truth: str | None, seed: int, real_time: bool = False, plant: str | None = None
):
    from pmalab.rig.base import RealClock
    from pmalab.rig.sim.manipulator import make_sim_manipulator
    from pmalab.rig.sim.truth import load_truth

    t = load_truth(truth) if truth else None  # checked once, before anything runs
    if plant:
        from pmalab.control.plant import make_plant_manipulator

        make_plant_manipulator(plant, t)  # refuse a bad model before any output exists

        def make_plant():
            return make_plant_manipulator(plant, t, clock=RealClock() if real_time else None)

        return make_plant

    def make():
        return make_sim_manipulator(t, seed=seed, clock=RealClock() if real_time else None)

    return make


def cmd_control(args: argparse.Namespace) -> int:
    from pmalab.control.experiments import check_duration, metrics_line

    if args.seed is not None and args.seed < 0:
        raise ConfigError(f"--seed: must be an integer ≥ 0, got {args.seed}")
    old = signal.signal(signal.SIGTERM, _sigterm)
    try:
        if args.experiments:
            for flag in ("controller", "reference", "loop", "duration", "hysteresis_compensation"):
                if getattr(args, flag) is not None:
                    raise ConfigError(
                        f"--{flag.replace('_', '-')}: not with --experiments (the file sets it)"
                    )
            return _run_experiments(args)
        for flag in ("controller", "reference", "duration"):
            if getattr(args, flag) is None:
                raise ConfigError(f"--{flag}: required (or give --experiments FILE)")
        if args.rig is not None or args.reference.strip().lower().endswith("deg"):
            return _run_joint(args, check_duration, metrics_line)
        if args.cocontraction is not None:
            raise ConfigError("--cocontraction: only for a joint (--rig PAIR, a deg reference)")
        return _run_one(args, check_duration, metrics_line)
    finally:
        signal.signal(signal.SIGTERM, old)


def _run_joint(args, check_duration, metrics_line) -> int:
    """Joint-angle control of an antagonistic pair (``--rig``, a deg reference)."""
    import json

    import numpy as np

    from pmalab.acquisition.recorder import Recorder
    from pmalab.control.controllers import CONTROLLERS
    from pmalab.control.joint import JOINT_SIGNALS, StaticPair, default_joint_settings, run_joint
    from pmalab.control.model import IdentifiedModel
    from pmalab.control.reference import parse_reference
    from pmalab.errors import SafetyAbort
    from pmalab.paths import check_output
    from pmalab.rig.loader import load_rig
    from pmalab.rig.pair import PairRig

    if args.controller not in CONTROLLERS:
        raise ConfigError(
            f"--controller: unknown '{args.controller}' (choose from {', '.join(CONTROLLERS)})"
        )
    ref = parse_reference(args.reference)
    if ref.unit != "deg":
        raise ConfigError(f"--reference: '{args.reference}': a joint follows an angle in deg")
    for flag in ("loop", "plant", "truth", "hysteresis_compensation"):
        if getattr(args, flag) is not None:
            raise ConfigError(f"--{flag.replace('_', '-')}: not with a joint (--rig PAIR)")
    if args.rig is None:
        raise ConfigError(
            "--rig: a joint-angle reference needs a pair rig (data/rigs/sim-pair.toml)"
        )
    duration = check_duration(args.duration, "--duration")
    p0 = 0.25 if args.cocontraction is None else float(args.cocontraction)
    check_output(args.out, args.force)
    model = IdentifiedModel.load(args.model)
    rig = load_rig(args.rig, seed=args.seed)
    if not isinstance(rig, PairRig) or rig.geometry is None:
        rig.close()
        raise ConfigError(f"--rig {args.rig}: not an antagonistic pair (rig kind sim-pair)")
    g = rig.geometry
    statics = StaticPair(model, model, g.mount_contraction_mm, g.radius_mm)
    settings = default_joint_settings(p0)
    with rig:
        run = run_joint(rig, args.controller, ref, duration, settings, statics)
    units = {
        "time": "s",
        "angle": "deg",
        "angle_reference": "deg",
        "angle_setpoint": "deg",
        "differential_feedforward": "MPa",
    }
    chans = {k: units.get(k, "MPa") for k in JOINT_SIGNALS}
    attrs = {
        "controller": args.controller,
        "reference": ref.text,
        "cocontraction_MPa": p0,
        "duration_s": duration,
        "model": model.source,
        "settings": json.dumps({"loop": settings.loop.gains.as_tuple(), "p0": p0}),
        "rig": args.rig,
    }
    with Recorder(
        args.out,
        [(args.controller, attrs)],
        {"command_line": " ".join(sys.argv)},
        channels=chans,
        summary=True,
    ) as rec:
        w = rec.writer(args.controller)
        w.extend([run.signals[k] for k in JOINT_SIGNALS], np.zeros(len(run.signals["time"])))
        w.set_summary(
            {
                "metrics": run.metrics,
                "vent": run.vent,
                "vent_confirmed": run.vent_confirmed,
                "cocontraction_MPa": p0,
            }
        )
        w.finish(run.status)
    m = run.metrics
    print(
        f"{args.out}: {args.controller} {ref.text} (joint angle, co-contraction {p0:g} MPa), "
        f"{len(run.signals['time'])} samples, {duration / max(run.wall_s, 1e-9):.0f}× real "
        f"time; {run.status}"
    )
    print(f"  {metrics_line({**m, 'unit': 'deg'})}")
    print(f"  {run.vent}")
    if not run.completed:
        raise SafetyAbort(f"{args.out}: run {run.status}; {run.vent}")
    return 0


def _note_ignored(model) -> None:
    if model is not None and model.ignored_effects:
        print(
            f"note: {model.source}: the controller inverts the base {model.law} law; the "
            f"identified effects ({', '.join(model.ignored_effects)}) are not inverted",
            file=sys.stderr,
        )


def _sigterm(signum, frame):  # SIGTERM ends a run like Ctrl-C: vent, keep the samples
    raise KeyboardInterrupt


def _run_one(args, check_duration, metrics_line) -> int:
    from pmalab.control.controllers import CONTROLLERS, default_settings
    from pmalab.control.model import IdentifiedModel
    from pmalab.control.record import ControlRecording, planned_attrs, run_metrics
    from pmalab.control.reference import parse_reference
    from pmalab.control.runner import run_control
    from pmalab.errors import SafetyAbort
    from pmalab.paths import check_output

    if args.controller not in CONTROLLERS:  # before any output exists
        raise ConfigError(
            f"--controller: unknown '{args.controller}' (choose from {', '.join(CONTROLLERS)})"
        )
    ref = parse_reference(args.reference)
    loop = args.loop or ref.quantity
    if loop != ref.quantity:
        unit = "MPa" if loop == "pressure" else "mm"
        raise ConfigError(
            f"--reference: '{args.reference}': the {loop} loop needs a magnitude in {unit}"
        )
    duration = check_duration(args.duration, "--duration")
    check_output(args.out, args.force)  # before anything runs
    model = IdentifiedModel.load(args.model) if loop == "position" else None
    _note_ignored(model)
    make = _make_rig_factory(args.truth, args.seed or 0, args.real_time, args.plant)
    rig = make()
    progress: Callable[[float], None] | None = None
    if sys.stderr.isatty():  # a long run shows where it is (simulated seconds)

        def show(t: float) -> None:
            print(
                f"\r{args.controller}: {t:5.0f} / {duration:g} s",
                end="",
                file=sys.stderr,
                flush=True,
            )

        progress = show
    settings = default_settings()
    if args.hysteresis_compensation is not None:
        from dataclasses import replace as _replace

        settings = _replace(settings, hysteresis_compensation=args.hysteresis_compensation == "on")
    cmd = " ".join(sys.argv)
    attrs = planned_attrs(
        args.controller,
        ref,
        duration,
        settings,
        model,
        command_line=cmd,
        truth=str(rig.info.get("truth", "")),
    )
    root = {"command_line": cmd}
    if args.plant:
        root["plant"] = str(rig.info.get("plant", args.plant))
    with rig:  # the file is live before the first sample: a crash leaves what was recorded
        with ControlRecording(
            args.out, [(args.controller, attrs)], loop, force=args.force, root_attrs=root
        ) as rec:
            w = rec.writer(args.controller)
            run = run_control(
                rig,
                args.controller,
                ref,
                duration,
                settings,
                model,
                name=args.controller,
                progress=progress,
                sink=w,
            )
            w.finish(run)
    if progress is not None:
        print(file=sys.stderr)
    m = run_metrics(run)
    print(
        f"{args.out}: {args.controller} {ref.text} ({loop} loop), {run.n} samples, "
        f"{duration / max(run.wall_s, 1e-9):.0f}× real time; {run.status}"
    )
    print(f"  {metrics_line(m)}")
    if not run.completed:
        raise SafetyAbort(
            f"{args.out}: run {run.status}; {run.attrs.get('vent')}; "
            "the samples so far are in the file"
        )
    return 0


def _run_experiments(args) -> int:
    from pmalab.control.experiments import load_experiments, run_experiments
    from pmalab.control.model import IdentifiedModel
    from pmalab.errors import SafetyAbort

    es = load_experiments(args.experiments)
    model = IdentifiedModel.load(args.model or es.model)
    _note_ignored(model)
    truth = args.truth or (str(es.truth) if es.truth else None)
    seed = args.seed if args.seed is not None else es.seed
    doc = run_experiments(
        es,
        args.out,
        force=args.force,
        model=model,
        make_rig=_make_rig_factory(truth, seed, args.real_time, args.plant),
        plant=args.plant,
    )
    bad = [r for r in doc["results"] if r["status"] != "completed"]
    print(f"{args.out}: {len(doc['results'])} runs, metrics in {args.out}/metrics.json")
    if bad:
        raise SafetyAbort(
            f"{args.out}: {bad[0]['experiment']} {bad[0]['controller']}: "
            f"{bad[0]['status']}; later runs not started"
        )
    return 0
