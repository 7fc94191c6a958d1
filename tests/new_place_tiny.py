"""Tiny settings of ``experiment=new_place`` for tests that run the real entry point (seconds, not minutes)."""

import tempfile
from pathlib import Path

from mission_tiny import TINY_MISSION

TINY_NEW_PLACE = [
    *(s for s in TINY_MISSION if s.startswith(("planner.", "warm_planner.", "hbni.", "study.", "progress"))),
    "new_place.train_per_class=5",
    "new_place.augment=0",
    "new_place.frames=5",
    "new_place.old.sequences=4",
    "new_place.labelled=[0,2]",
    "new_place.unlabelled=12",
    "new_place.generative_streams=50",
    "new_place.bank.sequences=2",
    "new_place.bank.workers=0",
    "new_place.bootstrap.replicates=2",
    "new_place.bootstrap.rollouts=4",
    "new_place.photos.train_per_class=5",
    "new_place.photos.augment=0",
    "new_place.photos.old_sequences=2",
    "new_place.photos.test_sequences=2",
    "new_place.calibration=temperature",  # one parameter: L-BFGS on a few separable frames takes long on the matrix
    f"new_place.cache_dir={Path(tempfile.gettempdir()) / 'hbni-pyro-test-new-place'}",
]
