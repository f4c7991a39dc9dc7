"""Acquisition: protocols, the 500 Hz runner, safety interlocks, crash-proof recording.

Public API (the CLI verbs ``run``, ``import``, ``recover`` are thin wrappers)::

    from pmalab.acquisition import load_protocol, run_protocol, RunnerOptions
    proto = load_protocol("seed-bouc-wen")            # or a path; .select(roles=[...])
    with rig:                                         # pmalab.rig.loader.load_rig("sim")
        results = run_protocol(rig, proto, "x.h5", force=True,
                               options=RunnerOptions(progress=False))

Each run in the file carries the contract attrs plus ``role`` ("identification" |
"validation"), ``steady_start_s``/``steady_end_s`` (the full-amplitude cycles, s from the
run's time zero), ``sample_rate_Hz`` as recorded (lower than
``requested_sample_rate_Hz`` on a reduced-rate rig) and, via
:func:`pmalab.runfile.read_runs`, ``status``, ``timing`` and ``device_stats`` (dict).
Modules: :mod:`.protocol` (TOML), :mod:`.waveforms` (commands), :mod:`.safety`,
:mod:`.recorder` (SWMR HDF5 writer), :mod:`.runner`, :mod:`.csv_import`, :mod:`.recover`,
:mod:`.live` (``run --live`` and ``view``: the live page; the runner sees it only as a
``RunnerOptions.observer``).
"""

from __future__ import annotations

from pmalab.lazy import lazy_exports

# names are imported on first use: every ``pmalab`` verb registers its options through
# ``pmalab.acquisition.cli``, and ``pmalab identify`` should not pay for the runner (numpy,
# h5py, the rig interface) before it starts
__getattr__, __all__ = lazy_exports(
    __name__,
    {
        "Protocol": "pmalab.acquisition.protocol",
        "RunSpec": "pmalab.acquisition.protocol",
        "load_protocol": "pmalab.acquisition.protocol",
        "parse_protocol": "pmalab.acquisition.protocol",
        "RunnerOptions": "pmalab.acquisition.runner",
        "RunResult": "pmalab.acquisition.runner",
        "run_protocol": "pmalab.acquisition.runner",
    },
)
