"""The distribution's version, one string for the three libraries and the experiments (``pyproject.toml`` reads it)."""

__version__ = "0.2.0"
