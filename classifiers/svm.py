"""One-vs-one linear SVMs trained in torch, Platt-scaled per pair and coupled to probabilities.

A scikit-learn classifier (``fit(X, y)``, ``decision_function``, ``predict_proba``, ``predict``, ``score``,
``classes_``, ``get_params``/``set_params``; arrays in, arrays out; ``sklearn.utils.estimator_checks`` pass, the
exceptions named in the tests), with torch paths for the pipeline (:meth:`OneVsOneSVC.proba`). Each class pair
``(i, j)``, ``i < j``, gets a linear SVM

    min_{w, b}  1/2 |w|^2 + 1/2 (b / B)^2 + C * sum_n max(0, 1 - y_n (w . x_n + b))^2

(squared hinge, ``y_n = +1`` for class ``i``; ``B`` the RMS example norm, so the bias is barely
regularised) solved exactly by Chapelle's primal Newton method in kernel form, batched over
every pair and every cross-validation fold in one tensor program.
Platt's sigmoid for each pair is fitted on decision values of ``cv``-fold models that never
saw the example (libsvm's ``svm_binary_svc_probability``), then the final SVMs are trained
on all data. Probabilities come from libsvm's pairwise coupling (Wu, Lin & Weng 2004).
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import Tensor

from classifiers.coupling import pairwise_coupling
from classifiers.platt import fit_platt, platt_predict
from hbni_infra.checks import as_float, as_int
from hbni_infra.tensorfile import load_tensors, save_tensors
from hbni_infra.threads import single_thread
from hbni_infra.streams import numpy_generator

__all__ = ["OneVsOneSVC", "bias_scale", "objective", "train_squared_hinge"]

_KIND = "classifiers.OneVsOneSVC"
_PROB_FLOOR = 1e-7  # libsvm clamps pairwise probabilities to [1e-7, 1 - 1e-7]


def bias_scale(x: Tensor) -> Tensor:
    """The constant ``B`` appended to every example: the root-mean-square example norm."""
    return x.pow(2).sum(1).mean().sqrt().clamp_min(1.0)


def objective(w: Tensor, b: Tensor, x: Tensor, y: Tensor, s: Tensor, c: float) -> Tensor:
    """Primal objective per problem: ``1/2 |w|^2 + 1/2 (b / B)^2 + C sum_n s_n max(0, 1 - y_n (w.x_n + b))^2``."""
    xi = (1 - y * (w @ x.T + b[:, None])).clamp_min(0)
    return 0.5 * (w * w).sum(-1) + 0.5 * (b / bias_scale(x)) ** 2 + c * (s * xi * xi).sum(-1)


def _dual_objective(beta: Tensor, kernel: Tensor, y: Tensor, s: Tensor, c: float) -> Tensor:
    f = beta @ kernel  # (Q, N) decision values
    xi = (1 - y * f).clamp_min(0)
    return 0.5 * (beta * f).sum(-1) + c * (s * xi * xi).sum(-1)


def train_squared_hinge(
    x: Tensor, y: Tensor, s: Tensor, c: float, max_iter: int = 100, chunk: int = 32
) -> tuple[Tensor, Tensor]:
    """Solve many squared-hinge linear SVM problems on shared examples at once (exact Newton).

    The bias is a weight on a constant feature ``B`` (:func:`bias_scale`), so it is regularised
    only by ``(b / B)^2 / 2``, negligible at the scale of the examples. With the kernel
    ``K = X X^T + B^2`` and ``w = X^T beta``, Chapelle's (2007) primal Newton step for the
    squared hinge is ``beta_A = (K_AA + I / 2C)^{-1} y_A``, ``beta = 0`` off the active set
    ``A = {n : y_n f_n < 1}``; the objective is piecewise quadratic, so the iteration (with
    Armijo backtracking as a safeguard) ends exactly when the active set stops changing.
    Every problem is one masked ``(N, N)`` Cholesky solve per step, batched; cost
    ``O(Q N^3)``, meant for up to a few thousand examples.

    Args:
        x: examples ``(N, D)`` float64.
        y: signs ``(Q, N)`` in {-1, +1} per problem.
        s: ``(Q, N)`` in {0, 1}: which examples each problem uses.
        c: the penalty ``C``.
        max_iter: Newton steps.
        chunk: problems solved together (bounds memory at ``chunk * N^2`` doubles).

    Returns:
        ``(w (Q, D), b (Q,))``.
    """
    scale2 = bias_scale(x) ** 2
    kernel = x @ x.T + scale2
    lam = torch.eye(x.shape[0], dtype=x.dtype) / (2 * c)
    member = s > 0
    betas = []
    for start in range(0, y.shape[0], chunk):
        yq, sq, mq = y[start : start + chunk], s[start : start + chunk], member[start : start + chunk]
        beta = torch.zeros_like(yq)
        f_obj = _dual_objective(beta, kernel, yq, sq, c)
        active = mq.clone()
        for _ in range(max_iter):
            a = active.to(x.dtype)
            system = kernel * (a[:, :, None] * a[:, None, :]) + lam
            target = torch.cholesky_solve((a * yq).unsqueeze(-1), torch.linalg.cholesky(system)).squeeze(-1)
            step = target - beta
            t = torch.ones(beta.shape[0], dtype=x.dtype)
            for _ in range(30):  # Armijo backtracking (a full step almost always passes)
                trial = beta + t[:, None] * step
                f_new = _dual_objective(trial, kernel, yq, sq, c)
                ok = f_new <= f_obj + 1e-12 * f_obj.abs()
                if ok.all():
                    break
                t = torch.where(ok, t, t / 2)
            beta, f_obj = trial, f_new
            new_active = mq & (yq * (beta @ kernel) < 1)
            if torch.equal(new_active, active) and bool((t == 1).all()):
                break
            active = new_active
        betas.append(beta)
    beta = torch.cat(betas)
    return beta @ x, beta.sum(-1) * scale2


def _as_2d(x: Any, name: str) -> Tensor:
    """Features ``(N, D)``, N, D >= 1, as a float64 tensor (from a tensor, an array or a nested sequence)."""
    if hasattr(x, "toarray") or type(x).__module__.startswith("scipy.sparse"):
        raise TypeError(f"{name}: sparse input is not supported, pass a dense array")
    if not isinstance(x, Tensor):
        if isinstance(x, (str, bytes)):
            raise TypeError(f"{name}: expected a (N, D) tensor or array, got {type(x).__name__}")
        x = np.asarray(x)
        if x.dtype.kind == "c":
            raise ValueError(f"{name}: Complex data not supported, expected real features")
        x = torch.from_numpy(np.array(x, dtype=np.float64))  # a copy: read-only or object arrays welcome
    if x.ndim != 2:
        raise ValueError(f"{name}: expected a (N, D) matrix, got shape {tuple(x.shape)}; Reshape your data")
    if x.shape[1] == 0:
        raise ValueError(f"{name}: 0 feature(s) (shape={tuple(x.shape)}) while a minimum of 1 is required.")
    if x.shape[0] == 0:
        raise ValueError(f"{name}: 0 sample(s) (shape={tuple(x.shape)}) while a minimum of 1 is required.")
    if x.is_complex():
        raise ValueError(f"{name}: Complex data not supported, expected real features")
    x = x.double()
    if not torch.isfinite(x).all():
        raise ValueError(f"{name}: contains NaN or inf")
    return x


def _labels(y: Any, n: int) -> np.ndarray:
    """Class labels ``(n,)``: any sortable values; refused when missing, of another length, or continuous."""
    if y is None:
        raise ValueError("y: requires y to be passed, but the target y is None")
    labels = np.asarray(y.detach().cpu().numpy() if isinstance(y, Tensor) else y)
    if labels.ndim != 1 or len(labels) != n:
        raise ValueError(f"y: expected shape ({n},), got {labels.shape}")
    if labels.dtype.kind in "fc":
        if not np.isfinite(labels).all():
            raise ValueError("y: Input y contains NaN or infinity")
        if (labels != np.round(labels)).any():
            raise ValueError("y: Unknown label type: continuous values; expected class labels")
    return labels


class OneVsOneSVC:
    """Multiclass linear SVM with Platt-scaled one-vs-one outputs and pairwise coupling.

    Args:
        C: penalty on the squared hinge loss (larger = less regularisation).
        cv: folds for the held-out decision values Platt's sigmoids are fitted on (libsvm uses 5).
        seed: seed of the cross-validation split.

    Attributes (after ``fit``):
        classes_: the sorted class labels (an array, as scikit-learn's).
        n_features_in_: ``D``, the number of features.
        pairs_: ``(P, 2)`` long, class indices ``(i, j)``, ``i < j``, in sklearn's ``ovo`` order.
        coef_, intercept_: ``(P, D)`` and ``(P,)``: the pairwise SVMs (positive = class ``i``).
        prob_a_, prob_b_: ``(P,)`` Platt parameters, ``P(i | f) = 1 / (1 + exp(A f + B))``.
    """

    def __init__(self, C: float = 1.0, cv: int = 5, seed: int = 0):
        _check_params(C, cv, seed)
        self.C = C
        self.cv = cv
        self.seed = seed

    _estimator_type = "classifier"  # scikit-learn < 1.6 reads this; newer versions read __sklearn_tags__

    def get_params(self, deep: bool = True) -> dict[str, Any]:
        """The constructor's arguments as given (``deep`` is accepted for scikit-learn; there are no sub-estimators)."""
        return {"C": self.C, "cv": self.cv, "seed": self.seed}

    def set_params(self, **params: Any) -> OneVsOneSVC:
        """Set constructor arguments, checked as the constructor checks them; returns ``self`` (the fit is kept)."""
        unknown = sorted(set(params) - {"C", "cv", "seed"})
        if unknown:
            raise ValueError(f"set_params: unknown parameters {unknown}, expected names among ['C', 'cv', 'seed']")
        merged = self.get_params() | params
        _check_params(merged["C"], merged["cv"], merged["seed"])
        self.__dict__.update(params)
        return self

    def __repr__(self) -> str:
        changed = [f"{k}={v!r}" for k, v in self.get_params().items() if v != {"C": 1.0, "cv": 5, "seed": 0}[k]]
        return f"{type(self).__name__}({', '.join(changed)})"

    def __sklearn_tags__(self) -> Any:
        """scikit-learn's tags (scikit-learn >= 1.6 calls this; imported here): a classifier of dense 2-d features."""
        from sklearn.utils import ClassifierTags, InputTags, Tags, TargetTags

        return Tags(
            estimator_type="classifier",
            target_tags=TargetTags(required=True),
            classifier_tags=ClassifierTags(),
            input_tags=InputTags(two_d_array=True),
        )

    def __sklearn_is_fitted__(self) -> bool:
        return "classes_" in self.__dict__

    # ---- training -------------------------------------------------------------------------------
    def _split(self, yi: np.ndarray) -> np.ndarray:
        """Stratified fold id per example (random within each class, seeded)."""
        rng = numpy_generator(int(self.seed))
        fold = np.empty(len(yi), dtype=np.int64)
        for k in np.unique(yi):
            idx = np.flatnonzero(yi == k)
            fold[rng.permutation(idx)] = np.arange(len(idx)) % int(self.cv)
        return fold

    def fit(self, X: Any, y: Sequence | np.ndarray | Tensor) -> OneVsOneSVC:
        """Train on features ``X (N, D)`` and labels ``y (N,)`` (any sortable labels, >= 2 classes)."""
        x = _as_2d(X, "X")
        labels = _labels(y, x.shape[0])
        classes, yi = np.unique(labels, return_inverse=True)
        m, cv = len(classes), int(self.cv)
        if m < 2:
            raise ValueError(f"y: expected at least 2 classes, got {m} class")
        counts = np.bincount(yi, minlength=m)
        if counts.min() < cv:
            raise ValueError(f"y: every class needs >= cv={cv} examples, got counts {counts.tolist()}")
        pairs = torch.combinations(torch.arange(m), 2)
        yt = torch.from_numpy(yi)
        in_i = yt[None, :] == pairs[:, :1]  # (P, N)
        member = in_i | (yt[None, :] == pairs[:, 1:])
        sign = torch.where(in_i, 1.0, -1.0).double()
        fold = torch.from_numpy(self._split(yi))
        # Problems: every pair x (each CV fold held out, then all data).
        held = torch.stack([fold == k for k in range(cv)] + [torch.zeros_like(fold, dtype=torch.bool)])
        s = (member[None] & ~held[:, None]).double()  # (K + 1, P, N)
        num_p = pairs.shape[0]
        with single_thread():  # small matrices: LAPACK thread hand-offs cost more than they save
            w, b = train_squared_hinge(x, sign.repeat(cv + 1, 1), s.reshape(-1, x.shape[0]), float(self.C))
        w, b = w.view(cv + 1, num_p, -1), b.view(cv + 1, num_p)
        # Held-out decision value of each example under the fold model that did not see it.
        dec_folds = torch.einsum("kpd,nd->kpn", w[:cv], x) + b[:cv, :, None]
        dec = dec_folds.gather(0, fold.view(1, 1, -1).expand(1, num_p, -1))[0]  # (P, N)
        self.prob_a_, self.prob_b_ = fit_platt(dec, in_i, member)
        self.classes_ = classes
        self.n_features_in_ = x.shape[1]
        self.pairs_ = pairs
        self.coef_, self.intercept_ = w[-1], b[-1]
        return self

    # ---- prediction -----------------------------------------------------------------------------
    def _check_fitted(self) -> None:
        if not self.__sklearn_is_fitted__():
            raise RuntimeError("OneVsOneSVC: call fit() or load() first")

    def _decision(self, X: Any) -> Tensor:
        """One-vs-one decision values ``(N, P)`` float64, pairs in ``pairs_`` order; > 0 favours the pair's first class."""
        self._check_fitted()
        x = _as_2d(X, "X")
        if x.shape[1] != self.coef_.shape[1]:
            raise ValueError(
                f"X has {x.shape[1]} features, but {type(self).__name__} is expecting {self.coef_.shape[1]} features "
                "as input"
            )
        return x @ self.coef_.T + self.intercept_

    def decision_function(self, X: Any) -> np.ndarray:
        """One-vs-one decision values as ``SVC(decision_function_shape="ovo")`` gives them: ``(N, P)``, pairs in
        ``pairs_`` order, > 0 favouring the pair's first class; for two classes ``(N,)``, > 0 favouring ``classes_[1]``."""
        dec = self._decision(X).numpy()
        return -dec[:, 0] if dec.shape[1] == 1 else dec

    def pairwise_proba(self, X: Any) -> Tensor:
        """``r (N, M, M)`` with ``r[n, i, j] = P(i | i or j, x_n)`` from the Platt sigmoids."""
        p = platt_predict(self._decision(X), self.prob_a_, self.prob_b_).clamp(_PROB_FLOOR, 1 - _PROB_FLOOR)
        m = len(self.classes_)
        r = p.new_zeros(p.shape[0], m, m)
        i, j = self.pairs_[:, 0], self.pairs_[:, 1]
        r[:, i, j] = p
        r[:, j, i] = 1 - p
        return r

    def proba(self, X: Any) -> Tensor:
        """Class probabilities ``(N, M)`` as a float64 torch tensor (rows sum to 1), columns in ``classes_`` order."""
        return pairwise_coupling(self.pairwise_proba(X))

    def predict_proba(self, X: Any) -> np.ndarray:
        """Class probabilities ``(N, M)`` float64 (rows sum to 1 within float64 rounding), columns in ``classes_``."""
        return self.proba(X).numpy()

    def predict(self, X: Any) -> np.ndarray:
        """The most probable class label per row ``(N,)`` (argmax of ``predict_proba``; ties -> lowest index)."""
        return self.classes_[self.proba(X).argmax(-1).numpy()]

    def score(self, X: Any, y: Sequence | np.ndarray | Tensor, sample_weight: Any = None) -> float:
        """Mean accuracy of :meth:`predict` on ``X`` against labels ``y`` (weighted by ``sample_weight``)."""
        truth = np.asarray(y.tolist() if isinstance(y, Tensor) else y)
        return float(np.average(self.predict(X) == truth, weights=sample_weight))

    # ---- storage --------------------------------------------------------------------------------
    def state(self) -> tuple[dict[str, Tensor], dict[str, Any]]:
        """Tensors and JSON metadata that :meth:`from_state` restores."""
        self._check_fitted()
        tensors = {
            "coef": self.coef_,
            "intercept": self.intercept_,
            "prob_a": self.prob_a_,
            "prob_b": self.prob_b_,
            "pairs": self.pairs_,
        }
        meta = {"classes": self.classes_.tolist(), "C": float(self.C), "cv": int(self.cv), "seed": int(self.seed)}
        return tensors, meta

    @classmethod
    def from_state(cls, tensors: dict[str, Tensor], meta: dict[str, Any]) -> OneVsOneSVC:
        """The model :meth:`state` describes, checked as at construction (``ValueError`` naming the entry)."""
        try:
            model = cls(
                C=as_float("state C", meta["C"], 0.0, low_open=True),
                cv=as_int("state cv", meta["cv"], minimum=2),
                seed=as_int("state seed", meta["seed"]),
            )
            model.classes_ = np.asarray(_class_list(meta["classes"]))
            model.n_features_in_ = int(tensors["coef"].shape[1])
            model.coef_, model.intercept_ = tensors["coef"].double(), tensors["intercept"].double()
            model.prob_a_, model.prob_b_ = tensors["prob_a"].double(), tensors["prob_b"].double()
            model.pairs_ = tensors["pairs"].long()
        except KeyError as exc:
            raise ValueError(f"state: missing entry {exc}") from None
        except TypeError as exc:
            raise ValueError(f"state: malformed entry ({exc})") from None
        if not all(
            bool(torch.isfinite(t).all()) for t in (model.coef_, model.intercept_, model.prob_a_, model.prob_b_)
        ):
            raise ValueError("state: coef, intercept, prob_a and prob_b must be finite")
        m, p = len(model.classes_), model.coef_.shape[0]
        if p != m * (m - 1) // 2 or model.pairs_.shape != (p, 2) or model.prob_a_.shape != (p,):
            raise ValueError(f"state: inconsistent shapes for {m} classes")
        return model

    def save(self, path: str | os.PathLike) -> Path:
        """Write the fitted model to one safetensors file (atomic, no pickle)."""
        return save_tensors(path, _KIND, *self.state())

    @classmethod
    def load(cls, path: str | os.PathLike) -> OneVsOneSVC:
        """Read a model written by :meth:`save`; ``ValueError`` for a corrupt or foreign file."""
        tensors, meta = load_tensors(path, _KIND)
        try:
            return cls.from_state(tensors, meta)
        except ValueError as exc:
            raise ValueError(f"path: {str(path)!r} holds an invalid {_KIND} ({exc})") from None


def _check_params(C: Any, cv: Any, seed: Any) -> None:
    """Refuse bad constructor arguments with an error naming the argument."""
    as_float("C", C, 0.0, low_open=True)
    as_int("cv", cv, minimum=2)
    as_int("seed", seed, minimum=0)


def _class_list(classes: Any) -> list:
    """A saved class list: distinct strings or ints, else ``ValueError``."""
    if not isinstance(classes, list) or not all(isinstance(c, (str, int)) and not isinstance(c, bool) for c in classes):
        raise ValueError(f"state classes: expected a list of class names, got {classes!r}")
    if len(set(classes)) != len(classes):
        raise ValueError(f"state classes: expected distinct names, got {classes!r}")
    return classes
