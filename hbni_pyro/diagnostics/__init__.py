"""Is a fitted noise model, or a filter on it, honest? Posterior predictive checks, simulation-based calibration,
reliability diagrams, and assertions for a user's test suite.

- :mod:`.predictive`: :func:`predictive_check`, the macro-observation process on held-out outputs against the
  same process on streams the posterior simulates (docs/predictive_checks.md).
- :mod:`.sbc`: :func:`run_sbc`, simulation-based calibration of a model's sampler.
- :mod:`.reliability`: the reliability diagram and expected calibration error of a filter's confidence.
- :mod:`.testing`: ``assert_*`` helpers that fail with the figures behind the verdict.
"""

from hbni_pyro.diagnostics.predictive import PredictiveCheck, predictive_check
from hbni_pyro.diagnostics.reliability import Reliability, reliability, stream_reliability
from hbni_pyro.diagnostics.sbc import SBCResult, run_sbc
from hbni_pyro.diagnostics.testing import (
    assert_calibrated,
    assert_predictive_check_fails,
    assert_predictive_check_passes,
)

__all__ = [
    "PredictiveCheck",
    "Reliability",
    "SBCResult",
    "assert_calibrated",
    "assert_predictive_check_fails",
    "assert_predictive_check_passes",
    "predictive_check",
    "reliability",
    "run_sbc",
    "stream_reliability",
]
