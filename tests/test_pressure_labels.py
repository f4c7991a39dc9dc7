"""A run's pressure label against its measured mean: offsets beyond the gauge noise and the
regulator's resolution are named with their size; a label within them is not."""

from __future__ import annotations

import numpy as np

from pmalab.pressure_labels import check_labels, label_warning


def _gauge(mean: float, n: int = 5000, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    # a 1 kPa-rms gauge read in 1 kPa steps, plus a slow ripple the regulator leaves
    p = mean + 0.001 * rng.standard_normal(n) + 0.002 * np.sin(np.linspace(0, 20, n))
    return np.round(p / 0.001) * 0.001


def test_offset_labels_are_named_with_their_offsets():
    checks = check_labels(
        [
            ("2bar", 0.2, _gauge(0.1963, seed=1)),  # the real file: 1.963 bar measured
            ("4bar", 0.4, _gauge(0.437, seed=2)),
            ("3bar", 0.3, _gauge(0.3, seed=3)),  # labelled right
        ]
    )
    assert [c.offset for c in checks] == [True, True, False]
    assert abs(checks[0].offset_MPa * 1000 + 3.7) < 0.3
    line = label_warning(checks)
    assert line.startswith("2 runs: measured mean pressure differs from the nominal by 3.7–37.")
    assert "2bar (-3.7)" in line and "--pressure measured" in line


def test_labels_within_noise_and_resolution_are_quiet():
    checks = check_labels([(f"r{i}", 0.35, _gauge(0.35, seed=10 + i)) for i in range(20)])
    assert not any(c.offset for c in checks)
    assert label_warning(checks) == ""
    # the tolerance is the regulator's resolution (0.88 kPa) + the gauge step + 3 se
    assert all(0.0018 < c.tolerance_MPa < 0.0025 for c in checks)
