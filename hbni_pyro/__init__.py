"""Hierarchical Bayesian Noise Inference (HBNI) for streams of classifier outputs.

Main entry points: :func:`fit` / :func:`fit_many` (posterior of a noise model: ``model="paper"``,
``"confusion"`` or ``"sequence"``, each a :class:`NoiseModel` in :mod:`hbni_pyro.variants`),
:class:`HBNIPosterior` (draws, summary, save/load, predictive), :class:`HyperPrior`,
the streaming filters (:class:`HBNIFilter`, :class:`StaticStateBayesFilter`, :class:`VotingFilter`,
:class:`MaxOfMeanFilter`; the calibrated peer: SSBF on frames calibrated by :func:`fit_frame_calibration`), the frame-correlation temper of the frame-level models (:func:`fit_temper`; the
sequence model estimates an AR(1) correlation of its frames instead, :mod:`hbni_pyro.frame_correlation`) and
macro-observations (:class:`MacroObservationProcess`, :func:`characterize` from the fitted model,
:func:`tabulate` from recorded streams, :class:`MacroObservationModel`), their calibration
(:func:`threshold_checks`, :func:`stream_reliability`, the stopping confidence that keeps a promised accuracy:
:func:`fit_stop_threshold`; without labels, :func:`fit_stop_unlabelled`), a sequence model adapted to a new place
from its unlabelled streams (:func:`adapt`, :class:`ShiftPrior`), closed-loop perception replaying recorded
streams through a process (:class:`StreamReplay`), and a live classified stream cut into consecutive
macro-observations (:func:`macro_observations`, :class:`Segment`).

See ``docs/architecture.md`` for the model, the layout and the conventions.
"""

from hbni_infra.version import __version__

from hbni_pyro.adapt import adapt
from hbni_pyro.calibration import (
    Fold,
    StopFit,
    cross_fit,
    fit_stop_threshold,
    fit_stop_unlabelled,
    reliability,
    stream_reliability,
    threshold_checks,
)
from hbni_pyro.checks import CheckResult, check
from hbni_pyro.confusion_model import confusion_model
from hbni_pyro.density import gamma_log_prob, lifted_dirichlet_log_prob
from hbni_pyro.filters import (
    FILTERS,
    StaticStateBayesFilter,
    HBNIFilter,
    MaxOfMeanFilter,
    VotingFilter,
    decide,
    make_filter,
)
from hbni_pyro.fit import fit, fit_many
from hbni_pyro.frame_calibration import CALIBRATIONS, FrameCalibration, fit_frame_calibration
from hbni_pyro.kernels import ConfusionMetropolis, HBNIMetropolis, SequenceMetropolis
from hbni_pyro.macro import (
    MacroObservationModel,
    MacroObservationProcess,
    characterize,
    tabulate,
)
from hbni_pyro.model import HyperPrior, hbni_model, log_joint
from hbni_pyro.posterior import HBNIPosterior
from hbni_pyro.replay import StreamReplay
from hbni_pyro.segments import Segment, macro_observations
from hbni_pyro.sequence_model import sequence_model
from hbni_pyro.shift_prior import ShiftPrior
from hbni_pyro.temper import TemperFit, fit_temper
from hbni_pyro.validation import OUTPUT_FLOOR, as_outputs
from hbni_pyro.variants import NOISE_MODELS, NoiseModel, noise_model, register

__all__ = [
    "__version__",
    "adapt",
    "CALIBRATIONS",
    "FILTERS",
    "FrameCalibration",
    "NOISE_MODELS",
    "OUTPUT_FLOOR",
    "StaticStateBayesFilter",
    "CheckResult",
    "ConfusionMetropolis",
    "HBNIFilter",
    "HBNIMetropolis",
    "HBNIPosterior",
    "HyperPrior",
    "MacroObservationModel",
    "MacroObservationProcess",
    "MaxOfMeanFilter",
    "NoiseModel",
    "Segment",
    "SequenceMetropolis",
    "ShiftPrior",
    "Fold",
    "StopFit",
    "StreamReplay",
    "TemperFit",
    "VotingFilter",
    "as_outputs",
    "characterize",
    "check",
    "confusion_model",
    "decide",
    "macro_observations",
    "make_filter",
    "noise_model",
    "register",
    "fit",
    "fit_many",
    "fit_frame_calibration",
    "cross_fit",
    "fit_stop_threshold",
    "fit_stop_unlabelled",
    "fit_temper",
    "gamma_log_prob",
    "hbni_model",
    "lifted_dirichlet_log_prob",
    "log_joint",
    "reliability",
    "sequence_model",
    "stream_reliability",
    "tabulate",
    "threshold_checks",
]
