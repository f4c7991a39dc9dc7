"""``load_rig(spec)``: a rig from ``"sim"`` or from a rig TOML file.

A rig file::

    [rig]
    kind = "sim"                 # a key of RIG_KINDS
    truth = "../truth/x.toml"    # sim only: truth file, relative to this rig file
    seed = 0                     # sim only: sensor-noise seed
    manual_muscle_regulator = false

    [limits]                     # optional: overrides pmalab.rig.base.Limits fields
    max_force_N = 1800

Each kind is a factory in :data:`RIG_KINDS`, ``factory(section, rig_file, *, seed, clock)
-> Rig`` where ``section`` is the ``[rig]`` table (minus ``kind``) and ``rig_file`` the
file's path (``None`` for the bare ``"sim"`` spec); the device-driver module registers its
kinds with one line: ``RIG_KINDS.register("modbus", make_modbus_rig, title=..., order=...)``
(:class:`pmalab.registry.Registry`, the mechanism laws, effects and controllers use too).
Factories report mistakes as one-line :class:`~pmalab.errors.ConfigError` naming the file
and field.  :func:`load_rig` then applies ``[limits]`` and records the file's text in
``rig.info["rig_file_text"]``.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

from pmalab.config import check_keys, load_toml
from pmalab.errors import ConfigError
from pmalab.paths import RIGS_DIR, shipped, shipped_names
from pmalab.registry import Registry
from pmalab.rig.base import Clock, Rig
from pmalab.rig.drivers import make_modbus_rig, make_nidaq_rig, make_t7_stream_rig
from pmalab.rig.drivers.rigfile import override_transport

RigFactory = Callable[..., Rig]


def _make_sim(
    section: dict[str, Any],
    rig_file: Path | None,
    *,
    seed: int | None = None,
    clock: Clock | None = None,
) -> Rig:
    from pmalab.rig.sim import make_sim_rig

    where = str(rig_file) if rig_file is not None else "sim"
    allowed = {"truth", "seed", "manual_muscle_regulator"}
    check_keys(
        section,
        allowed,
        "{where}: rig.{key}: unknown key for kind 'sim' (known: {known})",
        known=["kind", *sorted(allowed)],
        where=where,
    )
    truth = section.get("truth")
    truth_path: Path | None = None
    if truth is not None:
        if not isinstance(truth, str) or not truth:
            raise ConfigError(f"{where}: rig.truth: must be a path (text)")
        truth_path = Path(truth)
        if not truth_path.is_absolute() and rig_file is not None:
            truth_path = rig_file.parent / truth_path
        if not truth_path.exists():
            raise ConfigError(f"{where}: rig.truth: file not found: {truth_path}")
    seed = _sim_seed(section, where, seed)
    manual = section.get("manual_muscle_regulator", False)
    if not isinstance(manual, bool):
        raise ConfigError(f"{where}: rig.manual_muscle_regulator: must be true or false")
    return make_sim_rig(truth_path, seed=seed, clock=clock, manual_muscle_regulator=manual)


def _truth_path(
    section: dict[str, Any], key: str, rig_file: Path | None, where: str
) -> Path | None:
    """A ``[rig]`` truth-file field as a path (relative to the rig file), checked."""
    truth = section.get(key)
    if truth is None:
        return None
    if not isinstance(truth, str) or not truth:
        raise ConfigError(f"{where}: rig.{key}: must be a path (text)")
    path = Path(truth)
    if not path.is_absolute() and rig_file is not None:
        path = rig_file.parent / path
    if not path.exists():
        raise ConfigError(f"{where}: rig.{key}: file not found: {path}")
    return path


def _make_sim_pair(
    section: dict[str, Any],
    rig_file: Path | None,
    *,
    seed: int | None = None,
    clock: Clock | None = None,
) -> Rig:
    """The simulated antagonistic joint: ``flexor_truth``/``extensor_truth`` (truth files),
    ``seed`` and any :class:`~pmalab.rig.sim.pair.PairSpec` field (radius_mm,
    inertia_kg_m2, damping_N_m_s_per_rad, spring_N_m_per_rad, ...)."""
    from dataclasses import fields

    from pmalab.errors import RigError
    from pmalab.rig.sim.pair import PairSpec, make_sim_pair

    where = str(rig_file) if rig_file is not None else "sim-pair"
    spec_keys = {f.name for f in fields(PairSpec)}
    allowed = {"flexor_truth", "extensor_truth", "seed", *spec_keys}
    check_keys(
        section,
        allowed,
        "{where}: rig.{key}: unknown key for kind 'sim-pair' (known: {known})",
        known=["kind", *sorted(allowed)],
        where=where,
    )
    values = {}
    for k in spec_keys & set(section):
        v = section[k]
        if isinstance(v, bool) or not isinstance(v, int | float):
            raise ConfigError(f"{where}: rig.{k}: must be a number")
        values[k] = float(v)
    try:
        spec = PairSpec(**values).checked()
    except RigError as exc:
        raise ConfigError(f"{where}: rig.{str(exc).removeprefix('pair: ')}") from None
    seed = _sim_seed(section, where, seed)
    return make_sim_pair(
        _truth_path(section, "flexor_truth", rig_file, where),
        _truth_path(section, "extensor_truth", rig_file, where),
        spec=spec,
        seed=seed,
        clock=clock,
    )


def _sim_seed(section: dict[str, Any], where: str, seed: int | None) -> int:
    """A simulated rig's noise seed: an explicit one (``pmalab run --seed``) beats the rig
    file's ``seed`` key, which must be an integer ≥ 0; 0 when neither is given."""
    if "seed" in section:
        s = section["seed"]
        if isinstance(s, bool) or not isinstance(s, int) or s < 0:
            raise ConfigError(f"{where}: rig.seed: must be an integer ≥ 0")
        if seed is None:
            seed = s
    return 0 if seed is None else seed


def _make_sim_static(
    section: dict[str, Any],
    rig_file: Path | None,
    *,
    seed: int | None = None,
    clock: Clock | None = None,
) -> Rig:
    """The simulated static stand (:mod:`pmalab.rig.sim.static_rig`): ``truth`` (a static
    truth file, relative to the rig file) and ``seed``."""
    from pmalab.rig.sim.static_rig import make_static_rig

    where = str(rig_file) if rig_file is not None else "sim-static"
    check_keys(
        section,
        {"truth", "seed"},
        "{where}: rig.{key}: unknown key for kind 'sim-static' (known: {known})",
        known=["kind", "seed", "truth"],
        where=where,
    )
    seed = _sim_seed(section, where, seed)
    return make_static_rig(
        _truth_path(section, "truth", rig_file, where),
        seed=seed,
        clock=clock,
    )


#: rig kind → factory(section, rig_file, *, seed, clock) -> Rig
#: every rig-file ``kind`` → its factory; a backend is one file plus one line here
RIG_KINDS: Registry[RigFactory] = Registry("rig kind", ConfigError)
RIG_KINDS.register("sim", _make_sim, title="the physics-based simulated rig", order=1)
RIG_KINDS.register(
    "modbus",
    make_modbus_rig,
    order=2,
    title="Modbus TCP/RTU analog I/O, SMC ITV on RS-232C, load-cell indicators",
)
RIG_KINDS.register(
    "nidaqmx", make_nidaq_rig, order=3, title="an NI DAQ card under NI-DAQmx (hardware-timed)"
)
RIG_KINDS.register(
    "sim-pair",
    _make_sim_pair,
    order=1.5,
    title="a simulated antagonistic joint: two muscles on a pulley, each on its own regulator",
)
RIG_KINDS.register(
    "sim-static",
    _make_sim_static,
    order=1.7,
    title="a simulated static stand: a commanded muscle regulator, a clamp or a hanging mass",
)
RIG_KINDS.register(
    "labjack-t7-stream",
    make_t7_stream_rig,
    order=4,
    title="a LabJack T7 streaming on its own clock over Modbus TCP",
)


#: rig kind → how ``--host/--port`` rewrite its ``[rig]`` table (kinds with a network link)
TRANSPORT_OVERRIDES: dict[str, Callable[..., dict[str, Any]]] = {
    "modbus": override_transport,
    "labjack-t7-stream": override_transport,
}


def load_rig(
    spec: str | Path,
    *,
    seed: int | None = None,
    clock: Clock | None = None,
    host: str | None = None,
    port: int | None = None,
) -> Rig:
    """A rig from ``"sim"``, a shipped rig's name or a rig TOML path.

    Parameters
    ----------
    spec
        ``"sim"`` (the default simulated rig), the name of a shipped rig file
        (``"sim-viscous-friction"``, ``"labjack-t7"``, ...) or the path of a rig TOML file.
    seed
        Simulated rigs: the sensor-noise seed, an integer ≥ 0, overriding the rig file's
        ``seed``; ``None`` keeps the file's (default 0).
    clock
        The clock the rig runs on; ``None``: a simulated rig's virtual clock (faster than
        real time), the wall clock for hardware.
    host, port
        Replace a network rig's endpoint (``pmalab run --host/--port``, e.g. the port
        ``pmalab emulate --port`` uses).

    Returns
    -------
    Rig
        The rig; use it as a context manager (``with load_rig(...) as rig:``): leaving it
        vents the regulators and closes the devices.

    Raises
    ------
    pmalab.errors.ConfigError
        One line naming file and field: an unknown name or kind (listing the shipped
        choices), a bad field, an implausible calibration.
    """
    override = host is not None or port is not None
    if str(spec) == "sim":
        if override:
            raise ConfigError("--host/--port: the simulated rig 'sim' has no network link")
        rig = RIG_KINDS["sim"]({}, None, seed=seed, clock=clock)
        rig.info.setdefault("rig_file", "sim")
        return rig
    path = shipped(spec, RIGS_DIR)  # a shipped rig's name or clone path works anywhere
    where = str(spec)
    names = ", ".join(dict.fromkeys(["sim", *shipped_names(RIGS_DIR)]))
    doc, text = load_toml(
        path, "rig file", hint=f" (give a rig TOML file or a shipped rig: {names})"
    )
    check_keys(
        doc, ("rig", "limits"), "{where}: {key}: unknown section (known: rig, limits)", where=where
    )
    section = doc.get("rig")
    if not isinstance(section, dict):
        raise ConfigError(f"{where}: rig: missing [rig] table with kind = ...")
    section = dict(section)
    kind = section.pop("kind", None)
    if kind is None:
        raise ConfigError(f"{where}: rig.kind: missing (known: {', '.join(sorted(RIG_KINDS))})")
    if kind not in RIG_KINDS:
        raise ConfigError(
            f"{where}: rig.kind: unknown kind {kind!r} (known: {', '.join(sorted(RIG_KINDS))})"
        )
    if override:
        if kind not in TRANSPORT_OVERRIDES:
            raise ConfigError(
                f"--host/--port: {where} is a rig of kind {kind!r}, which has no "
                "network link (they apply to Modbus TCP rig files)"
            )
        section = TRANSPORT_OVERRIDES[kind](section, where, host=host, port=port)
    rig = RIG_KINDS[kind](section, path, seed=seed, clock=clock)
    if "limits" in doc:
        rig.limits = rig.limits.updated(doc["limits"], where)
    rig.info["rig_file"] = str(path)
    rig.info["rig_file_text"] = text
    return rig
