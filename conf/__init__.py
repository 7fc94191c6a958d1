"""The Hydra configs; installed inside the package as ``experiments.conf`` (a package, so that Hydra finds it)."""
