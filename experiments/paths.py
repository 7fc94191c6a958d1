"""Where runs, sweeps and caches live: one root, the same from any working directory.

The root is the environment variable ``HBNI_PYRO_ROOT`` when set, else the project folder (the one that holds
``conf/`` and ``experiments/``). The config reads it as ``${paths.root}`` (``conf/config.yaml``), and
:func:`experiments.latest_run` and ``stream.run=latest`` look under ``<root>/outputs``.
"""

from __future__ import annotations

import os
from pathlib import Path

from omegaconf import OmegaConf

ROOT_VARIABLE = "HBNI_PYRO_ROOT"


def project_root() -> Path:
    """The root every default path is relative to (absolute)."""
    override = os.environ.get(ROOT_VARIABLE)
    return Path(override).expanduser().resolve() if override else Path(__file__).resolve().parents[1]


def outputs_root() -> Path:
    """``<root>/outputs``: the runs, one folder per experiment."""
    return project_root() / "outputs"


def register_resolver() -> None:
    """Make ``${project_root:}`` available to the configs."""
    if not OmegaConf.has_resolver("project_root"):
        OmegaConf.register_new_resolver("project_root", lambda: str(project_root()))
