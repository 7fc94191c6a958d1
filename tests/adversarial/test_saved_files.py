"""Saved files at their boundary: edited, unsealed, ill-typed or out-of-range files are refused by name.

Every loader reads through :mod:`hbni_infra.tensorfile`, which checks the file's digest: an edit after
saving (a class list, one tensor entry) is refused. A file whose digest matches but whose values are bad
(written by hand and sealed with :func:`hbni_infra.tensorfile.seal`) is checked on load as the object is
at construction, and refused with a ``ValueError`` naming the file and the entry. Saves whose parent
path is a file name it.
"""

from __future__ import annotations

import json
import re
from collections.abc import Callable
from pathlib import Path

import pytest
import torch
from safetensors.torch import load as st_load
from safetensors.torch import save as st_save

from classifiers import FrameClassifier
from decpomdp import JointController
from hbni_infra.cache import load_entry, store_entry
from hbni_infra.tensorfile import load_tensors, save_tensors, seal
from hbni_pyro import FrameCalibration, HBNIPosterior, MacroObservationModel

POSTERIOR = "hbni_pyro.HBNIPosterior"
CLASSIFIER = "classifiers.FrameClassifier"
TABLE = "hbni_pyro.MacroObservationModel"
CONTROLLER = "decpomdp.JointController"


def _header(path: Path) -> dict[str, str]:
    raw = path.read_bytes()
    n = int.from_bytes(raw[:8], "little")
    return json.loads(raw[8 : 8 + n])["__metadata__"]


def edit(path: Path, meta: Callable[[dict], None] | None = None, tensors: Callable[[dict], None] | None = None) -> Path:
    """Change a saved file's metadata or tensors in place, keeping its recorded digest (a hand edit)."""
    header = _header(path)
    values = st_load(path.read_bytes())
    metadata = json.loads(header["metadata"])
    if meta is not None:
        meta(metadata)
    if tensors is not None:
        tensors(values)
    header["metadata"] = json.dumps(metadata)
    path.write_bytes(st_save(values, metadata=header))
    return path


def edit_sealed(path: Path, kind: str, **changes: Callable[[dict], None]) -> Path:
    """Edit a file and give it a matching digest: only the value checks on load stand between it and a user."""
    return seal(edit(path, **changes), kind)


def refused(path: Path, *words: str) -> str:
    """A pattern that a message naming ``path`` and every one of ``words`` matches."""
    return "".join(f"(?=.*{re.escape(w)})" for w in (repr(str(path)), *words))


def posterior(**kwargs) -> HBNIPosterior:
    g = torch.Generator().manual_seed(0)
    samples = {
        "theta": torch.rand(2, 5, 3, generator=g, dtype=torch.float64) * 10 + 0.5,
        "kappa": torch.rand(2, 5, generator=g, dtype=torch.float64) + 1,
        "gamma": torch.rand(2, 5, generator=g, dtype=torch.float64) + 5,
    }
    return HBNIPosterior(samples, torch.full((3,), 1 / 3, dtype=torch.float64), **kwargs)


@pytest.fixture
def posterior_file(tmp_path) -> Path:
    return posterior(class_names=("ambulance", "police_car", "food_crate")).save(tmp_path / "posterior.safetensors")


@pytest.fixture(scope="module")
def fitted_classifier() -> FrameClassifier:
    g = torch.Generator().manual_seed(0)
    return FrameClassifier(cv=2).fit_features(torch.randn(12, 1000, generator=g), ["b", "a", "c"] * 4)


@pytest.fixture
def classifier_file(tmp_path, fitted_classifier) -> Path:
    return fitted_classifier.save(tmp_path / "classifier.safetensors")


@pytest.fixture
def table_file(tmp_path) -> Path:
    joint = torch.zeros(3, 3, 2, dtype=torch.float64)
    joint[:, :, 0] = torch.eye(3) * 0.6 + 0.1
    joint[:, :, 1] = 0.1
    joint = joint / joint.sum((1, 2), keepdim=True)
    table = MacroObservationModel(joint, torch.zeros(3), {"threshold": 0.95}, ("a", "b", "c"))
    return table.save(tmp_path / "table.safetensors")


@pytest.fixture
def controller_file(tmp_path) -> Path:
    controller = JointController(
        torch.zeros(1, 2, 2, dtype=torch.long), torch.zeros(1, 2, 2, 2, dtype=torch.long), ("go", "stop"), ("x", "y")
    )
    return controller.save(tmp_path / "controller.safetensors")


# ---- edits after saving: the digest -------------------------------------------------------------------------------


def _swap_names(key: str) -> Callable[[dict], None]:
    def swap(meta: dict) -> None:
        names = meta[key] if key in meta else meta["head"]["classes"]
        names[0], names[1] = names[1], names[0]

    return swap


EDITS = {
    "posterior class names swapped": ("posterior_file", POSTERIOR, {"meta": _swap_names("class_names")}),
    "posterior theta entry doubled": (
        "posterior_file",
        POSTERIOR,
        {"tensors": lambda t: t["theta"].view(-1)[0].mul_(2)},
    ),
    "posterior hyperprior edited": (
        "posterior_file",
        POSTERIOR,
        {"meta": lambda m: m["hyperprior"].update(beta=3.0)},
    ),
    "posterior tensor dropped": ("posterior_file", POSTERIOR, {"tensors": lambda t: t.pop("kappa")}),
    "classifier class list swapped": ("classifier_file", CLASSIFIER, {"meta": _swap_names("classes")}),
    "classifier coefficient edited": (
        "classifier_file",
        CLASSIFIER,
        {"tensors": lambda t: t["head.coef"].view(-1)[3].add_(1.0)},
    ),
    "classifier padding edited": ("classifier_file", CLASSIFIER, {"meta": lambda m: m.update(padding=0.3)}),
    "table class names swapped": ("table_file", TABLE, {"meta": _swap_names("class_names")}),
    "table probability moved": (
        "table_file",
        TABLE,
        {"tensors": lambda t: t["joint"][0].copy_(t["joint"][1])},
    ),
    "controller action names swapped": ("controller_file", CONTROLLER, {"meta": _swap_names("action_names")}),
    "controller edge edited": (
        "controller_file",
        CONTROLLER,
        {"tensors": lambda t: t["next_node"].view(-1)[0].fill_(1)},
    ),
}


@pytest.mark.parametrize("case", list(EDITS))
def test_an_edit_after_saving_is_refused_naming_the_file(case, request):
    fixture, kind, change = EDITS[case]
    path = edit(request.getfixturevalue(fixture), **change)
    loader = {POSTERIOR: HBNIPosterior.load, CLASSIFIER: FrameClassifier.load, TABLE: MacroObservationModel.load}
    load = loader.get(kind, JointController.load)
    with pytest.raises(ValueError, match=refused(path, "does not match its digest")):
        load(path)


def test_a_file_without_a_digest_is_refused_with_the_call_that_adds_one(posterior_file):
    header = _header(posterior_file)
    del header["digest"]
    posterior_file.write_bytes(st_save(st_load(posterior_file.read_bytes()), metadata=header))
    with pytest.raises(ValueError, match=refused(posterior_file, "has no digest", "hbni_infra.tensorfile.seal(")):
        HBNIPosterior.load(posterior_file)
    seal(posterior_file, POSTERIOR)
    assert HBNIPosterior.load(posterior_file).class_names == ("ambulance", "police_car", "food_crate")


def test_a_garbled_digest_is_refused(posterior_file):
    header = _header(posterior_file)
    header["digest"] = "sha256:" + "0" * 64
    posterior_file.write_bytes(st_save(st_load(posterior_file.read_bytes()), metadata=header))
    with pytest.raises(ValueError, match=refused(posterior_file, "does not match its digest")):
        HBNIPosterior.load(posterior_file)


def test_cache_entries_and_generic_files_check_their_digest(tmp_path):
    entry = store_entry(tmp_path / "bank.safetensors", {"seed": 0}, {"x": torch.ones(3)})
    edit(entry, tensors=lambda t: t["x"].fill_(2.0))
    with pytest.raises(ValueError, match=refused(entry, "does not match its digest")):
        load_entry(entry, {"seed": 0})
    path = save_tensors(tmp_path / "thing.safetensors", "pkg.Thing", {"x": torch.ones(1)}, {"note": "a"})
    edit(path, meta=lambda m: m.update(note="b"))
    with pytest.raises(ValueError, match=refused(path, "does not match its digest")):
        load_tensors(path, "pkg.Thing")


def test_seal_refuses_a_file_of_another_kind_or_no_file(tmp_path, posterior_file):
    with pytest.raises(ValueError, match=refused(posterior_file, "expected a saved decpomdp.JointController")):
        seal(posterior_file, CONTROLLER)
    with pytest.raises(FileNotFoundError, match="missing.safetensors"):
        seal(tmp_path / "missing.safetensors", POSTERIOR)


# ---- values checked on load as at construction ---------------------------------------------------------------------


def _site(site: str, value: float) -> Callable[[dict], None]:
    return lambda t: t[site].view(-1)[1].fill_(value)


POSTERIOR_VALUES = {
    "NaN theta": ({"tensors": _site("theta", float("nan"))}, "samples['theta']", "finite"),
    "infinite theta": ({"tensors": _site("theta", float("inf"))}, "samples['theta']", "finite"),
    "negative theta": ({"tensors": _site("theta", -0.5)}, "samples['theta']", "> 0"),
    "zero kappa": ({"tensors": _site("kappa", 0.0)}, "samples['kappa']", "> 0"),
    "NaN gamma": ({"tensors": _site("gamma", float("nan"))}, "samples['gamma']", "finite"),
    "negative class prior": ({"tensors": _site("class_prior", -0.1)}, "class_prior", "positive"),
    "string frame correlation": ({"meta": lambda m: m.update(frame_correlation="0.0")}, "frame_correlation", "number"),
    "string hyperprior": ({"meta": lambda m: m["hyperprior"].update(beta="2.0")}, "HyperPrior.beta", "'2.0'"),
    "hyperprior not a table": ({"meta": lambda m: m.update(hyperprior=[2.0])}, "hbni_pyro.HBNIPosterior", "invalid"),
    "unknown model": ({"meta": lambda m: m.update(model="papers")}, "'papers'", "unknown noise model"),
    "model not a name": ({"meta": lambda m: m.update(model=["paper"])}, "['paper']", "unknown noise model"),
    "class names a string": ({"meta": lambda m: m.update(class_names="abc")}, "class_names", "sequence of names"),
    "class names repeated": ({"meta": lambda m: m.update(class_names=["a", "a", "b"])}, "class_names", "distinct"),
    "class names too few": ({"meta": lambda m: m.update(class_names=["a", "b"])}, "class_names", "3 distinct"),
    "theta missing": ({"tensors": lambda t: t.pop("theta")}, "missing", "theta"),
    "string version": ({"meta": lambda m: m.update(version="2")}, "format version '2'", "reads version 2"),
}


@pytest.mark.parametrize("case", list(POSTERIOR_VALUES))
def test_a_sealed_posterior_with_a_bad_value_is_refused_naming_the_entry(case, posterior_file):
    change, *words = POSTERIOR_VALUES[case]
    path = edit_sealed(posterior_file, POSTERIOR, **change)
    with pytest.raises(ValueError, match=refused(path, *words)):
        HBNIPosterior.load(path)


CLASSIFIER_VALUES = {
    "NaN padding": (lambda m: m.update(padding=float("nan")), "padding"),
    "infinite padding": (lambda m: m.update(padding=float("inf")), "padding"),
    "negative padding": (lambda m: m.update(padding=-0.1), "padding"),
    "string padding": (lambda m: m.update(padding="0.1"), "padding"),
    "fractional batch size": (lambda m: m.update(batch_size=2.5), "batch_size"),
    "string batch size": (lambda m: m.update(batch_size="4"), "batch_size"),
    "zero batch size": (lambda m: m.update(batch_size=0), "batch_size"),
    "zero threads": (lambda m: m.update(threads=0), "threads"),
    "string seed": (lambda m: m.update(seed="0"), "seed"),
    "backbone not a name": (lambda m: m.update(backbone=3), "backbone"),
    "string C": (lambda m: m["head"].update(C="1.0"), "C"),
    "one fold": (lambda m: m["head"].update(cv=1), "cv"),
    "classes a string": (lambda m: m["head"].update(classes="abc"), "classes"),
    "classes repeated": (lambda m: m["head"].update(classes=["a", "a", "c"]), "classes"),
    "classes booleans": (lambda m: m["head"].update(classes=[True, False, None]), "classes"),
}


@pytest.mark.parametrize("case", list(CLASSIFIER_VALUES))
def test_a_sealed_classifier_with_a_bad_setting_is_refused_naming_the_entry(case, classifier_file):
    change, word = CLASSIFIER_VALUES[case]
    path = edit_sealed(classifier_file, CLASSIFIER, meta=change)
    with pytest.raises(ValueError, match=refused(path, word)):
        FrameClassifier.load(path)


def test_a_sealed_classifier_with_a_nan_coefficient_or_scale_is_refused(tmp_path, fitted_classifier):
    for name in ("head.coef", "scale"):
        path = fitted_classifier.save(tmp_path / f"{name}.safetensors")
        edit_sealed(path, CLASSIFIER, tensors=lambda t, name=name: t[name].view(-1)[0].fill_(float("nan")))
        with pytest.raises(ValueError, match=refused(path, "finite")):
            FrameClassifier.load(path)


TABLE_VALUES = {
    "NaN probability": ({"tensors": lambda t: t["joint"].view(-1)[0].fill_(float("nan"))}, "joint"),
    "negative probability": ({"tensors": lambda t: t["joint"].view(-1)[0].fill_(-0.2)}, "joint"),
    "time-out above one": ({"tensors": lambda t: t["timed_out"].fill_(1.5)}, "timed_out"),
    "class names a string": ({"meta": lambda m: m.update(class_names="abc")}, "class_names"),
    "class names repeated": ({"meta": lambda m: m.update(class_names=["a", "b", "a"])}, "class_names"),
    "info not a table": ({"meta": lambda m: m.update(info=3)}, "hbni_pyro.MacroObservationModel"),
}


@pytest.mark.parametrize("case", list(TABLE_VALUES))
def test_a_sealed_table_with_a_bad_value_is_refused_naming_the_entry(case, table_file):
    change, word = TABLE_VALUES[case]
    path = edit_sealed(table_file, TABLE, **change)
    with pytest.raises(ValueError, match=refused(path, word)):
        MacroObservationModel.load(path)


CONTROLLER_VALUES = {
    "edge out of range": ({"tensors": lambda t: t["next_node"].view(-1)[0].fill_(5)}, "next_node"),
    "negative action": ({"tensors": lambda t: t["action"].view(-1)[0].fill_(-1)}, "action"),
    "observation names repeated": ({"meta": lambda m: m.update(obs_names=["x", "x"])}, "obs_names"),
    "action names a string": ({"meta": lambda m: m.update(action_names="go")}, "action_names"),
}


@pytest.mark.parametrize("case", list(CONTROLLER_VALUES))
def test_a_sealed_controller_with_a_bad_value_is_refused_naming_the_entry(case, controller_file):
    change, word = CONTROLLER_VALUES[case]
    path = edit_sealed(controller_file, CONTROLLER, **change)
    with pytest.raises(ValueError, match=refused(path, word)):
        JointController.load(path)


# ---- where a save goes ---------------------------------------------------------------------------------------------


SAVES = {
    "posterior": lambda path, clf: posterior().save(path),
    "classifier": lambda path, clf: clf.save(path),
    "controller": lambda path, clf: JointController(
        torch.zeros(1, 1, 1, dtype=torch.long), torch.zeros(1, 1, 1, 1, dtype=torch.long)
    ).save(path),
    "table": lambda path, clf: MacroObservationModel(torch.eye(2)[:, :, None], torch.zeros(2)).save(path),
    "tensors": lambda path, clf: save_tensors(path, "pkg.Thing", {"x": torch.ones(1)}, {}),
}


@pytest.mark.parametrize("what", list(SAVES))
@pytest.mark.parametrize("depth", [1, 2])
def test_a_save_under_a_file_names_the_parent_that_is_a_file(tmp_path, fitted_classifier, what, depth):
    blocker = tmp_path / "results"
    blocker.write_text("not a directory")
    target = blocker.joinpath(*["sub"] * (depth - 1), "model.safetensors")
    with pytest.raises(NotADirectoryError, match=refused(target, repr(str(blocker)), "is a file")):
        SAVES[what](target, fitted_classifier)
    assert blocker.read_text() == "not a directory"


def test_a_save_onto_a_directory_names_it(tmp_path):
    with pytest.raises(IsADirectoryError, match=refused(tmp_path, "is a directory")):
        posterior().save(tmp_path)


def test_scalars_empty_and_boolean_tensors_round_trip_under_their_digest(tmp_path):
    tensors = {"scalar": torch.tensor(1.5), "empty": torch.zeros(0, 3), "mask": torch.tensor([True, False])}
    path = save_tensors(tmp_path / "odd.safetensors", "pkg.Thing", tensors, {})
    back, _ = load_tensors(path, "pkg.Thing")
    assert all(torch.equal(back[k], v) for k, v in tensors.items())
    edit(path, tensors=lambda t: t["scalar"].fill_(2.5))
    with pytest.raises(ValueError, match=refused(path, "does not match its digest")):
        load_tensors(path, "pkg.Thing")


CALIBRATION = "FrameCalibration"  # the kind its files record


@pytest.mark.parametrize(
    "change, words",
    [
        ({"meta": lambda m: m.update(class_names=["b", "a", "c"])}, ("does not match its digest",)),
        ({"tensors": lambda t: t["weight"].view(-1)[0].fill_(3.0)}, ("does not match its digest",)),
    ],
)
def test_an_edited_frame_calibration_is_refused(tmp_path, change, words):
    path = FrameCalibration(torch.eye(3), torch.zeros(3), class_names=("a", "b", "c")).save(
        tmp_path / "cal.safetensors"
    )
    with pytest.raises(ValueError, match=refused(edit(path, **change), *words)):
        FrameCalibration.load(path)


@pytest.mark.parametrize(
    "change, word",
    [
        ({"tensors": lambda t: t["bias"].fill_(float("nan"))}, "finite"),
        ({"meta": lambda m: m.update(class_names="abc")}, "class_names"),
        ({"meta": lambda m: m.update(kind="spline")}, "kind"),
    ],
)
def test_a_sealed_frame_calibration_with_a_bad_value_is_refused_naming_the_file(tmp_path, change, word):
    path = FrameCalibration(torch.eye(3), torch.zeros(3), class_names=("a", "b", "c")).save(
        tmp_path / "cal.safetensors"
    )
    with pytest.raises(ValueError, match=refused(edit_sealed(path, CALIBRATION, **change), word)):
        FrameCalibration.load(path)
