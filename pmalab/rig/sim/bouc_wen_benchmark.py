"""The Bouc-Wen benchmark of Noël & Schoukens (2016), regenerated from its equations.

The system-identification field's hysteresis benchmark ("Hysteretic benchmark with a
dynamic nonlinearity", Workshop on nonlinear system identification benchmarks, 2016) is a
mass–spring–damper with a Bouc-Wen hysteretic force z::

    m·ÿ + c·ẏ + k·y + z = u,      ż = α·ẏ − β·(γ·|ẏ|·|z|^(ν−1)·z + δ·ẏ·|z|^ν)

with the published values m = 2 kg, c = 10 N·s/m, k = 5·10⁴ N/m, α = 5·10⁴ N/m,
β = 10³ m⁻¹, γ = 0.8, δ = −1.1, ν = 1; input u a force (N), output y a displacement (m),
sampled at 750 Hz, integrated at 20× that rate, output noise 8·10⁻⁶ m rms on the
training data, test outputs noise-free.  The ``nonlinear-benchmarks`` package downloads the
original files at run time (no network here), so this module integrates the equations
itself — independently of pmalab's models (no inverse crime: classical RK4 of the
time-domain equations at 15 kHz, the input evaluated exactly at every stage).

What the published description leaves open is our choice, stated here: random-phase
multisines with a flat amplitude spectrum on the 8192-sample grid's lines in 5–150 Hz,
50 N rms, one period of transient discarded (the record is steady state); training = two
periods of one realisation (16 384 samples), the multisine test = one period of another
realisation, the sweep test = a 40 N linear sine sweep 5 → 150 Hz at 5 Hz/s from rest.

Mapping to pmalab's run files (contraction positive, tension positive): the benchmark's
force u stretches the system, so pmalab's *contraction* is x = −y (mm) and its *tension*
is u (N).  Then u = m·ÿ + c·ẏ + k·y + z reads F = k'·x + h − m·ẍ − c'·ẋ, pmalab's base law
with inertia and viscous friction, with k' = −k, c' = c (N·s/mm), and h = z a Bouc-Wen law
of x with A = −α, β' = β·γ, γ' = −β·δ (per mm: A = −50 N/mm, β' = 0.8 /mm, γ' = 1.1 /mm).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from numba import njit

from pmalab.runfile import Run, write_runs

#: the published parameters (SI units)
PUBLISHED = {
    "m_kg": 2.0,
    "c_Ns_per_m": 10.0,
    "k_N_per_m": 5e4,
    "alpha_N_per_m": 5e4,
    "beta_per_m": 1e3,
    "gamma": 0.8,
    "delta": -1.1,
    "nu": 1.0,
}
#: the same system as a pmalab model (bouc-wen + inertia + viscous-friction), mm and N
AS_PMALAB = {
    "k": -50.0,
    "c0": 0.0,
    "A": -50.0,
    "beta": 0.8,
    "gamma": 1.1,
    "n": 1.0,
    "inertia_m": 2.0,
    "visc_c": 0.01,
}
FS_HZ = 750.0
UPSAMPLE = 20
PERIOD = 8192
BAND_HZ = (5.0, 150.0)
RMS_N = 50.0
NOISE_M = 8e-6
SWEEP = {"amplitude_N": 40.0, "f0_Hz": 5.0, "f1_Hz": 150.0, "rate_Hz_per_s": 5.0}
#: published rms simulation errors on the multisine test (m) and parameter counts
PUBLISHED_RESULTS = (
    ("linear state-space model (best linear approximation)", 1.6e-4, None),
    ("polynomial nonlinear state-space (PNLSS)", 1.2e-5, 217),
    ("neural state-space model", 7.5e-6, None),
)


@njit(cache=True, fastmath=False)
def _rhs(y, yd, z, u, m, c, k, al, be, ga, de, nu):
    az = abs(z)
    zn = az**nu if az > 0.0 else 0.0
    zn1 = az ** (nu - 1.0) if az > 0.0 else (1.0 if nu == 1.0 else 0.0)
    zd = al * yd - be * (ga * abs(yd) * zn1 * z + de * yd * zn)
    return yd, (u - k * y - c * yd - z) / m, zd


@njit(cache=True, fastmath=False)
def _rk4(u2, dt, m, c, k, al, be, ga, de, nu):
    """y at every step of a fixed-step RK4; ``u2`` holds the input at every half step."""
    n = (u2.shape[0] - 1) // 2
    out = np.empty(n + 1)
    y = 0.0
    yd = 0.0
    z = 0.0
    out[0] = 0.0
    for i in range(n):
        ua, um, ub = u2[2 * i], u2[2 * i + 1], u2[2 * i + 2]
        a1, b1, c1 = _rhs(y, yd, z, ua, m, c, k, al, be, ga, de, nu)
        a2, b2, c2 = _rhs(
            y + 0.5 * dt * a1,
            yd + 0.5 * dt * b1,
            z + 0.5 * dt * c1,
            um,
            m,
            c,
            k,
            al,
            be,
            ga,
            de,
            nu,
        )
        a3, b3, c3 = _rhs(
            y + 0.5 * dt * a2,
            yd + 0.5 * dt * b2,
            z + 0.5 * dt * c2,
            um,
            m,
            c,
            k,
            al,
            be,
            ga,
            de,
            nu,
        )
        a4, b4, c4 = _rhs(y + dt * a3, yd + dt * b3, z + dt * c3, ub, m, c, k, al, be, ga, de, nu)
        y += dt * (a1 + 2 * a2 + 2 * a3 + a4) / 6.0
        yd += dt * (b1 + 2 * b2 + 2 * b3 + b4) / 6.0
        z += dt * (c1 + 2 * c2 + 2 * c3 + c4) / 6.0
        out[i + 1] = y
    return out


def respond(u_half: np.ndarray, dt: float) -> np.ndarray:
    """The benchmark's displacement y (m) for an input given at every half step of ``dt``."""
    P = PUBLISHED
    return _rk4(
        np.ascontiguousarray(u_half, dtype=np.float64),
        float(dt),
        P["m_kg"],
        P["c_Ns_per_m"],
        P["k_N_per_m"],
        P["alpha_N_per_m"],
        P["beta_per_m"],
        P["gamma"],
        P["delta"],
        P["nu"],
    )


def multisine(seed: int, periods: int, fine: int) -> np.ndarray:
    """``periods`` periods of a random-phase multisine, ``fine`` points per 750 Hz sample
    (band-limited: exact between samples), scaled to :data:`RMS_N`."""
    rng = np.random.default_rng(seed)
    n = PERIOD * fine
    spec = np.zeros(n // 2 + 1, dtype=complex)
    f = np.arange(n // 2 + 1) * FS_HZ / PERIOD
    lines = np.flatnonzero((f >= BAND_HZ[0]) & (f <= BAND_HZ[1]))
    spec[lines] = np.exp(1j * rng.uniform(0.0, 2.0 * np.pi, lines.size))
    one = np.fft.irfft(spec, n)
    one *= RMS_N / float(np.std(one))
    return np.concatenate([np.tile(one, periods), one[:1]])


def sweep(fine: int) -> np.ndarray:
    """The linear sine sweep of :data:`SWEEP`, ``fine`` points per 750 Hz sample."""
    S = SWEEP
    T = (S["f1_Hz"] - S["f0_Hz"]) / S["rate_Hz_per_s"]
    n = int(round(T * FS_HZ)) * fine
    t = np.arange(n + 1) / (FS_HZ * fine)
    phase = 2.0 * np.pi * (S["f0_Hz"] * t + 0.5 * S["rate_Hz_per_s"] * t * t)
    return S["amplitude_N"] * np.sin(phase)


def _record(u_fine: np.ndarray, skip: int) -> tuple[np.ndarray, np.ndarray]:
    """(u, y) at 750 Hz after ``skip`` samples of transient; RK4 at 20×, half steps at 40×."""
    dt = 1.0 / (FS_HZ * UPSAMPLE)
    y = respond(u_fine, dt)
    step = 2 * UPSAMPLE  # fine points per 750 Hz sample (half steps)
    u = u_fine[::step]
    ys = y[::UPSAMPLE]
    return u[skip:], ys[skip:]


def _run(name: str, u: np.ndarray, y_m: np.ndarray, what: str) -> Run:
    n = u.shape[0]
    return Run(
        name=name,
        time=np.arange(n) / FS_HZ,
        position=-y_m * 1e3,
        force=u,
        muscle_pressure=np.zeros(n),
        attrs={
            "muscle_pressure_MPa": 0.0,
            "waveform": what,
            "frequency_Hz": BAND_HZ[1],
            "sample_rate_Hz": FS_HZ,
            "source": "Bouc-Wen benchmark (Noël & "
            "Schoukens 2016) regenerated by pmalab.rig.sim.bouc_wen_benchmark",
            "position_note": "contraction x = -y (benchmark displacement), mm",
        },
    )


def generate(out_dir: str | Path, seed: int = 0, force: bool = False) -> dict[str, Path]:
    """Write ``train.h5`` (noisy), ``test-multisine.h5`` and ``test-sweep.h5`` (noise-free)."""
    out = Path(out_dir)
    rng = np.random.default_rng(seed + 1000)
    fine = 2 * UPSAMPLE
    u, y = _record(multisine(seed, 3, fine), PERIOD)
    y_noisy = y + rng.normal(0.0, NOISE_M, y.shape)
    files = {}
    files["train"] = write_runs(
        out / "train.h5", [_run("multisine-train", u[:-1], y_noisy[:-1], "multisine")], force=force
    )
    u, y = _record(multisine(seed + 1, 2, fine), PERIOD)
    files["test-multisine"] = write_runs(
        out / "test-multisine.h5",
        [_run("multisine-test", u[:-1], y[:-1], "multisine")],
        force=force,
    )
    u, y = _record(sweep(fine), 0)
    files["test-sweep"] = write_runs(
        out / "test-sweep.h5", [_run("sweep-test", u, y, "sweep")], force=force
    )
    return files


def noise_floor_m() -> float:
    """The training output noise (m rms)."""
    return NOISE_M


def describe() -> str:
    P = PUBLISHED
    return (
        f"m={P['m_kg']} kg, c={P['c_Ns_per_m']} N s/m, k={P['k_N_per_m']:g} N/m, "
        f"alpha={P['alpha_N_per_m']:g} N/m, beta={P['beta_per_m']:g} 1/m, "
        f"gamma={P['gamma']}, delta={P['delta']}, nu={P['nu']}; fs={FS_HZ:g} Hz, "
        f"integration {UPSAMPLE}x, noise {NOISE_M:g} m rms (training)"
    )
