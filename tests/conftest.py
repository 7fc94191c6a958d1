"""Shared pytest setup: the repository root and a single-threaded torch for small tensor programs."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

REPO_ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="session")
def repo_root() -> Path:
    return REPO_ROOT


torch.set_num_threads(max(1, min(2, torch.get_num_threads())))
