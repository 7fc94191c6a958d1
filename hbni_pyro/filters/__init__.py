"""Streams of outputs into decisions: the streaming filters, per-frame calibration, the temper, the
macro-observation process and its tables, and when to stop.

- :mod:`.streaming`: HBNI's filter and the baselines (SSBF, voting, max-of-mean; :func:`make_filter`).
- :mod:`.frame_calibration`: the calibrated peer's per-frame map (temperature or matrix scaling).
- :mod:`.temper`: a filter's evidence weight for correlated frames, fitted on labelled streams.
- :mod:`.macro`: the macro-observation process, its table ``P(label, frames | true class)`` and how it is made
  (:func:`characterize` from a generative model, :func:`tabulate` from recorded streams).
- :mod:`.stopping`: the process at each threshold on labelled streams, and the stopping confidence that keeps a
  promised accuracy (on labelled streams, or on unlabelled ones scored by the filter's own posterior).
"""

from hbni_pyro.filters.frame_calibration import CALIBRATIONS, FrameCalibration, fit_frame_calibration
from hbni_pyro.filters.macro import (
    MacroObservation,
    MacroObservationBatch,
    MacroObservationModel,
    MacroObservationProcess,
    characterize,
    tabulate,
)
from hbni_pyro.filters.stopping import (
    DEFAULT_STOPS,
    Fold,
    StopFit,
    binomial_stderr,
    cross_fit,
    fit_stop_threshold,
    fit_stop_unlabelled,
    threshold_checks,
)
from hbni_pyro.filters.streaming import (
    FILTERS,
    HBNIFilter,
    MaxOfMeanFilter,
    StaticStateBayesFilter,
    StreamingFilter,
    VotingFilter,
    decide,
    make_filter,
)
from hbni_pyro.filters.temper import DEFAULT_GRID, TemperFit, fit_temper

__all__ = [
    "CALIBRATIONS",
    "DEFAULT_GRID",
    "DEFAULT_STOPS",
    "FILTERS",
    "Fold",
    "FrameCalibration",
    "HBNIFilter",
    "MacroObservation",
    "MacroObservationBatch",
    "MacroObservationModel",
    "MacroObservationProcess",
    "MaxOfMeanFilter",
    "StaticStateBayesFilter",
    "StopFit",
    "StreamingFilter",
    "TemperFit",
    "VotingFilter",
    "binomial_stderr",
    "characterize",
    "cross_fit",
    "decide",
    "fit_frame_calibration",
    "fit_stop_threshold",
    "fit_stop_unlabelled",
    "fit_temper",
    "make_filter",
    "tabulate",
    "threshold_checks",
]
