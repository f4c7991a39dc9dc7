"""Wire-level emulators of the rig's devices, driven by the simulated rig's physics.

They speak the real protocols over real sockets and ptys, so the real drivers of
:mod:`pmalab.rig.drivers` can be tried and tested with no hardware:

* :mod:`.plant` — :class:`~.plant.EmulatedPlant`: :class:`~pmalab.rig.sim.physics.RigPhysics`
  advanced to wall-clock time on every request;
* :mod:`.modbus_server` — a pymodbus 3.16 server (``SimDevice`` with an action callback),
  TCP on 127.0.0.1 or RTU on a pty;
* :mod:`.serial_devices` — the SMC ITV (RS-232C ``SET``/``MON``) and the load-cell
  indicator (streaming weight lines) on ptys;
* :mod:`.pty_link` — pty pairs, the paced RTU bridge, stable symlinks;
* :mod:`.faults` — :class:`~.faults.FaultPlan`: drop, garble, exception, disconnect,
  out-of-range injected on demand;
* :mod:`.launcher` — :func:`~.launcher.start_emulators` for a rig file (``pmalab emulate``).
"""
