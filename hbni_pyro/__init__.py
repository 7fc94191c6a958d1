"""Hierarchical Bayesian Noise Inference (HBNI) for streams of classifier outputs.

Main entry points: :func:`fit` / :func:`fit_many` (posterior of a noise model: ``model="paper"``,
``"confusion"`` or ``"sequence"``, each a :class:`NoiseModel` in :mod:`hbni_pyro.models`),
:class:`HBNIPosterior` (draws, summary, save/load, predictive), :class:`HyperPrior`, the models' output samplers
(:func:`sample_outputs`, :func:`sample_sequences`), the streaming filters (:class:`HBNIFilter`,
:class:`StaticStateBayesFilter`, :class:`VotingFilter`, :class:`MaxOfMeanFilter`; the calibrated peer: SSBF on
frames calibrated by :func:`fit_frame_calibration`), the frame-correlation temper of the frame-level models
(:func:`fit_temper`; the sequence model estimates an AR(1) correlation of its frames instead) and
macro-observations (:class:`MacroObservationProcess`, :func:`characterize` from the fitted model,
:func:`tabulate` from recorded streams, :class:`MacroObservationModel`), their calibration
(:func:`threshold_checks`, :func:`stream_reliability`, the stopping confidence that keeps a promised accuracy:
:func:`fit_stop_threshold`; without labels, :func:`fit_stop_unlabelled`), a sequence model adapted to a new place
from its unlabelled streams there (:func:`adapt`, :class:`ShiftPrior`), posterior predictive checks (:func:`predictive_check`) and simulation-based
calibration (:func:`run_sbc`), closed-loop perception replaying recorded streams through a process
(:class:`StreamReplay`), and a live classified stream cut into consecutive macro-observations
(:func:`macro_observations`, :class:`Segment`; with stamps and a controller: :func:`live_macro_observations`).

The package is a house of rooms, each with its ``__all__``: :mod:`~hbni_pyro.distributions` (hyperprior,
densities, samplers), :mod:`~hbni_pyro.mcmc` (the kernels' shared machinery), :mod:`~hbni_pyro.models` (one room
per noise model and their registry), :mod:`~hbni_pyro.posterior`, :mod:`~hbni_pyro.filters`,
:mod:`~hbni_pyro.diagnostics` and :mod:`~hbni_pyro.runtime`; :mod:`hbni_pyro.fit` fits and
:mod:`hbni_pyro.validation` checks classifier outputs at the boundary. See ``docs/architecture.md`` for the model,
the layout and the conventions.
"""

from hbni_infra.version import __version__

from hbni_pyro.diagnostics import (
    PredictiveCheck,
    Reliability,
    SBCResult,
    predictive_check,
    reliability,
    run_sbc,
    stream_reliability,
)
from hbni_pyro.distributions import HyperPrior, gamma_log_prob, lifted_dirichlet_log_prob, sample_dirichlet
from hbni_pyro.filters import (
    CALIBRATIONS,
    FILTERS,
    Fold,
    FrameCalibration,
    HBNIFilter,
    MacroObservationModel,
    MacroObservationProcess,
    MaxOfMeanFilter,
    StaticStateBayesFilter,
    StopFit,
    TemperFit,
    VotingFilter,
    binomial_stderr,
    characterize,
    cross_fit,
    decide,
    fit_frame_calibration,
    fit_stop_threshold,
    fit_stop_unlabelled,
    fit_temper,
    make_filter,
    tabulate,
    threshold_checks,
)
from hbni_pyro.fit import adapt, fit, fit_many
from hbni_pyro.models import (
    NOISE_MODELS,
    ConfusionMetropolis,
    HBNIMetropolis,
    NoiseModel,
    SequenceMetropolis,
    ShiftPrior,
    confusion_model,
    hbni_model,
    log_joint,
    model_names,
    noise_model,
    register,
    sample_outputs,
    sample_sequences,
    sequence_model,
)
from hbni_pyro.posterior import HBNIPosterior
from hbni_pyro.runtime import (
    LiveMacroObservation,
    Segment,
    StreamReplay,
    live_macro_observations,
    macro_observations,
)
from hbni_pyro.validation import OUTPUT_FLOOR, as_outputs

__all__ = [
    "__version__",
    "adapt",
    "CALIBRATIONS",
    "FILTERS",
    "NOISE_MODELS",
    "OUTPUT_FLOOR",
    "ConfusionMetropolis",
    "Fold",
    "FrameCalibration",
    "HBNIFilter",
    "HBNIMetropolis",
    "HBNIPosterior",
    "HyperPrior",
    "LiveMacroObservation",
    "MacroObservationModel",
    "MacroObservationProcess",
    "MaxOfMeanFilter",
    "NoiseModel",
    "PredictiveCheck",
    "Reliability",
    "SBCResult",
    "Segment",
    "SequenceMetropolis",
    "ShiftPrior",
    "StaticStateBayesFilter",
    "StopFit",
    "StreamReplay",
    "TemperFit",
    "VotingFilter",
    "as_outputs",
    "binomial_stderr",
    "characterize",
    "confusion_model",
    "cross_fit",
    "decide",
    "fit",
    "fit_frame_calibration",
    "fit_many",
    "fit_stop_threshold",
    "fit_stop_unlabelled",
    "fit_temper",
    "gamma_log_prob",
    "hbni_model",
    "lifted_dirichlet_log_prob",
    "live_macro_observations",
    "log_joint",
    "macro_observations",
    "make_filter",
    "model_names",
    "noise_model",
    "predictive_check",
    "register",
    "reliability",
    "run_sbc",
    "sample_dirichlet",
    "sample_outputs",
    "sample_sequences",
    "sequence_model",
    "stream_reliability",
    "tabulate",
    "threshold_checks",
]
