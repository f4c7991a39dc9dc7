"""Start state after the ramp-in: element laws on their own identification runs, by part.

A recorded run starts with a settle (the muscle contracted to rest) and a ramp-in; its
steady window begins where the ramp-in ends.  On fast runs (1.3 Hz and more with the
0.5 s ramp of ``data/protocols/laws-pressure.toml``) the ramp-in stretches the muscle by
4–6 mm and then turns back for 0.5–1.5 mm before the window opens, so the braid's
hysteretic state at the window's first sample is inside a minor loop: its small elements
follow the last short move, its large ones still hold the ramp-in's stretch.  An element
law's start state is one number h0 on a branch of the major loop
(:func:`pmalab.identify.laws._slide.slide_start`), which cannot express that; the misfit
lasts until the stroke has wiped the large elements, about the first half cycle.

For the element laws (Maxwell-slip, Prandtl-Ishlinskii) identified jointly on
``data/truth/laws/pi-rising-profile.toml`` (whose weights rise with the threshold, so the
large elements carry most of the friction) and ``pi-scaled-profile.toml``, this prints each
law's error on the runs it was identified on (every muscle parameter from its pressure
laws), as rms ÷ the run's noise σ, on the first half excitation cycle and on the rest,
averaged per frequency, with three start states:

* *now*: h0 and the force zero c0 fitted on the whole run (:func:`estimate_record`);
* *two reversals*: the state after a long move along the run's first motion, u1 mm
  against it and u2 mm back (the best of a grid; c0 refitted) — the family a ramp-in
  produces;
* *lead-in*: the state replayed along the recorded settle and ramp-in (the samples before
  ``steady_start_s``) from saturation by a contraction (the settle), nothing fitted but c0.

The identification itself is unchanged: the joint fits are those of ``pmalab identify``,
made with the start state *now*, so they carry its bias.  ``python -m bench lead_in``;
``PMALAB_BENCH_SEEDS=N`` seeds per case (default 2).
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import numpy as np
from numba import njit

from bench.bench_laws import campaign
from bench.table import print_table
from pmalab.paths import PROTOCOLS_DIR, TRUTH_DIR

CASES = ("laws/pi-rising-profile.toml", "laws/pi-scaled-profile.toml")
LAWS = ("maxwell-slip", "prandtl-ishlinskii")
#: grid of the two-reversal start state: u1 (mm, 1e3 = a long move: the branch start) and
#: u2 (mm, ≤ u1)
U1 = np.r_[np.geomspace(0.2, 12.0, 24), 1e3]
U2 = np.r_[0.0, np.geomspace(0.05, 4.0, 16)]


@njit(cache=True)
def _walk(z: np.ndarray, dx: float, k: np.ndarray, f: np.ndarray) -> None:
    """Elasto-slide elements (force z, N) moved by dx (mm), in place."""
    for i in range(z.shape[0]):
        zi = z[i] - k[i] * dx
        fi = abs(f[i])
        z[i] = fi if zi > fi else (-fi if zi < -fi else zi)


@njit(cache=True)
def _h_path(x: np.ndarray, k: np.ndarray, f: np.ndarray, z0: np.ndarray) -> np.ndarray:
    """h = Σ z_i (N) along the path ``x`` (mm) from the element forces ``z0``."""
    z = z0.copy()
    h = np.empty(x.shape[0])
    h[0] = z.sum()
    for j in range(x.shape[0] - 1):
        _walk(z, x[j + 1] - x[j], k, f)
        h[j + 1] = z.sum()
    return h


def _two_reversals(k: np.ndarray, f: np.ndarray, s: float, u1: float, u2: float) -> np.ndarray:
    """Element forces after a long move along ``s`` (+1: contracting), u1 mm against it and
    u2 mm along it again."""
    z = -s * np.abs(f)
    _walk(z, -s * u1, k, f)
    _walk(z, s * u2, k, f)
    return z


def _lead_in(x_lead: np.ndarray, k: np.ndarray, f: np.ndarray) -> np.ndarray:
    """Element forces at the end of the recorded lead-in ``x_lead`` (mm), from saturation
    by a contraction (the settle: the muscle contracted to rest)."""
    z = -np.abs(f)
    for j in range(x_lead.shape[0] - 1):
        _walk(z, x_lead[j + 1] - x_lead[j], k, f)
    return z


def run_parts(cf, run) -> dict[str, tuple[float, float]]:
    """{start: (first half cycle, rest)} rms error ÷ noise σ of ``cf``'s model on ``run``."""
    from pmalab.identify.estimation.records import estimate_record
    from pmalab.identify.laws._slide import first_direction
    from pmalab.identify.noise import noise_sigma
    from pmalab.identify.signals import Signals

    st = run.steady()
    rel = run.time - run.time[0]
    x_lead = np.asarray(run.position, float)[rel <= float(run.attrs["steady_start_s"]) + 1e-9]
    force = np.asarray(st.force, float)
    sig = Signals.from_run(st)
    sd = noise_sigma(force, st.time)
    early = (st.time - st.time[0]) < 0.5 / float(st.frequency)
    th = estimate_record(cf.model, sig, force, cf.theta(sig.p_nom), cf.bounds, cf.record_prior())
    pred = cf.model.predict(sig, th)
    law = cf.model.law
    kk, dd = law.elements(th)
    k, f = np.ascontiguousarray(kk, float), np.ascontiguousarray(kk * dd, float)
    rest = pred - law.h(sig.x, th)  # static part, effects and c0

    def parts(e: np.ndarray) -> tuple[float, float]:
        return (float(np.sqrt(np.mean(e[early] ** 2)) / sd),
                float(np.sqrt(np.mean(e[~early] ** 2)) / sd))

    out = {"now": parts(force - pred)}
    x = np.ascontiguousarray(sig.x, float)
    s0 = float(first_direction(x))
    best, best_e = np.inf, force - pred
    for s in (s0, -s0):
        for u1 in U1:
            for u2 in U2[U2 <= u1]:
                e = force - rest - _h_path(x, k, f, _two_reversals(k, f, s, u1, u2))
                e = e - e.mean()  # c0 refitted
                c = float(e @ e)
                if c < best:
                    best, best_e = c, e
    out["two reversals"] = parts(best_e)
    z = _lead_in(x_lead, k, f)
    e = force - rest - _h_path(np.r_[x_lead[-1], x], k, f, z)[1:]
    out["lead-in"] = parts(e - e.mean())
    return out


def main() -> None:
    from pmalab.identify.api import identify
    from pmalab.runfile import read_runs

    seeds = int(os.environ.get("PMALAB_BENCH_SEEDS", "2"))
    starts = ("now", "two reversals", "lead-in")
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        for name in CASES:
            for seed in range(7, 7 + seeds):
                c = campaign(TRUTH_DIR / name, PROTOCOLS_DIR / "laws-pressure.toml", seed, work)
                runs = [r for r in read_runs(c) if r.attrs.get("role") == "identification"]
                for law in LAWS:
                    cf = identify(read_runs(c), law, jobs=2).campaign
                    by_f: dict[float, list[dict[str, tuple[float, float]]]] = {}
                    for r in runs:
                        by_f.setdefault(float(r.frequency), []).append(run_parts(cf, r))
                    for fr, parts in sorted(by_f.items()):
                        cells = [
                            " / ".join(f"{np.mean([p[s][i] for p in parts]):.2f}" for s in starts)
                            for i in (0, 1)
                        ]
                        worst = max(p["now"][0] for p in parts)
                        rows.append((Path(name).stem, seed, law, f"{fr:g}", len(parts), *cells,
                                     f"{worst:.2f}"))
    print("element laws on their own identification runs (rms ÷ noise σ), by part of the run;"
          " start: now / two reversals / lead-in")
    print_table(("truth (data/truth/laws)", "seed", "law", "Hz", "runs",
                 "first half cycle", "rest", "first half, worst run now"), rows)


if __name__ == "__main__":
    main()
