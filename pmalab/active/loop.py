"""Active identification: diagnose, run the experiment that decides, diagnose again.

``pmalab diagnose CAMPAIGN.h5 --rig RIG --run-suggested [--budget 300] [--yes]`` and
:func:`diagnose_active`:

1. diagnose the campaign (the same :func:`~pmalab.identify.diagnosis.diagnose` as ``pmalab
   diagnose``);
2. when two or more effects explain the residual about equally (``ambiguous``), design the
   experiment that separates their models most relative to the noise floor, within the
   remaining rig-time budget (:mod:`.design`); an experiment whose expected separation is
   below :data:`~pmalab.active.design.MIN_SEPARATION` is not worth running and ends the loop;
3. show it as a protocol (the TOML ``pmalab run`` takes) with the reason, and ask before the
   rig moves (``confirm`` callback; ``--yes`` for scripts and the simulated rig);
4. record it through the acquisition runner — the rig's limits checked before anything
   moves, limits on every sample, the regulators vented on every exit — into a round file
   next to the campaign, then append its runs to the campaign in place (only the round's
   runs are written and read, never the whole campaign: :func:`append_runs`);
5. repeat until the verdict is unambiguous, nothing worth measuring is left, the budget is
   spent or ``max_rounds`` is reached, and say which.

A trip, Ctrl-C or a dead device during a round ends the loop: the round file keeps every
sample recorded (an aborted run is marked so, and is not appended), the campaign file is
intact, and the diagnosis of what was recorded before is written.
"""

from __future__ import annotations

import math
import os
import sys
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, cast

from pmalab.active.design import MIN_SEPARATION, Experiment, design, experiment_toml
from pmalab.errors import PmalabError
from pmalab.identify.diagnosis import diagnose
from pmalab.identify.long_records import fit_part, long_runs
from pmalab.identify.schema import ActiveRoundEntry
from pmalab.runfile import read_runs, seal_attrs

#: rounds at most (each is one recorded experiment)
MAX_ROUNDS = 3
#: default rig-time budget (s)
DEFAULT_BUDGET_S = 300.0

#: why the loop stopped (``stop_reason`` codes)
STOP_REASONS = {
    "unambiguous": "the verdict is unambiguous: nothing more is worth measuring",
    "no-experiment": "no experiment the rig can run within the budget separates the "
    "candidate models by ≥ {min_sep:g}× the noise floor",
    "budget": "the rig-time budget is spent",
    "rounds": "the maximum number of rounds was reached",
    "declined": "the suggested experiment was not confirmed",
    "aborted": "a round was aborted",
}


class ActiveError(PmalabError):
    """Bad active-identification input (a campaign that cannot be extended...)."""


@dataclass
class ActiveRound:
    """One round: the experiment run, what it was expected to show, the verdict after."""

    round: int
    experiment: dict[str, Any]
    expected_separation: dict[str, Any]
    protocol: str
    file: str
    recorded_runs: list[str]
    rig_time_s: float
    verdict: dict[str, Any] = field(default_factory=dict)

    def as_json(self) -> ActiveRoundEntry:
        """The diagnosis.json entry (its one declaration: the schema's ActiveRoundEntry)."""
        return {
            "round": self.round,
            "experiment": self.experiment,
            "expected_separation": self.expected_separation,
            "protocol": self.protocol,
            "file": self.file,
            "recorded_runs": self.recorded_runs,
            "rig_time_s": self.rig_time_s,
            "verdict": self.verdict,
        }


@dataclass
class ActiveResult:
    """The final diagnosis, the rounds run and why the loop stopped."""

    diagnosis: Any  # pmalab.identify.diagnosis.Diagnosis
    rounds: list[ActiveRound]
    stop_reason: str
    stop_text: str
    rig_time_s: float
    budget_s: float
    initial_verdict: dict[str, Any] = field(default_factory=dict)

    def final(self) -> Any:
        """The diagnosis to write: ``rounds`` holds the active rounds (each with
        ``experiment``, ``expected_separation`` and ``verdict``); the ladder's own per-step
        rankings move to ``settings.ladder_rounds``, the loop's outcome to
        ``settings.active``."""
        from dataclasses import replace

        d = self.diagnosis
        active = {
            "stop_reason": self.stop_reason,
            "stop": self.stop_text,
            "rig_time_s": self.rig_time_s,
            "budget_s": self.budget_s,
            "initial_verdict": self.initial_verdict,
        }
        return replace(
            d,
            rounds=[r.as_json() for r in self.rounds],
            settings={**d.settings, "ladder_rounds": d.rounds, "active": active},
        )

    def to_json(self) -> dict[str, Any]:
        """diagnosis.json as written (see :meth:`final`)."""
        return self.final().to_json()


def verdict_of(d: Any) -> dict[str, Any]:
    """The part of a diagnosis a round's outcome is judged by: the ranking's summary, and
    each candidate's held-out nrmse per run (``per_run[effect][run label]``), so a round can
    be judged on the runs it recorded."""
    first = d.ranking[0] if d.ranking else {}
    held = list(d.settings.get("held_out", []))
    per_run = {
        r["effect"]: dict(zip(held, (float(v) for v in r.get("per_run_after") or [])))
        for r in d.ranking
    }
    base = d.ladder[0] if d.ladder else {}
    per_run["base"] = dict(zip(held, (float(v) for v in base.get("per_run") or [])))
    return {
        "first": first.get("effect"),
        "significant": bool(first.get("significant")),
        "ambiguous": list(d.ambiguous),
        "final_model": "+".join([d.final_law or d.model, *d.final_effects]),
        "verdict": d.verdict,
        "ranking": [
            {
                "effect": r["effect"],
                "nrmse_after": r["nrmse_after"],
                "fall_percent": r["fall_percent"],
                "significant": r["significant"],
            }
            for r in d.ranking
        ],
        "per_run": per_run,
    }


Recorder = Callable[[str, Path, int], list[str]]
Confirm = Callable[[Experiment, str], bool]


def diagnose_active(
    campaign: str | Path,
    record: Recorder,
    *,
    model: str = "bouc-wen",
    budget_s: float = DEFAULT_BUDGET_S,
    confirm: Confirm | None = None,
    max_rounds: int = MAX_ROUNDS,
    effects: Sequence[str] | None = None,
    jobs: int = 1,
    log: Callable[[str], None] | None = None,
    protocol_duration: Callable[[str], float] | None = None,
    options: Mapping[str, Any] | None = None,
) -> ActiveResult:
    """Diagnose ``campaign`` and run the experiments that decide (module doc).

    ``record(protocol_toml, round_file, round_index) -> run names`` records a protocol on
    the rig into ``round_file`` (raises :class:`~pmalab.errors.PmalabError` on an abort,
    after venting); :func:`rig_recorder` builds one from a rig spec.  ``confirm(experiment,
    protocol_toml) -> bool`` is asked before every round (None: run without asking).
    ``protocol_duration(toml) -> s``: rig time of a protocol (for the budget).
    ``options``: the diagnosis's other settings (``laws``, ``max_steps``, ``effects_files``,
    ``whole_run``: :func:`~pmalab.identify.diagnosis.diagnose`'s keywords), used for the
    first diagnosis and for every round's.
    """
    opts = dict(options or {})
    path = Path(campaign)
    say = log or (lambda s: print(s, file=sys.stderr))
    if budget_s <= 0 or not math.isfinite(budget_s):
        raise ActiveError(f"--budget: must be a positive number of seconds, got {budget_s:g}")
    runs = [fit_part(r) for r in read_runs(path, skip_incomplete=True, long_runs=long_runs())]
    d = diagnose(runs, model, effects=effects, jobs=jobs, **opts)
    initial = verdict_of(d)
    rounds: list[ActiveRound] = []
    spent = 0.0
    stop = "rounds"
    for i in range(1, max_rounds + 1):
        if len(d.ambiguous) < 2:
            stop = "unambiguous"
            break
        left = budget_s - spent
        dur = _duration_fn(protocol_duration)
        best, _scored, _models = design(
            runs,
            # the final model's law (the ladder may have switched it) and its effects
            d.final_law or model,
            d.final_effects,
            d.ambiguous,
            d.noise_floor.get("per_run", {}),
            budget_s=left,
            round_index=i,
            duration_of=dur,
            effects_files=opts.get("effects_files") or (),
        )
        if best is None:
            stop = "budget" if spent > 0 else "no-experiment"
            break
        if best.separation < MIN_SEPARATION:
            stop = "no-experiment"
            break
        name = f"{path.stem}-round{i}"
        toml = experiment_toml(best, name, best.reason)
        say(
            f"round {i}: ambiguous {', '.join(d.ambiguous)}; suggested experiment "
            f"({best.duration_s:.0f} s of rig time): {best.reason}"
        )
        if confirm is not None and not confirm(best, toml):
            stop = "declined"
            break
        round_file = _round_path(path, i)
        try:
            names = record(toml, round_file, i)
        except PmalabError as exc:
            # the campaign is untouched; the round file keeps what was recorded
            err = RoundAborted(
                str(exc),
                ActiveResult(
                    d, rounds, "aborted", f"round {i} was aborted: {exc}", spent, budget_s, initial
                ),
                round_file,
            )
            err.exit_code = exc.exit_code  # a safety abort keeps its exit status (4)
            err.hard_exit = exc.hard_exit
            raise err from exc
        added = append_runs(path, round_file, names)
        spent += best.duration_s
        # only the round's runs are read: the campaign's were read before
        new_runs = read_runs(path, added, long_runs=long_runs()) if added else []
        runs = [*runs, *(fit_part(r) for r in new_runs)]
        d = diagnose(runs, model, effects=effects, jobs=jobs, **opts)
        rounds.append(
            ActiveRound(
                round=i,
                experiment=best.as_json(),
                expected_separation={"min_x_floor": best.separation, "pairs": best.pairs},
                protocol=toml,
                file=str(round_file),
                recorded_runs=names,
                rig_time_s=best.duration_s,
                verdict=verdict_of(d),
            )
        )
        say(
            f"round {i}: recorded {len(names)} runs ({best.duration_s:.0f} s); now "
            + (f"{d.ranking[0]['effect']} first" if d.ranking else "no ranking")
            + (
                f", still ambiguous with {', '.join(d.ambiguous[1:])}"
                if len(d.ambiguous) > 1
                else ", not ambiguous"
            )
        )
    else:
        stop = "rounds" if len(d.ambiguous) >= 2 else "unambiguous"
    text = STOP_REASONS[stop].format(min_sep=MIN_SEPARATION)
    return ActiveResult(d, rounds, stop, text, spent, budget_s, initial)


class RoundAborted(PmalabError):
    """A round's recording was aborted; ``partial`` holds the diagnosis so far."""

    exit_code = 4

    def __init__(self, msg: str, partial: ActiveResult, round_file: Path):
        super().__init__(msg)
        self.partial = partial
        self.round_file = round_file


def _duration_fn(protocol_duration: Callable[[str], float] | None):
    if protocol_duration is None:
        return None

    def dur(fields: list[dict[str, Any]]) -> float:
        from pmalab.active.design import Experiment as _E

        e = _E("", 1.0, 1.0, 1.0, fields)
        return protocol_duration(experiment_toml(e, "duration-check", ""))

    return dur


def _round_path(campaign: Path, i: int) -> Path:
    p = campaign.with_name(f"{campaign.stem}-round{i}.h5")
    k = 2
    while p.exists():
        p = campaign.with_name(f"{campaign.stem}-round{i}-{k}.h5")
        k += 1
    return p


#: the campaign's hidden group a round's runs are copied into before they join ``/runs``
#: (run-file readers read ``/runs`` only)
STAGING = ".appending"


def append_runs(campaign: Path, round_file: Path, names: Sequence[str]) -> list[str]:
    """Append the completed runs ``names`` of ``round_file`` to ``campaign``, in place; the
    names they got in the campaign (``<name>-2``... when taken).

    Only the round's runs are written: the campaign's own runs are neither copied nor
    rewritten (a campaign of long records is gigabytes; copying it every round cost as
    much as the round).  Each run is copied into the hidden group ``/.appending`` (which no
    reader looks at), flushed, and then linked into ``/runs`` under its name — so ``/runs``
    only ever holds whole runs.  A failure while copying (a full disk) removes the partial
    copy; the runs already in ``/runs`` are never touched.  A copy cut by a crash is left in
    ``/.appending``, invisible to readers, and removed by the next append."""
    import h5py

    appended: list[str] = []
    try:
        with h5py.File(round_file, "r") as src, h5py.File(campaign, "a") as dst:
            if STAGING in dst:
                del dst[STAGING]  # a copy a crash cut short (never in /runs)
            runs = dst.require_group("runs")
            stage = dst.create_group(STAGING)
            for n in names:
                new = n
                k = 2
                while new in runs or new in appended:
                    new = f"{n}-{k}"
                    k += 1
                # round_file is the run file the round's recorder wrote (its /runs group)
                src.copy(cast(h5py.Group, src["runs"])[n], stage, name=new)
                stage[new].attrs["appended_from"] = str(round_file.name)
                seal_attrs(stage[new])  # the attrs' digest covers the new one too
                dst.flush()
                dst.move(f"{STAGING}/{new}", f"runs/{new}")
                dst.flush()
                appended.append(new)
            del dst[STAGING]
        with open(campaign, "rb+") as fh:
            os.fsync(fh.fileno())
    except (OSError, RuntimeError, KeyError) as exc:  # a full disk, a run the round lacks
        _drop_staging(campaign)
        raise ActiveError(
            f"{campaign}: appending round {round_file.name} failed ({exc}); "
            + (
                f"runs {', '.join(appended)} were appended before it"
                if appended
                else "the campaign's runs are as they were"
            )
        ) from None
    return appended


def _drop_staging(campaign: Path) -> None:
    """Remove a partial copy left in the campaign's staging group (best effort)."""
    import h5py

    try:
        with h5py.File(campaign, "a") as f:
            if STAGING in f:
                del f[STAGING]
    except (OSError, RuntimeError):
        pass


def rig_recorder(rig_spec: str, *, seed: int | None = None, quiet: bool = True) -> Recorder:
    """A recorder on ``rig_spec`` (``sim`` or a rig TOML) through the acquisition runner.

    Every round opens the rig, runs the protocol with the runner's limits and venting, and
    closes it; a simulated rig gets a new sensor-noise seed per round (``seed + round``)."""
    from pmalab.acquisition.cli import load_rig_spec
    from pmalab.acquisition.protocol import parse_protocol
    from pmalab.acquisition.runner import RunnerOptions, run_protocol

    def record(toml: str, out: Path, i: int) -> list[str]:
        protocol = parse_protocol(toml, where=f"round {i} protocol")
        rig = load_rig_spec(rig_spec, seed=None if seed is None else seed + i)
        if seed is None and rig.info.get("kind") == "sim":
            rig.close()
            base = int(rig.info.get("seed") or 0)
            rig = load_rig_spec(rig_spec, seed=base + 1000 * i)
        opts = RunnerOptions(
            progress=not quiet,
            extra_attrs={
                "command_line": " ".join(sys.argv),
                "rig_spec": rig_spec,
                "active_round": i,
            },
        )
        with rig:
            results = run_protocol(rig, protocol, out, force=False, options=opts)
        vent = rig.last_vent
        if vent is not None and not vent.ok:
            raise ActiveError(
                f"{out}: round {i} recorded, but the regulators' vent was not "
                f"confirmed: {vent.line()}"
            )
        return [r.name for r in results if r.status == "completed"]

    return record


def protocol_duration(toml: str) -> float:
    """Rig time (s) of a protocol text, by the protocol's own arithmetic."""
    from pmalab.acquisition.protocol import parse_protocol

    return float(parse_protocol(toml, where="suggested protocol").duration_s)
