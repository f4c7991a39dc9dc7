"""Benchmarks (``make bench``).  Each ``bench/bench_*.py`` defines ``main() -> None`` that
prints one table; ``python -m bench`` runs them all (or ``python -m bench NAME``)."""
