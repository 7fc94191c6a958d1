"""Names at every junction: classifier to posterior, posterior or table to domain, controller to domain or executor.

Each junction compares the names both sides carry and puts the columns in one order, or refuses with a
message naming both lists; a fitted posterior without names is refused where names are needed, with how
to add them. Tiny objects throughout: a posterior built from a few draws, a classifier fitted on random
features, tables written by hand.
"""

from __future__ import annotations

import argparse
import re

import pytest
import torch

import hbni_pyro
from classifiers import FrameClassifier, class_columns, classify_frames
from classifiers.sources import open_source
from decpomdp import ControllerExecutor, JointController, simulate
from decpomdp.domains import DisasterRelief
from decpomdp.domains.disaster_relief import CLASSES, greedy_controller
from experiments import ros_node
from experiments.studies.stream import Settings, load_models
from hbni_pyro import HBNIPosterior, MacroObservationModel, live_macro_observations, macro_observations

ALPHABETICAL = ["a_crate", "b_car", "c_copter"]
DOMAIN_ORDER = ["c_copter", "a_crate", "b_car"]  # a posterior's column order, not the classifier's


def words(*parts: str) -> str:
    """A pattern matched by a message holding every one of ``parts`` (in any order)."""
    return "".join(f"(?=.*{re.escape(p)})" for p in parts)


def posterior(class_names=None, num_classes: int = 3) -> HBNIPosterior:
    g = torch.Generator().manual_seed(1)
    samples = {
        "theta": torch.rand(2, 4, num_classes, generator=g, dtype=torch.float64) * 5 + 1,
        "kappa": torch.ones(2, 4, dtype=torch.float64),
        "gamma": torch.ones(2, 4, dtype=torch.float64),
    }
    prior = torch.full((num_classes,), 1 / num_classes, dtype=torch.float64)
    return HBNIPosterior(samples, prior, class_names=class_names)


def process(class_names=None, num_classes: int = 3) -> hbni_pyro.MacroObservationProcess:
    return hbni_pyro.MacroObservationProcess(hbni_pyro.HBNIFilter(posterior(class_names, num_classes)), 0.9, 4)


def table(class_names=None) -> MacroObservationModel:
    m = len(CLASSES)
    joint = torch.zeros(m, m, 2, dtype=torch.float64)
    joint[:, :, 0] = torch.eye(m) * 0.5 + 0.05
    joint[:, :, 1] = torch.arange(m, dtype=torch.float64) / 100
    joint = joint / joint.sum((1, 2), keepdim=True)
    return MacroObservationModel(joint, torch.zeros(m), {}, class_names)


def outputs(n: int, m: int = 3) -> list[tuple[int, torch.Tensor]]:
    return [(i, torch.full((m,), 1 / m, dtype=torch.float64)) for i in range(n)]


@pytest.fixture(scope="module")
def clf() -> FrameClassifier:
    g = torch.Generator().manual_seed(0)
    return FrameClassifier(cv=2).fit_features(torch.randn(12, 1000, generator=g), ALPHABETICAL[::-1] * 4)


@pytest.fixture(scope="module")
def files(tmp_path_factory, clf):
    root = tmp_path_factory.mktemp("names")
    return {
        "classifier": clf.save(root / "classifier.safetensors"),
        "unnamed": posterior().save(root / "unnamed.safetensors"),
        "named": posterior(DOMAIN_ORDER).save(root / "named.safetensors"),
        "foreign": posterior(["x", "y", "z"]).save(root / "foreign.safetensors"),
    }


# ---- classifier to posterior: the stream experiment and the ROS node ----------------------------------------------


def stream_models(files, posterior_file: str, classes=None):
    settings = Settings(
        "clip.mp4", None, None, files["classifier"], files[posterior_file], classes, 1.0, 0.95, 10, 4, (), False
    )
    return load_models(settings)


def test_the_stream_reads_the_classifier_in_the_posteriors_order(files):
    models = stream_models(files, "named")
    assert models.classes == DOMAIN_ORDER and models.process.class_names == tuple(DOMAIN_ORDER)


def test_the_stream_names_an_unnamed_posterior_from_stream_classes(files):
    models = stream_models(files, "unnamed", DOMAIN_ORDER)
    assert models.classes == DOMAIN_ORDER and models.process.class_names == tuple(DOMAIN_ORDER)


STREAM_REFUSALS = {
    "unnamed posterior, no classes": ("unnamed", None, ("stream.classes", "has no class names", ".named(")),
    "classes reversed": ("named", DOMAIN_ORDER[::-1], ("stream.classes", str(DOMAIN_ORDER), str(DOMAIN_ORDER[::-1]))),
    "classes alphabetical": ("named", ALPHABETICAL, ("stream.classes", str(DOMAIN_ORDER), str(ALPHABETICAL))),
    "posterior of other classes": ("foreign", None, ("stream.classifier", str(ALPHABETICAL), "['x', 'y', 'z']")),
    "too few classes for an unnamed posterior": ("unnamed", ["a_crate", "b_car"], ("stream.classes", "3 distinct")),
    "repeated classes": ("unnamed", ["a_crate", "a_crate", "b_car"], ("stream.classes", "distinct")),
    "other classes for an unnamed posterior": ("unnamed", ["x", "y", "z"], ("stream.classifier", str(ALPHABETICAL))),
}


@pytest.mark.parametrize("case", list(STREAM_REFUSALS))
def test_the_stream_refuses_names_that_do_not_meet(files, case):
    posterior_file, classes, message = STREAM_REFUSALS[case]
    with pytest.raises(ValueError, match=words(*message)):
        stream_models(files, posterior_file, classes)


def node_args(files, posterior_file: str, classes=None) -> argparse.Namespace:
    argv = ["--classifier", str(files["classifier"]), "--posterior", str(files[posterior_file])]
    return ros_node.parse_args(argv + ([f"--classes={','.join(classes)}"] if classes else []))


def test_the_node_reads_the_classifier_in_the_posteriors_order(files):
    assert ros_node.load_pipeline(node_args(files, "named")).classes == DOMAIN_ORDER


@pytest.mark.parametrize(
    "posterior_file, classes, message",
    [
        ("unnamed", None, ("--classes", "has no class names")),
        ("named", DOMAIN_ORDER[::-1], ("--classes", str(DOMAIN_ORDER), str(DOMAIN_ORDER[::-1]))),
        ("foreign", None, ("--classifier", str(ALPHABETICAL), "['x', 'y', 'z']")),
    ],
)
def test_the_node_refuses_names_that_do_not_meet(files, posterior_file, classes, message):
    with pytest.raises(ValueError, match=words(*message)):
        ros_node.load_pipeline(node_args(files, posterior_file, classes))


# ---- the runtime: classify_frames, macro_observations, live -------------------------------------------------------


@pytest.mark.parametrize(
    "classes, error, message",
    [
        ("abc", TypeError, ("classes", "str")),
        (None, TypeError, ("classes", "None")),
        (["a", "a", "b"], ValueError, ("classes", "distinct")),
        (["a", "b"], ValueError, ("classes", "3 distinct")),
        (["a", 2, "c"], ValueError, ("classes", "distinct names")),
    ],
)
def test_macro_observations_refuse_classes_that_are_not_names(classes, error, message):
    with pytest.raises(error, match=words(*message)):
        next(macro_observations(outputs(3), process(), classes))


def test_macro_observations_refuse_an_unnamed_posterior_saying_how_to_name_it():
    with pytest.raises(ValueError, match=words("process", "no class names", str(DOMAIN_ORDER), ".named(")):
        next(macro_observations(outputs(3), process(), DOMAIN_ORDER))
    with pytest.raises(ValueError, match=words("process", "no class names")):
        next(live_macro_observations(outputs(3), process(), DOMAIN_ORDER))


def test_macro_observations_refuse_the_posteriors_names_in_another_order():
    with pytest.raises(ValueError, match=words("classes", str(DOMAIN_ORDER), str(ALPHABETICAL))):
        next(macro_observations(outputs(3), process(DOMAIN_ORDER), ALPHABETICAL))
    with pytest.raises(TypeError, match=words("process", "MacroObservationProcess")):
        next(macro_observations(outputs(3), "hbni", DOMAIN_ORDER))


def test_a_baseline_filter_takes_the_callers_names():
    baseline = hbni_pyro.MacroObservationProcess(hbni_pyro.VotingFilter(3), 0.9, 2)
    assert next(macro_observations(outputs(3), baseline, DOMAIN_ORDER)).name == DOMAIN_ORDER[0]


@pytest.mark.parametrize(
    "classes, error, message",
    [
        ("abc", TypeError, ("classes", "str")),
        (["a_crate", "b_car"], ValueError, ("classes", str(ALPHABETICAL))),
        (["a_crate", "b_car", "b_car"], ValueError, ("classes", str(ALPHABETICAL))),
        ([["a_crate"], "b_car", "c_copter"], ValueError, ("classes", str(ALPHABETICAL))),
        (["a_crate", "b_car", "x"], ValueError, ("classes", "'x'")),
    ],
)
def test_class_columns_refuse_names_that_are_not_the_classifiers(clf, classes, error, message):
    with pytest.raises(error, match=words(*message)):
        class_columns(clf, classes)
    with pytest.raises(error, match=words(*message)):
        next(classify_frames([], clf, classes))


def test_an_empty_source_path_is_refused():
    for source in ("", "  "):
        with pytest.raises(ValueError, match=words("source", "empty path")):
            open_source(source)


# ---- naming a posterior --------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "names, error, message",
    [
        (None, TypeError, ("class_names", "NoneType")),
        ("abc", TypeError, ("class_names", "str")),
        (["a", "a", "b"], ValueError, ("class_names", "distinct")),
        (["a", "b", "c", "d"], ValueError, ("class_names", "3 distinct")),
    ],
)
def test_naming_a_posterior_checks_the_names(names, error, message):
    with pytest.raises(error, match=words(*message)):
        posterior().named(names)


def test_a_named_posterior_refuses_other_names_naming_both_lists():
    with pytest.raises(ValueError, match=words("where", str(DOMAIN_ORDER), "['x', 'y', 'z']")):
        posterior(DOMAIN_ORDER).match_names(["x", "y", "z"], "where")
    assert posterior(DOMAIN_ORDER).match_names(None, "where").class_names == tuple(DOMAIN_ORDER)


def test_fit_refuses_class_names_that_are_a_string():
    obs = torch.full((6, 3), 1 / 3, dtype=torch.float64)
    with pytest.raises(TypeError, match=words("class_names", "str")):
        hbni_pyro.fit(obs, torch.arange(3).repeat(2), class_names="abc", progress=False)


def test_a_table_refuses_class_names_that_are_a_string():
    with pytest.raises(TypeError, match=words("class_names", "str")):
        table("abcdef")


# ---- posterior or table to domain ----------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "names, message",
    [
        (CLASSES[::-1], ("perception", str(CLASSES[::-1]), str(CLASSES), "perception.reordered(")),
        (sorted(CLASSES), ("perception", str(sorted(CLASSES)), str(CLASSES), "another order")),
        ([f"class{i}" for i in range(6)], ("perception", "'class0'", str(CLASSES))),
    ],
)
def test_the_domain_refuses_a_table_named_otherwise(names, message):
    with pytest.raises(ValueError, match=words(*message)):
        DisasterRelief(perception=table(names))


def test_a_reordered_table_fits_the_domain_and_keeps_its_law():
    reversed_table = table(CLASSES[::-1])
    fitted = reversed_table.reordered(CLASSES)
    assert DisasterRelief(perception=fitted).perception is fitted
    m = len(CLASSES)
    for c in range(m):
        for label in range(m):
            torch.testing.assert_close(fitted.joint[c, label], reversed_table.joint[m - 1 - c, m - 1 - label])
    assert DisasterRelief(perception=table()).perception.class_names is None  # unnamed: the domain's order


@pytest.mark.parametrize(
    "source, names, message",
    [
        (None, CLASSES, ("class_names", "None")),
        (CLASSES, CLASSES[:5] + ["x"], ("class_names", "'x'")),
        (CLASSES, "ambulance", ("class_names", "str")),
    ],
)
def test_reordering_needs_a_named_table_and_a_reordering(source, names, message):
    error = TypeError if isinstance(names, str) else ValueError
    with pytest.raises(error, match=words(*message)):
        table(source).reordered(names)


def test_the_domain_refuses_a_replay_of_a_posterior_named_otherwise():
    m = len(CLASSES)
    streams = torch.full((m, 2, m), 1 / m, dtype=torch.float64)
    replay = hbni_pyro.StreamReplay(process(CLASSES[::-1], m), streams, torch.arange(m))
    with pytest.raises(ValueError, match=words("perception", str(CLASSES[::-1]), str(CLASSES))):
        DisasterRelief(perception=replay)


# ---- controller to domain or executor ------------------------------------------------------------------------------


def renamed(controller: JointController, actions=None, observations=None) -> JointController:
    env = DisasterRelief()
    return controller.named(actions or env.action_names, observations or env.obs_names)


@pytest.mark.parametrize("which", ["action_names", "obs_names"])
def test_simulate_refuses_a_controller_planned_for_other_names(which):
    env = DisasterRelief()
    names = getattr(env, which)[::-1]
    controller = renamed(greedy_controller(2), **{"actions" if which == "action_names" else "observations": names})
    with pytest.raises(ValueError, match=words("controller", which, str(names), str(getattr(env, which)))):
        simulate(env, controller, 2, torch.Generator().manual_seed(0))
    with pytest.raises(ValueError, match=words("controller", which, str(names))):
        ControllerExecutor.for_domain(controller, 0, env)


def test_an_executor_takes_a_named_controllers_names_and_refuses_others():
    env = DisasterRelief()
    controller = renamed(greedy_controller(2))
    executor = ControllerExecutor(controller, 0)
    assert executor.action.name == "infer" and executor.obs_names == env.obs_names
    others = [f"ma{i}" for i in range(len(env.action_names))]
    with pytest.raises(ValueError, match=words("controller", "action_names", str(others), str(env.action_names))):
        ControllerExecutor(controller, 0, others)
    with pytest.raises(ValueError, match=words("controller", "obs_names")):
        ControllerExecutor(controller, 0, None, env.obs_names[::-1])


# ---- a process and the posterior its table is simulated from -------------------------------------------------------


def test_characterize_refuses_a_generative_posterior_named_otherwise():
    with pytest.raises(ValueError, match=words("generative", str(DOMAIN_ORDER), str(ALPHABETICAL))):
        hbni_pyro.characterize(process(DOMAIN_ORDER), posterior(ALPHABETICAL), 2, seed=0)


def test_a_baseline_table_takes_the_generative_posteriors_names():
    baseline = hbni_pyro.MacroObservationProcess(hbni_pyro.StaticStateBayesFilter(3), 0.9, 2)
    assert hbni_pyro.characterize(baseline, posterior(DOMAIN_ORDER), 2, seed=0).class_names == tuple(DOMAIN_ORDER)


def test_the_calibrated_filter_refuses_a_calibration_named_otherwise_than_the_posterior():
    calibration = hbni_pyro.FrameCalibration(torch.eye(3), torch.zeros(3), class_names=ALPHABETICAL)
    with pytest.raises(ValueError, match=words("posterior", str(ALPHABETICAL), str(DOMAIN_ORDER))):
        hbni_pyro.make_filter("calibrated", posterior(DOMAIN_ORDER), calibration=calibration)
    named = hbni_pyro.make_filter("calibrated", posterior(ALPHABETICAL), calibration=calibration)
    assert named.class_names == tuple(ALPHABETICAL)
