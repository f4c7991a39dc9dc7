"""The notebook API: load → identify → predict → plot, in a few lines.

>>> from pmalab.identify import load, identify
>>> runs = load("campaign.h5")                       # every run of the file (canonical units)
>>> res = identify(runs, model="bouc-wen")           # runs with role "validation" are held out
>>> res.parameters                                   # DataFrame: one row per run
>>> res.validation_table                             # fit %, nrmse, energy error per held-out run
>>> force = res.predict(runs[0])                     # pressure-quadratic free-run prediction (N)
>>> res.plot_loops()                                 # measured vs model force–position loops
>>> res.save("out/")                                 # identification.json + predictions.h5

Units everywhere: time s, position mm (contraction, + = shorter), force N (tension),
pressure MPa.  Plots use matplotlib only.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path

import numpy as np

from pmalab.arguments import DEFAULT_JOBS, default_jobs
from pmalab.errors import PmalabError
from pmalab.identify.campaign import (
    ModelSpec,
    check_prediction,  # noqa: F401  (re-exported: the notebook API)
    fit_and_validate,
)
from pmalab.identify.campaign.trajectory import run_trajectory
from pmalab.identify.long_records import fit_part
from pmalab.identify.messages import note
from pmalab.identify.model import ForceModel
from pmalab.identify.outputs import Identification
from pmalab.identify.reading import read_files
from pmalab.runfile import Run


class RunList(list):
    """A list of :class:`~pmalab.runfile.Run` with a readable summary."""

    def by_role(self, role: str) -> RunList:
        return RunList(r for r in self if r.attrs.get("role") == role)

    def __getitem__(self, key):  # type: ignore[override]
        if isinstance(key, str):
            for r in self:
                if r.name == key or r.label == key:
                    return r
            raise KeyError(key)
        out = super().__getitem__(key)
        return RunList(out) if isinstance(key, slice) else out

    def __repr__(self) -> str:
        rows = [
            f"{r.label}  p={r.nominal_pressure:.4g} MPa  f={r.frequency} Hz  "
            f"{r.attrs.get('waveform', '')}  {len(r)} samples  {r.attrs.get('role', '')}"
            for r in self
        ]
        return f"RunList({len(self)} runs)\n  " + "\n  ".join(rows)


def load(
    *paths: str | Path | Sequence[str | Path],
    runs: Iterable[str] | None = None,
    include_aborted: bool = False,
    muscle: str | None = None,
) -> RunList:
    """Every complete run of the given contract files (or the named ``runs``), canonical units.

    Runs that were aborted or interrupted (status ``aborted: ...`` / ``running``) are
    skipped with one :class:`~pmalab.errors.RunFileWarning` each unless ``include_aborted``
    or named in ``runs``; a file given twice is refused.  A long run (≥
    :data:`~pmalab.identify.long_records.LONG_RUN_SAMPLES` samples) is read a window at a
    time and decimated, as its attrs' ``decimation`` states
    (:mod:`pmalab.identify.long_records`).

    Parameters
    ----------
    *paths
        Run files (HDF5, ``pmalab.run`` contract), or lists of them.
    runs
        Names of the runs to read (default: every complete run).
    include_aborted
        Also read aborted and interrupted runs (the samples they hold).
    muscle
        Which muscle of a file recording several (an antagonistic pair): its isobaric
        runs and its channels (:func:`pmalab.runfile.read_runs`).

    Returns
    -------
    RunList
        The runs in canonical units: time s, position mm (contraction positive), force N
        (tension positive), pressure MPa gauge.

    Raises
    ------
    pmalab.errors.RunFileError
        One line naming file, run and channel: a missing file or channel, unequal lengths,
        time not increasing, NaNs, a file given twice.
    """
    flat: list[str | Path] = []
    for p in paths:
        if isinstance(p, str | Path):
            flat.append(p)
        else:
            flat.extend(p)
    return RunList(read_files(flat, runs, include_aborted=include_aborted, muscle=muscle))


def split_roles(runs: Sequence[Run]) -> tuple[list[Run], list[Run]]:
    """Split a campaign by each run's ``role`` attr.

    Parameters
    ----------
    runs
        The runs, e.g. from :func:`load`.

    Returns
    -------
    tuple of (list of Run, list of Run)
        (identification, validation): the runs whose ``role`` is ``"validation"`` are held
        out, every other run (a missing ``role`` included) identifies; order is kept.
    """
    ident = [r for r in runs if r.attrs.get("role") != "validation"]
    val = [r for r in runs if r.attrs.get("role") == "validation"]
    return ident, val


def long_record_notes(runs: Sequence[Run]) -> list[str]:
    """One note per long record: how it was read and which part the run-level fit used."""
    out: list[str] = []
    for r in runs:
        dec = r.attrs.get("decimation") or {}
        if int(dec.get("stride", 1)) <= 1:
            continue
        part = r.attrs.get("fit_part") or {}
        text = (
            f"{r.label}: a long record ({dec.get('samples_read'):,} samples) read in windows "
            f"and decimated to {dec.get('samples_per_cycle', 0):.0f} samples a cycle "
            "(anti-aliased; identification.json 'decimation')"
        )
        if part:
            text += (
                f"; its run-level fit uses its first {part.get('cycles')} of "
                f"{part.get('of_cycles'):g} cycles, its parameter trajectory all of them"
            )
        out.append(note("long-record", text, run=r.label))
    return out


def gap_notes(runs: Sequence[Run]) -> list[str]:
    """One note per run whose samples have gaps (time steps > 1.5× the median: samples the
    device did not deliver, recorded as gaps, never filled in).

    The laws integrate position segment by segment, so a gap is bridged by a straight
    segment: exact for a hysteresis law while the motion does not reverse inside the gap,
    and the velocity/acceleration effects see one longer step there.  A gap longer than
    2 % of the motion's period may hide a reversal: the note says so.
    """
    out = []
    for r in runs:
        t = np.asarray(r.time, float)
        if t.size < 3:
            continue
        dt = np.diff(t)
        med = float(np.median(dt))
        big = np.flatnonzero(dt > 1.5 * med)
        if not big.size:
            continue
        missing = int(np.sum(np.round(dt[big] / med) - 1))
        longest = float(dt[big].max())
        period = 1.0 / r.frequency if r.frequency else None
        risky = period is not None and longest > 0.02 * period
        out.append(
            f"{r.label}: {big.size} gap(s) in the samples ({missing} missing, longest "
            f"{1e3 * longest:.1f} ms at t={t[big[np.argmax(dt[big])]] - t[0]:.3f} s), "
            "bridged by a straight position segment (the law integrates position)"
            + (
                "; the longest exceeds 2 % of the motion's period and may hide a "
                "reversal: check the fit there, or split the run"
                if risky
                else ""
            )
        )
    return out


def identify(
    runs: Sequence[Run] | Run,
    model: str | ForceModel = "bouc-wen",
    *,
    effects: Sequence[str] = (),
    effects_files: Sequence[str] = (),
    validate: Sequence[Run] | None = None,
    jobs: int | None = None,
    scheduler: str | None = None,
    fixed: Mapping[str, float | None] | None = None,
    free: Sequence[str] = (),
    initial: str = "estimate",
    progress: bool = False,
    pressure_model: str = "joint",
    whole_run: bool = False,
    output: str = "force",
    structure: str = "auto",
) -> Identification:
    """Identify ``model`` on ``runs`` and validate on held-out runs.

    Runs whose ``role`` attr is ``"validation"`` are held out automatically (and added to
    ``validate``); nothing else is dropped.

    Parameters
    ----------
    runs
        The identification runs (canonical units, as :func:`load` gives them).
    model
        A law id (``"bouc-wen"``, ``"duhem"``, ``"prandtl-ishlinskii"``,
        ``"maxwell-slip"``) or a composed :class:`~pmalab.identify.model.ForceModel`.
    effects
        Effect ids to add (``--add``), e.g. ``["viscous-friction"]``.
    effects_files
        Python files defining user effects.
    validate
        Held-out runs the pressure-law model predicts free-running.
    jobs, scheduler
        Worker processes (default: ``$PMALAB_JOBS`` when set, else 2, as the command
        line), or a Dask scheduler address (``tcp://host:port``).
    fixed, free
        Parameters held at a value, and parameters the law fixes by default set free.
    initial
        How a validation run's record parameters (start state, force zero) are set:
        ``"estimate"`` (fitted on the run's first whole excitation cycles, about a third
        of it, its error scored on the rest), ``"burn-in"`` (one period replayed before
        the run) or ``"zero"``
        (:func:`~pmalab.identify.estimation.records.predict_record`).
    progress
        Draw a progress bar on stderr.
    pressure_model
        ``"joint"`` (default: the pressure laws refined on all runs at once,
        :mod:`pmalab.identify.estimation.joint`) or ``"per-run"`` (the seeds' quadratics
        through the per-run values).
    whole_run
        Use every sample instead of each recorded run's full-amplitude cycles
        (:meth:`~pmalab.runfile.Run.steady`).
    output
        ``"force"`` (the model driven by the measured position predicts the force) or
        ``"position"`` (output error: the model driven by the measured force is integrated
        forward and its simulated position fitted,
        :mod:`pmalab.identify.estimation.output_error`).
    structure
        The pressure structure of an element law's elements: ``"auto"`` (chosen by
        leave-one-pressure-out evidence, :mod:`pmalab.identify.campaign.structure`),
        ``"free"``, ``"scaled"`` or ``"scaled-thresholds"``.

    Returns
    -------
    Identification
        Per-run parameters with standard errors (N, mm, MPa units of each law), the
        pressure laws, and the validation metrics (``nrmse``: RMS error over the standard
        deviation of the measured force); ``save(dir)`` writes what ``pmalab identify``
        writes.
    """
    if output not in ("force", "position"):
        raise PmalabError(f"output must be 'force' or 'position', not {output!r}")
    jobs = default_jobs(DEFAULT_JOBS) if jobs is None else jobs
    runs_l = [runs] if isinstance(runs, Run) else list(runs)
    if not whole_run:
        runs_l = [r.steady() for r in runs_l]
        validate = None if validate is None else [r.steady() for r in validate]
    # a long record's run-level fit uses its first cycles, its trajectory all of it; held-out
    # long records are validated on the same part as `pmalab diagnose` holds out
    records = list(runs_l)
    runs_l = [fit_part(r) for r in records]
    record_of = {id(p): r for p, r in zip(runs_l, records)}
    validate = None if validate is None else [fit_part(r) for r in validate]
    ident, held = split_roles(runs_l)
    notes: list[str] = [
        note(
            "held-out",
            f"{r.label}: role 'validation' in the run file, held out for validation",
            run=r.label,
        )
        for r in held
    ]
    notes += gap_notes([*runs_l, *(validate or [])])
    notes += long_record_notes([*runs_l, *(validate or [])])
    if not ident:
        raise PmalabError(
            "no identification runs: every run read from the files has role 'validation'"
        )
    if isinstance(model, ForceModel):
        spec = None
        fm: ForceModel | ModelSpec = model
        if effects or effects_files:
            raise PmalabError("pass effects inside the ForceModel or as ids, not both")
    else:
        spec = ModelSpec(model, tuple(effects), tuple(str(f) for f in effects_files))
        built = spec.build()  # fail early (unknown model/effect) before any work
        if output == "position":
            from pmalab.identify.forward import plant_slots

            plant_slots(built)  # an effect without a forward form, refused by name
        fm = spec
    cf, vals, warns = fit_and_validate(
        ident,
        fm,
        [*held, *(validate or [])],
        initial=initial,
        fixed=fixed,
        free=free,
        jobs=jobs,
        scheduler=scheduler,
        progress=progress,
        pressure_model=pressure_model,
        output=output,
        structure=structure,
    )
    trajectory = []
    if output == "force":
        for run, rf in zip(ident, cf.runs):
            tr = run_trajectory(record_of.get(id(run), run), cf.model, rf.result)
            if tr is not None:
                trajectory.append(tr)
    return Identification(
        campaign=cf,
        runs=ident,
        spec=spec,
        initial=initial,
        notes=notes,
        validation=vals,
        validation_warnings=warns,
        trajectory=trajectory,
    )


class DiagnosisResult:
    """:func:`diagnose` for notebooks: the ranking and the ladder as DataFrames.

    ``ranking``: one row per effect, best first (index ``effect``; held-out ``nrmse_before``,
    ``nrmse_after``, ``fall_percent``, ``gain_x_floor``, ``n_params``, ``significant``,
    ``ambiguous``); ``ladder``: one row per step (index ``step``; ``model``, ``added``,
    ``nrmse``, ``fit_percent``); ``worst``: the runs where the base model fails worst
    (:func:`pmalab.identify.headline.worst_runs`).  ``summary`` is the sentence the CLI
    prints, ``ranking_table()``/``ladder_table()`` its text tables, ``plot()`` the
    ranking/ladder figure, ``save(dir)`` writes diagnosis.json and predictions.h5 (the
    same files as ``pmalab diagnose``).  Anything else is read from the underlying
    :class:`pmalab.identify.diagnosis.Diagnosis` (``raw``).
    """

    def __init__(self, raw):
        self.raw = raw

    @property
    def ranking(self):
        """The candidate effects, best first.

        Returns
        -------
        pandas.DataFrame
            Index ``effect``; ``nrmse_before`` and ``nrmse_after`` (mean held-out nrmse
            without and with the effect, dimensionless: RMS error / SD of the measured
            force), ``fall_percent`` (positive = the error falls), ``gain_x_floor``,
            ``n_params``, ``significant`` (the tool would tell you to add it) and
            ``ambiguous``.
        """
        import pandas as pd

        rows = [
            _scalars(r) | {"ambiguous": r["effect"] in self.raw.ambiguous} for r in self.raw.ranking
        ]
        first = ["effect", "nrmse_before", "nrmse_after", "fall_percent", "significant"]
        df = pd.DataFrame(rows)
        if df.empty:
            return pd.DataFrame(columns=pd.Index(first)).set_index("effect")
        order = [c for c in first if c in df] + [c for c in df if c not in first]
        return df[order].set_index("effect")

    @property
    def ladder(self):
        """The ladder: the error as the significant effects are added one at a time.

        Returns
        -------
        pandas.DataFrame
            Index ``step`` (0 = the base model); ``model`` (law and effects in force),
            ``added`` (the effect or law added at that step), ``nrmse`` (mean held-out
            nrmse) and ``fit_percent`` (100·(1 − nrmse)).
        """
        import pandas as pd

        rows = [
            {
                "step": s["step"],
                "model": "+".join([self.raw.model, *s.get("effects", [])]),
                "added": s.get("added"),
                "nrmse": s["nrmse"],
                "fit_percent": s.get("fit_percent"),
            }
            | {k: v for k, v in _scalars(s).items() if k not in ("model", "step")}
            for s in self.raw.ladder
        ]
        return pd.DataFrame(rows).set_index("step")

    @property
    def worst(self):
        """The runs where the base model fails worst.

        Returns
        -------
        pandas.DataFrame
            Index ``run``, worst first; ``rmse_N`` (the base model's RMS force error, N),
            ``nrmse`` and ``worst_region`` (where in the loop the error is largest).
        """
        import pandas as pd

        from pmalab.identify.headline import worst_runs

        d = self.raw.diagnostics
        return pd.DataFrame(
            [
                {
                    "run": k,
                    "rmse_N": d[k].get("rmse"),
                    "nrmse": d[k].get("nrmse"),
                    "worst_region": d[k].get("worst_region"),
                }
                for k in worst_runs(d)
            ]
        ).set_index("run")

    @property
    def summary(self) -> str:
        """The verdict sentence ``pmalab diagnose`` prints (base error against the noise
        floor, the ladder, where the rest of the residual lies)."""
        return self.raw.summary

    def ranking_table(self) -> str:
        return self.raw.ranking_table()

    def ladder_table(self) -> str:
        return self.raw.ladder_table()

    def plot(self, path: str | Path | None = None):
        """Draw the ranking (held-out nrmse without and with each effect) and the ladder.

        Parameters
        ----------
        path
            Also save the figure there (PNG, PDF or SVG by the suffix); ``None``: only
            return it.

        Returns
        -------
        matplotlib.figure.Figure
            The figure: the ranking's bars on the left, the ladder on the right.
        """
        return self.raw.plot(path)

    def save(self, out_dir: str | Path, force: bool = False) -> tuple[Path, Path]:
        """Write ``diagnosis.json`` and ``predictions.h5``, as ``pmalab diagnose`` does.

        Parameters
        ----------
        out_dir
            The directory to write (made when missing).
        force
            Overwrite existing outputs; without it an existing file is refused and nothing
            is written.

        Returns
        -------
        tuple of (Path, Path)
            The paths of ``diagnosis.json`` and ``predictions.h5``.

        Raises
        ------
        pmalab.errors.OutputExistsError
            An output exists and ``force`` is false.
        """
        from pmalab.identify.diagnosis import write_outputs

        return write_outputs(self.raw, out_dir, force=force)

    def __getattr__(self, name: str):
        if name == "raw":
            raise AttributeError(name)
        return getattr(self.raw, name)

    def __repr__(self) -> str:
        return (
            f"{self.summary}\n\nEffect ranking (held-out nrmse without → with each "
            f"effect):\n{self.ranking_table()}\n\nLadder:\n{self.ladder_table()}"
        )


def _scalars(row: dict) -> dict:
    """The plain (str/number/bool/None) entries of a JSON row: the DataFrame columns."""
    return {k: v for k, v in row.items() if v is None or isinstance(v, str | int | float | bool)}


def diagnose(runs: Sequence[Run] | Run, model: str = "bouc-wen", **kwargs) -> DiagnosisResult:
    """Diagnose ``model`` on ``runs``: what ``pmalab diagnose`` computes, as a notebook view.

    Parameters
    ----------
    runs
        The campaign (runs tagged ``role = "validation"`` are held out; without any, some
        runs are held out as ``pmalab diagnose`` does).
    model
        The base law id.
    **kwargs
        The options of :func:`pmalab.identify.diagnosis.diagnose`: ``validate``,
        ``effects``, ``effects_files``, ``max_steps``, ``jobs``, ``progress``,
        ``whole_run``, ``laws``, ``scheduler``.

    Returns
    -------
    DiagnosisResult
        The ranking of candidate effects (held-out nrmse without and with each), the ladder
        of the error falling, the worst runs and the summary sentence.
    """
    from pmalab.identify.diagnosis import diagnose as _diagnose

    runs_l = [runs] if isinstance(runs, Run) else list(runs)
    return DiagnosisResult(_diagnose(runs_l, model=model, **kwargs))
