"""The one estimation engine (every fit pmalab makes goes through it).

* :mod:`.basis` — the pressure basis (Legendre in the identified range) and the one
  weighted polynomial fit with round-off-robust order selection;
* :mod:`.problem` — :class:`~.problem.Problem`: shared parameters through the pressure
  basis (order 0–2) plus per-run blocks (start state, record nuisances), one residual and
  Jacobian;
* :mod:`.solver` — the one bounded least-squares call and the one uncertainty / N_eff;
* :mod:`.records` — the one record policy (how a predicted run's own parameters are set);
* :mod:`.single` — a single run's fit (a one-record problem with a variable-projection start);
* :mod:`.joint` — the campaign's joint pressure-law fit (a many-record problem).
"""
