"""MCMC kernels for the HBNI noise models, runnable by ``pyro.infer.MCMC``."""

from hbni_pyro.kernels.confusion_mh import ConfusionMetropolis
from hbni_pyro.kernels.mh import HBNIMetropolis
from hbni_pyro.kernels.sequence_mh import SequenceMetropolis

__all__ = ["ConfusionMetropolis", "HBNIMetropolis", "SequenceMetropolis"]
