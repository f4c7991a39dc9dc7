"""Experiment design: the next run that separates the candidate models most.

When diagnosis leaves two or more effects explaining the residual about equally (the
ranking's ``ambiguous`` list), each is a *candidate model*: the current model plus that
effect, identified on the campaign's identification runs by THE identification
(:func:`~pmalab.identify.campaign.validation.fit_and_validate`, the same call ``pmalab
identify --add`` makes).  Each candidate experiment — a waveform, a frequency and an
amplitude at the pressures of the held-out runs — is predicted with every candidate model;
the experiment is worth running when the models' predicted forces differ by more than the
record's own noise.

Expected separation (dimensionless, "× the noise floor"): for each pair of candidate models
A, B and each new run, rms(F_A − F_B) over the full-amplitude cycles divided by the
measurement noise of the force (N rms, the noise floor estimated on the held-out run at that
pressure, :mod:`pmalab.identify.noise`); the smallest pair's value (the pair hardest to
separate) over the mean of the runs.  It is what the new validation runs will show: a model
that predicts the new run wrong by several times the noise loses to the one that predicts it
right.

Position of a run not yet recorded: the muscle's contraction x(t) (mm) is synthesised from
the held-out run at the same pressure — its mean and half-range on the full-amplitude cycles,
scaled with the cylinder amplitude, on the candidate waveform (a triangle's corners rounded
by a 20 ms moving average, as a pressure regulator's lag rounds them).  The candidate
models predict the force from that x (``initial="burn-in"``: one cycle replayed to put the
hysteretic state on its orbit).  The shape of x only ranks the candidates; what is then
recorded is measured, never synthesised.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from pmalab.errors import PmalabError
from pmalab.identify.campaign import ModelSpec, fit_and_validate
from pmalab.identify.diagnosis.heldout import choose
from pmalab.runfile import Run

#: candidate frequencies (Hz); each must also pass the protocol's own limits
FREQUENCIES_HZ = (0.25, 0.5, 1.0, 2.0, 4.0)
#: candidate waveforms (the runner's ``waveform`` values)
WAVEFORMS = ("sine", "triangle")
#: candidate cylinder-amplitude scales relative to the template run
AMPLITUDE_SCALES = (1.0, 0.5)
#: an experiment below this expected separation (× noise floor) is not worth rig time
MIN_SEPARATION = 1.0
#: experiments within this fraction of the best separation count as equally good (the
#: shortest of them is chosen)
NEAR_BEST = 0.9
#: corner rounding of a synthesised triangle (s)
TRIANGLE_ROUNDING_S = 0.02


@dataclass
class CandidateModel:
    """One competing model: the current model with one of the ambiguous effects."""

    effect: str
    effects: tuple[str, ...]
    fit: Any  # CampaignFit
    #: the effect's own parameters at each template pressure {p: {name: value}}
    params: dict[float, dict[str, float]] = field(default_factory=dict)


@dataclass
class Experiment:
    """A candidate experiment and what the candidate models predict for it."""

    waveform: str
    frequency_Hz: float
    amplitude_scale: float
    cycles: float
    #: one run spec (protocol fields) per pressure
    runs: list[dict[str, Any]]
    duration_s: float = 0.0
    #: smallest pairwise separation, × the noise floor (mean over the runs)
    separation: float = 0.0
    #: every pair's separation {"a vs b": value}
    pairs: dict[str, float] = field(default_factory=dict)
    #: the same experiment's separation on the campaign's existing conditions (context)
    reason: str = ""

    @property
    def label(self) -> str:
        amp = "" if self.amplitude_scale == 1.0 else f", {self.amplitude_scale:g}× amplitude"
        ps = ", ".join(f"{r['muscle_pressure_MPa']:g}" for r in self.runs)
        return f"{self.frequency_Hz:g} Hz {self.waveform}{amp} at {ps} MPa"

    def as_json(self) -> dict[str, Any]:
        return {
            "waveform": self.waveform,
            "frequency_Hz": self.frequency_Hz,
            "amplitude_scale": self.amplitude_scale,
            "cycles": self.cycles,
            "duration_s": self.duration_s,
            "runs": self.runs,
            "label": self.label,
            "reason": self.reason,
        }


def _steady_cycles(run: Run) -> Run:
    return run.steady()


def _template_stats(run: Run) -> tuple[float, float]:
    """(mean, half-range) of the contraction on the run's full-amplitude cycles (mm)."""
    x = _steady_cycles(run).position
    lo, hi = np.percentile(x, [1.0, 99.0])
    return float(0.5 * (lo + hi)), float(0.5 * (hi - lo))


def synth_position(t: np.ndarray, waveform: str, f: float, mean: float, half: float) -> np.ndarray:
    """Contraction x(t) (mm) of a run not yet recorded (see module doc).

    Phase: x starts at its minimum (the muscle stretched, as a ramp-in leaves it)."""
    ph = (f * t) % 1.0
    if waveform == "triangle":
        shape = np.where(ph < 0.5, 4.0 * ph - 1.0, 3.0 - 4.0 * ph)
        dt = float(np.median(np.diff(t)))
        k = max(int(round(TRIANGLE_ROUNDING_S / dt)), 1)
        if k > 1:
            pad = np.concatenate([np.full(k, shape[0]), shape, np.full(k, shape[-1])])
            shape = np.convolve(pad, np.ones(k) / k, mode="same")[k:-k]
    else:
        shape = -np.cos(2.0 * np.pi * ph)
    return mean + half * shape


def synth_run(template: Run, waveform: str, f: float, scale: float, cycles: float) -> Run:
    """An in-memory run (no force) at the template's pressure and sample rate."""
    rate = float(template.attrs.get("sample_rate_Hz") or 1.0 / np.median(np.diff(template.time)))
    n = int(round((cycles / f) * rate))
    t = np.arange(n) / rate
    mean, half = _template_stats(template)
    x = synth_position(t, waveform, f, mean, half * scale)
    p = np.full(n, template.nominal_pressure)
    attrs = {
        "muscle_pressure_MPa": template.nominal_pressure,
        "frequency_Hz": f,
        "waveform": waveform,
        "sample_rate_Hz": rate,
    }
    return Run(
        name=f"design-{waveform}-{f:g}Hz",
        time=t,
        position=x,
        force=np.zeros(n),
        muscle_pressure=p,
        attrs=attrs,
    )


def fit_candidates(
    train: Sequence[Run],
    held: Sequence[Run],
    law: str,
    base_effects: Sequence[str],
    ambiguous: Sequence[str],
    effects_files: Sequence[str] = (),
) -> list[CandidateModel]:
    """Identify the current model + each ambiguous effect (THE identification)."""
    from pmalab.identify.campaign.fit import fit_campaign

    base = tuple(e for e in base_effects if e not in ambiguous)
    base_fit = fit_campaign(list(train), ModelSpec(law, base, tuple(effects_files)))
    base_names = set(base_fit.parameter_names)
    out = []
    for e in ambiguous:
        effects = (*base, e)
        cf, _, _ = fit_and_validate(
            list(train), ModelSpec(law, effects, tuple(effects_files)), list(held)
        )
        own = [n for n in cf.parameter_names if n not in base_names]
        params = {}
        for r in held:
            th = cf.theta(r.nominal_pressure)
            params[float(r.nominal_pressure)] = {n: th[n] for n in own if n in th}
        out.append(CandidateModel(e, effects, cf, params))
    return out


def _separations(
    models: Sequence[CandidateModel], runs: Sequence[Run], noise_N: Sequence[float]
) -> tuple[float, dict[str, float]]:
    """(min pairwise separation, every pair's) of ``models`` on ``runs`` (× noise)."""
    preds = []
    for m in models:
        per = []
        for r in runs:
            with np.errstate(all="ignore"):
                per.append(m.fit.predict(r, force=None, initial="burn-in"))
        preds.append(per)
    pairs: dict[str, float] = {}
    for (i, a), (j, b) in itertools.combinations(enumerate(models), 2):
        vals = []
        for k, r in enumerate(runs):
            keep = _after_first_cycle(r)
            d = preds[i][k][keep] - preds[j][k][keep]
            rms = float(np.sqrt(np.mean(d**2))) if np.all(np.isfinite(d)) else 0.0
            vals.append(rms / max(noise_N[k], 1e-9))
        pairs[f"{a.effect} vs {b.effect}"] = float(np.mean(vals))
    return (min(pairs.values()) if pairs else 0.0), pairs


def _after_first_cycle(r: Run) -> np.ndarray:
    f = r.frequency or 0.0
    if f <= 0:
        return np.ones(len(r), dtype=bool)
    return (r.time - r.time[0]) >= 1.0 / f


def _amplitude(r: Run) -> float | None:
    proto = r.attrs.get("protocol")
    v = proto.get("amplitude_MPa") if isinstance(proto, dict) else None
    v = r.attrs.get("amplitude_MPa") if v is None else v
    return None if v is None else float(v)


def candidate_experiments(
    templates: Sequence[Run], campaign: Sequence[Run] = ()
) -> list[tuple[str, float, float]]:
    """(waveform, frequency, amplitude scale) triples not yet recorded at the templates'
    pressures (a condition already in ``campaign`` or the templates is not proposed again)."""
    done = set()
    for t in templates:
        a0 = _amplitude(t)
        for r in [*templates, *campaign]:
            if abs(r.nominal_pressure - t.nominal_pressure) > 1e-3 or not r.frequency:
                continue
            a = _amplitude(r)
            scale = round(a / a0, 2) if (a is not None and a0) else 1.0
            done.add((str(r.attrs.get("waveform", "sine")), round(r.frequency, 6), scale))
    out = []
    for w, f, s in itertools.product(WAVEFORMS, FREQUENCIES_HZ, AMPLITUDE_SCALES):
        if (w, round(f, 6), round(s, 2)) not in done:
            out.append((w, f, s))
    return out


def cycles_for(f: float) -> float:
    """Cycles per new run: the first puts the hysteretic state on its orbit, the rest are
    evidence; more of them at higher frequency where they are cheap."""
    return 3.0 if f < 1.0 else (4.0 if f < 3.0 else 6.0)


def run_fields(
    template: Run,
    name: str,
    waveform: str,
    f: float,
    scale: float,
    cycles: float,
    role: str = "validation",
) -> dict[str, Any]:
    """Protocol fields of a new validation run modelled on ``template``'s own protocol."""
    proto = template.attrs.get("protocol")
    proto = dict(proto) if isinstance(proto, dict) else {}
    keep = (
        "muscle_pressure_MPa",
        "offset_MPa",
        "amplitude_MPa",
        "magnitude_MPa",
        "ramp_s",
        "settle_s",
        "preload_MPa",
        "pressure_tolerance_MPa",
        "pressure_stable_s",
        "pressure_timeout_s",
    )
    out: dict[str, Any] = {k: proto[k] for k in keep if k in proto and proto[k] is not None}
    out.setdefault("muscle_pressure_MPa", float(template.nominal_pressure))
    for k in ("amplitude_MPa", "magnitude_MPa"):
        if k in out:
            out[k] = round(float(out[k]) * scale, 6)
    out.update(
        {
            "name": name,
            "role": role,
            "waveform": waveform,
            "frequency_Hz": float(f),
            "cycles": float(cycles),
        }
    )
    return out


def design(
    runs: Sequence[Run],
    law: str,
    base_effects: Sequence[str],
    ambiguous: Sequence[str],
    noise_floor: dict[str, float],
    *,
    budget_s: float = math.inf,
    round_index: int = 1,
    validate: Sequence[Run] = (),
    effects_files: Sequence[str] = (),
    duration_of=None,
    with_identification: bool = True,
) -> tuple[Experiment | None, list[Experiment], list[CandidateModel]]:
    """The experiment that separates the ``ambiguous`` effects most (module doc).

    ``runs``: the campaign (steady windows are taken here, as diagnosis does);
    ``noise_floor``: the diagnosis's per-held-out-run noise floor (nrmse, by run label);
    ``duration_of(fields_list) -> s``: rig time of a list of run specs (the protocol's own
    arithmetic; default ramp + settle + cycles / f per run).
    Returns (best or None, every candidate scored, the candidate models).
    """
    steady = [r.steady() for r in runs]
    split = choose(steady, [r.steady() for r in validate])
    held = list(split.held)
    models = fit_candidates(split.train, held, law, base_effects, ambiguous, effects_files)
    # one template per distinct held-out pressure (the held-out runs sit inside the
    # identified range: the new runs need no extrapolated pressure law)
    templates: dict[float, Run] = {}
    # (runs this loop recorded are not templates: their amplitude may be scaled)
    for r in sorted(held, key=lambda r: "active_round" in r.attrs):
        templates.setdefault(round(float(r.nominal_pressure), 4), r)
    tpl = list(templates.values())
    train_levels: dict[float, Run] = {}
    for r in sorted(split.train, key=lambda r: "active_round" in r.attrs):
        train_levels.setdefault(round(float(r.nominal_pressure), 4), r)
    train_tpl = list(train_levels.values())
    noise_N = []
    for r in tpl:
        fl = noise_floor.get(r.label)
        if fl is None:
            from pmalab.identify.noise import noise_floor_nrmse

            fl = noise_floor_nrmse(r.force, r.time)
        noise_N.append(float(fl) * float(np.std(r.force)))
    dur = duration_of or _default_duration
    scored: list[Experiment] = []
    for w, f, s in candidate_experiments(tpl, steady):
        cyc = cycles_for(f)
        fields = [run_fields(t, _name(round_index, w, f, s, t), w, f, s, cyc) for t in tpl]
        if with_identification:
            fields += [
                run_fields(t, _name(round_index, w, f, s, t), w, f, s, cyc, role="identification")
                for t in train_tpl
            ]
        try:
            d = float(dur(fields))
        except PmalabError:  # the protocol refuses it (e.g. too fast for the rig's rate)
            continue
        if d > budget_s:
            continue
        sims = [synth_run(t, w, f, s, cyc) for t in tpl]
        sep, pairs = _separations(models, sims, noise_N)
        scored.append(Experiment(w, f, s, cyc, fields, d, sep, pairs))
    # what the campaign's own conditions show (why it was ambiguous)
    now_sep, _ = _separations(models, tpl, noise_N)
    if not scored:
        return None, [], models
    best_sep = max(e.separation for e in scored)
    near = [e for e in scored if e.separation >= NEAR_BEST * best_sep]
    best = min(near, key=lambda e: (e.duration_s, -e.separation))
    best.reason = _reason(models, best, now_sep, tpl)
    return best, sorted(scored, key=lambda e: -e.separation), models


def _name(i: int, w: str, f: float, s: float, t: Run) -> str:
    return f"r{i}-{w[:3]}{f:g}Hz-{1000 * t.nominal_pressure:.0f}kPa" + (
        "" if s == 1.0 else f"-x{s:g}"
    )


def _default_duration(fields: Sequence[dict[str, Any]]) -> float:
    return float(
        sum(
            float(x.get("settle_s", 0.5))
            + float(x.get("ramp_s", 0.5))
            + float(x["cycles"]) / float(x["frequency_Hz"])
            for x in fields
        )
    )


def _fmt_params(m: CandidateModel) -> str:
    if not m.params:
        return m.effect
    p, vals = next(iter(m.params.items()))
    txt = ", ".join(f"{k} = {v:.3g}" for k, v in vals.items())
    return f"{m.effect} ({txt} at {p:g} MPa)" if txt else m.effect


def _reason(
    models: Sequence[CandidateModel], e: Experiment, now: float, templates: Sequence[Run]
) -> str:
    names = " and ".join(_fmt_params(m) for m in models)
    here = ", ".join(
        sorted(
            {
                f"{r.frequency:g} Hz {r.attrs.get('waveform', 'sine')}"
                for r in templates
                if r.frequency
            }
        )
    )
    return (
        f"{names} predict forces that differ by {e.separation:.1f}× the noise floor on a "
        f"{e.label} (on the campaign's {here or 'runs'}: {now:.1f}×)"
    )


def experiment_toml(e: Experiment, name: str, why: str) -> str:
    """The experiment as a protocol file (the TOML ``pmalab run --protocol`` takes)."""
    lines = [
        f"# {why}",
        "[protocol]",
        f'name = "{name}"',
        f'description = "{e.label}: suggested by pmalab diagnose --run-suggested"',
        "",
    ]
    for r in e.runs:
        lines.append("[[run]]")
        for k, v in r.items():
            lines.append(f"{k} = {_toml_value(v)}")
        lines.append("")
    return "\n".join(lines)


def _toml_value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int | float):
        return repr(float(v)) if isinstance(v, float) else str(v)
    return '"' + str(v).replace("\\", "\\\\").replace('"', '\\"') + '"'
