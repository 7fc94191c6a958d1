"""The config boundary: a setting the chosen experiment never reads is refused before any work, naming the key and
the experiment, for one run (the check ``experiments.run`` makes at the start) and for a ``-m`` sweep (every job
checked in the parent before any is launched). Composition-time checks: Hydra's compose API, no subprocess, except
one real sweep."""

import dataclasses
from pathlib import Path

import pytest
import torch
from experiment_runs import run_experiment
from hydra import initialize_config_dir
from hydra.core.global_hydra import GlobalHydra
from hydra.types import RunMode
from omegaconf import DictConfig, OmegaConf

import hbni_pyro
from experiments.schemas import (
    build_settings,
    check_overrides,
    compose_config,
    register,
    typed_settings,
    unread_settings,
)
from experiments.sweep import SweepGuard, check_sweep, sweep_jobs
from hbni_pyro import NOISE_MODELS, sample_outputs

ROOT = Path(__file__).resolve().parents[2]
CONF = str(ROOT / "conf")
EXPERIMENTS = sorted(p.stem for p in (ROOT / "conf" / "experiment").glob("*.yaml"))
register()


def _refused(overrides: list[str]) -> str:
    """The message of the refusal of ``overrides`` (a run's check at its start)."""
    settings = typed_settings(compose_config(overrides))
    with pytest.raises(ValueError) as info:
        check_overrides(settings, overrides)
    return str(info.value)


# (the overrides of one run, the key the message names) -- every one a setting the experiment never reads
UNREAD = [
    (["experiment=hbni_toy", "hbni.model=sequence"], "hbni.model"),
    (["experiment=hbni_toy", "hbni.filter.mode=plugin"], "hbni.filter.mode"),
    (["experiment=hbni_toy", "hbni.hyperprior.look_vertex=2.0"], "hbni.hyperprior.look_vertex"),
    (["experiment=hbni_toy", "toy.near_perfect_hyperprior.offdiag_loc_sd=0.3"], "toy.near_perfect_hyperprior"),
    (["experiment=filtering_error", "hbni.model=confusion"], "hbni.model"),
    (["experiment=filtering_error", "hbni.hyperprior.within_scale=1.0"], "hbni.hyperprior.within_scale"),
    (["experiment=macro_observation", "hbni.model=sequence"], "hbni.model"),
    (["experiment=macro_observation", "hbni.hyperprior.between_df=3.0"], "hbni.hyperprior.between_df"),
    (["experiment=perception_replay", "hbni.hyperprior.beta=3.0"], "hbni.hyperprior.beta"),
    (["experiment=perception_replay", "hbni.model=paper", "hbni.hyperprior.look_sd=2.0"], "hbni.hyperprior.look_sd"),
    (["experiment=package_delivery", "hbni.model=paper"], "hbni.model"),
    (["experiment=package_delivery", "hbni.fit.num_chains=4"], "hbni.fit.num_chains"),
    (["experiment=package_delivery", "hbni=default"], "hbni"),
    (["experiment=package_delivery", "planners.gdice.ls_candidates=10"], "planners.gdice.ls_candidates"),
    (["experiment=package_delivery", "reference.planner.ls_patience=3"], "reference.planner.ls_patience"),
    (["experiment=disaster_relief", "hbni.filter.mode=plugin"], "hbni.filter.mode"),
    (["experiment=disaster_relief", "planners.cold.ce_injection_until=0.5"], "planners.cold.ce_injection_until"),
    (["experiment=dpomdp_benchmarks", "hbni.fit.method=nuts"], "hbni.fit.method"),
    (["experiment=dpomdp_benchmarks", "planner.duel_z=2.0"], "planner.duel_z"),
    (["experiment=mission", "warm_start=false", "warm_planner.budget=100"], "warm_planner.budget"),
    (["experiment=mission", "warm_start=false", "planner@warm_planner=gdice"], "warm_planner"),
    (["experiment=mission", "domain.perception=null"], "domain.perception"),
    (["experiment=mission", "hbni.hyperprior.omega=3.0"], "hbni.hyperprior.omega"),
    (
        [
            "experiment=mission",
            "mission.planning_model=empirical",
            "mission.compare_planning_models=false",
            "mission.generative_streams=10",
        ],
        "mission.generative_streams",
    ),
    (["experiment=mission", "planner.ce_injection_threshold=0.2"], "planner.ce_injection_threshold"),
    (["experiment=mission_full", "warm_planner.ce_alpha=0.3"], "warm_planner.ce_alpha"),
    (["experiment=mission_full", "hbni.model=confusion", "hbni.hyperprior.within_df=3.0"], "hbni.hyperprior.within_df"),
    (["experiment=stream", "seed=3"], "seed"),
    (["experiment=stream", "hbni.model=paper"], "hbni.model"),
    (["experiment=stream", "hbni.fit.num_samples=10"], "hbni.fit.num_samples"),
    (["experiment=stream", "hbni.hyperprior.beta=3.0"], "hbni.hyperprior.beta"),
    (["experiment=stream", "stream.agent=1"], "stream.agent"),
    (
        ["experiment=stream", "stream.classifier=c.safetensors", "stream.posterior=p.safetensors", "stream.run=r"],
        "stream.run",
    ),
    (["experiment=noise_models", "hbni.model=paper"], "hbni.model"),
    (["experiment=noise_models", "study.images_calibration=0.3"], "study.images_calibration"),
    (
        ["experiment=noise_models", "study.models=[paper]", "hbni.hyperprior.look_vertex=2.0"],
        "hbni.hyperprior.look_vertex",
    ),
]


@pytest.mark.parametrize("overrides, key", UNREAD, ids=[" ".join(o[1:]) for o, _ in UNREAD])
def test_a_setting_the_experiment_never_reads_is_refused_naming_it_and_the_experiment(overrides, key):
    experiment = overrides[0].split("=", 1)[1]
    message = _refused(overrides)
    assert message.startswith(f"{key}") and f"experiment {experiment} never reads" in message, message


@pytest.mark.parametrize("name", EXPERIMENTS)
def test_every_unread_key_of_every_experiment_is_refused_and_every_read_one_accepted(name):
    """Each key the experiment declares unread is refused when set; every other leaf of its config is accepted."""
    cfg = compose_config([f"experiment={name}"])
    settings = typed_settings(cfg)
    unread = unread_settings(settings)
    assert name not in ("hbni_toy", "package_delivery", "stream") or unread
    for key in unread:
        with pytest.raises(ValueError, match=f"^{key}: experiment {name} never reads it"):
            check_overrides(settings, [f"{key}=1"])
    plain = OmegaConf.to_container(cfg, resolve=False)
    leaves = [key for key in _leaves(plain, "") if not any(key == u or key.startswith(f"{u}.") for u in unread)]
    assert leaves
    check_overrides(settings, [f"{key}=1" for key in leaves])


def _leaves(node, path):
    if isinstance(node, dict) and node:
        for key, value in node.items():
            yield from _leaves(value, f"{path}.{key}" if path else str(key))
    else:
        yield path


def test_the_settings_the_refusal_accepts_still_run_the_same_checks():
    """A read key with a bad value is not reported as unread: the range check names it."""
    cfg = compose_config(["experiment=macro_observation", "hbni.filter.mode=mean"])
    check_overrides(typed_settings(cfg), ["hbni.filter.mode=mean"])
    with pytest.raises(ValueError, match=r"^hbni.filter.mode: expected one of \['marginal', 'plugin'\]"):
        build_settings(cfg)


def _sweep_config(overrides: list[str]) -> DictConfig:
    """The parent's config of ``python -m experiments.run -m <overrides>`` (as Hydra composes it)."""
    return GlobalHydra.instance().hydra.compose_config("config", overrides, run_mode=RunMode.MULTIRUN)


# (a sweep's overrides, the key, the experiment and the job the message names)
SWEEPS = [
    (["experiment=hbni_toy", "hbni.model=paper,sequence"], "hbni.model", "hbni_toy", 0),
    (["experiment=hbni_toy", "hbni.filter.mode=marginal,plugin"], "hbni.filter.mode", "hbni_toy", 0),
    (["experiment=hbni_toy,package_delivery", "hbni.fit.num_chains=2"], "hbni.fit.num_chains", "package_delivery", 1),
    (["experiment=mission", "warm_start=true,false", "warm_planner.budget=5"], "warm_planner.budget", "mission", 1),
    (["experiment=stream", "seed=0,1"], "seed", "stream", 0),
    (
        ["experiment=disaster_relief", "planners.gdice.ls_patience=1,2,3"],
        "planners.gdice.ls_patience",
        "disaster_relief",
        0,
    ),
    (
        ["experiment=mission", "hbni.model=paper,sequence", "hbni.hyperprior.beta=3.0"],
        "hbni.hyperprior.beta",
        "mission",
        1,
    ),
]


@pytest.mark.parametrize("overrides, key, experiment, job", SWEEPS, ids=[" ".join(s[0]) for s in SWEEPS])
def test_a_sweep_over_an_unread_key_is_refused_before_any_job(overrides, key, experiment, job):
    with initialize_config_dir(config_dir=CONF, version_base="1.3"):
        config = _sweep_config(overrides)
        jobs = sweep_jobs(config)
        with pytest.raises(ValueError) as info:
            check_sweep(config, jobs)
    message = str(info.value)
    assert message.startswith(f"{key}: experiment {experiment} never reads") and f"(job {job}: " in message, message


def test_a_sweep_over_read_keys_passes_its_check():
    with initialize_config_dir(config_dir=CONF, version_base="1.3"):
        config = _sweep_config(["experiment=filtering_error", "hbni.filter.mode=marginal,plugin", "seed=0,1"])
        jobs = sweep_jobs(config)
        check_sweep(config, jobs)
    assert len(jobs) == 4 and ["experiment=filtering_error", "hbni.filter.mode=plugin", "seed=1"] in jobs


def test_the_sweep_guard_exits_2_with_one_line(capsys):
    with initialize_config_dir(config_dir=CONF, version_base="1.3"):
        config = _sweep_config(["experiment=hbni_toy", "hbni.model=paper,sequence"])
        with pytest.raises(SystemExit) as info:
            SweepGuard().on_multirun_start(config)
    assert info.value.code == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("config error: hbni.model: experiment hbni_toy never reads it") and "\n" not in err


@pytest.mark.slow  # starts the entry point in a process
def test_a_real_sweep_over_an_unread_key_fails_before_any_work(tmp_path):
    sweep = tmp_path / "sweep"
    proc = run_experiment(
        ["-m", "experiment=hbni_toy", "hbni.model=paper,sequence", f"hydra.sweep.dir={sweep}"],
        ROOT,
        check=False,
        timeout=300,
    )
    assert proc.returncode == 2, proc.stderr
    assert "config error: hbni.model: experiment hbni_toy never reads it" in proc.stderr
    assert not sweep.exists()  # no job folder, no report: nothing ran


def _fit(model: str, hyperprior: hbni_pyro.HyperPrior) -> torch.Tensor:
    g = torch.Generator().manual_seed(0)
    classes = torch.arange(3).repeat_interleave(4)
    obs = sample_outputs(torch.tensor([2.0, 6.0, 20.0]), classes, g)
    kw = {"sequence_ids": classes} if NOISE_MODELS[model].sequences else {}
    post = hbni_pyro.fit(
        obs, classes, model=model, **kw, num_chains=2, num_samples=20, warmup_steps=20, seed=0, progress=False,
        hyperprior=hyperprior,
    )  # fmt: skip
    return torch.cat([v.reshape(-1) for v in post.samples.values()])


@pytest.mark.parametrize("model", sorted(NOISE_MODELS))
def test_a_noise_model_reads_its_hyperprior_fields_and_no_other(model):
    """Doubling every field a model does not declare leaves its fit unchanged; doubling the ones it does changes it."""
    base = hbni_pyro.HyperPrior()
    fields = set(NOISE_MODELS[model].hyperprior_fields)
    others = {f.name: 2 * getattr(base, f.name) for f in dataclasses.fields(base) if f.name not in fields}
    read = {name: 2 * getattr(base, name) for name in fields}
    reference = _fit(model, base)
    assert torch.equal(_fit(model, dataclasses.replace(base, **others)), reference)
    assert not torch.equal(_fit(model, dataclasses.replace(base, **read)), reference)
