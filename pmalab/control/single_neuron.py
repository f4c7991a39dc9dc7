"""Single-neuron adaptive PID (seed S1): three gains learned online, normalised weights.

The neuron's inputs are the incremental PID's state variables (dimensionless: divided by
the loop's ``e_scale``)::

    x1 = e(k)            (integral)      x2 = e(k) − e(k−1)   (proportional)
    x3 = −(ỹ(k) − 2ỹ(k−1) + ỹ(k−2))      (derivative on the filtered measurement, see pid)

and its output is the control increment Δu = K·Σ w̄_i·x_i with normalised weights
w̄_i = w_i / Σ|w_j| and a fixed neuron gain K.  The weights learn by the supervised Hebb
rule (Liu's single-neuron PID, S1's "disposed canonically" normalised form)::

    w_i(k+1) = w_i(k) + η_i · z(k) · u(k) · x_i(k),    z = e/e_scale,  u = u/u_scale

(the unknown ∂y/∂u of the gradient form is replaced by its sign, +1 for both loops: more
force → more contraction, more command → more pressure).

Equivalence with the classic PID at start (the seeds' "same initial gains"): in
discrete-gain terms (Kp, Ki·T, Kd/T) K is their sum and w_i(0) each one's share, so the
neuron starts as exactly the classic PID.  Boundedness: weights are kept ≥ 1e-6 (a
weight cannot change sign), the normalisation keeps every discrete gain ≤ K, and each gain
is clipped to ``gain_bounds`` × its initial value; learning rates are clipped to
[0, ``max_rate``].
"""

from __future__ import annotations

from pmalab.control.pid import IncrementalPID, LoopSettings

#: learning rates (dimensionless) a settings table leaves out: no learning
#: (the tuned ones are in :func:`pmalab.control.controllers.default_settings`)
DEFAULT_RATES = {"eta_i": 0.0, "eta_p": 0.0, "eta_d": 0.0}
W_FLOOR = 1e-6


class SingleNeuronPID(IncrementalPID):
    """S1's single-neuron PID (``name = "sn-pid"``)."""

    name = "sn-pid"
    title = "single-neuron adaptive PID (S1: supervised Hebb, normalised weights)"
    order = 2

    def __init__(self, settings: LoopSettings) -> None:
        super().__init__(settings)
        dt = settings.dt
        g = settings.gains
        disc = (g.ki * dt, g.kp, g.kd / dt)  # discrete gains: integral, proportional, derivative
        self.K = sum(abs(v) for v in disc)
        self.w0 = tuple(v / self.K for v in disc)
        self.w = list(self.w0)
        self.eta = tuple(
            settings.rate(self.name, k, DEFAULT_RATES[k]) for k in ("eta_i", "eta_p", "eta_d")
        )

    def reset(self, u0: float = 0.0) -> None:
        super().reset(u0)
        if hasattr(self, "w0"):
            self.w = list(self.w0)

    def adapt(self, e: float, xp: float, xi: float, xd: float, y: float) -> None:
        s = self.s
        es = s.e_scale
        dt = s.dt
        x = (e / es, xp / es, xd * dt / es)  # x1, x2, x3 (dimensionless)
        zu = (e / es) * (self.u / s.u_scale)
        w = self.w
        for i in range(3):
            wi = w[i] + self.eta[i] * zu * x[i]
            w[i] = wi if wi > W_FLOOR else W_FLOOR
        total = w[0] + w[1] + w[2]
        K = self.K
        self.ki = K * w[0] / total / dt
        self.kp = K * w[1] / total
        self.kd = K * w[2] / total * dt
        self.clip_gains()
