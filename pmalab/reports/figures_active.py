"""The active-identification page: the experiments the diagnosis ran and the ranking after each.

Input: ``diagnosis.json`` written by ``pmalab diagnose ... --run-suggested`` — ``rounds``
(each with ``experiment``, ``expected_separation``, ``verdict``) and
``settings.active.initial_verdict`` (the ranking before the first round).  NRMSE = RMS error
/ std of the measured tension, on the held-out runs (which grow as rounds add validation runs:
each point is the validation error on the campaign as it stood after that round).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from matplotlib.figure import Figure

from pmalab.reports import style


def has_active_rounds(diag: Mapping[str, Any]) -> bool:
    """True when ``diag`` comes from an active-identification loop."""
    return bool((diag.get("settings") or {}).get("active"))


def _candidates(initial: Mapping[str, Any], rounds: Sequence[Mapping[str, Any]]) -> list[str]:
    """The effects worth drawing: those ambiguous at any point, else the first two."""
    names: list[str] = []
    for v in [initial, *[r.get("verdict") or {} for r in rounds]]:
        for e in v.get("ambiguous") or []:
            if e not in names:
                names.append(e)
    if len(names) < 2:
        for r in (initial.get("ranking") or [])[:2]:
            if r["effect"] not in names:
                names.append(r["effect"])
    return names


@style.styled
def active_figure(diag: Mapping[str, Any]) -> Figure:
    """Left: the held-out NRMSE of the current model + each candidate effect after every
    round (round 0 = the campaign as given); right: the experiments run, with their expected
    and obtained outcome."""
    act = diag["settings"]["active"]
    initial = act.get("initial_verdict") or {}
    rounds = list(diag.get("rounds") or [])
    fig = style.new_figure("Active identification: the experiments run and the ranking after each")
    ax, axt = fig.subplots(1, 2, gridspec_kw={"width_ratios": [1.0, 1.25]})
    # each point: the candidates' validation NRMSE on the runs THAT round recorded (round 0:
    # the campaign's own held-out runs), as identified after that round — the evidence the
    # round added.  Mixing runs of different rounds in one mean would read as the error rising.
    groups: list[tuple[str, dict[str, Any], set[str]]] = [
        ("campaign's held-out runs", initial, set((initial.get("per_run") or {}).get("base", {})))
    ]
    for r in rounds:
        names = set(r.get("recorded_runs") or [])
        v = r.get("verdict") or {}
        labels = {
            lb for lb in (v.get("per_run") or {}).get("base", {}) if lb.rsplit(":", 1)[-1] in names
        }
        groups.append((f"round {r['round']}'s runs", v, labels))
    xs = list(range(len(groups)))
    names = ["base", *_candidates(initial, rounds)]
    for k, name in enumerate(names):
        ys = []
        for _, v, labels in groups:
            per = (v.get("per_run") or {}).get(name, {})
            vals = [per[lb] for lb in labels if lb in per]
            ys.append(sum(vals) / len(vals) if vals else float("nan"))
        # markers only: the groups hold different runs, a line between them is no trend
        off = 0.08 * (k - (len(names) - 1) / 2)
        ax.plot(
            [x + off for x in xs],
            ys,
            "s" if name == "base" else "o",
            ms=8,
            ls="none",
            color="0.5" if name == "base" else None,
            label="base model" if name == "base" else f"+ {name}",
        )
    ax.set_xticks(xs, [g[0] for g in groups], rotation=15, ha="right")
    ax.set_xlim(-0.5, len(xs) - 0.5)
    ax.set_ylabel("validation NRMSE on those runs")
    ax.set_ylim(bottom=0)
    ax.set_title("Each candidate on the runs each round recorded")
    ax.legend(loc="best", framealpha=0.9)
    axt.axis("off")
    lines = [
        *style.wrap(
            f"Started: first {initial.get('first') or '-'}"
            + (
                f", ambiguous {', '.join(initial['ambiguous'])}"
                if initial.get("ambiguous")
                else ", not ambiguous"
            ),
            72,
        ),
        "",
    ]
    for r in rounds:
        e, v = r["experiment"], r.get("verdict") or {}
        sep = r.get("expected_separation") or {}
        lines += style.wrap(
            f"Round {r['round']}: {e.get('label', '')} — "
            f"{r.get('rig_time_s', 0):.0f} s of rig time, "
            f"{len(r.get('recorded_runs') or [])} runs",
            72,
            subsequent_indent="    ",
        )
        lines += style.wrap(
            f"why: {e.get('reason', '')}", 72, initial_indent="  ", subsequent_indent="    "
        )
        lines += style.wrap(
            f"expected separation {float(sep.get('min_x_floor', 0)):.1f}× the noise floor → "
            f"first {v.get('first') or '-'}"
            + (
                f", ambiguous {', '.join(v['ambiguous'])}"
                if v.get("ambiguous")
                else ", not ambiguous"
            ),
            72,
            initial_indent="  ",
            subsequent_indent="    ",
        )
        lines.append("")
    if not rounds:
        lines.append("No experiment was run.")
    lines += style.wrap(
        f"Stopped: {act.get('stop', '')} ({float(act.get('rig_time_s', 0)):.0f} "
        f"s of {float(act.get('budget_s', 0)):.0f} s rig time).",
        72,
    )
    axt.text(
        0.0,
        1.0,
        "\n".join(lines),
        va="top",
        ha="left",
        fontsize=8.5,
        family="monospace",
        transform=axt.transAxes,
    )
    return fig
