"""The report of an antagonistic pair: ``pmalab report PAIR.h5... --out R.pdf``.

A pair file is a run file (format 2) whose runs declare two or more muscles (``pmalab run
--rig data/rigs/sim-pair.toml``), or a joint-control file (``pmalab control --rig PAIR``:
runs with ``angle`` and ``angle_reference``).  Read through :mod:`pmalab.runfile` only.

Pages: both muscles' force–contraction loops side by side (each from the runs that held
it isobaric, one colour per pressure, on one force and one contraction scale); then per
run the joint angle, both muscles' pressures and both tensions against time; a joint-control
run shows the angle against its reference and set point, and both pressure commands.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from pmalab.errors import PmalabError
from pmalab.reports.errors import ReportError
from pmalab.reports.pdf import PageSpec, ReportPlan, write_plan
from pmalab.runfile import Run, muscles_of, open_h5, read_run_datasets, read_runs

#: one colour per muscle, in declaration order (flexor, extensor, ...)
MUSCLE_COLOURS = ("tab:blue", "tab:orange", "tab:green", "tab:red")


def _run_names(path: Path) -> list[str]:
    import h5py

    f = open_h5(path)
    try:
        g = f.get("runs")
        return list(g.keys()) if isinstance(g, h5py.Group) else []
    finally:
        f.close()


def is_pair_file(path: str | Path) -> bool:
    """True for a run file declaring several muscles, or a joint-control file."""
    p = Path(path)
    if not p.is_file() or p.suffix.lower() not in (".h5", ".hdf5"):
        return False
    try:
        if len(muscles_of(p)) > 1:
            return True
        names = _run_names(p)
        return bool(names) and "angle_reference" in read_run_datasets(p, names[0])
    except PmalabError:
        return False


@dataclass
class PairFile:
    """What the pages draw: each muscle's held runs, and every run's datasets."""

    path: Path
    muscles: tuple[str, ...]
    held: dict[str, list[Run]]
    datasets: dict[str, dict[str, np.ndarray]]


def load_pair_file(path: str | Path) -> PairFile:
    """A pair file's runs; :class:`ReportError` (one line) on a problem."""
    p = Path(path)
    try:
        muscles = muscles_of(p)
        held: dict[str, list[Run]] = {}
        if len(muscles) > 1:
            for m in muscles:
                held[m] = read_runs(p, muscle=m, skip_incomplete=True)
        data = {n: {k: v for k, (v, _) in read_run_datasets(p, n).items()} for n in _run_names(p)}
    except PmalabError as exc:
        raise ReportError(str(exc)) from None
    return PairFile(p, muscles if len(muscles) > 1 else (), held, data)


def loops_figure(pf: PairFile) -> Figure:
    """Both muscles' force–contraction loops side by side, on one scale."""
    fig = Figure(figsize=(11.0, 5.2))
    axes = fig.subplots(1, len(pf.muscles), sharex=True, sharey=True, squeeze=False)[0]
    import matplotlib as mpl

    pressures = sorted({round(r.nominal_pressure, 4) for rs in pf.held.values() for r in rs})
    cmap = mpl.colormaps["viridis"]
    span = (min(pressures), max(pressures)) if pressures else (0.0, 1.0)

    def colour(p: float):
        lo, hi = span
        return cmap(0.1 + 0.8 * ((p - lo) / (hi - lo) if hi > lo else 0.5))

    for ax, m in zip(axes, pf.muscles, strict=True):
        runs = pf.held.get(m, [])
        for r in runs:
            s = r.steady()
            ax.plot(
                s.position,
                s.force,
                lw=0.8,
                color=colour(r.nominal_pressure),
                label=f"{r.nominal_pressure:.3g} MPa",
            )
        ax.set_title(
            f"{m}: {len(runs)} isobaric run(s) (held, the other muscle driving)", fontsize=10
        )
        ax.set_xlabel("contraction x (mm, + = shorter)")
        ax.grid(alpha=0.3)
        if runs:
            ax.legend(title="held at", fontsize=8, title_fontsize=8, loc="upper right")
        else:
            ax.text(0.5, 0.5, "no run held this muscle", ha="center", transform=ax.transAxes)
    axes[0].set_ylabel("tension F (N)")
    fig.suptitle(f"{pf.path.name}: both muscles of the pair, one force and contraction scale")
    fig.tight_layout(rect=(0, 0.02, 1, 0.95))
    return fig


def run_figure(pf: PairFile, name: str) -> Figure:
    """One run against time: the joint angle (and its reference), pressures, tensions."""
    d = pf.datasets[name]
    t = d["time"]
    control = "angle_reference" in d
    muscles = pf.muscles or ("flexor", "extensor")
    tensions = any(f"force_{m}" in d for m in muscles)
    fig = Figure(figsize=(11.0, 7.5 if tensions else 5.5))
    axes = fig.subplots(3 if tensions else 2, 1, sharex=True)
    ax_a, ax_p = axes[0], axes[1]
    ax_f = axes[2] if tensions else None
    ax_a.plot(t, d["angle"], lw=0.9, color="k", label="angle (measured)")
    if control:
        ax_a.plot(t, d["angle_reference"], lw=0.8, ls="--", color="tab:red", label="reference")
        ax_a.plot(
            t,
            d["angle_setpoint"],
            lw=0.8,
            color="tab:purple",
            alpha=0.7,
            label="set point (shaped)",
        )
    ax_a.set_ylabel("joint angle (deg)")
    ax_a.legend(fontsize=8, loc="upper right")
    for i, m in enumerate(muscles):
        c = MUSCLE_COLOURS[i % len(MUSCLE_COLOURS)]
        if f"muscle_pressure_{m}" in d:
            ax_p.plot(t, d[f"muscle_pressure_{m}"], lw=0.9, color=c, label=f"{m} (measured)")
        if f"muscle_pressure_command_{m}" in d:
            ax_p.plot(
                t,
                d[f"muscle_pressure_command_{m}"],
                lw=0.7,
                ls="--",
                color=c,
                label=f"{m} (command)",
            )
        if ax_f is not None and f"force_{m}" in d:
            # one cable: the two tensions differ only by the joint's inertia and friction,
            # so the second is dashed over the first rather than hiding it
            ax_f.plot(
                t,
                d[f"force_{m}"],
                lw=1.6 if i == 0 else 0.9,
                ls="-" if i == 0 else "--",
                color=c,
                label=m,
            )
    ax_p.set_ylabel("pressure (MPa)")
    ax_p.legend(fontsize=8, loc="upper right", ncol=2)
    if ax_f is not None:
        ax_f.set_ylabel("tension (N)")
        ax_f.legend(fontsize=8, loc="upper right")
    for ax in axes:
        ax.grid(alpha=0.3)
    axes[-1].set_xlabel("time (s" + (" from the reference's start)" if control else ")"))
    fig.suptitle(f"{pf.path.name}: run '{name}'")
    fig.tight_layout(rect=(0, 0.02, 1, 0.96))
    return fig


def pair_plan(paths: list[str]) -> ReportPlan:
    """The pair report's pages (both muscles' loops, then one page per run) for the
    antagonistic-pair run files ``paths``."""
    files = [load_pair_file(p) for p in paths]
    pages: list[tuple[str, Callable[[], Figure]]] = []
    for pf in files:
        stem = pf.path.stem
        if pf.muscles:
            pages.append((f"{stem}-muscles", lambda pf=pf: loops_figure(pf)))
        for name in pf.datasets:
            pages.append((f"{stem}-{name}", lambda pf=pf, name=name: run_figure(pf, name)))
    specs = [PageSpec(slug, slug, lambda i, n, make=make: make()) for slug, make in pages]
    return ReportPlan(specs, "pmalab antagonistic-pair report")


def build_pair_report(
    paths: Sequence[str | Path],
    out: str | Path,
    force: bool = False,
    *,
    png_dir: str | Path | None = None,
    svg_dir: str | Path | None = None,
    progress: Callable[[str], None] | None = None,
    bar: bool = False,
    jobs: int | None = None,
    start_method: str | None = None,
) -> Path:
    """Render the pair report of ``paths`` into ``out`` (a temporary file until complete).

    ``jobs`` worker processes render the pages (default: the CPUs this process may use;
    1 renders in this process); the PDF's pages are the same either way.
    """
    return write_plan(
        pair_plan,
        ([str(p) for p in paths],),
        out,
        force,
        png_dir=png_dir,
        svg_dir=svg_dir,
        progress=progress,
        bar=bar,
        jobs=jobs,
        start_method=start_method,
    )


__all__ = ["build_pair_report", "is_pair_file", "load_pair_file", "loops_figure", "run_figure"]
