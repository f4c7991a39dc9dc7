"""RBF-network-tuned PID (seed S2): a 3-4-1 Gaussian network estimates the plant's Jacobian,
gradient descent with momentum tunes the PID gains.

Network (Liu's RBF-PID, S2 §3.1–3.2), on dimensionless signals (``u_scale``, ``y_scale``)::

    X = [u(k), y(k), y(k−1)]                 3 inputs
    h_j = exp(−‖X − c_j‖² / (2·b_j²))        4 Gaussian hidden nodes
    y_m = Σ w_j·h_j                          1 output: the network's model of y(k+1)

Identification (instantaneous cost E = ½(y − y_m)², learning rate η, momentum α)::

    w_j  += η·(y − y_m)·h_j                            + α·(w_j(k−1) − w_j(k−2))
    b_j  += η·(y − y_m)·w_j·h_j·‖X − c_j‖²/b_j³        + α·(…)
    c_ji += η·(y − y_m)·w_j·h_j·(x_i − c_ji)/b_j²      + α·(…)

Jacobian ∂y/∂u ≈ Σ w_j·h_j·(c_1j − u)/b_j², clipped to [0, ``jac_max``]: both loops'
plants are known to be increasing (more tension → more contraction, more command → more
pressure), and a network still learning must not turn the gains' descent around.  PID gains
(cost ½e², gradient descent)::

    Kp += η_p·e·J·x_P·Kp0,   Ki += η_i·e·J·x_I·Ki0,   Kd += η_d·e·J·x_D·Kd0

with e and x_P = Δe, x_I = e, x_D the incremental PID's signals made dimensionless
(÷ ``e_scale``), each gain moving in proportion to its initial value, and clipped to ``gain_bounds`` × their initial values (which equal the classic PID's).
The network sees y(k) at sample k and was fed u(k−1): it learns y(k) from
[u(k−1), y(k−1), y(k−2)] and then predicts with the newest values.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from pmalab.control.pid import IncrementalPID, LoopSettings

#: rates a settings table leaves out (gain rates 0: no tuning; the tuned ones are in
#: :func:`pmalab.control.controllers.default_settings`)
#: rates a settings table leaves out (gain rates 0: no tuning; the tuned ones are in
#: :func:`pmalab.control.controllers.default_settings`)
DEFAULT_RATES = {
    "eta": 0.2,
    "alpha": 0.05,
    "eta_p": 0.0,
    "eta_i": 0.0,
    "eta_d": 0.0,
    "jac_max": 2.0,
}
N_HIDDEN = 4
N_IN = 3


@njit(cache=True)
def _hidden(net, X, h):
    """Gaussian outputs h_j of the network ``net`` (rows: w, b, c_0, c_1, c_2) for ``X``."""
    for j in range(N_HIDDEN):
        d2 = 0.0
        for i in range(N_IN):
            d = X[i] - net[2 + i, j]
            d2 += d * d
        b = net[1, j]
        h[j] = math.exp(-d2 / (2.0 * b * b))


@njit(cache=True)
def rbf_step(net, prev, X_learn, y, X_now, eta, alpha, jac_max, h):
    """One identification step on (``X_learn`` → ``y``), then the Jacobian at ``X_now``.

    ``net``/``prev``: (5, 4) arrays — rows w, b, c_0..c_2 — now and one step ago (the
    momentum term).  Returns ∂y/∂u clipped to [0, ``jac_max``].
    """
    _hidden(net, X_learn, h)
    ym = 0.0
    for j in range(N_HIDDEN):
        ym += net[0, j] * h[j]
    err = y - ym
    for j in range(N_HIDDEN):
        w = net[0, j]
        b = net[1, j]
        hj = h[j]
        d2 = 0.0
        for i in range(N_IN):
            d = X_learn[i] - net[2 + i, j]
            d2 += d * d
        g = eta * err * w * hj
        w_new = w + eta * err * hj + alpha * (w - prev[0, j])
        b_new = b + g * d2 / (b * b * b) + alpha * (b - prev[1, j])
        prev[0, j] = w
        prev[1, j] = b
        net[0, j] = min(max(w_new, -100.0), 100.0)
        net[1, j] = min(max(b_new, 0.05), 20.0)  # a width must stay positive and finite
        for i in range(N_IN):
            c = net[2 + i, j]
            c_new = c + g * (X_learn[i] - c) / (b * b) + alpha * (c - prev[2 + i, j])
            prev[2 + i, j] = c
            net[2 + i, j] = min(max(c_new, -10.0), 10.0)
    _hidden(net, X_now, h)
    jac = 0.0
    for j in range(N_HIDDEN):
        b = net[1, j]
        jac += net[0, j] * h[j] * (net[2, j] - X_now[0]) / (b * b)
    if not jac == jac:
        return 0.0
    return min(max(jac, 0.0), jac_max)


class RbfPID(IncrementalPID):
    """S2's RBF-network-tuned PID (``name = "rbf-pid"``)."""

    name = "rbf-pid"
    title = "RBF-network-tuned PID (S2: 3-4-1 Gaussian Jacobian, momentum descent)"
    order = 3

    def __init__(self, settings: LoopSettings) -> None:
        super().__init__(settings)

        def r(key: str, default: float) -> float:
            return settings.rate(self.name, key, default)

        self.eta = r("eta", DEFAULT_RATES["eta"])
        self.alpha = min(r("alpha", DEFAULT_RATES["alpha"]), 0.95)
        self.eta_pid = (
            r("eta_p", DEFAULT_RATES["eta_p"]),
            r("eta_i", DEFAULT_RATES["eta_i"]),
            r("eta_d", DEFAULT_RATES["eta_d"]),
        )
        self.jac_max = r("jac_max", DEFAULT_RATES["jac_max"])
        self._init_net()

    def _init_net(self) -> None:
        # centres spread over the normalised operating range, unit widths, small weights
        net = np.zeros((2 + N_IN, N_HIDDEN))
        net[0, :] = 0.1
        net[1, :] = 1.0
        for j in range(N_HIDDEN):
            net[2:, j] = 0.25 * j
        self.net = net
        self.prev = net.copy()
        self._h = np.zeros(N_HIDDEN)
        self._xl = np.zeros(N_IN)
        self._xn = np.zeros(N_IN)
        self.jac = 0.0
        self.y1 = self.y2 = None
        self.u_prev = 0.0

    def reset(self, u0: float = 0.0) -> None:
        super().reset(u0)
        if hasattr(self, "eta_pid"):
            self._init_net()
            self.u_prev = u0 / self.s.u_scale

    def adapt(self, e: float, xp: float, xi: float, xd: float, y: float) -> None:
        s = self.s
        yn = y / s.y_scale
        if self.y1 is None:
            self.y1 = self.y2 = yn
        # learn y(k) from what produced it, then linearise around the newest input
        xl, xn = self._xl, self._xn
        xl[0], xl[1], xl[2] = self.u_prev, self.y1, self.y2
        xn[0], xn[1], xn[2] = self.u / s.u_scale, yn, self.y1
        jac = rbf_step(self.net, self.prev, xl, yn, xn, self.eta, self.alpha, self.jac_max, self._h)
        self.jac = jac
        self.y2, self.y1 = self.y1, yn
        ep, ei, ed = self.eta_pid
        if jac == 0.0 or (ep == 0.0 and ei == 0.0 and ed == 0.0):
            return
        es = s.e_scale
        en = e / es
        g0 = self.g0
        # gains move in proportion to their initial size (dimensionless updates)
        self.kp += ep * en * jac * (xp / es) * g0.kp
        self.ki += ei * en * jac * (xi / (es * s.dt)) * g0.ki
        self.kd += ed * en * jac * (xd * s.dt / es) * g0.kd
        self.clip_gains()

    def step(self, r: float, y: float, ff: float = 0.0) -> float:
        u = super().step(r, y, ff)
        self.u_prev = u / self.s.u_scale  # what the next sample's y answers to
        return u
