"""A fitted noise model's posterior: :class:`HBNIPosterior` (draws by chain, summary with ESS and R-hat, save/load,
ArviZ export, predictive streams) and what it needs."""

from hbni_pyro.posterior.posterior import HBNIPosterior, effective_sample_size, posterior_from_samples, quantiles

__all__ = ["HBNIPosterior", "effective_sample_size", "posterior_from_samples", "quantiles"]
