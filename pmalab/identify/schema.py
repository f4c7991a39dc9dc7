"""The result files' structure — declared once, read by one reader each.

``identification.json`` (:class:`IdentificationDoc`, written by
:func:`pmalab.identify.outputs.identification_dict`), ``diagnosis.json``
(:class:`DiagnosisDoc`, :meth:`pmalab.identify.diagnosis.diagnose.Diagnosis.to_json`),
``predictions.h5`` (:class:`PredictionsDoc`,
:func:`pmalab.identify.predictions.write_predictions_file`) and a control run's ``summary`` (:class:`ControlSummary`,
:func:`pmalab.control.record.run_summary`).  docs/reference/json.md describes the keys.

The TypedDicts are the single source: :func:`check` derives every test from their
annotations (``typing.get_type_hints``), so a reader checks exactly what is declared here.
A key without ``NotRequired`` must be present with the declared JSON type; a
``NotRequired`` key may be absent (older files, other writers) but has the declared type
when present; ``X | None`` admits ``null`` (NaN/inf are written as ``null``).  Keys not
declared are allowed (forward compatibility) and not checked.

A malformed file raises one line naming the file and the key path, e.g.
``out/identification.json: validation[1].nrmse: expected a number, got "x"``.

Units: force N, position mm (contraction positive) unless a key says ``_m``, pressure MPa,
frequency Hz, time s; ``nrmse`` is the RMS error over the measured force's standard
deviation (dimensionless) and ``fit_percent`` is ``100 (1 - nrmse)``.
"""

# no ``from __future__ import annotations``: the TypedDicts' NotRequired markers must be
# evaluated when the classes are made (Python 3.11 loses them from string annotations)

import functools
import json
import types
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import (
    Any,
    Literal,
    NotRequired,
    TypedDict,
    Union,
    cast,
    get_args,
    get_origin,
    get_type_hints,
    is_typeddict,
)

import numpy as np

from pmalab.config import load_json
from pmalab.errors import PmalabError
from pmalab.identify.predictions import PREDICTIONS_FORMAT
from pmalab.runfile import decode_attr

IDENTIFICATION_JSON = "identification.json"
DIAGNOSIS_JSON = "diagnosis.json"
PREDICTIONS_H5 = "predictions.h5"


class ResultFileError(PmalabError):
    """An identification/diagnosis/predictions file (or a control run's summary) is
    missing or malformed; the message names the file and the key at fault."""


# =========================================================================== identification
class MessageDoc(TypedDict):
    """One typed message (:class:`pmalab.identify.messages.Message`)."""

    #: ``note`` | ``detail`` | ``warning``
    kind: str
    #: stable identifier for programs
    code: str
    text: str
    #: the numbers and names the text mentions
    data: dict[str, Any]


class BranchRmse(TypedDict):
    """RMS force error (N) on each branch of the loop; null where a branch is empty."""

    stretch: float | None
    release: float | None


class Correlation(TypedDict):
    """The parameter estimates' correlation matrix (rows and columns in ``names`` order)."""

    names: list[str]
    matrix: list[list[float | None]]


class QuadraticModelFit(TypedDict):
    """The pressure-law model's fit on one identification run."""

    fit_percent: NotRequired[float | None]
    nrmse: NotRequired[float | None]
    #: N
    rmse: NotRequired[float | None]


class RowMetrics(TypedDict):
    """What identification runs and validation rows share: the run and its fit metrics."""

    #: the run file (null for a run that was never in a file)
    file: str | None
    run: str
    #: nominal muscle pressure, MPa
    muscle_pressure_MPa: float
    #: the run's drive frequency, Hz
    frequency_Hz: NotRequired[float | None]
    waveform: NotRequired[str]
    #: RMS force error over the measured force's standard deviation
    nrmse: float
    #: RMS force error, N
    rmse: NotRequired[float | None]
    fit_percent: NotRequired[float | None]
    #: largest |force error|, N
    max_error: NotRequired[float | None]
    #: loop-energy error, % of the measured loop's energy
    energy_error_percent: NotRequired[float | None]
    #: loop energy per cycle, mJ
    energy_measured_mJ_per_cycle: NotRequired[float | None]
    energy_model_mJ_per_cycle: NotRequired[float | None]
    branch_rmse: NotRequired[BranchRmse]
    #: output error (``identify --output position``): the simulated position's RMS error
    #: in m and mm, its nrmse and fit %
    rmse_position_m: NotRequired[float | None]
    rmse_position_mm: NotRequired[float | None]
    nrmse_position: NotRequired[float | None]
    fit_percent_position: NotRequired[float | None]


class IdentificationRun(RowMetrics):
    """One identification run (``runs[i]``): its own fit."""

    role: NotRequired[str]
    #: parameter name → value (units in the document's ``parameter_units``)
    parameters: dict[str, float]
    #: parameter name → standard error (null where not estimable, e.g. a fixed parameter)
    stderr: NotRequired[dict[str, float | None]]
    correlation: NotRequired[Correlation]
    fixed: NotRequired[list[str]]
    warnings: NotRequired[list[str]]
    notes: NotRequired[list[str]]
    messages: NotRequired[list[MessageDoc]]
    n_samples: NotRequired[int]
    #: effective number of independent samples (autocorrelated residual)
    n_eff: NotRequired[float | None]
    n_free: NotRequired[int]
    aic: NotRequired[float | None]
    bic: NotRequired[float | None]
    condition_number: NotRequired[float | None]
    quadratic_model: NotRequired[QuadraticModelFit]


class ValidationRow(RowMetrics):
    """One held-out run (``validation[i]``) predicted by the pressure-law model."""

    role: NotRequired[str]
    #: ``ok`` | ``extrapolated`` | ``diverged``
    status: NotRequired[str]
    message: NotRequired[str | None]
    #: its pressure lies outside the identified range
    extrapolated: NotRequired[bool]
    #: the metrics score the run from this time on (s from its first sample): its record
    #: parameters were estimated on the part before
    scored_from_s: NotRequired[float | None]
    #: the noise floor (nrmse) of the scored part
    noise_floor_nrmse: NotRequired[float | None]


class InputFile(TypedDict):
    """One input run file (``inputs[i]``)."""

    file: str
    runs: NotRequired[list[str]]
    #: run name → ``identification`` | ``validation``
    roles: NotRequired[dict[str, str]]
    #: sha256, size_bytes, file_attrs, runs (each run's attrs)
    provenance: NotRequired[dict[str, Any]]


class PressureFitStats(TypedDict):
    """How a parameter's pressure law θ(p) = q0 + q1 p + q2 p² (p in MPa) fits."""

    r2: NotRequired[float | None]
    degree: NotRequired[int]
    residuals: NotRequired[list[float | None]]
    #: MPa
    pressures: NotRequired[list[float | None]]
    values: NotRequired[list[float | None]]
    stderr: NotRequired[list[float | None]]
    method: NotRequired[str]
    per_run_quadratic: NotRequired[list[float | None]]
    per_run_r2: NotRequired[float | None]


class JointFit(TypedDict):
    """The joint refinement of the pressure laws on all identification runs at once."""

    #: run labels, the order of every per-run list
    runs: NotRequired[list[str]]
    nrmse: list[float | None]
    mean_nrmse: float | None
    nrmse_per_run_quadratics: NotRequired[list[float | None]]
    mean_nrmse_per_run_quadratics: NotRequired[float | None]
    nrmse_start: NotRequired[list[float | None]]
    mean_nrmse_start: NotRequired[float | None]
    #: parameter → polynomial order in pressure (0-2)
    orders: dict[str, int]
    constants: NotRequired[dict[str, Any]]
    #: the start hysteresis state per run, N
    h0: list[float | None]
    #: nuisance name → one value per run
    per_run: NotRequired[dict[str, list[float | None]]]
    legendre: NotRequired[dict[str, Any]]
    legendre_stderr: NotRequired[dict[str, Any]]
    n_eff: NotRequired[float | None]
    bic: NotRequired[float | None]
    nfev: NotRequired[int]
    success: NotRequired[bool]
    message: NotRequired[str]
    note: NotRequired[str]


class InitialState(TypedDict):
    """The estimated start state of each run of an output-error fit (one value per run)."""

    #: mm
    x0_mm: list[float | None]
    #: mm/s
    v0_mm_per_s: list[float | None]
    #: N
    h0_N: list[float | None]


class OutputErrorFit(TypedDict):
    """The output-error fit (``identify --output position``): the free-run simulated
    position's errors per run (m)."""

    runs: list[str]
    #: m
    rmse_position_m: list[float | None]
    nrmse_position: list[float | None]
    #: m, at the start of the fit
    rmse_position_m_start: NotRequired[list[float | None]]
    initial_state: NotRequired[InitialState]
    substeps_per_sample: NotRequired[list[int]]
    orders: NotRequired[dict[str, int]]
    stderr_at_mean_pressure: NotRequired[dict[str, Any]]
    nfev: NotRequired[int]
    success: NotRequired[bool]
    message: NotRequired[str]
    note: NotRequired[str]


class StructureCandidate(TypedDict):
    """One candidate pressure structure and its held-out evidence."""

    #: ``free`` | ``scaled`` | ``scaled-thresholds``
    structure: str
    #: RMS leave-one-pressure-out nrmse over the left-out runs (None: failed)
    heldout_nrmse: float | None
    #: pressure-law coefficients of the muscle (k, c0 and the law's; no h0)
    n_params: int | None
    heldout_nrmse_per_run: list[float]
    #: where the kept joint fit started: ``free laws`` | ``per-run fits`` (a structured
    #: candidate is refined from both, the lower training cost kept)
    start: NotRequired[str]
    status: NotRequired[str]
    reason: NotRequired[str]


class StructurePrior(TypedDict):
    """The prior an element law's structure was fitted with (smoothness over a threshold
    grid, or shrinkage of the element corrections), its strength chosen by
    leave-one-pressure-out evidence."""

    #: what is penalised, in words
    prior: str
    criterion: str
    #: strengths λ tried (dimensionless: the penalty's share of the data cost per unit mean
    #: square of the penalised quantity) and the RMS held-out nrmse of each
    strengths: list[float]
    heldout_nrmse: list[float]
    #: the strength kept (0: no prior)
    chosen_strength: float
    note: NotRequired[str]


class StructureElements(TypedDict):
    """How many of a free-element structure's elements the muscle needs (Maxwell-slip),
    chosen by leave-one-pressure-out evidence; tried only when some element carries little
    of the friction."""

    criterion: str
    #: element counts tried and the RMS held-out nrmse of each
    counts: list[int]
    heldout_nrmse: list[float]
    chosen: int
    #: elements removed (1-based) for the chosen count
    removed: list[int]


class PressureStructure(TypedDict):
    """``identification.json`` ``pressure_structure``: how an element law's elements change
    with pressure, chosen by held-out evidence across pressure."""

    law: str
    chosen: str
    #: ``leave-one-pressure-out (...)`` or ``user``
    criterion: str
    #: how much higher (%) the best other candidate's held-out nrmse is than the winner's
    #: (negative: the winner was kept as the simpler one within 1 % of a better score)
    margin_percent: float | None
    #: the interior pressure levels left out in turn, MPa
    levels_left_out_MPa: list[float]
    candidates: list[StructureCandidate]
    #: structure → the prior its fit was given (when one was tried)
    priors: NotRequired[dict[str, StructurePrior]]
    #: structure → how many of its elements the muscle needs (free-element laws)
    element_counts: NotRequired[dict[str, StructureElements]]


class IdentificationDoc(TypedDict):
    """``identification.json``: the model, the per-run fits, the pressure laws and the
    validation on held-out runs."""

    #: the hysteresis law (``bouc-wen``, ``duhem``...)
    model: str
    #: the law with its effects (``bouc-wen+viscous-friction``)
    model_full: NotRequired[str]
    effects: NotRequired[list[str]]
    pmalab_version: NotRequired[str]
    #: ISO 8601, UTC
    created: NotRequired[str]
    inputs: NotRequired[list[InputFile]]
    parameter_names: list[str]
    #: parameter → unit (N, N/mm, mm, ...)
    parameter_units: NotRequired[dict[str, str | None]]
    parameter_docs: NotRequired[dict[str, str | None]]
    state_parameters: NotRequired[list[str]]
    runs: list[IdentificationRun]
    #: ``joint`` | ``per-run``
    pressure_model: NotRequired[str]
    #: parameter → [q0, q1, q2] of θ(p) = q0 + q1 p + q2 p² (p in MPa)
    pressure_fits: NotRequired[dict[str, list[float | None]]]
    pressure_fits_per_run: NotRequired[dict[str, list[float | None]]]
    pressure_fit_stats: NotRequired[dict[str, PressureFitStats]]
    #: [lo, hi], MPa
    pressure_range_MPa: NotRequired[list[float | None]]
    joint_fit: NotRequired[JointFit | None]
    #: which pressure structure an element law's elements took (None: the law has none)
    pressure_structure: NotRequired[PressureStructure | None]
    #: ``force`` | ``position``
    output: NotRequired[str]
    output_error: NotRequired[OutputErrorFit | None]
    #: parameter → [lo, hi]
    parameter_bounds: NotRequired[dict[str, list[float | None]]]
    validation: NotRequired[list[ValidationRow]]
    warnings: NotRequired[list[str]]
    notes: NotRequired[list[str]]
    messages: NotRequired[list[MessageDoc]]
    #: how the fit was made (text per step)
    method: NotRequired[dict[str, Any]]
    #: per run: the samples each stage used (``read``: a long record's anti-aliased
    #: decimation, or whole; ``joint_fit``: the joint fit's stride, ≥ 100 samples a cycle)
    decimation: NotRequired[list[dict[str, Any]]]
    #: long records: the model refitted on windows along each run (parameters vs cycle)
    trajectory: NotRequired[list[dict[str, Any]]]
    #: per run: nominal vs measured mean pressure (``nominal_MPa``, ``measured_mean_MPa``,
    #: ``offset_kPa``, ``tolerance_kPa``, ``label_offset``; ``label_MPa`` with --pressure measured)
    pressure_labels: NotRequired[list[dict[str, Any]]]


# =========================================================================== diagnosis
class RankingEntry(TypedDict):
    """One candidate effect scored by the held-out nrmse (``ranking[i]``, best first)."""

    effect: str
    #: mean held-out nrmse of the model it is added to, over the runs that are evidence
    #: (``left_out``: the rest); null when none is
    nrmse_before: float | None
    #: null when the identification with the effect raised (``status`` "failed")
    nrmse_after: float | None
    #: the ladder added it (significant at its step)
    significant: bool
    #: "ok", or "failed" (the identification with it diverged, did not converge or raised,
    #: or the check that its fall is its own raised: ``reason`` says why, and the entry
    #: carries no fall)
    status: NotRequired[str]
    reason: NotRequired[str]
    fall_percent: NotRequired[float | None]
    fall_se_percent: NotRequired[float | None]
    n_params: NotRequired[int | None]
    runs_improved: NotRequired[float | None]
    #: the fall in nrmse in units of the noise floor
    gain_x_floor: NotRequired[float | None]
    #: the part of that fall the effect's own force carries (per run the smaller of the
    #: fall and the rise when the effect's force is removed from the identified model),
    #: noise floors; null when not measured (the effect declares no ``absent`` values)
    gain_carried_x_floor: NotRequired[float | None]
    #: per held-out run: nrmse of the identified model with the effect's force removed
    per_run_without_effect: NotRequired[list[float] | None]
    block_t: NotRequired[float | None]
    per_run_before: NotRequired[list[float | None]]
    per_run_after: NotRequired[list[float | None] | None]
    diverged: NotRequired[list[Any]]
    #: held-out runs left out of the evidence: the model scored against diverged there
    #: (present only when there are such runs)
    left_out: NotRequired[list[str]]
    title: NotRequired[str]
    explanation: NotRequired[str]
    signature: NotRequired[str]
    #: round 1's verdict: significant against the base model alone
    significant_alone: NotRequired[bool]
    #: the ladder step that added the effect (null: not added)
    ladder_step: NotRequired[int | None]
    #: the round every number of this row comes from: the ladder step that added the
    #: effect, else 1 (against the base model); ``rounds[round - 1]`` holds its full row
    round: NotRequired[int]
    #: the model it was scored against: "base", or the effects (and changed law) of the
    #: step before ``ladder_step``
    scored_against: NotRequired[str]


class LadderEntry(TypedDict):
    """One step of the ladder (``ladder[i]``; step 0 is the base model)."""

    step: int
    #: held-out nrmse of the step's model
    nrmse: float
    fit_percent: NotRequired[float | None]
    effects: NotRequired[list[str]]
    #: the effect this step added (null at step 0 or for a law switch)
    added: NotRequired[str | None]
    law: NotRequired[str | None]
    switched_law: NotRequired[str | None]
    per_run: NotRequired[list[float | None]]
    model: NotRequired[str]
    #: held-out runs on which the step's prediction diverged or ran off to nrmse ≥ 10
    #: (present only when there are such runs; they are no evidence for the next step's
    #: candidates)
    diverged: NotRequired[list[str]]


class LawEntry(TypedDict):
    """Another hysteresis law scored like an effect (``laws[i]``, best first): against the
    base model, or, for a law the ladder switched to, against the model of the step before."""

    law: str
    #: as ``RankingEntry.nrmse_before``
    nrmse_before: float | None
    #: null when the law's identification raised
    nrmse_after: float | None
    #: null when the law's fit failed (``status`` "failed", ``reason``)
    fall_percent: float | None
    #: the ladder switched to this law and it is the final model's (as
    #: ``RankingEntry.significant``: only a law the ladder took, and no later step replaced,
    #: is claimed)
    significant: bool
    #: round 1's verdict: the law against the base model alone
    significant_alone: NotRequired[bool]
    #: the verdict against the final model, where the ladder scored the law against it;
    #: null when it stopped first (step limit, noise floor); absent when the ladder took no
    #: step or took this law
    significant_last: NotRequired[bool | None]
    #: the step that switched to this law (null if none; set also when a later step
    #: replaced it)
    ladder_step: NotRequired[int | None]
    #: the round the row's numbers come from (``rounds[round - 1].laws``;
    #: ``settings.ladder_rounds`` after active identification)
    round: NotRequired[int]
    #: the model the law was scored against (``"base"`` or the effects of that step)
    scored_against: NotRequired[str]
    status: NotRequired[str]
    reason: NotRequired[str]
    gain_x_floor: NotRequired[float | None]
    block_t: NotRequired[float | None]
    runs_improved: NotRequired[float | None]
    #: per held-out run: the nrmse of the model the law was scored against
    #: (``scored_against``: the base model unless the ladder switched to the law)
    per_run_before: NotRequired[list[float]]
    per_run_after: NotRequired[list[float | None] | None]
    #: held-out runs at their noise floor with the base model and with the law
    runs_at_floor: NotRequired[int]
    #: held-out runs left out of the evidence (see ``RankingEntry.left_out``)
    left_out: NotRequired[list[str]]
    #: the pressure structure the law's elements took (``free`` | ``scaled`` |
    #: ``scaled-thresholds``), chosen by leave-one-pressure-out held-out error; absent for
    #: a law without structures
    structure: NotRequired[str | None]
    #: how much higher (%) the runner-up structure's held-out error was
    structure_margin_percent: NotRequired[float | None]
    #: structure → its leave-one-pressure-out held-out nrmse
    structure_heldout_nrmse: NotRequired[dict[str, float | None]]


class NoiseFloor(TypedDict):
    """The measurement-noise floor (nrmse) of the held-out runs."""

    mean_nrmse: float | None
    #: run label → nrmse floor
    per_run: dict[str, float | None]
    method: NotRequired[str]


class Residual(TypedDict):
    """Where the final model's residual beyond the noise lies (shares of its power: loop,
    above_band, offset, other...) and what to look at next."""

    next: NotRequired[str | None]
    text: NotRequired[str]


class Binned(TypedDict):
    """The residual (N) binned by one variable."""

    centers: list[Any]
    mean: list[float | None]
    ci95: NotRequired[list[float | None]]
    unit: NotRequired[str]


class Correlogram(TypedDict):
    """An auto- or cross-correlation of the residual."""

    #: s
    lags_s: list[float]
    values: list[float | None]
    bound95: NotRequired[float | None]


class Region(TypedDict):
    """The residual on one branch and position third of the loop (N)."""

    branch: str
    position: str
    rms: float | None
    mean: NotRequired[float | None]


class LoopPhase(TypedDict):
    """The residual (N) against the loop's phase (degrees)."""

    centers_deg: list[float]
    mean: NotRequired[list[float | None]]
    rms: NotRequired[list[float | None]]


class RunDiagnostics(TypedDict):
    """The residual diagnostics of one held-out run (``diagnostics[label]``)."""

    binned: NotRequired[dict[str, Binned]]
    acf: NotRequired[Correlogram]
    ccf_input: NotRequired[Correlogram]
    worst_region: NotRequired[str]
    #: N
    rmse: NotRequired[float | None]
    nrmse: NotRequired[float | None]
    nrmse_final: NotRequired[float | None]
    noise_floor_nrmse: NotRequired[float | None]
    regions: NotRequired[list[Region]]
    loop_phase: NotRequired[LoopPhase]
    residual_shares: NotRequired[dict[str, Any]]


class CampaignBin(TypedDict):
    """The residual (N) across the campaign, binned by pressure level or frequency."""

    centers: list[float]
    rms: NotRequired[list[float | None]]
    mean: NotRequired[list[float | None]]
    ci95_rms: NotRequired[list[float | None]]
    unit: NotRequired[str]


class RoundEntry(TypedDict):
    """One ranking round of the ladder (candidates as in ``ranking``, loosely typed)."""

    step: int
    ambiguous: NotRequired[list[str]]
    candidates: NotRequired[list[dict[str, Any]]]
    #: the other laws scored in this round, against the same model (as ``laws`` rows,
    #: without the ladder's keys)
    laws: NotRequired[list[dict[str, Any]]]


class ActiveRoundEntry(TypedDict):
    """One round of active identification (``diagnose --run-suggested``): the experiment
    designed and run on the rig, the separation it was expected to show, the verdict after."""

    round: int
    experiment: dict[str, Any]
    expected_separation: dict[str, Any]
    #: the protocol file's text (TOML) that was run
    protocol: str
    #: the round's own run file
    file: str
    recorded_runs: list[str]
    #: s of rig time the round took
    rig_time_s: float
    verdict: NotRequired[dict[str, Any]]


class DiagnosisDoc(TypedDict):
    """``diagnosis.json``: the effect ranking, the ladder, the noise floor and the
    residual diagnostics of the held-out runs."""

    model: str
    ranking: list[RankingEntry]
    ambiguous: NotRequired[list[str]]
    suggested_experiment: NotRequired[str]
    ladder: NotRequired[list[LadderEntry]]
    #: held-out run label → its diagnostics
    diagnostics: NotRequired[dict[str, RunDiagnostics]]
    #: ``pressure_level`` / ``frequency`` → binned residual
    campaign_diagnostics: NotRequired[dict[str, CampaignBin]]
    #: the ladder's ranking rounds; after ``diagnose --run-suggested`` the active rounds
    #: (the ladder's then move to ``settings.ladder_rounds``)
    rounds: NotRequired[list[RoundEntry | ActiveRoundEntry]]
    final_model: NotRequired[str]
    final_law: NotRequired[str]
    laws: NotRequired[list[LawEntry]]
    #: the laws that predict the held-out runs about equally well as the best law, best
    #: first, among the laws of one round (empty: one stands out, or fewer than two cut
    #: the error of the model they were scored against)
    laws_alike: NotRequired[list[str]]
    residual: NotRequired[Residual]
    settings: NotRequired[dict[str, Any]]
    summary: NotRequired[str]
    noise_floor: NotRequired[NoiseFloor]
    #: ``floor`` | ``unexplained``
    verdict: NotRequired[str]


# =========================================================================== control
class ControlMetrics(TypedDict):
    """A control run's tracking metrics (:mod:`pmalab.control.metrics`), in the loop's
    unit (mm for position, MPa for pressure)."""

    #: the reference's kind (sine, square, ...)
    kind: str
    rms_error: float | None
    max_error: float | None
    unit: NotRequired[str]
    completed: NotRequired[bool]
    steps: NotRequired[list[dict[str, Any]]]


class ControlSummary(TypedDict):
    """A control run's end-of-run facts (its ``summary`` dataset, JSON)."""

    metrics: ControlMetrics
    vent: NotRequired[Any]
    vent_confirmed: NotRequired[bool | None]
    #: s
    wall_time_s: float | None
    #: the run's mean muscle pressure, MPa
    muscle_pressure_MPa: float
    n_samples: int


class LawRow(TypedDict):
    """One law of ``identify --model a,b,c`` (``laws.json``), nrmse of force."""

    law: str
    #: mean held-out nrmse (None without held-out runs)
    validation_nrmse: float | None
    validation_per_run: list[float]
    identification_nrmse: float
    parameters_per_run: int
    directory: str
    #: validation nrmse / the held-out runs' noise floor
    x_floor: float | None
    #: the pressure structure the law's elements took (None: the law offers none)
    pressure_structure: NotRequired[str | None]


class LawsDoc(TypedDict):
    """``laws.json``: the laws ranked, best first."""

    noise_floor_nrmse: float | None
    laws: list[LawRow]


class ExperimentResult(TypedDict):
    """One (experiment, controller) run of ``pmalab control --experiments``."""

    experiment: str
    reference: str
    controller: str
    status: str
    metrics: ControlMetrics
    seeds: NotRequired[Any]


class ControlMetricsDoc(TypedDict):
    """``metrics.json`` of ``pmalab control --experiments``."""

    experiments: str
    file: str | None
    controllers: list[str]
    results: list[ExperimentResult]


# =========================================================================== the checker
_Fail = Callable[[str, str], PmalabError]


def _show(v: Any) -> str:
    """A value as a message shows it (JSON spelling, short)."""
    if isinstance(v, dict):
        return "an object"
    if isinstance(v, list):
        return "a list"
    try:
        s = json.dumps(v)
    except (TypeError, ValueError):
        s = repr(v)
    return s if len(s) <= 40 else s[:37] + "..."


def _is_union(tp: Any) -> bool:
    return get_origin(tp) in (Union, types.UnionType)


def _describe(tp: Any) -> str:
    """``a number``, ``a list``, ``an object or null`` ..."""
    if _is_union(tp):
        return " or ".join(
            "null" if a is type(None) else _describe(a)
            for a in sorted(get_args(tp), key=lambda a: a is type(None))
        )
    origin = get_origin(tp)
    if origin is Literal:
        return "one of " + ", ".join(json.dumps(a) for a in get_args(tp))
    if origin is list or tp is list:
        return "a list"
    if origin is dict or tp is dict or is_typeddict(tp):
        return "an object"
    return {float: "a number", int: "an integer", str: "a string", bool: "true or false"}.get(
        tp, "a value"
    )


@functools.cache
def _fields(td: type) -> tuple[dict[str, Any], frozenset[str]]:
    """A TypedDict's (key → type, required keys)."""
    return get_type_hints(td), frozenset(cast(Any, td).__required_keys__)


def _ok_scalar(v: Any, tp: Any) -> bool:
    if tp is float:
        return isinstance(v, int | float) and not isinstance(v, bool)
    if tp is int:
        return isinstance(v, int) and not isinstance(v, bool)
    if tp is str:
        return isinstance(v, str)
    if tp is bool:
        return isinstance(v, bool)
    return True


def _matches(v: Any, tp: Any) -> bool:
    """Whether ``v`` has ``tp``'s outer JSON type (a union: any of its members)."""
    if tp is Any or tp is object:
        return True
    if _is_union(tp):
        return any(_matches(v, a) for a in get_args(tp))
    if tp is type(None):
        return v is None
    origin = get_origin(tp)
    if origin is Literal:
        return v in get_args(tp)
    if origin is list or tp is list:
        return isinstance(v, list)
    if origin is dict or tp is dict or is_typeddict(tp):
        return isinstance(v, dict)
    return _ok_scalar(v, tp)


def _check(v: Any, tp: Any, at: str, fail: _Fail) -> None:
    if not _matches(v, tp):
        raise fail(at, f"expected {_describe(tp)}, got {_show(v)}")
    if _is_union(tp):  # descend into the member that matched (None needs nothing more)
        members = [a for a in get_args(tp) if a is not type(None) and _matches(v, a)]
        # of several objects, the one whose required keys the value has (else the first:
        # its missing key is then named)
        tp = next(
            (a for a in members if is_typeddict(a) and _fields(a)[1] <= set(v)),
            members[0] if members else None,
        )
        if tp is None:
            return
    origin, args = get_origin(tp), get_args(tp)
    if origin is list and args:
        for i, x in enumerate(v):
            _check(x, args[0], f"{at}[{i}]", fail)
    elif origin is dict and len(args) == 2:
        for k, x in v.items():
            _check(x, args[1], f"{at}.{k}" if at else str(k), fail)
    elif is_typeddict(tp):
        hints, required = _fields(tp)
        for k, ktp in hints.items():
            sub = f"{at}.{k}" if at else k
            if k not in v:
                if k in required:
                    raise fail(sub, "missing key")
                continue
            _check(v[k], ktp, sub, fail)


def check(obj: Any, schema: Any, where: str, *, error: type[PmalabError] = ResultFileError) -> Any:
    """Check ``obj`` (parsed JSON) against ``schema`` (a TypedDict, or any type the module's
    TypedDicts use); return it unchanged or raise ``error``: ``WHERE: KEY.PATH: what``."""

    def fail(at: str, msg: str) -> PmalabError:
        return error(f"{where}: {at}: {msg}" if at else f"{where}: {msg}")

    if is_typeddict(schema) and not isinstance(obj, dict):
        raise fail("", f"expected a JSON object at the top level, got {_show(obj)}")
    _check(obj, schema, "", fail)
    return obj


def check_identification(
    obj: Any, path: str | Path, *, error: type[PmalabError] = ResultFileError
) -> IdentificationDoc:
    """Check a parsed ``identification.json`` (:class:`IdentificationDoc`)."""
    return check(obj, IdentificationDoc, str(path), error=error)


def check_diagnosis(
    obj: Any, path: str | Path, *, error: type[PmalabError] = ResultFileError
) -> DiagnosisDoc:
    """Check a parsed ``diagnosis.json`` (:class:`DiagnosisDoc`)."""
    return check(obj, DiagnosisDoc, str(path), error=error)


def read_identification(
    path: str | Path, *, error: type[PmalabError] = ResultFileError
) -> IdentificationDoc:
    """Read and check ``identification.json``."""
    obj = load_json(path, "result file", error=error)
    return check_identification(obj, path, error=error)


def read_diagnosis(path: str | Path, *, error: type[PmalabError] = ResultFileError) -> DiagnosisDoc:
    """Read and check ``diagnosis.json``."""
    obj = load_json(path, "result file", error=error)
    return check_diagnosis(obj, path, error=error)


def read_laws(path: str | Path, *, error: type[PmalabError] = ResultFileError) -> LawsDoc:
    """Read and check ``laws.json`` (``pmalab identify --model a,b,c``)."""
    return check(load_json(path, "result file", error=error), LawsDoc, str(path), error=error)


def read_control_metrics(
    path: str | Path, *, error: type[PmalabError] = ResultFileError
) -> ControlMetricsDoc:
    """Read and check a control experiments' ``metrics.json``."""
    return check(
        load_json(path, "result file", error=error), ControlMetricsDoc, str(path), error=error
    )


def read_control_summary(
    path: str | Path, run: str, *, error: type[PmalabError] = ResultFileError
) -> ControlSummary:
    """Read and check the ``summary`` of run ``run`` of a ``pmalab control`` output file."""
    import h5py

    where = f"{path}: /runs/{run}/summary"
    try:
        f = h5py.File(path, "r")
    except OSError:
        raise error(f"{path}: not a readable HDF5 file") from None
    with f:
        ds = f.get(f"runs/{run}/summary")
        if not isinstance(ds, h5py.Dataset):
            raise error(f"{where}: missing dataset")
        raw = bytes(np.asarray(ds[()], dtype=np.uint8))
    if not raw:
        raise error(f"{where}: empty (the run has not ended)")
    try:
        obj = json.loads(raw.decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise error(f"{where}: malformed JSON ({exc})") from None
    return check(obj, ControlSummary, where, error=error)


# =========================================================================== predictions
#: the datasets every ``/runs/<key>`` group of ``predictions.h5`` holds (s, mm, MPa, N, N)
PREDICTION_CHANNELS = ("time", "position", "muscle_pressure", "force", "force_model")


@dataclass
class PredictionRun:
    """One ``/runs/<key>`` group: its 1-D float arrays (``time`` s, ``position`` mm,
    ``muscle_pressure`` MPa, ``force`` N, ``force_model`` N and, where written,
    ``force_model_quadratic`` N and ``position_model`` mm), their ``units`` and the
    group's attrs (``role``, ``file``, ``run``, ``muscle_pressure_MPa``, ``frequency_Hz``,
    ``waveform``, ``model``)."""

    key: str
    role: str
    arrays: dict[str, np.ndarray]
    attrs: dict[str, Any] = field(default_factory=dict)
    units: dict[str, str] = field(default_factory=dict)


@dataclass
class PredictionsDoc:
    """``predictions.h5``: the root attrs and the runs in file order."""

    model: str
    format_version: int | None
    runs: list[PredictionRun]


def read_predictions(
    path: str | Path, *, error: type[PmalabError] = ResultFileError
) -> PredictionsDoc:
    """Read and check ``predictions.h5`` (:mod:`pmalab.identify.predictions`)."""
    import h5py

    try:
        f = h5py.File(path, "r")
    except OSError:
        raise error(f"{path}: not a readable HDF5 file") from None
    with f:
        fmt = decode_attr(f.attrs.get("format"))
        if fmt != PREDICTIONS_FORMAT:
            raise error(f"{path}: format: expected {PREDICTIONS_FORMAT!r}, got {fmt!r}")
        runs = f.get("runs")
        if runs is None:
            raise error(f"{path}: no '/runs' group")
        if not isinstance(runs, h5py.Group):
            raise error(f"{path}: '/runs' is not a group")
        version = f.attrs.get("format_version")
        out = PredictionsDoc(
            model=str(decode_attr(f.attrs.get("model", ""))),
            format_version=None if version is None else int(version),
            runs=[],
        )
        for key in runs:
            g = runs[key]
            where = f"{path}: /runs/{key}"
            if not isinstance(g, h5py.Group):
                raise error(f"{where}: not a group")
            arrays: dict[str, np.ndarray] = {}
            units: dict[str, str] = {}
            for ch in PREDICTION_CHANNELS:
                if ch not in g:
                    raise error(f"{where}/{ch}: missing dataset")
            for ch in [*PREDICTION_CHANNELS, *(c for c in g if c not in PREDICTION_CHANNELS)]:
                ds = g[ch]
                if not isinstance(ds, h5py.Dataset):
                    continue
                a = np.asarray(ds[()], dtype=np.float64)
                if a.ndim != 1:
                    raise error(f"{where}/{ch}: expected 1-D, got shape {a.shape}")
                arrays[ch] = a
                if "units" in ds.attrs:
                    units[ch] = str(decode_attr(ds.attrs["units"]))
            n = {c: arrays[c].shape[0] for c in PREDICTION_CHANNELS}
            if len(set(n.values())) != 1:
                desc = ", ".join(f"{c}={m}" for c, m in n.items())
                raise error(f"{where}: datasets have unequal lengths ({desc})")
            if n["time"] < 2:
                raise error(f"{where}/time: too few samples ({n['time']})")
            for ch, a in arrays.items():
                if a.shape[0] != n["time"]:
                    raise error(f"{where}/{ch}: {a.shape[0]} samples, time has {n['time']}")
            attrs = {k: decode_attr(v) for k, v in g.attrs.items()}
            role = attrs.get("role")
            if not isinstance(role, str) or not role:
                raise error(
                    f"{where}: attr 'role': expected a string such as identification, "
                    f"validation, diagnosis, diagnosis-final, got {role!r}"
                )
            out.runs.append(PredictionRun(str(key), role, arrays, attrs, units))
        return out
