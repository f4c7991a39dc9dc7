"""CLI verbs of this area (see pmalab/cli.py): ``identify`` (and ``diagnose``).

Each verb has its own ``_register_<verb>(sub)``; :func:`register` calls them all, so a new
verb is one function and one line here.
"""

from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import TYPE_CHECKING

from pmalab.arguments import (
    DEFAULT_JOBS,
    JOBS_ENV,
    check_max_steps,
    default_jobs,
    fixes,
    law_names,
)
from pmalab.console import (
    VERBOSE,
    add_verbosity,
    note,
    show_progress,
    table_printer,
    verbosity,
    warning,
)
from pmalab.errors import PmalabError
from pmalab.lazy import gc_paused, is_the_command, with_stack_room

if TYPE_CHECKING:
    from pmalab.identify.reading import Reading


@contextmanager
def _fitting_code() -> Iterator[None]:
    """The fitting code's imports (the block's) and numba's first load of compiled code,
    with the garbage collector paused: it would walk their objects again and again.  They
    are frozen after when this is the process's first import of them in the ``pmalab``
    command (:func:`pmalab.lazy.is_the_command`), so no later collection walks them either."""
    with gc_paused(freeze=is_the_command() and "scipy" not in sys.modules):
        yield
        from pmalab.identify.estimation import problem
        from pmalab.identify.zero_phase import load_compiled

        load_compiled()
        problem.load_compiled()


@contextmanager
def _discarded_on_failure(reading: Reading | None) -> Iterator[None]:
    """The block, and the reading child stopped and reaped if the block fails (Ctrl-C while
    importing): it would wait on its pipe as long as this process lives."""
    try:
        yield
    except BaseException:
        if reading is not None:
            reading.discard()
        raise


def _reading_while_importing(args: argparse.Namespace, muscle: str | None) -> Reading | None:
    """With more than one job, the command's files read in a forked child while this
    process imports the fitting code (:func:`pmalab.identify.reading.start_reading`);
    None with one job (everything in this process, nothing forked)."""
    if args.jobs <= 1:
        return None
    from pmalab.identify.reading import start_reading

    return start_reading(
        args.files, args.validate or (), include_aborted=args.include_aborted, muscle=muscle
    )


def resolve_jobs(jobs: int | None) -> int:
    """``--jobs`` as given, else ``$PMALAB_JOBS``, else :data:`pmalab.arguments.DEFAULT_JOBS`.

    Parameters
    ----------
    jobs
        The option's value (None: not given).

    Returns
    -------
    int
        Worker processes, ≥ 1.

    Raises
    ------
    PmalabError
        Fewer than one, or ``$PMALAB_JOBS`` not a whole number (one line).
    """
    n = default_jobs(DEFAULT_JOBS) if jobs is None else jobs
    if n < 1:
        raise PmalabError(f"--jobs {n}: must be at least 1")
    return n


def _add_parallel(p: argparse.ArgumentParser, what: str, more: str = "") -> None:
    """``--jobs N`` (worker processes) and ``--scheduler ADDRESS`` (a Dask cluster)."""
    p.add_argument(
        "--jobs",
        type=int,
        default=None,
        metavar="N",
        help=f"parallel worker processes (default {DEFAULT_JOBS}, or ${JOBS_ENV} when set)",
    )
    p.add_argument(
        "--scheduler",
        default=None,
        metavar="ADDRESS",
        help=f"run {what} on a Dask distributed scheduler (tcp://host:port){more}",
    )


def register(sub: argparse._SubParsersAction) -> None:
    """Add this area's verbs to the ``pmalab`` parser."""
    _register_identify(sub)
    _register_diagnose(sub)
    _register_simulate(sub)


# --------------------------------------------------------------------------- identify
def _register_identify(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "identify",
        help="fit hysteresis models ({laws}) per run, pressure laws, validation",
        description=(
            "Identify F = k·x + c0 + h (h: one of the laws {laws}) on every run of the given files, "
            "fit each parameter as a quadratic in muscle pressure, and validate the "
            "pressure-quadratic model on held-out runs (runs with role 'validation' in the "
            "inputs, and every run of --validate files).  Writes OUT/identification.json "
            "and OUT/predictions.h5."
        ),
    )
    p.add_argument("files", nargs="+", metavar="FILE.h5", help="identification run files")
    p.add_argument(
        "--muscle",
        metavar="NAME|all",
        help="files recording several muscles (an antagonistic pair): identify this one "
        "from the runs that held it isobaric; 'all': each into OUT/NAME/",
    )
    p.add_argument(
        "--model",
        required=True,
        metavar="LAW[,LAW...]",
        help="hysteresis law: {laws} (or any law file in identify/laws/); several, "
        "comma-separated, identify each "
        "into OUT/LAW/ and print one table ranking them",
    )
    p.add_argument(
        "--add",
        action="append",
        default=[],
        metavar="EFFECT",
        help="add an effect by id (repeatable): {effects}",
    )
    p.add_argument(
        "--effects",
        action="append",
        default=[],
        metavar="FILE.py",
        help="Python file defining user effects (Effect subclasses)",
    )
    p.add_argument(
        "--validate",
        nargs="+",
        default=[],
        metavar="FILE.h5",
        help="held-out run files to validate on",
    )
    p.add_argument(
        "--hold-out",
        action="append",
        default=[],
        metavar="RUN[,RUN]",
        help="hold these runs of the input files out for validation (as "
        "`pmalab diagnose` does when no --validate is given)",
    )
    p.add_argument("--out", required=True, metavar="DIR", help="output directory")
    p.add_argument("--force", action="store_true", help="overwrite existing outputs")
    _add_parallel(p, "the fits")
    p.add_argument(
        "--fix",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="hold a parameter at a value (repeatable)",
    )
    p.add_argument(
        "--free",
        action="append",
        default=[],
        metavar="NAME",
        help="free a parameter the law fixes by default (bouc-wen: n; duhem: a)",
    )
    p.add_argument(
        "--initial",
        default="estimate",
        choices=("estimate", "burn-in", "zero"),
        help="record parameters of validation predictions (start state, force zero): "
        "estimate (default: fitted on the record's first excitation cycle(s), about a "
        "third of it, and the error scored on the rest), burn-in (one period replayed "
        "before the run) or zero",
    )
    p.add_argument(
        "--output",
        default="force",
        choices=("force", "position"),
        help="what the model is fitted to predict: force (from the measured "
        "position, default) or position (output error: the model driven by "
        "the measured force, simulated forward; needs a moving mass, e.g. "
        "--add inertia)",
    )
    p.add_argument(
        "--pressure-model",
        default="joint",
        choices=("joint", "per-run"),
        help="pressure laws: refined jointly on all runs with chosen orders "
        "(default) or the seeds' per-run quadratics",
    )
    p.add_argument(
        "--structure",
        default="auto",
        choices=("auto", "free", "scaled", "scaled-thresholds"),
        help="how an element law's elements change with pressure: chosen by "
        "leave-one-pressure-out evidence (auto, default), every parameter its own law "
        "(free), one profile scaled in magnitude (scaled), and its slip displacements "
        "scaled too (scaled-thresholds)",
    )
    _add_static_options(p, "identify")
    add_verbosity(p)
    _add_input_options(p)
    p.set_defaults(func=run_identify)


def _add_static_options(p: argparse.ArgumentParser, verb: str) -> None:
    """``--static``, ``--drive``, ``--length``, ``--diameter`` (identify and diagnose)."""
    p.add_argument(
        "--static",
        metavar="MAP",
        help=f"static characterization ({verb}): the static map F_s(x, p) — linear (k(p)·x + "
        "c0(p)), chou-hannaford (braid angle, diameter, end effect; needs --length) or "
        "tondu-lopez (needs --length and --diameter) — plus the --model law on --drive, "
        "one set of parameters for every run of any test type (default for "
        "isometric, isotonic and free runs: linear); --model none for the map alone",
    )
    p.add_argument(
        "--drive",
        choices=("pressure", "position", "both"),
        help="with --static: what drives the law — the pressure (inflation vs deflation; "
        "default for isometric/isotonic runs), the contraction (isobaric runs) or both "
        "(one law on each, free runs)",
    )
    p.add_argument(
        "--loop-scale",
        choices=("none", "pressure"),
        default="none",
        help="with --static: 'pressure' scales the pressure law's loop by p/p_max (friction "
        "proportional to the contact pressure, Tondu-Lopez: the loop pinches at p = 0); "
        "default none (one width at every pressure)",
    )
    p.add_argument(
        "--length",
        type=float,
        metavar="MM",
        help="with --static: the muscle's relaxed active length in mm (measured)",
    )
    p.add_argument(
        "--diameter",
        type=float,
        metavar="MM",
        help="with --static tondu-lopez: the muscle's relaxed outer diameter in mm",
    )


def _add_input_options(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--include-aborted",
        action="store_true",
        help="also use runs that were aborted or interrupted (default: skip them "
        "with a warning; their fragments are not full tests)",
    )
    p.add_argument(
        "--whole-run",
        action="store_true",
        help="use every sample, including the settle time and ramps (default: "
        "the full-amplitude cycles recorded in steady_start_s/steady_end_s)",
    )
    p.add_argument(
        "--pressure",
        choices=("nominal", "measured"),
        default="nominal",
        help="each run's pressure for the pressure laws: its nominal label (protocol, file "
        "name; default) or its measured mean; runs whose measured mean differs from the "
        "label beyond the gauge noise and regulator resolution are named either way",
    )


def _identify_each_muscle(args: argparse.Namespace) -> int:
    """``--muscle all``: identify every muscle the input files record into OUT/NAME/."""
    from pathlib import Path

    from pmalab.runfile import muscles_of

    names: list[str] = []
    for f in args.files:
        for m in muscles_of(f):
            if m not in names:
                names.append(m)
    for m in names:
        print(f"muscle {m}:")
        sub = argparse.Namespace(**{**vars(args), "muscle": m, "out": str(Path(args.out) / m)})
        rc = identify_command(sub)
        if rc:
            return rc
    return 0


def _pressure_labels(args: argparse.Namespace, runs: list, val: list) -> tuple[list, list]:
    """Warn about runs whose measured mean pressure differs from their label; with
    ``--pressure measured`` give every run its measured mean."""
    from pmalab.identify.labels import check_runs, use_measured
    from pmalab.pressure_labels import label_warning

    whole = bool(getattr(args, "whole_run", False))
    measured = getattr(args, "pressure", "nominal") == "measured"
    line = label_warning(
        check_runs([*runs, *val], whole),
        "the pressure laws now use the measured mean" if measured else "the pressure laws",
    )
    if line:
        if measured:
            line = line.split(" — give --pressure measured")[0]
        warning(line)
    if measured:
        return use_measured(runs, whole), use_measured(val, whole)
    return runs, val


def _from_the_shell(command: Callable[[argparse.Namespace], int], args: argparse.Namespace) -> int:
    """A fitting verb's ``command`` as the shell runs it (BLAS loaded on one thread by
    :func:`pmalab.cli.main`, as for every verb) with frame-stack room
    (:func:`pmalab.lazy.with_stack_room`: its imports and fits never map and unmap
    CPython's frame-stack chunks call after call)."""
    return with_stack_room(command, args)


def run_identify(args: argparse.Namespace) -> int:
    """``pmalab identify``: :func:`identify_command` from the shell (:func:`_from_the_shell`)."""
    return _from_the_shell(identify_command, args)


def identify_command(args: argparse.Namespace) -> int:
    """The ``pmalab identify`` command (see :func:`_register_identify`); 0 on success."""
    from pathlib import Path

    from pmalab.paths import prepare_output_dir

    args.jobs = resolve_jobs(args.jobs)
    for f in args.effects:
        if not Path(f).is_file():
            raise PmalabError(f"--effects {f}: no such file")
    if args.muscle == "all":
        return _identify_each_muscle(args)
    if "," in args.model and args.static:
        raise PmalabError(
            f"--model {args.model}: with --static give one law (or none); "
            "`pmalab diagnose --static` ranks the laws"
        )
    if "," in args.model:
        return run_identify_many(args)
    # refuse early, before any work, if outputs exist or cannot be written
    out = prepare_output_dir(args.out, ("identification.json", "predictions.h5"), args.force)
    m = args.muscle
    # with a second core, a child reads the files while this process imports the fitting
    # code (SciPy, numba); --jobs 1 keeps everything in this one process
    reading = _reading_while_importing(args, m)

    with _discarded_on_failure(reading), _fitting_code():
        from pmalab.identify.api import RunList, identify, load
        from pmalab.identify.messages import sort_messages
        from pmalab.runfile import check_distinct, check_distinct_runs
    read = reading.result() if reading is not None else None
    if read is not None:
        runs, val = RunList(read[0]), (RunList(read[1]) if args.validate else [])
    else:
        check_distinct(args.files, args.validate)
        runs = load(args.files, include_aborted=args.include_aborted, muscle=m)
        val = (
            load(args.validate, include_aborted=args.include_aborted, muscle=m)
            if args.validate
            else []
        )
    check_distinct_runs([*runs, *val])
    runs, val = _pressure_labels(args, runs, val)
    hold = [n for item in args.hold_out for n in item.split(",") if n]
    if hold:
        unknown = [n for n in hold if not any(n in (r.name, r.label) for r in runs)]
        if unknown:
            raise PmalabError(f"--hold-out {unknown[0]}: no such run in the input files")
        val = [r for r in runs if r.name in hold or r.label in hold] + list(val)
        runs = [r for r in runs if not (r.name in hold or r.label in hold)]
    if args.static or any(r.test_type != "isobaric" for r in runs):
        from pmalab.identify.static.cli import run_static

        return run_static(args, runs, val, out, auto=not args.static)
    if args.model == "none":
        raise PmalabError("--model none: only with --static (the static map alone)")
    res = identify(
        runs,
        args.model,
        effects=args.add,
        effects_files=args.effects,
        validate=val,
        jobs=args.jobs,
        scheduler=args.scheduler,
        fixed=fixes(args.fix),
        free=args.free,
        initial=args.initial,
        progress=show_progress(args),
        pressure_model=args.pressure_model,
        whole_run=args.whole_run,
        output=args.output,
        structure=args.structure,
    )
    jpath, hpath = res.save(out, force=args.force)

    level = verbosity(args)
    show = table_printer(args)
    w = max(
        [len(rf.label) for rf in res.campaign.runs]
        + [len(v.run.label) for v in res.validation]
        + [10]
    )
    show(
        f"model {res.model.name}: {len(res.campaign.runs)} identification run(s), "
        f"{len(res.validation)} validation run(s)"
    )
    oe = res.campaign.output_error
    for i, rf in enumerate(res.campaign.runs):
        r = rf.result
        if oe is not None:
            show(
                f"  identify  {rf.label:<{w}}  p={rf.p_nom:6.4f} MPa  position rmse "
                f"{oe.rmse_mm[i] * 1e-3:9.3g} m  nrmse {oe.nrmse[i]:.4f}  (output error; "
                f"force-direction start {oe.rmse_mm_start[i] * 1e-3:.3g} m)"
            )
            continue
        show(
            f"  identify  {rf.label:<{w}}  p={rf.p_nom:6.4f} MPa  fit {r.fit_percent:6.2f} %  "
            f"rmse {r.rmse:7.3g} N"
        )
    for v in res.validation:
        m = v.metrics
        head = f"  validate  {v.run.label:<{w}}  p={v.run.nominal_pressure:6.4f} MPa  "
        if getattr(v, "diverged", False):
            show(head + f"prediction DIVERGED ({v.message})")
            continue
        if "rmse_position_m" in m:
            show(
                head + f"position rmse {m['rmse_position_m']:9.3g} m  "
                f"nrmse {m['nrmse_position']:.4f}  fit {m['fit_percent_position']:6.2f} %"
            )
            continue
        show(
            head + f"fit {m['fit_percent']:6.2f} %  rmse {m['rmse']:7.3g} N  "
            f"energy {m['energy_error_percent']:+.1f} %"
            + ("  (extrapolated in pressure)" if getattr(v, "status", "") == "extrapolated" else "")
        )
    st = getattr(res.campaign, "structure", None)
    if st is not None:
        show(f"  {structure_line(st)}")
    if res.campaign.output != "position":
        from pmalab.identify.outputs import validation_headline

        line = validation_headline(res.validation)
        if line:
            show(line)
    sys.stdout.flush()
    msgs = sort_messages(
        [*res.notes, *res.warnings],
        [
            (rf.label, rf.result.warnings, getattr(rf.result, "notes", []))
            for rf in res.campaign.runs
        ],
    )
    if level > 0:
        for n in msgs.notes:
            note(n)
    if level >= VERBOSE:
        for n in msgs.details:
            note(n)
    for wmsg in msgs.warnings:
        warning(wmsg)
    print(f"wrote {jpath} and {hpath}")
    return 0


# --------------------------------------------------------------------------- diagnose
def _register_diagnose(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "diagnose",
        help="where the model fails, which effect is missing, and the error falling",
        description=(
            "Fit the base model, rank every effect of the catalogue (and --effects files) on "
            "held-out data, climb the ladder (add the best significant effect, repeat), and "
            "localise the base model's error.  Writes OUT/diagnosis.json and "
            "OUT/predictions.h5; prints the ranking and the ladder."
        ),
    )
    p.add_argument("files", nargs="+", metavar="FILE.h5", help="run files to diagnose")
    p.add_argument(
        "--muscle",
        metavar="NAME",
        help="files recording several muscles (an antagonistic pair): diagnose this one",
    )
    p.add_argument(
        "--model",
        required=True,
        metavar="LAW",
        help="hysteresis law: {laws} (or any law file in identify/laws/)",
    )
    p.add_argument(
        "--validate",
        nargs="+",
        default=[],
        metavar="FILE.h5",
        help="held-out run files (default: the last third of every run)",
    )
    p.add_argument("--out", required=True, metavar="DIR", help="output directory")
    p.add_argument("--force", action="store_true", help="overwrite existing outputs")
    p.add_argument(
        "--effects",
        action="append",
        default=[],
        metavar="FILE.py",
        help="Python file defining user effects (Effect subclasses), repeatable",
    )
    p.add_argument(
        "--only",
        action="append",
        default=None,
        metavar="EFFECT",
        help="rank only these effect ids (repeatable; default: all of {effects})",
    )
    p.add_argument(
        "--max-steps",
        type=int,
        default=3,
        metavar="N",
        help="most steps the ladder takes (adding an effect or changing the law; default 3)",
    )
    p.add_argument(
        "--laws",
        default=None,
        metavar="A,B|none",
        help="other hysteresis laws scored like effects (default: every law; 'none' scores none)",
    )
    _add_parallel(p, "the candidates' identifications", "; the same numbers as locally")
    p.add_argument(
        "--plot", default=None, metavar="FILE.png", help="also save the ranking/ladder figure"
    )
    _add_static_options(p, "diagnose")
    add_verbosity(p)
    _add_input_options(p)
    p.set_defaults(func=run_diagnose)


def run_diagnose(args: argparse.Namespace) -> int:
    """``pmalab diagnose``: :func:`diagnose_command` from the shell (:func:`_from_the_shell`)."""
    return _from_the_shell(diagnose_command, args)


def diagnose_command(args: argparse.Namespace) -> int:
    """The ``pmalab diagnose`` command (see :func:`_register_diagnose`); 0 on success."""
    from pathlib import Path

    from pmalab.paths import check_output, prepare_output_dir

    args.jobs = resolve_jobs(args.jobs)
    check_max_steps(args.max_steps)
    out = prepare_output_dir(args.out, ("diagnosis.json", "predictions.h5"), args.force)
    if args.plot:
        check_output(args.plot, args.force)
        plot_dir = Path(args.plot).resolve().parent
        if not plot_dir.is_dir() or not os.access(plot_dir, os.W_OK):
            raise PmalabError(f"--plot {args.plot}: cannot write there")
    mus = args.muscle
    # with a second core, a child reads the files while this process imports the fitting
    # code (SciPy, numba), as `pmalab identify` does; --jobs 1 keeps everything here
    reading = _reading_while_importing(args, mus)

    with _discarded_on_failure(reading), _fitting_code():
        from pmalab.identify.diagnosis import diagnose, write_outputs
        from pmalab.identify.diagnosis.diagnose import against_words
        from pmalab.identify.headline import WORST_BY, worst_runs
        from pmalab.identify.long_records import fit_part, long_runs
        from pmalab.runfile import check_distinct, check_distinct_runs, read_many

    read = reading.result() if reading is not None else None
    if read is not None:
        got, got_val = read
    else:
        check_distinct(args.files, args.validate)
        lr = long_runs()
        got = read_many(args.files, include_aborted=args.include_aborted, long_runs=lr, muscle=mus)
        got_val = (
            read_many(args.validate, include_aborted=args.include_aborted, long_runs=lr, muscle=mus)
            if args.validate
            else []
        )
    # a long record is diagnosed on the cycles its run-level fit uses (its first ones)
    runs = [fit_part(r) for r in got]
    val = [fit_part(r) for r in got_val]
    check_distinct_runs([*runs, *val])
    runs, val = _pressure_labels(args, runs, val)
    laws = law_names(args.laws)
    if args.static or any(r.test_type != "isobaric" for r in runs):
        from pmalab.identify.static.cli import run_static_diagnose

        return run_static_diagnose(args, runs, val, out, laws)
    d = diagnose(
        runs,
        model=args.model,
        validate=val,
        effects=args.only,
        effects_files=args.effects,
        max_steps=args.max_steps,
        jobs=args.jobs,
        progress=show_progress(args),
        whole_run=args.whole_run,
        laws=laws,
        scheduler=args.scheduler,
    )
    jpath, hpath = write_outputs(d, out, force=args.force)
    st = d.settings
    show = table_printer(args)
    show(f"Held out ({st['validation']}): {', '.join(st['held_out'])}")
    show(
        f"Effect ranking ({args.model}; validation nrmse of `pmalab identify` without → "
        f"with each effect; noise floor {d.noise_floor['mean_nrmse']:.4f}):"
    )
    show(d.ranking_table())
    if d.ambiguous:
        show(
            f"ambiguous: {', '.join(d.ambiguous)} — suggested experiment: {d.suggested_experiment}"
        )
    show("\nLadder (the error falling step by step):")
    show(d.ladder_table())
    if d.laws:
        show("\nOther laws (validation nrmse of `pmalab identify --model LAW`, same runs):")
        show(
            _table(
                [
                    (
                        "law",
                        "against",
                        "nrmse before",
                        "nrmse after",
                        "fall %",
                        "× floor gain",
                        "significant",
                        "structure",
                    )
                ]
                + [
                    (
                        lw["law"],
                        # the model the row was scored against: the base, or for the law
                        # the ladder switched to, the model of the step before
                        against_words(lw.get("scored_against")),
                        # null: no held-out run left to judge on
                        "—" if lw["nrmse_before"] is None else f"{lw['nrmse_before']:.4f}",
                        # null: the law's identification raised
                        "—" if lw["nrmse_after"] is None else f"{lw['nrmse_after']:.4f}",
                        "—" if lw["fall_percent"] is None else f"{lw['fall_percent']:+.1f}",
                        "—" if lw["gain_x_floor"] is None else f"{lw['gain_x_floor']:+.2f}",
                        "fit failed"
                        if lw.get("status") == "failed"
                        else (
                            "yes"
                            if lw["significant"]
                            # taken by the ladder, then replaced by another law
                            else "replaced"
                            if lw.get("ladder_step") is not None
                            # significant against the base model alone, not taken
                            else ("alone only" if lw.get("significant_alone") else "no")
                        ),
                        lw.get("structure") or "-",
                    )
                    for lw in d.laws
                ]
            )
        )
    hint = " ".join(
        [
            "pmalab identify",
            *args.files,
            "--model",
            d.final_law or args.model,
            *[f"--add {e}" for e in d.final_effects],
            *(["--validate", *args.validate] if args.validate else []),
            *([st["identify_hint"]] if st.get("identify_hint") else []),
            "--out DIR",
        ]
    )
    show(f"\nSame numbers from identification: {hint}")
    show(f"\nWhere the base model fails (worst runs first: {WORST_BY}):")
    for key in worst_runs(d.diagnostics, 3):
        show(f"  {key}: {d.diagnostics[key]['worst_region']}")
    show()
    print(d.summary)
    if args.plot:
        d.plot(check_output(args.plot, args.force))
    print(f"wrote {jpath} and {hpath}")
    return 0


def run_identify_many(args: argparse.Namespace) -> int:
    """``--model a,b,c``: one identification per law into OUT/LAW/, one ranking table.

    Every law is identified on the same runs and validated on the same held-out runs with
    the same engine; the table ranks them by mean validation nrmse, with each validation
    run's noise floor (:mod:`pmalab.identify.noise`) for scale.  OUT/laws.json holds the
    table."""
    import json
    from pathlib import Path

    import numpy as np

    from pmalab.identify.api import identify, load
    from pmalab.identify.laws import LAWS
    from pmalab.identify.outputs import validation_floor
    from pmalab.paths import check_output, prepare_output_dir
    from pmalab.runfile import check_distinct, check_distinct_runs

    laws = [m.strip() for m in args.model.split(",")]
    if not any(laws):
        raise PmalabError(f"--model {args.model!r}: names no law (choose from {', '.join(LAWS)})")
    if not all(laws):
        raise PmalabError(
            f"--model {args.model!r}: an empty name between commas (e.g. bouc-wen,duhem)"
        )
    for m in laws:
        if m not in LAWS:
            raise PmalabError(f"--model {m}: unknown law (choose from {', '.join(LAWS)})")
    if len(set(laws)) != len(laws):
        raise PmalabError(f"--model {args.model}: a law is named twice")
    if args.hold_out or args.fix or args.free:
        raise PmalabError("--hold-out, --fix and --free: give one --model at a time")
    structured = [m for m in laws if args.structure in ("auto", "free", *LAWS[m].structures)]
    if len(structured) < len(laws) and args.structure != "auto":
        other = next(m for m in laws if m not in structured)
        raise PmalabError(
            f"--structure {args.structure}: {other} offers "
            f"{', '.join(['free', *LAWS[other].structures])}"
        )
    outs = {
        m: prepare_output_dir(
            str(Path(args.out) / m), ("identification.json", "predictions.h5"), args.force
        )
        for m in laws
    }
    table_path = check_output(Path(args.out) / "laws.json", args.force)
    check_distinct(args.files, args.validate)
    mus = getattr(args, "muscle", None)
    runs = load(args.files, include_aborted=args.include_aborted, muscle=mus)
    val = (
        load(args.validate, include_aborted=args.include_aborted, muscle=mus)
        if args.validate
        else []
    )
    check_distinct_runs([*runs, *val])
    rows = []
    floors: list[float] = []
    for m in laws:
        res = identify(
            runs,
            m,
            effects=args.add,
            effects_files=args.effects,
            validate=val,
            jobs=args.jobs,
            scheduler=args.scheduler,
            initial=args.initial,
            progress=show_progress(args),
            pressure_model=args.pressure_model,
            whole_run=args.whole_run,
            structure=args.structure if m in structured else "auto",
        )
        res.save(outs[m], force=args.force)
        if not floors:
            floors = [validation_floor(v) or float("nan") for v in res.validation]
        vn = [float(v.metrics["nrmse"]) for v in res.validation]
        fit = [float(rf.result.metrics["nrmse"]) for rf in res.campaign.runs]
        k = len(
            {
                p.name
                for rf in res.campaign.runs
                for p in rf.result.params
                if p.vary and p.name not in res.model.state_params
            }
            | set(res.campaign.shape_reference)  # held per run, fitted as campaign constants
        )
        rows.append(
            {
                "law": m,
                "validation_nrmse": float(np.mean(vn)) if vn else None,
                "validation_per_run": vn,
                "identification_nrmse": float(np.mean(fit)),
                "parameters_per_run": k,
                "directory": str(outs[m]),
                # the pressure structure the law's elements took (None: the law has none)
                "pressure_structure": None
                if res.campaign.structure is None
                else res.campaign.structure.chosen,
            }
        )
    floor = float(np.mean(floors)) if floors else None
    show = table_printer(args)
    for r in rows:
        v = r["validation_nrmse"]
        r["x_floor"] = (v / floor) if (v is not None and floor) else None
    rows.sort(
        key=lambda r: (
            r["validation_nrmse"] is None,
            r["validation_nrmse"] or 0.0,
            r["identification_nrmse"],
        )
    )
    show(
        f"Laws on {len(runs)} run(s), validated on {len(floors)} held-out run(s)"
        + (f" (noise floor {floor:.4f})" if floor else "")
        + ", best first:"
    )
    show(
        _table(
            [
                (
                    "law",
                    "validation nrmse",
                    "× floor",
                    "fit nrmse (per run)",
                    "parameters",
                    "structure",
                )
            ]
            + [
                (
                    r["law"],
                    "-" if r["validation_nrmse"] is None else f"{r['validation_nrmse']:.4f}",
                    "-" if r["x_floor"] is None else f"{r['x_floor']:.2f}",
                    f"{r['identification_nrmse']:.4f}",
                    str(r["parameters_per_run"]),
                    r["pressure_structure"] or "-",
                )
                for r in rows
            ]
        )
    )
    table_path.write_text(json.dumps({"noise_floor_nrmse": floor, "laws": rows}, indent=1))
    print(f"wrote {', '.join(str(outs[r['law']]) for r in rows)} and {table_path}")
    show(f"side by side: pmalab report {args.out} --out laws.pdf")
    return 0


def structure_line(st) -> str:
    """One line naming the pressure structure a campaign chose and its evidence."""
    if not st.scores:
        return f"pressure structure: {st.chosen} (chosen by the user)"
    best = st.scores[st.chosen]
    others = ", ".join(
        f"{s} {v:.4f} ({100.0 * (v / best - 1.0):+.1f} %)"
        for s, v in sorted(st.scores.items(), key=lambda kv: kv[1])
        if s != st.chosen
    )
    ec = getattr(st, "elements", {}).get(st.chosen)
    pr = getattr(st, "priors", {}).get(st.chosen)
    tail = f"; {ec.summary()}" if ec is not None else ""
    tail += f"; {pr.what}: {pr.summary()}" if pr is not None else ""
    return (
        f"pressure structure: {st.chosen} — leave-one-pressure-out held-out nrmse {best:.4f} "
        f"({st.n_params[st.chosen]} coefficients); {others}{tail}"
    )


def _table(rows: list[tuple[str, ...]]) -> str:
    w = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
    out = []
    for j, r in enumerate(rows):
        out.append("  ".join(c.ljust(w[i]) if i == 0 else c.rjust(w[i]) for i, c in enumerate(r)))
        if j == 0:
            out.append("  ".join("-" * x for x in w))
    return "\n".join(out)


# --------------------------------------------------------------------------- simulate
def _register_simulate(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "simulate",
        help="run an identified model forward on a recorded input (force->position and back)",
        description=(
            "Integrate the model of MODEL_DIR/identification.json on every run of INPUT.h5 "
            "and write a run file with the simulated channel in place of the measured one. "
            "--input position: measured position in, force out (what identify predicts); "
            "--input force: measured force in, position out (needs a moving mass: the "
            "inertia effect or --load-mass); --input pressure: the muscle moves a load "
            "(--load-mass kg, --load-stiffness N/mm, --preload N) driven by the recorded "
            "pressure.  Default: the direction the model was identified in."
        ),
    )
    p.add_argument("model_dir", metavar="MODEL_DIR", help="directory of identification.json")
    p.add_argument("input", metavar="INPUT.h5", help="run file giving the inputs")
    p.add_argument("--out", required=True, metavar="SIM.h5", help="run file to write")
    p.add_argument(
        "--input",
        dest="direction",
        default=None,
        choices=("position", "force", "pressure"),
        help="which channel drives it",
    )
    p.add_argument("--load-mass", type=float, default=0.0, metavar="KG")
    p.add_argument("--load-stiffness", type=float, default=0.0, metavar="N_PER_MM")
    p.add_argument("--preload", type=float, default=0.0, metavar="N")
    p.add_argument("--force", action="store_true", help="overwrite an existing output")
    p.add_argument(
        "--whole-run",
        action="store_true",
        help="every sample (default: each run's full-amplitude window, as identify)",
    )
    add_verbosity(p)
    p.set_defaults(func=run_simulate)


def run_simulate(args: argparse.Namespace) -> int:
    import time
    from dataclasses import replace

    import numpy as np

    from pmalab.identify.estimation.output_error import (
        position_data,
        position_metrics,
        predict_position,
    )
    from pmalab.identify.estimation.records import predict_record
    from pmalab.identify.forward import IdentifiedPlant, Load, simulate
    from pmalab.identify.signals import Signals
    from pmalab.paths import check_output
    from pmalab.runfile import read_runs, write_runs

    for name in ("load_mass", "load_stiffness", "preload"):
        v = getattr(args, name)
        if not np.isfinite(v) or (name != "preload" and v < 0):
            raise PmalabError(f"--{name.replace('_', '-')} {v}: must be a finite value >= 0")
    check_output(args.out, args.force)
    plant = IdentifiedPlant.read(args.model_dir)
    direction = args.direction or ("force" if plant.output == "position" else "position")
    runs = read_runs(args.input)
    if not args.whole_run:
        runs = [r.steady() for r in runs]
    load = Load(args.load_mass, args.load_stiffness, args.preload)
    out = []
    for r in runs:
        t0 = time.perf_counter()
        sig = Signals.from_run(r)
        th = plant.theta(float(r.nominal_pressure))
        if direction == "position":
            f = predict_record(
                plant.model, sig, th, force=r.force, initial=plant.initial, bounds=plant.bounds
            )
            new = replace(r, force=f)
            err = f"force rmse {float(np.sqrt(np.mean((f - r.force) ** 2))):.4g} N"
        elif direction == "force":
            xm, _ = predict_position(
                plant.model, th, position_data(r.label, sig, r.force, r.position), plant.bounds
            )
            new = replace(r, position=xm)
            err = f"position rmse {position_metrics(r.position, xm)['rmse_position_m']:.4g} m"
        else:
            if load.mass_kg <= 0 and "inertia" not in [e.id for e in plant.model.effects]:
                raise PmalabError(
                    "--input pressure: the muscle must move a mass: give --load-mass KG"
                )
            s = simulate(
                plant.model,
                plant.free_laws(),
                r.time,
                0.0,
                r.muscle_pressure,
                p_nom=float(r.nominal_pressure),
                load=load,
                x0=float(r.position[0]),
                bounds=plant.bounds,
            )
            new = replace(r, position=s.position, force=s.tension)
            err = (
                f"position rmse {position_metrics(r.position, s.position)['rmse_position_m']:.4g}"
                f" m ({s.status})"
            )
        bad = [c for c in ("position", "force") if not np.all(np.isfinite(getattr(new, c)))]
        if bad:  # a runaway model: refuse before anything is written
            raise PmalabError(
                f"{r.label}: the simulated {bad[0]} is not finite (the model ran away); "
                "nothing written"
            )
        new.attrs = {
            **r.attrs,
            "simulated_by": "pmalab simulate",
            "simulated_input": direction,
            "simulated_model": plant.source,
        }
        out.append(new)
        print(
            f"  {r.label}: {len(r)} samples, {direction} in, {time.perf_counter() - t0:.3f} s; "
            f"vs measured: {err}"
        )
    path = write_runs(args.out, out, force=args.force)
    print(f"wrote {path}")
    return 0
