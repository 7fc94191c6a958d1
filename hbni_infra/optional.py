"""Optional dependencies: import one where a feature needs it, or say which extra installs it.

The core install carries what the robot loop needs; plots, ArviZ export, the sample photographs, ROS bags and
the torchvision backbones come with the extras of ``pyproject.toml``.
"""

from __future__ import annotations

import importlib
from types import ModuleType


def require(module: str, extra: str, feature: str) -> ModuleType:
    """The module ``module`` (dotted), or an ``ImportError`` saying that ``feature`` needs ``hbni-pyro[extra]``."""
    try:
        return importlib.import_module(module)
    except ImportError as exc:
        raise ImportError(
            f"{feature} needs the package {module.split('.')[0]!r}: pip install 'hbni-pyro[{extra}]'"
        ) from exc
