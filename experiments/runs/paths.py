"""Where runs, sweeps and caches live: under one root, never inside the installed package.

The root is the environment variable ``HBNI_PYRO_ROOT`` when set, else the current working directory (as
with any command-line tool: run from a checkout's root, the runs land in its ``outputs/``). The config reads
it as ``${paths.root}`` (``conf/config.yaml``), and :func:`experiments.latest_run` and ``stream.run=latest``
look under ``<root>/outputs``.
"""

from __future__ import annotations

import os
from pathlib import Path

from omegaconf import OmegaConf

ROOT_VARIABLE = "HBNI_PYRO_ROOT"


def project_root() -> Path:
    """The root every default path is relative to (absolute): ``HBNI_PYRO_ROOT``, else the working directory."""
    override = os.environ.get(ROOT_VARIABLE)
    return Path(override).expanduser().resolve() if override else Path.cwd().resolve()


def outputs_root() -> Path:
    """``<root>/outputs``: the runs, one folder per experiment."""
    return project_root() / "outputs"


def register_resolver() -> None:
    """Make ``${project_root:}`` available to the configs."""
    if not OmegaConf.has_resolver("project_root"):
        OmegaConf.register_new_resolver("project_root", lambda: str(project_root()))
