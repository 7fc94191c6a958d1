"""Every experiment config composes against its typed schema; bad values fail before any work, naming the key.

Type errors and unknown keys fail while Hydra composes; ranges (and keys added with ``+``) fail in
``build_settings``, which ``experiments.run`` calls before the experiment starts.
"""

from pathlib import Path

import pytest
from hydra.errors import ConfigCompositionException
from hydra.utils import get_method

from experiments.schemas import SCHEMAS, build_settings, compose_config, register

CONF = Path(__file__).resolve().parents[2] / "conf"
EXPERIMENTS = sorted(p.stem for p in (CONF / "experiment").glob("*.yaml"))
register()


def _compose(*overrides: str):
    return compose_config(overrides, return_hydra_config=True)


def test_every_experiment_has_a_schema():
    assert "hbni_toy" in EXPERIMENTS and set(EXPERIMENTS) <= set(SCHEMAS)


@pytest.mark.parametrize("name", EXPERIMENTS)
def test_experiment_config_composes_and_checks(name):
    cfg = _compose(f"experiment={name}")
    assert cfg.name == name
    assert callable(get_method(cfg.entry))
    assert cfg.hydra.launcher._target_.endswith("JoblibLauncher")
    assert len(cfg.headline) >= 1
    build_settings(cfg)


# (experiment, override, the key the message names) -- a wrong type fails while composing
TYPE_ERRORS = [
    ("hbni_toy", "seed=abc", "seed"),
    ("hbni_toy", "progress=maybe", "progress"),
    ("hbni_toy", "toy.per_class=abc", "toy.per_class"),
    ("hbni_toy", "hbni.fit.num_chains=two", "hbni.fit.num_chains"),
    ("hbni_toy", "hbni.hyperprior.beta=big", "hbni.hyperprior.beta"),
    ("filtering_error", "study.num_trials=1.5", "study.num_trials"),
    ("macro_observation", "study.threshold=high", "study.threshold"),
    ("perception_replay", "study.frames=x", "study.frames"),
    ("perception_replay", "classifier.C=big", "classifier.C"),
    ("package_delivery", "planners.gdice.ce_alpha=fast", "planners.gdice.ce_alpha"),
    ("package_delivery", "domain.joint_wait=long", "domain.joint_wait"),
    ("disaster_relief", "study.reeval_rollouts=many", "study.reeval_rollouts"),
    ("dpomdp_benchmarks", "study.caps.iterations=x", "study.caps.iterations"),
    ("mission", "mission.threshold=abc", "mission.threshold"),
    ("mission", "domain.num_agents=two", "domain.num_agents"),
    ("mission", "warm_start=maybe", "warm_start"),
]


@pytest.mark.parametrize("name, override, key", TYPE_ERRORS)
def test_a_wrong_type_fails_while_composing(name, override, key):
    with pytest.raises(ConfigCompositionException) as info:
        _compose(f"experiment={name}", override)
    assert f"full_key: {key}" in str(info.value.__cause__)


@pytest.mark.parametrize(
    "name, override", [("mission", "mission.nope=1"), ("hbni_toy", "toy.nope=1"), ("hbni_toy", "nope=1")]
)
def test_an_unknown_key_fails_while_composing(name, override):
    with pytest.raises(ConfigCompositionException, match="Could not override"):
        _compose(f"experiment={name}", override)


# (experiment, override, the start of the message)
RANGE_ERRORS = [
    ("hbni_toy", "toy.per_class=0", "toy.per_class: expected an int >= 1"),
    ("hbni_toy", "toy.theta=[1.0,-2.0]", "toy.theta: expected at least 2 noise levels > 0"),
    ("hbni_toy", "hbni.fit.method=hmc", "hbni.fit.method: expected one of ['mh', 'nuts']"),
    ("hbni_toy", "hbni.fit.warmup_steps=-1", "hbni.fit.warmup_steps: expected an int >= 0"),
    ("macro_observation", "hbni.filter.mode=mean", "hbni.filter.mode: expected one of ['marginal', 'plugin']"),
    ("hbni_toy", "hbni.hyperprior.beta=-1", "hbni.hyperprior: HyperPrior.beta: expected a positive finite number"),
    ("hbni_toy", "toy.near_perfect_hyperprior.eta=0", "toy.near_perfect_hyperprior: HyperPrior.eta"),
    ("filtering_error", "study.targets=[0.5,1.5]", "study.targets: expected a finite number in (0, 1]"),
    ("filtering_error", "study.training_sizes=[]", "study.training_sizes: expected sizes >= 1"),
    ("macro_observation", "study.threshold=0", "study.threshold: expected a finite number in (0, 1]"),
    ("perception_replay", "study.classes=[irobot,unicorn]", "study.classes: expected at least 2 distinct objects"),
    ("perception_replay", "classifier.cv=1", "classifier.cv: expected an int >= 2"),
    ("perception_replay", "+study.mission.fog=[1,2]", "study.mission: unknown field(s) ['fog']"),
    ("package_delivery", "planners.gdice.ce_alpha=2", "planners.gdice.ce_alpha: expected a finite number in (0, 1]"),
    ("package_delivery", "planners.cold.ce_alpha=2", "planners.cold.ce_alpha: expected a finite number in (0, 1]"),
    ("package_delivery", "reference.runs=0", "reference.runs: expected an int >= 1"),
    ("package_delivery", "planners.gdice.ce_elites=500", "planners.gdice.ce_elites: expected <= ce_samples"),
    ("package_delivery", "domain.gamma=1.5", "domain.gamma: expected a finite number in (0, 1]"),
    ("package_delivery", "study.alpha_sweep=[0.1,3]", "study.alpha_sweep: expected a finite number in (0, 1]"),
    (
        "package_delivery",
        "study.seeded.ce_init_weight=2",
        "study.seeded: ce_init_weight: expected a finite number in [0, 1]",
    ),
    ("package_delivery", "+study.seeded.speed=2", "study.seeded: unknown planner setting(s) ['speed']"),
    ("disaster_relief", "study.reeval_rollouts=1", "study.reeval_rollouts: expected an int >= 2"),
    ("disaster_relief", "domain.degrade_prob=2", "domain.degrade_prob: expected a finite number in [0, 1]"),
    ("dpomdp_benchmarks", "study.caps.restarts=0", "study.caps.restarts: expected an int >= 1"),
    ("mission", "mission.threshold=1.5", "mission.threshold: expected a finite number in (0, 1]"),
    ("mission", "mission.temper=auto", "mission.temper: expected 'fit' or a float in (0, 1]"),
    ("mission", "mission.temper=0", "mission.temper: expected 'fit' or a float in (0, 1]"),
    ("mission", "mission.temper=1.5", "mission.temper: expected 'fit' or a float in (0, 1]"),
    ("mission", "mission.temper=0.5", "mission.temper: the 'sequence' model counts correlated frames itself"),
    ("mission", "mission.planning_model=oracle", "mission.planning_model: expected one of ['empirical', 'generative']"),
    ("mission", "mission.frames=0", "mission.frames: expected an int >= 1"),
    ("mission", "mission.calibration=platt", "mission.calibration: expected one of ['temperature', 'matrix']"),
    ("mission", "mission.hbni_stop=early", "mission.hbni_stop: expected one of ['calibrated', 'nominal']"),
    ("mission", "mission.stop_folds=1", "mission.stop_folds: expected an int >= 2, got 1"),
    ("mission", "mission.stop_folds=49", "mission.stop_folds: expected at most calib_sequences=48, got 49"),
    ("mission", "+mission.conditions.fog=[0.1,0.2]", "mission.conditions: unknown field(s) ['fog']"),
    ("mission", "perception=oracle", "perception: expected a subset of ['hbni', 'calibrated', 'ssbf', 'max_of_mean']"),
    ("mission", "warm_planner.budget=0", "warm_planner.budget: expected an int >= 1"),
    ("mission", "study.threads=0", "study.threads: expected an int >= 1"),
    ("mission", "+mission.foo=1", "mission.foo: Key 'foo' not in 'MissionBlock'"),
    ("mission_full", "planner.num_nodes=0", "planner.num_nodes: expected an int >= 1"),
    ("mission", "mission.bank.powered.entries=[hbni_exact]", "mission.bank.powered.entries: expected policies among"),
    ("mission", "mission.bank.powered.max_sequences=1", "mission.bank.powered.max_sequences: expected an int >= 2"),
    ("mission", "mission.bank.powered.margin=0.5", "mission.bank.powered.margin: expected a finite number in [1, 4]"),
]


@pytest.mark.parametrize("name, override, message", RANGE_ERRORS)
def test_an_out_of_range_value_fails_the_check_naming_the_key(name, override, message):
    cfg = _compose(f"experiment={name}", override)
    with pytest.raises(ValueError) as info:
        build_settings(cfg)
    assert str(info.value).startswith(message), str(info.value)


def test_the_mission_plans_with_no_hand_written_controller():
    """The default main job and the larger mission plan perfect perception from scratch and each variant from that
    plan, the larger one with more rollouts."""
    main = _compose("experiment=mission")
    assert main.warm_start and main.planner.ce_reactive and main.planner.ce_result == "duel"
    assert main.warm_planner.phases == ["ls"]
    full = _compose("experiment=mission_full")
    assert full.warm_start and full.planner.budget > main.planner.budget
    assert full.planner.ce_reactive and full.warm_planner.budget > main.warm_planner.budget


def _schema_fields(schema, seen):
    """(class, field) of every field of ``schema`` and the blocks below it, the generated target blocks excepted."""
    import dataclasses

    from experiments.schemas.targets import TargetBlock

    if schema in seen or issubclass(schema, TargetBlock):
        return
    seen.add(schema)
    for f in dataclasses.fields(schema):
        if f.default_factory is not dataclasses.MISSING and dataclasses.is_dataclass(f.default_factory):
            yield from _schema_fields(f.default_factory, seen)
        else:
            yield schema, f


def test_the_yaml_is_the_only_place_for_defaults():
    """Every schema field is MISSING (or a block): a study's settings live in conf/, and every experiment sets every
    key. The blocks typed after a library callable (``hbni.fit``, ``hbni.filter``) take that callable's defaults."""
    from omegaconf import MISSING, OmegaConf

    from experiments.schemas.targets import signature_defaults
    from hbni_pyro import HBNIFilter, fit

    library = {"FitBlock": signature_defaults(fit), "FilterBlock": signature_defaults(HBNIFilter)}
    seen: set = set()
    defaults = [
        (cls.__name__, f.name)
        for schema in SCHEMAS.values()
        for cls, f in _schema_fields(schema, seen)
        if f.default is not MISSING and library.get(cls.__name__, {}).get(f.name, MISSING) != f.default
    ]
    assert defaults == []
    for name in EXPERIMENTS:
        cfg = compose_config([f"experiment={name}"])
        assert OmegaConf.missing_keys(cfg) == set(), name


def test_a_block_set_to_null_is_not_searched_for_unread_settings():
    """``mission.conditions=null`` (a block set to null) is a setting like any other, not a crash of the check."""
    from experiments.schemas import check_overrides, typed_settings

    overrides = [
        "experiment=mission",
        "perception=hbni",
        "hbni.model=paper",
        "mission.temper=0.5",
        "mission.conditions=null",
    ]
    check_overrides(typed_settings(_compose(*overrides)), overrides)
