"""FrameClassifier and its SVM head as scikit-learn classifiers: params, clone, cross-validation, score, tags, numpy
outputs, and scikit-learn's estimator checks (every check on the head, which takes feature arrays; those that apply to
images on the classifier)."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
import torch

from classifiers import FrameClassifier, OneVsOneSVC
from classifiers.data import render_images

sklearn = pytest.importorskip("sklearn", minversion="1.6")  # __sklearn_tags__ is read from 1.6 on
from sklearn.base import clone, is_classifier  # noqa: E402
from sklearn.datasets import make_blobs  # noqa: E402
from sklearn.model_selection import StratifiedKFold, cross_val_score  # noqa: E402
from sklearn.utils import estimator_checks  # noqa: E402
from sklearn.utils.estimator_checks import parametrize_with_checks  # noqa: E402

VEHICLES = ("irobot", "quadrotor", "racecar")

# scikit-learn's estimator checks that apply to an estimator whose X is a batch of images: they pass.
APPLICABLE = (
    "check_estimator_cloneable",
    "check_estimator_tags_renamed",
    "check_valid_tag_types",
    "check_estimator_repr",
    "check_no_attributes_set_in_init",
    "check_mixin_order",
    "check_parameters_default_constructible",
    "check_get_params_invariance",
    "check_set_params",
    "check_fit1d",
    "check_n_features_in_after_fitting",
    "check_estimators_partial_fit_n_features",
    "check_non_transformer_estimators_n_iter",
    "check_decision_proba_consistency",
    "check_classifiers_one_label_sample_weights",
    "check_supervised_y_no_nan",
)
_ARRAYS = "fits or predicts on 2-d numeric feature arrays; X here is a batch of uint8 BGR images"
_ON_IMAGES = _ARRAYS + " (tested on images in this file)"
# The others, and why they are skipped.
SKIPPED = {
    "check_do_not_raise_errors_in_init_or_set_params": "the project validates at the public boundary: __init__ and "
    "set_params refuse a bad value at once with an error naming the argument (scikit-learn defers it to fit)",
    "check_estimators_unfitted": "predicting before fit raises RuntimeError naming fit() (the project's error for an "
    "unfitted model), not scikit-learn's NotFittedError; also " + _ARRAYS,
    "check_classifiers_one_label": "a single class is refused on purpose (y: expected at least 2 classes); "
    "also " + _ARRAYS,
    "check_estimators_pickle": "persistence is save()/load() to safetensors (no pickle); also " + _ARRAYS,
    "check_array_api_input": "the array API is not offered: images are numpy arrays or torch tensors",
    "check_estimators_fit_returns_self": _ON_IMAGES,
    "check_estimators_overwrite_params": _ON_IMAGES,
    "check_dont_overwrite_parameters": _ON_IMAGES,
    "check_fit_idempotent": _ON_IMAGES,
    "check_fit_check_is_fitted": _ON_IMAGES,
    "check_methods_subset_invariance": _ON_IMAGES,
    "check_methods_sample_order_invariance": _ON_IMAGES,
    "check_fit_score_takes_y": _ON_IMAGES,
    "check_dict_unchanged": _ON_IMAGES,
    "check_classifiers_train": _ON_IMAGES,
    "check_classifiers_classes": _ON_IMAGES,
    **{
        name: _ARRAYS
        for name in (
            "check_readonly_memmap_input",
            "check_positive_only_tag_during_fit",
            "check_estimators_dtypes",
            "check_complex_data",
            "check_dtype_object",
            "check_estimators_empty_data_messages",
            "check_pipeline_consistency",
            "check_estimators_nan_inf",
            "check_estimator_sparse_tag",
            "check_estimator_sparse_array",
            "check_estimator_sparse_matrix",
            "check_f_contiguous_array_estimator",
            "check_classifier_data_not_an_array",
            "check_classifiers_regression_target",
            "check_supervised_y_2d",
            "check_fit2d_1sample",
            "check_fit2d_1feature",
            "check_n_features_in",
            "check_fit2d_predict1d",
            "check_requires_y_none",
        )
    },
}


@pytest.fixture(scope="module")
def images():
    """Four rendered training snapshots per vehicle ``(12, 240, 320, 3)`` and their labels."""
    x = np.concatenate([render_images(name, 4, "training", seed=5) for name in VEHICLES])
    return x, np.repeat(VEHICLES, 4)


@pytest.mark.parametrize("name", APPLICABLE + tuple(SKIPPED))
def test_sklearn_estimator_checks(name):
    if name in SKIPPED:
        pytest.skip(SKIPPED[name])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # sklearn warns that the estimator does not inherit its BaseEstimator
        getattr(estimator_checks, name)("FrameClassifier", FrameClassifier())


def test_every_sklearn_check_is_run_or_skipped_with_a_reason():
    yield_all = getattr(estimator_checks, "_yield_all_checks", None)
    if yield_all is None:
        pytest.skip("this scikit-learn does not list its checks")

    class TwoDimensional(FrameClassifier):  # the tags that make sklearn list every check it has
        def __sklearn_tags__(self):
            tags = super().__sklearn_tags__()
            tags.input_tags.two_d_array = True
            return tags

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # sklearn warns that the estimator does not inherit its BaseEstimator
        listed = {getattr(check, "func", check).__name__ for check in yield_all(TwoDimensional(), legacy=True)}
    assert listed <= set(APPLICABLE) | set(SKIPPED), sorted(listed - set(APPLICABLE) - set(SKIPPED))
    assert not set(APPLICABLE) & set(SKIPPED)


def test_params_repr_tags_and_clone(fitted_classifier):
    clf = FrameClassifier(C=0.5, seed=np.int64(3), padding=0.2)
    assert is_classifier(clf) and is_classifier(fitted_classifier)
    assert repr(clf) == "FrameClassifier(C=0.5, padding=0.2, seed=np.int64(3))"
    assert repr(FrameClassifier()) == "FrameClassifier()"
    params = clf.get_params()
    assert params["seed"] is clf.seed and params["C"] == 0.5 and params["backbone"] == "efficientnet_lite0"
    copy = clone(clf)
    assert copy is not clf and copy.get_params() == params and copy.classes_ is None
    refit = clone(fitted_classifier)
    assert (
        refit.classes_ is None and not hasattr(refit, "mean_") and refit.get_params() == fitted_classifier.get_params()
    )
    assert clf.set_params(C=2.0, cv=3) is clf and (clf.C, clf.cv) == (2.0, 3)
    assert "backbone_" not in FrameClassifier().__dict__  # nothing is loaded before it is needed


def test_cross_val_score_on_rendered_images(images):
    x, y = images
    scores = cross_val_score(FrameClassifier(cv=2), x, y, cv=2)
    # the same folds by hand: fit on one half, mean accuracy of predict on the other
    expected = []
    for train, test in StratifiedKFold(2).split(x, y):
        clf = FrameClassifier(cv=2).fit(x[train], y[train])
        expected.append(np.mean(np.array(clf.predict(x[test])) == y[test]))
    assert scores.shape == (2,) and np.allclose(scores, expected) and ((0 <= scores) & (scores <= 1)).all()


def test_fit_score_and_the_checks_sklearn_runs_on_arrays_done_on_images(images):
    x, y = images
    clf = FrameClassifier(cv=2, seed=1)
    before = clf.get_params()
    assert clf.fit(x, y) is clf  # fit returns self
    assert all(clf.get_params()[k] is v for k, v in before.items())  # fit changes no parameter
    p = clf.predict_proba(x)
    assert isinstance(p, np.ndarray) and p.dtype == np.float64 and p.shape == (12, 3)
    np.testing.assert_allclose(p.sum(1), 1.0, rtol=0, atol=4 * np.finfo(np.float64).eps)
    assert np.array_equal(clf.fit(x, y).predict_proba(x), p)  # idempotent
    np.testing.assert_allclose(clf.predict_proba(x[5:9]), p[5:9], atol=1e-5)  # subset invariance
    order = np.arange(11, -1, -1)
    np.testing.assert_allclose(clf.predict_proba(x[order]), p[order], atol=1e-5)  # sample order invariance
    predicted = clf.predict(x)
    assert isinstance(predicted, np.ndarray) and predicted.shape == (12,)
    hits = predicted == y
    assert clf.score(x, y) == pytest.approx(hits.mean())
    weights = np.linspace(1.0, 2.0, 12)
    assert clf.score(x, list(y), sample_weight=weights) == pytest.approx((hits * weights).sum() / weights.sum())
    with pytest.raises(RuntimeError, match="fit"):
        FrameClassifier().predict(x)


BAD_PARAMS = [
    ("padding", float("nan"), ValueError),
    ("padding", math.inf, ValueError),
    ("padding", -0.1, ValueError),
    ("padding", "0.1", TypeError),
    ("batch_size", 2.5, TypeError),
    ("batch_size", 0, ValueError),
    ("batch_size", True, TypeError),
    ("C", 0.0, ValueError),
    ("C", float("nan"), ValueError),
    ("cv", 1, ValueError),
    ("cv", 2.0, TypeError),
    ("seed", -1, ValueError),
    ("seed", 1.5, TypeError),
    ("threads", 0, ValueError),
    ("threads", 1.0, TypeError),
    ("backbone", "resnet", ValueError),
    ("backbone", "alexnet", ValueError),  # needs weights_path
    ("weights_path", 3, TypeError),
    ("half", 1, TypeError),
    ("half", True, ValueError),  # half precision on CUDA only
    ("dtype", "float16", TypeError),
    ("dtype", torch.float64, ValueError),
    ("device", "no-such-device", ValueError),
    ("device", 0, TypeError),
    ("precision", "int4", ValueError),
    ("precision", None, TypeError),
]
"""A bad value of every constructor argument and the error it gets."""


@pytest.mark.parametrize(("name", "value", "error"), BAD_PARAMS)
def test_bad_params_are_refused_in_init_set_params_and_assignment(name, value, error):
    with pytest.raises(error, match=name):
        FrameClassifier(**{name: value})
    clf = FrameClassifier()
    with pytest.raises(error, match=name):
        clf.set_params(**{name: value})
    assert clf.get_params() == FrameClassifier().get_params()  # a refused set_params changes nothing
    with pytest.raises(error, match=name):
        setattr(clf, name, value)  # clf.padding = float("nan") is checked as the constructor checks it
    assert clf.get_params() == FrameClassifier().get_params()  # a refused assignment changes nothing


def test_every_parameter_is_checked_on_assignment():
    """Each constructor argument goes through the one check __init__ and set_params use (the list above has a bad
    value for every one); a good value is stored as given and drops what it invalidates."""
    assert {name for name, _, _ in BAD_PARAMS} == set(FrameClassifier().get_params())
    clf = FrameClassifier()
    clf.backbone_  # noqa: B018 - loads the backbone
    clf.device = "meta"
    assert clf.device == "meta" and clf.backbone_.device == torch.device("meta")  # placement dropped and redone
    clf.seed = np.int64(4)
    assert clf.seed is clf.get_params()["seed"]


def test_neg_log_loss_scoring_has_nothing_to_warn_about(images):
    x, y = images
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # rows off one by 3e-8 used to warn on every fold
        scores = cross_val_score(FrameClassifier(cv=2), x, y, cv=2, scoring="neg_log_loss")
    assert scores.shape == (2,) and (scores < 0).all()


# ---- the SVM head: every scikit-learn check, those that cannot pass named --------------------------------------
_PLATT_ARGMAX = (
    "predict is the argmax of the Platt-scaled, coupled probabilities (what predict_proba returns), whose boundary is "
    "the decision function's shifted by Platt's intercept, as in libsvm's SVC(probability=True): a point in a hundred "
    "near the boundary is labelled against the sign of its decision value"
)
HEAD_FAILURES = {
    "check_estimators_unfitted": "predicting before fit raises RuntimeError naming fit(), the project's error for an "
    "unfitted model (scikit-learn's NotFittedError lives in scikit-learn, which the library does not import)",
    "check_do_not_raise_errors_in_init_or_set_params": "the project validates at the public boundary: __init__ and "
    "set_params refuse a bad value at once, naming the argument",
    "check_classifiers_train": _PLATT_ARGMAX,
    "check_classifiers_classes": _PLATT_ARGMAX,
    "check_supervised_y_2d": "a (N, 1) y is refused with an error naming y, not reshaped behind a warning",
    "check_fit2d_1feature": "Platt's sigmoids are fitted on cv-fold held-out decision values, so every class needs cv "
    "(5) examples; the check's data has a class with 3",
}


with warnings.catch_warnings():
    warnings.simplefilter("ignore")  # sklearn warns, listing the checks, that the head does not inherit BaseEstimator
    _HEAD_CHECKS = parametrize_with_checks(
        [OneVsOneSVC()], expected_failed_checks=lambda est: HEAD_FAILURES, xfail_strict=True
    )


@_HEAD_CHECKS
def test_head_passes_sklearn_estimator_checks(estimator, check):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # sklearn warns that the estimator does not inherit its BaseEstimator
        check(estimator)


def test_head_does_what_the_failing_checks_test_otherwise():
    """What check_classifiers_train and _classes also test: accuracy on blobs, shapes, string classes, errors."""
    x, y = make_blobs(n_samples=300, centers=3, random_state=0, cluster_std=0.5)
    head = OneVsOneSVC().fit(x, y)
    assert head.score(x, y) > 0.99 and head.decision_function(x).shape == (300, 3)
    p = head.predict_proba(x)
    assert np.array_equal(p.argmax(1), head.predict(x)) and p.shape == (300, 3)
    names = np.array(["one", "two", "three"])[y]
    assert head.fit(x, names).classes_.tolist() == ["one", "three", "two"]
    binary = OneVsOneSVC().fit(x[y < 2], names[y < 2])
    dec = binary.decision_function(x[y < 2])
    agree = (binary.classes_[(dec > 0).astype(int)] == binary.predict(x[y < 2])).mean()
    assert dec.shape == (200,) and agree > 0.98  # > 0 favours classes_[1], as scikit-learn's binary classifiers
    with pytest.raises(ValueError, match="X has 1 features, but OneVsOneSVC is expecting 2 features"):
        head.predict(x[:, :1])
    with pytest.raises(ValueError, match="Reshape your data"):
        head.predict(x[0])


def test_set_params_errors_and_backbone_reload(tmp_path):
    with pytest.raises(ValueError, match="unknown parameters.*'gamma'"):
        FrameClassifier().set_params(gamma=1)
    with pytest.raises(FileNotFoundError, match="weights_path"):
        FrameClassifier().set_params(weights_path=tmp_path / "missing.pth")
    clf = FrameClassifier()
    assert clf.backbone_.device == torch.device("cpu")
    assert clf.to("meta") is clf and clf.device == "meta" and clf.backbone_.device == torch.device("meta")
    assert clf.set_params(device="cpu").backbone_.device == torch.device("cpu")
