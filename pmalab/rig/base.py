"""The rig interface: what a test protocol needs from a rig, and no more.

Units and signs (docs/explanation/physics.md): time s, position mm (contraction, positive = shorter than the
nominal length), force N (tension), pressures MPa gauge.

A rig is four things:

* a :class:`Clock` — real time, or virtual time that jumps to any deadline at once so a
  simulated run goes as fast as the physics allows;
* a :class:`Sampler` delivering timestamped :class:`Block` s of the five channels.  A
  hardware-timed DAQ returns buffered blocks at its own pace (``hardware_timed = True``);
  a software-polled backend returns a block of one sample per call, and the runner decides
  when to call it (absolute deadlines on the rig's clock);
* a :class:`PressureRegulator` for the cylinder's proportional regulator (setpoint MPa);
* a :class:`MusclePressureSupply` — a second regulator (``automatic``) or a manual one
  that the operator turns when prompted.

Venting is reported, never assumed: ``vent()`` returns a :class:`VentResult` saying whether
the zero command was *confirmed* by the device (acknowledged, and read back where the
device allows), *failed* (with the reason), or is *manual* (a hand-set regulator software
cannot vent); :meth:`Rig.vent` collects both into a :class:`VentReport` whose one-line
:meth:`~VentReport.line` tells the operator what to do when a vent was not confirmed.

Implementations: :mod:`pmalab.rig.sim` (simulated physics), :mod:`pmalab.rig.drivers`
(Modbus / serial devices).  The runner in :mod:`pmalab.acquisition` only sees this module.
"""

from __future__ import annotations

import dataclasses
import math
import time as _time
from abc import ABC, abstractmethod
from collections.abc import Callable
from dataclasses import dataclass, field
from enum import Enum
from typing import Any

import numpy as np

from pmalab.channels import STANDARD_CHANNELS, Channels
from pmalab.config import check_keys
from pmalab.errors import ConfigError
from pmalab.runfile import CANONICAL_UNITS

#: the five channels a single-muscle sampler delivers, in this order, with their units
CHANNELS: tuple[str, ...] = (
    "time",
    "position",
    "force",
    "muscle_pressure",
    "cylinder_pressure",
)
#: channel → unit; the run file's canonical units are the one source (pmalab.runfile)
CHANNEL_UNITS: dict[str, str] = CANONICAL_UNITS
#: the single-muscle isobaric rig's declaration (:mod:`pmalab.channels`): the five sampled
#: channels and the cylinder command the runner records beside them
SINGLE_MUSCLE_CHANNELS: Channels = Channels(STANDARD_CHANNELS)


def sampled(channels: Channels) -> tuple[str, ...]:
    """The channels a sampler delivers besides ``time`` (commands are the runner's)."""
    return tuple(c.name for c in channels if c.kind not in ("time", "command"))


# --------------------------------------------------------------------------- clocks
class Clock(ABC):
    """Monotonic time in seconds since the clock was created."""

    virtual: bool = False

    @abstractmethod
    def now(self) -> float: ...

    @abstractmethod
    def sleep_until(self, t: float) -> None:
        """Return at (or just after) time ``t``; return at once if ``t`` has passed."""


class RealClock(Clock):
    """Wall-clock time from ``time.perf_counter``.

    ``sleep_until`` sleeps until ``spin_s`` before the deadline and then spins, which keeps
    the lateness of a 500 Hz loop well under a millisecond on an idle Linux machine.
    """

    virtual = False

    def __init__(self, spin_s: float = 0.0015) -> None:
        self._t0 = _time.perf_counter()
        self.spin_s = spin_s

    def now(self) -> float:
        return _time.perf_counter() - self._t0

    def sleep_until(self, t: float) -> None:
        remaining = t - self.now()
        if remaining > self.spin_s:
            _time.sleep(remaining - self.spin_s)
        while self.now() < t:
            pass


class VirtualClock(Clock):
    """Simulated time: ``sleep_until`` jumps straight to the deadline."""

    virtual = True

    def __init__(self, start: float = 0.0) -> None:
        self._t = float(start)

    def now(self) -> float:
        return self._t

    def sleep_until(self, t: float) -> None:
        if t > self._t:
            self._t = float(t)

    def advance(self, dt: float) -> None:
        self._t += float(dt)


# --------------------------------------------------------------------------- data
@dataclass
class Block:
    """Consecutive samples of a rig's channels (1-D arrays of equal length).

    ``time`` is each sample's actual timestamp on the rig's clock, in s.  A single-muscle
    rig fills the five named fields; a rig declaring other channels (a second muscle, a
    joint angle) delivers them in ``extra`` by name, and fills the named fields it does not
    have with zeros.  :meth:`column` finds either.
    """

    time: np.ndarray
    position: np.ndarray
    force: np.ndarray
    muscle_pressure: np.ndarray
    cylinder_pressure: np.ndarray
    extra: dict[str, np.ndarray] = field(default_factory=dict)

    def __len__(self) -> int:
        return int(self.time.shape[0])

    def column(self, name: str) -> np.ndarray:
        """The samples of one channel.

        Parameters
        ----------
        name
            A named field (``position``, ``force``, ...) or a channel in ``extra``.

        Returns
        -------
        numpy.ndarray
            Its samples, in the channel's unit (position mm contraction positive, force N
            tension positive, pressures MPa gauge, or as the rig declares it).
        """
        col = self.extra.get(name)
        return col if col is not None else getattr(self, name)

    @classmethod
    def of(cls, time: np.ndarray, columns: dict[str, np.ndarray]) -> Block:
        """A block of any declared channels.

        Parameters
        ----------
        time
            Each sample's timestamp on the rig's clock, s.
        columns
            The channels by name; the single-muscle fields it lacks are zeros (never read
            by a loop that iterates the rig's declaration), the rest go to ``extra``.

        Returns
        -------
        Block
            The block.
        """
        z = np.zeros_like(time)
        named = ("position", "force", "muscle_pressure", "cylinder_pressure")
        return cls(
            time,
            *(columns.get(n, z) for n in named),
            extra={k: v for k, v in columns.items() if k not in named},
        )

    @classmethod
    def single(
        cls,
        t: float,
        position: float,
        force: float,
        muscle_pressure: float,
        cylinder_pressure: float,
    ) -> Block:
        a = np.array
        return cls(a([t]), a([position]), a([force]), a([muscle_pressure]), a([cylinder_pressure]))


#: the largest magnitude a rig file's ``[limits]`` may give: a McKibben muscle is rated
#: 0.6 MPa and proportional regulators 0.9 MPa (1.2 MPa is beyond any such rig), a DMSP
#: muscle pulls at most ~1.5 kN (20 kN is a load cell's range, never a muscle's), and a
#: muscle of a few hundred mm contracts by a quarter of its length (500 mm)
PHYSICAL_LIMITS = {
    "max_muscle_pressure_MPa": 1.2,
    "max_cylinder_pressure_MPa": 1.2,
    "max_force_N": 20e3,
    "min_position_mm": 500.0,
    "max_position_mm": 500.0,
}


@dataclass
class Limits:
    """Safety limits enforced by the runner on every sample (from the rig file).

    A sample beyond any of them aborts the run: the runner vents the regulators and closes
    the file with the samples so far.  Pressures are MPa gauge, force N (tension), position
    mm (contraction positive; a negative minimum allows a little stretch past nominal).
    """

    max_muscle_pressure_MPa: float = 0.6
    max_cylinder_pressure_MPa: float = 0.9
    max_force_N: float = 2000.0
    min_position_mm: float = -5.0
    max_position_mm: float = 35.0

    def updated(self, table: Any, where: str) -> Limits:
        """A copy with the fields of a rig file's ``[limits]`` table.

        Parameters
        ----------
        table
            The ``[limits]`` table (field → number, in the fields' units).
        where
            The file, named in any error.

        Returns
        -------
        Limits
            The limits, each checked: a number, > 0 where it must be, min < max, and
            within :data:`PHYSICAL_LIMITS` (beyond is a unit mistake).

        Raises
        ------
        pmalab.errors.ConfigError
            One line naming ``where`` and the field.
        """
        if not isinstance(table, dict):
            raise ConfigError(f"{where}: limits: must be a table")
        names = {f.name for f in dataclasses.fields(Limits)}
        values = dataclasses.asdict(self)
        check_keys(
            table, names, "{where}: limits.{key}: unknown limit (known: {known})", where=where
        )
        for key, v in table.items():
            if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
                raise ConfigError(f"{where}: limits.{key}: must be a number")
            values[key] = float(v)
        if values["min_position_mm"] >= values["max_position_mm"]:
            raise ConfigError(f"{where}: limits.min_position_mm: must be < limits.max_position_mm")
        for key in ("max_muscle_pressure_MPa", "max_cylinder_pressure_MPa", "max_force_N"):
            if values[key] <= 0:
                raise ConfigError(f"{where}: limits.{key}: must be > 0")
        for key, hi in PHYSICAL_LIMITS.items():
            v = values[key]
            if abs(v) > hi:
                raise ConfigError(
                    f"{where}: limits.{key} = {v:g}: beyond what any PMA rig reaches "
                    f"(|value| ≤ {hi:g}); a unit mistake?"
                )
        return Limits(**values)


# --------------------------------------------------------------------------- venting
class VentOutcome(Enum):
    """What a vent command achieved, as far as the device lets software know."""

    #: the device acknowledged the zero command (and read it back where it can)
    CONFIRMED = "confirmed"
    #: not confirmed: the command was not acknowledged, or the read-back is not zero
    FAILED = "failed"
    #: a hand-set regulator: software cannot vent it, the operator must
    MANUAL = "manual"


@dataclass(frozen=True)
class VentResult:
    """The outcome of one ``vent()`` and, in ``detail``, how it was confirmed or why not
    (one line, e.g. ``"write acknowledged, register 1000 reads back 0 V"``)."""

    outcome: VentOutcome
    detail: str = ""

    @classmethod
    def confirmed(cls, detail: str) -> VentResult:
        return cls(VentOutcome.CONFIRMED, detail)

    @classmethod
    def failed(cls, detail: str) -> VentResult:
        return cls(VentOutcome.FAILED, detail)

    @classmethod
    def manual(cls, detail: str = "set by hand") -> VentResult:
        return cls(VentOutcome.MANUAL, detail)

    @property
    def ok(self) -> bool:
        return self.outcome is VentOutcome.CONFIRMED


#: what the operator must do when a regulator's vent is not confirmed, per role
VENT_ACTIONS: dict[str, str] = {
    "cylinder regulator": "close the cylinder's supply valve and exhaust the cylinder by hand",
    "muscle regulator": "close the muscle's supply valve and exhaust the muscle by hand",
    "flexor regulator": "close the flexor's supply valve and exhaust it by hand",
    "extensor regulator": "close the extensor's supply valve and exhaust it by hand",
}
MANUAL_ACTION = "turn it to 0 MPa and exhaust the muscle"


def vent_phrase(role: str, res: VentResult) -> str:
    """``role`` and its vent outcome in words, with the operator's action when needed."""
    if res.outcome is VentOutcome.CONFIRMED:
        return f"{role} vented (confirmed: {res.detail})" if res.detail else f"{role} vented"
    if res.outcome is VentOutcome.MANUAL:
        return f"{role} is manual and NOT vented by software: {MANUAL_ACTION}"
    why = f" ({res.detail})" if res.detail else ""
    return f"{role} vent FAILED{why}: {VENT_ACTIONS.get(role, 'vent it by hand')}"


@dataclass(frozen=True)
class VentReport:
    """The vent outcome of each of the rig's regulators (cylinder first, then muscle)."""

    cylinder: VentResult
    muscle: VentResult
    #: how the two regulators are named (a pair of muscles: each muscle's regulator)
    roles: tuple[str, str] = ("cylinder regulator", "muscle regulator")

    @property
    def items(self) -> tuple[tuple[str, VentResult], ...]:
        return ((self.roles[0], self.cylinder), (self.roles[1], self.muscle))

    @property
    def failed(self) -> list[str]:
        """Roles whose vent was attempted and not confirmed."""
        return [role for role, r in self.items if r.outcome is VentOutcome.FAILED]

    @property
    def ok(self) -> bool:
        """True when no vent failed (a manual regulator is the operator's, not a failure)."""
        return not self.failed

    def merged(self, later: VentReport) -> VentReport:
        """Combine two vent attempts (e.g. the abort's and the closing one).

        Parameters
        ----------
        later
            The later attempt.

        Returns
        -------
        VentReport
            Per regulator, the confirmed one of the two outcomes, else the later.
        """

        def pick(a: VentResult, b: VentResult) -> VentResult:
            return a if a.ok and not b.ok else b

        return VentReport(
            pick(self.cylinder, later.cylinder), pick(self.muscle, later.muscle), self.roles
        )

    def line(self) -> str:
        """Every regulator's outcome in words, ``; ``-separated.

        Returns
        -------
        str
            One line, e.g. ``cylinder regulator vented (confirmed: ...); muscle regulator
            is manual and NOT vented by software: ...``; a failed vent names what the
            operator must do.
        """
        return "; ".join(vent_phrase(role, r) for role, r in self.items)


#: confirms a vent already commanded (may wait for a read-back) and returns its outcome
VentConfirm = Callable[[], VentResult]


def _raised(what: str, exc: Exception) -> VentResult:
    text = " ".join(str(exc).split()) or type(exc).__name__
    return VentResult.failed(f"{what} raised {type(exc).__name__}: {text}")


def vent_safely(vent: Callable[[], Any], what: str = "vent()") -> VentResult:
    """Call a ``vent`` and return its :class:`VentResult`; an exception or a missing
    result (a driver that does not report) is a FAILED vent, never a silent success."""
    try:
        res = vent()
    except Exception as exc:
        return _raised(what, exc)
    if not isinstance(res, VentResult):
        return VentResult.failed(f"{what} reported no outcome")
    return res


def start_vent_safely(device: Any, what: str) -> VentConfirm:
    """Phase one of a vent: command zero now (``device.start_vent()``, or ``vent()`` for
    an object without it) and return the confirmation; never raises."""
    start = getattr(device, "start_vent", None)
    if not callable(start):
        return lambda: vent_safely(device.vent, f"{what} vent()")
    try:
        confirm = start()
    except Exception as exc:
        res = _raised(f"{what} vent()", exc)
        return lambda: res
    if not callable(confirm):
        return lambda: vent_safely(lambda: confirm, f"{what} vent()")
    return lambda: vent_safely(confirm, f"{what} vent()")


# --------------------------------------------------------------------------- devices
class Sampler(ABC):
    """Delivers timestamped blocks of the five channels."""

    #: True for a DAQ that samples on its own hardware clock and buffers
    hardware_timed: bool = False
    #: the rate the sampler was configured for (Hz)
    sample_rate_Hz: float = 500.0
    #: (low, high) Hz for a sampler that programs its own clock to the protocol's rate in
    #: :meth:`configure`; None: a hardware-timed sampler runs at ``sample_rate_Hz`` only
    rate_range_Hz: tuple[float, float] | None = None

    def configure(self, rate_Hz: float) -> None:  # noqa: B027 - optional hook
        """Set the rate the next :meth:`start` samples at.

        The runner calls this with the protocol's rate before starting: a hardware-timed
        sampler programs its sample clock; a software-polled one is paced by the runner and
        may ignore it.

        Parameters
        ----------
        rate_Hz
            The sample rate, Hz (500 for pmalab's protocols).
        """

    def start(self) -> None:  # noqa: B027 - optional hook
        """Begin acquisition (hardware-timed samplers start their clock here)."""

    def stop(self) -> None:  # noqa: B027 - optional hook
        """End acquisition."""

    @abstractmethod
    def read_block(self) -> Block:
        """Return the next samples (at least one).

        Software-polled samplers take one sample now and return a block of one;
        hardware-timed samplers wait for and return what the device has buffered.

        Returns
        -------
        Block
            The samples in engineering units (calibrated): time s on the rig's clock,
            position mm (contraction positive), force N (tension positive), pressures MPa
            gauge.

        Raises
        ------
        pmalab.errors.RigError
            A device fault that retries did not fix (the runner then vents and aborts).
        """


class PressureRegulator(ABC):
    """A proportional pressure regulator (e.g. SMC ITV1050: 0–0.9 MPa)."""

    max_pressure_MPa: float = 0.9

    @abstractmethod
    def set_pressure(self, mpa: float) -> None:
        """Command a pressure.

        Parameters
        ----------
        mpa
            The gauge pressure, MPa, 0 ≤ ``mpa`` ≤ ``max_pressure_MPa`` (the runner checks
            the rig's limits before commanding).
        """

    @abstractmethod
    def vent(self) -> VentResult:
        """Command zero pressure and say whether the device confirmed it.

        Must never raise (it is called on every exit path).

        Returns
        -------
        VentResult
            :meth:`VentResult.confirmed` when the device acknowledged the command (and
            read it back as zero where it can), else :meth:`VentResult.failed` naming the
            reason.
        """

    def start_vent(self) -> VentConfirm:
        """Command zero now; confirm later.

        :meth:`Rig.vent` commands every regulator before confirming any, so a slow
        confirmation (an ITV's output falling) never delays the other regulator's vent.
        Drivers whose confirmation waits override this; the default vents at once.

        Returns
        -------
        VentConfirm
            A callable returning the :class:`VentResult` (it may wait for a read-back).
        """
        res = self.vent()
        return lambda: res


class MusclePressureSupply(ABC):
    """How the muscle's (nominally constant) pressure is set."""

    #: True when software sets the pressure (second regulator); False for a manual
    #: regulator, where the runner prompts the operator and waits for the reading.
    automatic: bool = False

    @abstractmethod
    def request(self, mpa: float, prompt: Callable[[str], None] | None = None) -> None:
        """Ask for a muscle pressure: set it (automatic) or prompt the operator (manual).

        Parameters
        ----------
        mpa
            The gauge pressure, MPa.
        prompt
            Shows the operator's instruction for a manual regulator (``None``: the
            supply's own way, if any); an automatic supply ignores it.
        """

    def vent(self) -> VentResult:
        """Vent the muscle (automatic supplies override this).

        Returns
        -------
        VentResult
            For a manual regulator :meth:`VentResult.manual`: software cannot vent it and
            the operator must (every message says so).
        """
        if self.automatic:
            return VentResult.failed(f"{type(self).__name__} has no vent")
        return VentResult.manual()

    def start_vent(self) -> VentConfirm:
        """Command zero now, confirm later (see :meth:`PressureRegulator.start_vent`).

        Returns
        -------
        VentConfirm
            A callable returning the :class:`VentResult`.
        """
        res = self.vent()
        return lambda: res


class RegulatedMuscleSupply(MusclePressureSupply):
    """The muscle fed by a software-set proportional regulator (automatic): a request sets
    it, a vent commands it to zero and confirms as the regulator does."""

    automatic = True

    def __init__(self, regulator: PressureRegulator) -> None:
        self.regulator = regulator

    def request(self, mpa: float, prompt: Callable[[str], None] | None = None) -> None:
        self.regulator.set_pressure(mpa)

    def vent(self) -> VentResult:
        return self.regulator.vent()

    def start_vent(self) -> VentConfirm:
        return self.regulator.start_vent()


class RigDevices:
    """What every rig shares, whatever it drives: a clock, a sampler, its channels declared
    as data (:mod:`pmalab.channels`), and one way to close — vent everything, then release
    the devices.  Subclasses say how they vent (:meth:`vent`)."""

    clock: Clock
    sampler: Sampler
    info: dict[str, Any]
    #: what the rig measures and commands, in the order its sampler delivers them
    channels: Channels = SINGLE_MUSCLE_CHANNELS

    def vent(self) -> Any:  # pragma: no cover - every rig overrides it
        raise NotImplementedError

    def close(self) -> Any:
        """Vent everything and release the devices; returns the vent's outcome (a message
        must never claim a vent that was not confirmed).  Safe to call more than once.

        Each step runs even when an earlier one fails; the first failure of stopping or
        closing the sampler is raised at the end (a failed vent is reported, never raised).
        """
        vented = self.vent()
        first: Exception | None = None
        closer = getattr(self.sampler, "close", None)
        for step in [self.sampler.stop] + ([closer] if callable(closer) else []):
            try:
                step()
            except Exception as exc:
                first = first or exc
        if first is not None:
            raise first
        return vented

    def __enter__(self) -> Any:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


@dataclass
class Rig(RigDevices):
    """A complete rig: clock, sampler, cylinder regulator, muscle pressure supply, limits."""

    clock: Clock
    sampler: Sampler
    cylinder_regulator: PressureRegulator
    muscle_supply: MusclePressureSupply
    limits: Limits = field(default_factory=Limits)
    #: provenance recorded with every run: rig file text, calibration, device ids, ...
    info: dict[str, Any] = field(default_factory=dict)
    #: the outcome of the latest :meth:`vent` (None before the first)
    last_vent: VentReport | None = field(default=None, repr=False)

    def vent(self) -> VentReport:
        """Vent the cylinder regulator first (it moves the load), then the muscle supply;
        only then wait for their confirmations.

        Never raises; the muscle is vented even when the cylinder's vent failed.

        Returns
        -------
        VentReport
            Each regulator's outcome (confirmed, failed or manual), also kept in
            :attr:`last_vent`.
        """
        cyl = start_vent_safely(self.cylinder_regulator, "cylinder regulator")
        mus = start_vent_safely(self.muscle_supply, "muscle supply")
        self.last_vent = VentReport(cyl(), mus())
        return self.last_vent

    def close(self) -> VentReport:
        """Vent everything and release the devices (:meth:`RigDevices.close`).

        Returns
        -------
        VentReport
            The vent's outcome (also in :attr:`last_vent`); a failed vent is reported,
            never raised.
        """
        return super().close()

    def __enter__(self) -> Rig:
        return self
