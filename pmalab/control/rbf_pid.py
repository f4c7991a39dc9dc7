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

from pmalab.control.pid import IncrementalPID, LoopSettings

#: rates a settings table leaves out (gain rates 0: no tuning; the tuned ones are in
#: :func:`pmalab.control.controllers.default_settings`)
DEFAULT_RATES = {"eta": 0.2, "alpha": 0.05, "eta_p": 0.0, "eta_i": 0.0, "eta_d": 0.0,
                 "jac_max": 2.0}
N_HIDDEN = 4


class RbfPID(IncrementalPID):
    """S2's RBF-network-tuned PID (``name = "rbf-pid"``)."""

    name = "rbf-pid"

    def __init__(self, settings: LoopSettings) -> None:
        super().__init__(settings)
        def r(key: str, default: float) -> float:
            return settings.rate(self.name, key, default)

        self.eta = r("eta", DEFAULT_RATES["eta"])
        self.alpha = min(r("alpha", DEFAULT_RATES["alpha"]), 0.95)
        self.eta_pid = (r("eta_p", DEFAULT_RATES["eta_p"]), r("eta_i", DEFAULT_RATES["eta_i"]),
                        r("eta_d", DEFAULT_RATES["eta_d"]))
        self.jac_max = r("jac_max", DEFAULT_RATES["jac_max"])
        self._init_net()

    def _init_net(self) -> None:
        # centres spread over the normalised operating range, unit widths, small weights
        self.c = [[0.25 * j, 0.25 * j, 0.25 * j] for j in range(N_HIDDEN)]
        self.b = [1.0] * N_HIDDEN
        self.w = [0.1] * N_HIDDEN
        self.c1 = [row[:] for row in self.c]
        self.b1 = self.b[:]
        self.w1 = self.w[:]
        self.jac = 0.0
        self.y1 = self.y2 = None
        self.u_prev = 0.0

    def reset(self, u0: float = 0.0) -> None:
        super().reset(u0)
        if hasattr(self, "eta_pid"):
            self._init_net()
            self.u_prev = u0 / self.s.u_scale

    def _hidden(self, X: tuple[float, float, float]) -> list[float]:
        out = []
        for j in range(N_HIDDEN):
            c = self.c[j]
            d2 = (X[0] - c[0]) ** 2 + (X[1] - c[1]) ** 2 + (X[2] - c[2]) ** 2
            out.append(math.exp(-d2 / (2.0 * self.b[j] ** 2)))
        return out

    def _learn(self, X: tuple[float, float, float], y: float) -> None:
        """One gradient step with momentum on E = ½(y − y_m)² for input ``X``."""
        h = self._hidden(X)
        ym = sum(wj * hj for wj, hj in zip(self.w, h))
        err = y - ym
        eta, al = self.eta, self.alpha
        for j in range(N_HIDDEN):
            wj, bj, cj, hj = self.w[j], self.b[j], self.c[j], h[j]
            d2 = sum((X[i] - cj[i]) ** 2 for i in range(3))
            w_new = wj + eta * err * hj + al * (wj - self.w1[j])
            b_new = bj + eta * err * wj * hj * d2 / bj**3 + al * (bj - self.b1[j])
            b_new = min(max(b_new, 0.05), 20.0)  # a width must stay positive and finite
            c_new = [cj[i] + eta * err * wj * hj * (X[i] - cj[i]) / bj**2
                     + al * (cj[i] - self.c1[j][i]) for i in range(3)]
            self.w1[j], self.b1[j], self.c1[j] = wj, bj, cj
            self.w[j] = min(max(w_new, -100.0), 100.0)
            self.b[j] = b_new
            self.c[j] = [min(max(v, -10.0), 10.0) for v in c_new]

    def adapt(self, e: float, xp: float, xi: float, xd: float, y: float) -> None:
        s = self.s
        yn = y / s.y_scale
        if self.y1 is None:
            self.y1 = self.y2 = yn
        # learn y(k) from what produced it, then linearise around the newest input
        self._learn((self.u_prev, self.y1, self.y2), yn)
        un = self.u / s.u_scale
        X = (un, yn, self.y1)
        h = self._hidden(X)
        jac = sum(self.w[j] * h[j] * (self.c[j][0] - un) / self.b[j] ** 2 for j in range(N_HIDDEN))
        jac = min(max(jac, 0.0), self.jac_max) if jac == jac else 0.0
        self.jac = jac
        es = s.e_scale
        en = e / es
        ep, ei, ed = self.eta_pid
        g0 = self.g0
        # gains move in proportion to their initial size (dimensionless updates)
        self.kp += ep * en * jac * (xp / es) * g0.kp
        self.ki += ei * en * jac * (xi / (es * s.dt)) * g0.ki
        self.kd += ed * en * jac * (xd * s.dt / es) * g0.kd
        self.clip_gains()
        self.y2, self.y1 = self.y1, yn

    def step(self, r: float, y: float, ff: float = 0.0) -> float:
        u = super().step(r, y, ff)
        self.u_prev = u / self.s.u_scale  # what the next sample's y answers to
        return u
