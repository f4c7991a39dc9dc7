"""THE estimation problem: shared parameters through a pressure basis, plus per-run blocks.

Every fit in pmalab is an instance of one problem.  Given runs i = 1..R (each a record at
nominal muscle pressure p_i) and a force model F(sig; θ):

* every *shared* parameter θ_j is a polynomial of order d_j ∈ {0, 1, 2} in p through the
  Legendre basis of :mod:`.basis`: θ_j(p_i) = Σ_d c_jd·P_d(u(p_i)), clipped into the
  parameter's bounds (order 0 coefficients are bounded directly);
* every *per-run* parameter (the record's start state h0 and the record nuisances of the
  effects, e.g. a drift rate or a tared force zero) has one free value per run;
* the residual of run i is (F_model − F_measured)·w_i, stacked over runs.

A single-run fit is R = 1 with every order 0 and w = 1; a campaign's joint pressure-law fit
is R runs with w_i = 1/(σ_i·√N_i) (σ_i the run's own error scale, so each run counts
equally); refitting the record parameters of a held-out run with the muscle parameters
held is a problem with no shared parameters.  One residual, one Jacobian, one solver
(:mod:`.solver`) and one uncertainty estimate serve them all.

Jacobian: forward differences per *parameter* (one perturbation of θ_j evaluated on each
run, chained to its basis coefficients) and per run for the per-run parameters; the linear
parameters are analytic: ∂F/∂k is the (effect-transformed) drive position and ∂F/∂c0 = 1.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from numba import njit

from pmalab.identify.estimation.basis import PressureBasis
from pmalab.identify.model import ForceModel
from pmalab.identify.signals import Signals

#: an unweighted residual beyond this (N) is a runaway prediction; it is clipped here
RUNAWAY_N = 1e9
#: parameters whose residual derivative is known in closed form (F = k·x + c0 + ...)
LINEAR = ("k", "c0")
#: the relative forward-difference step
_SQRT_EPS = math.sqrt(np.finfo(float).eps)
#: the steps of a row weighed without a difference quotient (:meth:`Problem._weigh_own`)
_ONE = np.ones(1)
#: one run's model parts at a parameter set: drive signals, law extras, k·x + c0, h
_Parts = tuple[Signals, dict[str, float], np.ndarray, np.ndarray]
#: Problem's last residual: z's bytes, the residual, the parts, raw θ, every run's θ
_Cache = tuple[bytes, np.ndarray, "list[_Parts] | None", np.ndarray, list[dict[str, float]]]


@njit(cache=True, fastmath=False, error_model="numpy")
def _difference_rows(E, force, w, cap, r0, steps, over, quotient):  # pragma: no cover
    """Forward differences from predictions, in place: row k of ``E`` (a prediction of the
    run) becomes (((E_k − force)·w) − r0) / steps_k, the weighting skipped when w is 1 —
    :meth:`Problem._weigh`'s and the difference quotient's operations, element by element,
    in one pass over the row (without ``quotient``: the weighted errors (E_k − force)·w).  A row with a weighted error beyond ``cap`` (or NaN) is left
    as its weighted errors, to be clipped by the caller: flagged in ``over`` (all False on
    entry); returns how many there are."""
    rows, n = E.shape
    count = 0
    for k in range(rows):
        bad = 0  # a count, not a flag: the loops stay vector loops
        if w != 1.0:
            for t in range(n):
                e = (E[k, t] - force[t]) * w
                E[k, t] = e
                bad += 0 if (e <= cap and e >= -cap) else 1
        else:
            for t in range(n):
                e = E[k, t] - force[t]
                E[k, t] = e
                bad += 0 if (e <= cap and e >= -cap) else 1
        if bad == 0:
            if not quotient:
                continue
            h = steps[k]
            for t in range(n):
                E[k, t] = (E[k, t] - r0[t]) / h
        else:
            over[k] = True
            count += 1
    return count


def load_compiled() -> None:
    """Load the compiled difference kernel now (:func:`_difference_rows` on a few samples
    of the types a fit passes), so forked workers inherit it instead of each loading or
    compiling its own."""
    E = np.zeros((1, 4))
    _difference_rows(E, np.zeros(4), 1.0, 1.0, np.zeros(4), np.ones(1), np.zeros(1, np.bool_), True)


def _clipped(e: np.ndarray, cap: float) -> np.ndarray:
    """``e`` with every entry within ±``cap``: NaN and +inf become ``cap``, −inf ``-cap``
    (a new array)."""
    return np.clip(np.nan_to_num(e, nan=cap, posinf=cap, neginf=-cap), -cap, cap)


@dataclass
class Record:
    """One run's data for the estimator (signals already filtered, possibly subsampled)."""

    label: str
    p_nom: float
    sig: Signals
    force: np.ndarray  # N
    weight: float = 1.0  # residual multiplier

    @property
    def n(self) -> int:
        return int(self.force.shape[0])

    @property
    def sd(self) -> float:
        return max(float(np.std(self.force)), 1e-9)


class Problem:
    """Residual and Jacobian of one estimation problem (see the module docstring).

    ``free``: shared parameter names with their pressure orders ``degree``; ``constants``:
    parameters held fixed on every run; ``run_params``: per-run parameter names;
    ``bounds``: (lo, hi) per parameter; ``cap``: limit of one weighted residual (a runaway
    prediction becomes a large finite cost instead of inf), None for no cap.
    """

    def __init__(
        self,
        model: ForceModel,
        records: Sequence[Record],
        *,
        free: Sequence[str],
        degree: Mapping[str, int],
        constants: Mapping[str, float],
        bounds: Mapping[str, tuple[float, float]],
        run_params: Sequence[str] = (),
        cap: float | None = None,
        basis: PressureBasis | None = None,
    ) -> None:
        self.model, self.records = model, list(records)
        self.free = list(free)
        self.degree = {n: int(degree[n]) for n in self.free}
        self.constants = dict(constants)
        self.bounds = dict(bounds)
        self.run_params = list(run_params)
        self.cap = cap
        self.basis = basis or PressureBasis.over([r.p_nom for r in self.records])
        ps = [r.p_nom for r in self.records]
        self.B = {n: self.basis.matrix(ps, self.degree[n]) for n in self.free}
        #: every free parameter of order 0 with its basis 1 at every run (a single run's
        #: fit): θ_n is then z_n itself at every run (:meth:`_at`)
        self._order0 = all(
            self.degree[n] == 0 and bool(np.all(self.B[n] == 1.0)) for n in self.free
        )
        self.slices: dict[str, slice] = {}
        i = 0
        for n in self.free:
            self.slices[n] = slice(i, i + self.degree[n] + 1)
            i += self.degree[n] + 1
        self.n_coef = i
        self.n_var = i + len(self.records) * len(self.run_params)
        offs = np.cumsum([0] + [r.n for r in self.records])
        self.rows = [slice(int(a), int(b)) for a, b in itertools.pairwise(offs)]
        self.n_rows = int(offs[-1])
        #: each free parameter's bounds (θ is clipped into them)
        b = np.array([self.bounds.get(n, (-np.inf, np.inf)) for n in self.free], dtype=float)
        self._lo, self._hi = b.reshape(len(self.free), 2).T
        self._lo_col, self._hi_col = self._lo[:, None], self._hi[:, None]
        #: the last residual: (z's bytes, residual, each run's model parts or None, and
        #: :meth:`_at` at z) — the Jacobian at the same z starts from them
        self._cache: _Cache | None = None
        #: :meth:`_basis_layout` by (run, shared parameters with a column there)
        self._layouts: dict[tuple[int, tuple[str, ...]], tuple] = {}
        #: parameters whose finite-difference column reuses parts of the model at z
        #: (:meth:`ForceModel.unchanged_parts`); only for the force output
        self._reuse: dict[str, str] = (
            model.unchanged_parts(self.records[0].sig)
            if type(self).output is Problem.output and self.records
            else {}
        )
        if not model.predicts_by_parts:
            # a model with its own prediction: its force need not be k·x + c0 + the rest
            self.analytic_linear = False

    # ------------------------------------------------------------------ layout
    def block(self, j: int) -> slice:
        """z indices of the j-th per-run parameter (``run_params[j]``), one per run."""
        R = len(self.records)
        return slice(self.n_coef + j * R, self.n_coef + (j + 1) * R)

    def z_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Bounds of z: order-0 coefficients and per-run values bounded, higher orders free
        (their θ is clipped instead)."""
        lo = np.full(self.n_var, -np.inf)
        hi = np.full(self.n_var, np.inf)
        for n in self.free:
            if self.degree[n] == 0:
                lo[self.slices[n]], hi[self.slices[n]] = self.bounds.get(n, (-np.inf, np.inf))
        for j, rn in enumerate(self.run_params):
            lo[self.block(j)], hi[self.block(j)] = self.bounds.get(rn, (-np.inf, np.inf))
        return lo, hi

    def z_from(
        self,
        coefs: Mapping[str, Sequence[float] | np.ndarray],
        run_values: Mapping[str, Sequence[float]] | None = None,
    ) -> np.ndarray:
        """z from Legendre coefficients per free parameter (padded/truncated to its order)
        and per-run values per run parameter (default 0)."""
        z = np.zeros(self.n_var)
        for n in self.free:
            c = np.atleast_1d(np.asarray(coefs[n], dtype=float))
            k = self.degree[n] + 1
            z[self.slices[n]] = np.concatenate([c, np.zeros(max(0, k - c.size))])[:k]
        for j, rn in enumerate(self.run_params):
            if run_values and rn in run_values:
                z[self.block(j)] = [float(v) for v in run_values[rn]]
        return z

    def coefficients(self, z: np.ndarray) -> dict[str, np.ndarray]:
        return {n: np.array(z[self.slices[n]]) for n in self.free}

    def run_values(self, z: np.ndarray) -> dict[str, list[float]]:
        return {rn: [float(v) for v in z[self.block(j)]] for j, rn in enumerate(self.run_params)}

    # ------------------------------------------------------------------ parameters
    def raw(self, z: np.ndarray) -> dict[str, np.ndarray]:
        """Unclipped θ_j at every run's pressure."""
        return {n: self.B[n] @ z[self.slices[n]] for n in self.free}

    def thetas(self, z: np.ndarray) -> list[dict[str, float]]:
        """The full parameter set of every run."""
        return self._at(z)[1]

    def _at(self, z: np.ndarray) -> tuple[np.ndarray, list[dict[str, float]]]:
        """(the unclipped θ of every free parameter at every run, shape (free, runs); the
        full parameter set of every run)."""
        z = np.asarray(z, dtype=float)
        R = len(self.records)
        if self._order0:
            # B_n·c_n at every run is 0 + 1·c_n: c_n itself, a −0.0 made +0.0 (the matmul's
            # numbers, NaN and inf as they are)
            RAW = np.add(z[: self.n_coef], 0.0)[:, None]
            if R != 1:
                RAW = np.repeat(RAW, R, axis=1)
        else:
            # :meth:`raw`'s products, each written straight into its row (the same matmul)
            RAW = np.empty((len(self.free), R))
            for j, n in enumerate(self.free):
                np.matmul(self.B[n], z[self.slices[n]], out=RAW[j])
        # each law clipped to its bounds at every run at once (np.clip: the same min/max)
        free = np.clip(RAW, self._lo_col, self._hi_col).T.tolist()
        per_run = z[self.n_coef :].reshape(-1, R).T.tolist()
        out = []
        for i in range(R):
            th = dict(self.constants)
            th.update(zip(self.free, free[i]))
            th.update(zip(self.run_params, per_run[i]))
            out.append(th)
        return RAW, out

    # ------------------------------------------------------------------ residuals
    #: k and c0 enter the output linearly (True for the force output; a simulated position
    #: depends on them nonlinearly, :mod:`.output_error`)
    analytic_linear = True

    def output(self, i: int, th: Mapping[str, float]) -> np.ndarray:
        """The model's output on run i: the free-run force (N)."""
        return self.model.predict(self.records[i].sig, th)

    def run_residual(self, i: int, th: Mapping[str, float]) -> np.ndarray:
        """Run i's weighted residual (N × weight) at the parameters ``th``; a runaway
        prediction is clipped (see ``cap``)."""
        with np.errstate(all="ignore"):
            return self._run_residual(i, th)

    def _run_residual(self, i: int, th: Mapping[str, float]) -> np.ndarray:
        """:meth:`run_residual` for callers that already ignore floating-point warnings
        (the Jacobian's hundreds of calls: one ``errstate`` for all of them)."""
        if self._fresh_output():
            return self._weigh_own(i, self.output(i, th))
        return self._weigh(i, self.output(i, th))

    def _fresh_output(self) -> bool:
        """Whether :meth:`output` is a new array of the caller's every time (this class's
        force output of a model predicted by its parts: :meth:`ForceModel.assemble`'s sum),
        so it may be weighed in place."""
        got = self.__dict__.get("_fresh")
        if got is None:
            got = self._fresh = type(self).output is Problem.output and self.model.predicts_by_parts
        return got

    def _weigh(self, i: int, out: np.ndarray) -> np.ndarray:
        """Run i's weighted residual of the output ``out``, a runaway clipped (see ``cap``)."""
        r = self.records[i]
        e = out - r.force
        if r.weight != 1.0:
            # in place: the same product as (out − force)·w (x·1.0 is x, so a unit weight
            # is not multiplied at all)
            np.multiply(e, r.weight, out=e)
        # one reduction: the largest |e| is NaN (a NaN anywhere) or inf (an inf anywhere),
        # and `not (m <= cap)` is then True, as it is for a finite m above the cap
        m = float(np.abs(e).max())
        cap = self._clip_at()
        if not m <= cap:
            e = _clipped(e, cap)
        return e

    def _clip_at(self) -> float:
        """Where a weighted error is clipped: ``cap``, else :data:`RUNAWAY_N` (a runaway
        state: large and finite, squares stay representable)."""
        return RUNAWAY_N if self.cap is None else self.cap

    def _weigh_own(self, i: int, out: np.ndarray) -> np.ndarray:
        """:meth:`_weigh` of a new array of the caller's (a prediction from
        :meth:`ForceModel.assemble`), weighed in place in one compiled pass: the same
        numbers."""
        if not (out.dtype == np.float64 and out.ndim == 1 and out.flags.c_contiguous and out.size):
            return self._weigh(i, out)
        r = self.records[i]
        cap = self._clip_at()
        force = np.ascontiguousarray(r.force, dtype=np.float64)
        over = np.zeros(1, dtype=np.bool_)
        E = out.reshape(1, -1)
        if _difference_rows(E, force, float(r.weight), float(cap), force, _ONE, over, False):
            # beyond the cap: clipped as _weigh clips it
            return _clipped(out, cap)
        return out

    def residual(self, z: np.ndarray) -> np.ndarray:
        key = np.asarray(z, dtype=float).tobytes()
        if self._cache is not None and self._cache[0] == key:
            return self._cache[1]
        parts: list[_Parts] | None = None
        RAW, ths = self._at(z)
        with np.errstate(all="ignore"):
            if self._reuse:
                # the model's parts kept for the Jacobian's columns at this z (the same
                # numbers as output(): predict is parts + assemble)
                m = self.model
                parts = [m.parts(r.sig, th) for r, th in zip(self.records, ths)]
                es = [
                    self._weigh_own(i, m.assemble(s, lin, h, th))
                    for i, ((s, _, lin, h), th) in enumerate(zip(parts, ths))
                ]
            else:
                es = [self._run_residual(i, th) for i, th in enumerate(ths)]
        # one run: its residual is a new array already (no copy to stack)
        e = es[0] if len(es) == 1 else np.concatenate(es)
        self._cache = (key, e, parts, RAW, ths)
        return e

    def jac(self, z: np.ndarray, run_only: bool = False) -> np.ndarray:
        """Jacobian of :meth:`residual` (``run_only``: only the per-run columns are filled)."""
        z = np.asarray(z, dtype=float)
        r0 = self.residual(z)
        # every entry is written (a column without a derivative at a run is set to 0 there)
        J = np.empty((self.n_rows, self.n_var))
        with np.errstate(all="ignore"):
            self._fill_jac(J, z, r0, run_only)
        return J

    def _fill_jac(self, J: np.ndarray, z: np.ndarray, r0: np.ndarray, run_only: bool) -> None:
        """:meth:`jac`'s columns, in place (under one ``errstate``): every entry of J, the
        columns without a derivative at a run (a clipped θ, another run's per-run parameter,
        the shared parameters with ``run_only``) set to 0 there.

        With the model's parts at z kept by :meth:`residual`, the columns of the law's
        parameters on one run are evaluated together (:meth:`_law_columns`); every other
        column one by one (:meth:`dresid`).  Each column is the same forward difference
        either way.  Which columns a run has and where they go in J depend only on the run,
        the parameters clipped there and ``run_only``: :meth:`_plan`, made once for each."""
        c = self._cache
        if c is not None and c[0] == z.tobytes():
            _, _, parts, RAW, ths = c
        else:
            parts, (RAW, ths) = None, self._at(z)
        # a clipped θ does not move with z at that run: no column there
        inside = None if run_only else ((self._lo_col <= RAW) & (RAW <= self._hi_col)).T.tolist()
        has_parts = bool(parts)
        # :meth:`_plan` by (run, parameters inside their bounds there or None, parts kept),
        # kept until :attr:`_reuse` is replaced
        got = self.__dict__.get("_plans")
        if got is None or got[0] is not self._reuse:
            got = self._plans = (self._reuse, {})
        plans: dict[tuple, tuple] = got[1]
        for i, th in enumerate(ths):
            rows = self.rows[i]
            key = (i, None if inside is None else tuple(inside[i]), has_parts)
            plan = plans.get(key)
            if plan is None:
                plan = plans[key] = self._plan(*key)
            batch, rest, shared, stack, per_run, zero = plan
            for js in zero:
                J[rows, js] = 0.0
            part = parts[i] if parts else None
            # every column of run i: the law's (one call), then the others, one by one
            ds = list(self._law_columns(i, th, batch, r0, part)) if batch and part else []
            ds += [self.dresid(i, th, n, r0, part) for n in rest]
            if stack is not None:
                # every shared column of run i at once, written row by row: J =
                # ∂r/∂θ_n · B_n(p_i), the same single multiplication per entry as a product
                # per parameter (which writes J column by column: slower on many runs);
                # (samples, columns): each column's d stacked once, in J's column order
                rep, b, unit, segments = stack
                D = np.array([ds[k] for k in rep]).T
                for js, dsl in segments:
                    if unit:
                        # every B_n(p_i) is 1 (order 0: a single run's fit): d·1 is d, bit
                        # for bit, so the entries are copied, not multiplied
                        J[rows, js] = D[:, dsl]
                    else:
                        np.multiply(D[:, dsl], b[:, dsl], out=J[rows, js])
            else:
                for k, n in shared:
                    # np.outer's products, written straight into J (no temporary)
                    np.multiply(ds[k][:, None], self.B[n][i][None, :], out=J[rows, self.slices[n]])
            for k, col in per_run:
                J[rows, col] = ds[k]

    def _plan(self, i: int, inside: tuple[bool, ...] | None, has_parts: bool) -> tuple:
        """How :meth:`_fill_jac` makes run i's columns, a tuple of:

        * the law's parameters evaluated together by :meth:`_law_columns` (none unless
          there are two or more and the parts at z are kept);
        * the other parameters, one :meth:`dresid` each (``ds``: the columns in that order);
        * the shared parameters (index in ``ds``, name) written one by one, or ``()`` when
          they are stacked;
        * the stack or None: for each of J's columns the index in ``ds`` of its derivative,
          the basis values, whether all are 1, and J's adjacent column ranges with the
          matching ranges of the stack;
        * the per-run columns (index in ``ds``, column of J);
        * the ranges of J's columns without a derivative at run i (set to 0).

        ``inside``: whether each free parameter is within its bounds at run i (None: only
        the per-run columns)."""
        # (parameter, its column for a per-run parameter; None: through the basis)
        cols: list[tuple[str, int | None]] = []
        if inside is not None:
            cols += [(n, None) for n, ok in zip(self.free, inside) if ok]
        cols += [(rn, self.block(j).start + i) for j, rn in enumerate(self.run_params)]
        law = self._law_names() if has_parts else set()
        batch = [nc for nc in cols if nc[0] in law]
        if len(batch) <= 1:
            batch = []
        done = {n for n, _ in batch}
        order = batch + [nc for nc in cols if nc[0] not in done]
        shared = [(k, n) for k, (n, col) in enumerate(order) if col is None]
        shared.sort(key=lambda kn: self.slices[kn[1]].start)  # J's column order
        stack = None
        if len(shared) > 1:
            where, rep, b, unit = self._basis_layout(i, tuple(n for _, n in shared))
            if unit or len(self.records) > 1:
                cols_j = np.arange(where.start, where.stop) if isinstance(where, slice) else where
                # J's adjacent column ranges (one when every column is there)
                segments = []
                a = 0
                for e in range(1, len(cols_j) + 1):
                    if e == len(cols_j) or cols_j[e] != cols_j[e - 1] + 1:
                        segments.append(
                            (slice(int(cols_j[a]), int(cols_j[e - 1]) + 1), slice(a, e))
                        )
                        a = e
                stack = (tuple(shared[k][0] for k in rep), b, unit, tuple(segments))
        per_run = tuple((k, col) for k, (_, col) in enumerate(order) if col is not None)
        # J's columns with no derivative at run i, as adjacent ranges
        written = np.zeros(self.n_var, dtype=bool)
        for n in (n for _, n in shared):
            written[self.slices[n]] = True
        for _, col in per_run:
            written[col] = True
        zero = []
        a = None
        for c in range(self.n_var + 1):
            if c < self.n_var and not written[c]:
                a = c if a is None else a
            elif a is not None:
                zero.append(slice(a, c))
                a = None
        return (
            tuple(n for n, _ in batch),
            tuple(n for n, _ in order[len(batch) :]),
            tuple(shared) if stack is None else (),
            stack,
            per_run,
            tuple(zero),
        )

    def _law_names(self) -> set[str]:
        """The law's parameters among the reused parts (:attr:`_reuse`), kept until it is
        replaced."""
        got = self.__dict__.get("_law_of")
        if got is None or got[0] is not self._reuse:
            got = self._law_of = (self._reuse, {n for n, k in self._reuse.items() if k == "law"})
        return got[1]

    def _basis_layout(
        self, i: int, names: tuple[str, ...]
    ) -> tuple[slice | np.ndarray, tuple[int, ...], np.ndarray, bool]:
        """Where run i's Jacobian entries of the shared parameters ``names`` go: (their
        columns of J — a slice when they are adjacent —, for each column the index of its
        parameter in ``names``, the basis value B_n(p_i) of each column, and whether every
        one of those values is exactly 1)."""
        key = (i, names)
        got = self._layouts.get(key)
        if got is None:
            cols = np.concatenate(
                [np.arange(self.slices[n].start, self.slices[n].stop) for n in names]
            )
            rep = tuple(k for k, n in enumerate(names) for _ in range(self.degree[n] + 1))
            b = np.concatenate([np.asarray(self.B[n][i], dtype=np.float64) for n in names])
            adjacent = bool(np.all(np.diff(cols) == 1))
            where = slice(int(cols[0]), int(cols[-1]) + 1) if adjacent else cols
            got = self._layouts[key] = (where, rep, b[None, :], bool(np.all(b == 1.0)))
        return got

    def _step(self, name: str, v: float) -> float:
        """The forward-difference step of θ_name at v: √eps·max(1, |v|), backward where the
        forward point would leave the bounds."""
        lo, hi = self.bounds.get(name, (-np.inf, np.inf))
        h = _SQRT_EPS * max(1.0, abs(v))
        if v + h > hi:
            h = -h
        if not (lo <= v + h <= hi):
            h = -h
        return h

    def _law_columns(
        self, i: int, th: Mapping[str, float], names: Sequence[str], r0: np.ndarray, parts: _Parts
    ) -> np.ndarray:
        """The forward differences of run i's residual in each of the law's parameters
        ``names`` (rows), from one :meth:`HysteresisLaw.h_many` call: the drive, extras and
        linear term are those at ``th``; each effect's term is evaluated for every row's h
        at once (a built-in effect's term reads only its own parameters, which a law column
        leaves as they are).  Elementwise the same operations as :meth:`dresid`."""
        s, extras, lin, _ = parts
        steps = np.empty(len(names))
        th2s = []
        for k, n in enumerate(names):
            v = th[n]
            steps[k] = h = self._step(n, v)
            th2 = dict(th)
            th2[n] = v + h
            th2s.append(th2)
        H = self.model.law.h_many(s.x, th2s, extras)
        # a new array (lin + H): the residual's operations done in place, the same numbers
        E = self.model.assemble_many(s, lin, H, th)
        return self._differences(i, E, r0, steps)

    def _differences(self, i: int, E: np.ndarray, r0: np.ndarray, steps: np.ndarray) -> np.ndarray:
        """Run i's forward differences from predictions ``E`` (rows, a new array of the
        caller's, overwritten): ((E_k − force)·w, clipped as :meth:`_weigh` clips it, − r0)
        / steps_k, each row as :meth:`dresid` computes it."""
        r = self.records[i]
        cap = self._clip_at()
        force = np.ascontiguousarray(r.force, dtype=np.float64)
        if E.dtype == np.float64 and E.ndim == 2 and E.flags.c_contiguous and E.size:
            # one compiled pass per row: the same operations, element by element
            rows = self.rows[i]
            over = np.zeros(E.shape[0], dtype=np.bool_)
            if _difference_rows(E, force, float(r.weight), float(cap), r0[rows], steps, over, True):
                for k in np.flatnonzero(over):
                    E[k] = _clipped(E[k], cap)
                    np.subtract(E[k], r0[rows], out=E[k])
                    np.divide(E[k], steps[k], out=E[k])
            return E
        np.subtract(E, force, out=E)
        if r.weight != 1.0:
            np.multiply(E, r.weight, out=E)
        # no row beyond the cap (max and min propagate a NaN): nothing to clip; else the
        # rows that are, each as :meth:`_weigh` clips it
        if not (E.max() <= cap and E.min() >= -cap):
            for k in np.flatnonzero(~(np.abs(E).max(axis=1) <= cap)):
                E[k] = _clipped(E[k], cap)
        np.subtract(E, r0[self.rows[i]], out=E)
        np.divide(E, steps[:, None], out=E)
        return E

    def dresid(
        self,
        i: int,
        th: Mapping[str, float],
        name: str,
        r0: np.ndarray,
        parts: _Parts | None = None,
    ) -> np.ndarray:
        """∂(run i's residual)/∂θ_name: analytic for k and c0, else a forward difference
        (stepping back at the upper bound).  Floating-point warnings are the caller's
        (:meth:`jac` ignores them once for all its columns).

        ``parts``: the model's parts of run i at ``th`` (:meth:`ForceModel.parts`); the
        perturbed prediction then recomputes only what the parameter can change (h and the
        effect terms for a law parameter, the terms alone for a force-only effect
        parameter), with the same operations in the same order as a whole prediction."""
        rec = self.records[i]
        if name == "c0" and self.analytic_linear:
            return np.full(rec.n, rec.weight)
        if name == "k" and self.analytic_linear:
            # the drive at th: kept with the parts, else the effects' transforms again
            s = parts[0] if parts is not None else self.model.drive(rec.sig, th)
            return s.x * rec.weight
        v = th[name]
        h = self._step(name, v)
        th2 = dict(th)
        th2[name] = v + h
        kind = self._reuse.get(name) if parts is not None else None
        if kind is None or parts is None:
            if self._fresh_output():
                # a whole prediction, weighed and differenced in place in one pass
                out = self.output(i, th2)
                return self._differences(i, out.reshape(1, -1), r0, np.array([h]))[0]
            e = self._run_residual(i, th2)
        else:
            s, extras, lin, hy = parts
            if kind == "law":
                hy = np.asarray(self.model.law.h(s.x, th2, extras), dtype=np.float64)
            # assemble's new array: weighed and differenced in place, as one row
            out = self.model.assemble(s, lin, hy, th2)
            return self._differences(i, out.reshape(1, -1), r0, np.array([h]))[0]
        # e is a new array (:meth:`_weigh`'s): the difference quotient in place
        np.subtract(e, r0[self.rows[i]], out=e)
        np.divide(e, h, out=e)
        return e

    # ------------------------------------------------------------------ summaries
    def per_run_rmse(self, z: np.ndarray) -> list[float]:
        """Each run's rmse (N) of the unweighted residual."""
        e = self.residual(z)
        return [
            float(np.sqrt(e[s] @ e[s] / r.n)) / r.weight for r, s in zip(self.records, self.rows)
        ]

    def per_run_nrmse(self, z: np.ndarray) -> list[float]:
        return [rm / r.sd for rm, r in zip(self.per_run_rmse(z), self.records)]
