"""Hierarchical Bayesian Noise Inference (HBNI) for streams of classifier outputs.

Main entry points: :func:`fit` / :func:`fit_many` (posterior over per-class noise),
:class:`HBNIPosterior` (draws, summary, save/load, predictive), :class:`HyperPrior`,
the streaming filters (:class:`HBNIFilter`, :class:`SSBF`, :class:`VotingFilter`,
:class:`MaxOfMeanFilter`), the frame-correlation temper (:func:`fit_temper`) and
macro-observations (:class:`MacroObservationProcess`, :func:`characterize` from the fitted model,
:func:`tabulate` from recorded streams, :class:`MacroObservationModel`) and closed-loop perception
replaying recorded streams through a process (:class:`StreamReplay`).

See ``docs/architecture.md`` for the model, the layout and the conventions.
"""

from hbni_pyro.density import gamma_log_prob, lifted_dirichlet_log_prob
from hbni_pyro.filters import SSBF, HBNIFilter, MaxOfMeanFilter, VotingFilter, decide
from hbni_pyro.fit import fit, fit_many
from hbni_pyro.kernels import HBNIMetropolis
from hbni_pyro.macro import MacroObservationModel, MacroObservationProcess, characterize, tabulate
from hbni_pyro.model import HyperPrior, hbni_model, log_joint
from hbni_pyro.posterior import HBNIPosterior
from hbni_pyro.replay import StreamReplay
from hbni_pyro.temper import TemperFit, fit_temper
from hbni_pyro.validation import OUTPUT_FLOOR, as_outputs

__all__ = [
    "HBNIFilter",
    "HBNIMetropolis",
    "HBNIPosterior",
    "HyperPrior",
    "MacroObservationModel",
    "MacroObservationProcess",
    "MaxOfMeanFilter",
    "OUTPUT_FLOOR",
    "SSBF",
    "StreamReplay",
    "TemperFit",
    "VotingFilter",
    "as_outputs",
    "characterize",
    "decide",
    "fit",
    "fit_many",
    "fit_temper",
    "gamma_log_prob",
    "hbni_model",
    "lifted_dirichlet_log_prob",
    "log_joint",
    "tabulate",
]
