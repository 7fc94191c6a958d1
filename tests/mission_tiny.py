"""Tiny settings of ``experiment=mission`` for tests that run the real entry point (seconds, not minutes)."""

TINY_MISSION = [
    "mission.train_per_class=5", "mission.augment=0", "mission.calib_sequences=1", "mission.char_sequences=2",
    "mission.frames=5", "hbni.fit.num_chains=2", "hbni.fit.num_samples=40", "hbni.fit.warmup_steps=40",
    "study.reeval_rollouts=20",
    "progress=false", "mission.bank.sequences=2", "mission.bank.workers=0", "mission.generative_streams=50",
    "mission.bootstrap.replicates=2", "mission.bootstrap.rollouts=4",
    *(f"{planner}.{setting}" for planner in ("planner", "warm_planner") for setting in (
        "patience=1", "num_nodes=6", "start_nodes=3", "ce_iterations=2", "ce_samples=10", "ce_elites=2",
        "ce_memory=1", "ce_rollouts=4", "ce_screen_rollouts=2", "ls_candidates=40", "ls_stages=[[2,0.5],[4,2]]",
        "duel_rollouts=20", "visit_rollouts=10")),
    "planner.budget=3000", "warm_planner.budget=1000",
]
