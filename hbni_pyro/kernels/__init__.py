"""MCMC kernels for the HBNI model, runnable by ``pyro.infer.MCMC``."""

from hbni_pyro.kernels.mh import HBNIMetropolis

__all__ = ["HBNIMetropolis"]
