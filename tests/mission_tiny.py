"""Tiny settings of ``experiment=mission`` for tests that run the real entry point (seconds, not minutes).

Each planner gets only settings it reads (a setting the chosen planner ignores is refused): the mission's planner
both phases', the warm start (local search only) local search's, and G-DICE (``TINY_MISSION_GDICE``) its
cross-entropy's; without warm starts (``TINY_MISSION_FROM_SCRATCH``, ``warm_start=false``) no warm_planner setting.
"""

import tempfile
from pathlib import Path

_COMMON = ("patience=1", "num_nodes=6", "start_nodes=3")
_CE = ("ce_iterations=2", "ce_samples=10", "ce_elites=2", "ce_memory=1", "ce_rollouts=4", "ce_screen_rollouts=2")
_LS = ("ls_candidates=40", "ls_stages=[[2,0.5],[4,2]]", "duel_rollouts=20", "visit_rollouts=10")
_BASE = [
    "mission.train_per_class=5",
    "mission.augment=0",
    "mission.calib_sequences=2",
    "study.threads=1",  # xdist already runs a worker per core
    "mission.char_sequences=2",
    "mission.frames=5",
    "hbni.fit.num_chains=2",
    "hbni.fit.num_samples=40",
    "hbni.fit.warmup_steps=40",
    "study.reeval_rollouts=20",
    "progress=false",
    "mission.bank.sequences=2",
    "mission.bank.workers=0",
    "mission.bank.powered.max_sequences=8",  # HBNI's value test: at most 4 sequences per class rendered on demand
    "mission.generative_streams=50",
    "mission.bootstrap.replicates=2",
    "mission.bootstrap.rollouts=4",
    *(f"warm_planner.{setting}" for setting in (*_COMMON, *_LS)),
    "planner.budget=3000",
    "warm_planner.budget=1000",
]
TINY_MISSION = [*_BASE, *(f"planner.{setting}" for setting in (*_COMMON, *_CE, *_LS))]
TINY_MISSION_GDICE = ["planner=gdice", *_BASE, *(f"planner.{setting}" for setting in (*_COMMON, *_CE))]
TINY_MISSION_FROM_SCRATCH = ["warm_start=false", *(s for s in TINY_MISSION if not s.startswith("warm_planner."))]

TINY_BANKS = f"mission.bank.cache_dir={Path(tempfile.gettempdir()) / 'hbni-pyro-test-banks'}"
"""The tiny runs' bank cache, shared across runs so that a second run with the same settings finds its bank."""
