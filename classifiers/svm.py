"""One-vs-one linear SVMs trained in torch, Platt-scaled per pair and coupled to probabilities.

The scikit-learn conventions apply: ``fit(X, y)``, ``decision_function``, ``predict_proba``,
``predict`` and ``classes_``. Each class pair ``(i, j)``, ``i < j``, gets a linear SVM

    min_{w, b}  1/2 |w|^2 + C * sum_n max(0, 1 - y_n (w . x_n + b))^2     (y_n = +1 for class i)

(squared hinge, unregularised bias) solved by a truncated Newton method (Newton steps from
conjugate gradients on Hessian-vector products, Armijo backtracking; the primal method of
liblinear), batched over every pair and every cross-validation fold in one tensor program.
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
from classifiers.storage import load_tensors, save_tensors

__all__ = ["OneVsOneSVC", "train_squared_hinge"]

_KIND = "classifiers.OneVsOneSVC"
_PROB_FLOOR = 1e-7  # libsvm clamps pairwise probabilities to [1e-7, 1 - 1e-7]


def _objective(w: Tensor, b: Tensor, x: Tensor, y: Tensor, s: Tensor, c: float) -> Tensor:
    xi = (1 - y * (w @ x.T + b[:, None])).clamp_min(0)
    return 0.5 * (w * w).sum(-1) + c * (s * xi * xi).sum(-1)


def _cg(x: Tensor, active: Tensor, gw: Tensor, gb: Tensor, c: float, rtol: Tensor, max_iter: int):
    """Conjugate gradients for the Newton system ``H d = -g`` of each problem (rows), batched.

    ``H = I + 2C X_A^T X_A`` on ``w`` (``A`` = active examples) and ``2C |A|`` on the bias.
    A problem stops once its residual is below ``rtol``; the others continue.
    """

    def hess(vw: Tensor, vb: Tensor, act: Tensor) -> tuple[Tensor, Tensor]:
        u = 2 * c * act * (vw @ x.T + vb[:, None])
        return vw + u @ x, u.sum(-1) + 1e-10 * vb

    dw, db = torch.zeros_like(gw), torch.zeros_like(gb)
    rw, rb = -gw, -gb
    pw, pb = rw.clone(), rb.clone()
    rr = (rw * rw).sum(-1) + rb * rb
    for _ in range(max_iter):
        live = (rr.sqrt() > rtol).nonzero().squeeze(-1)
        if live.numel() == 0:
            break
        hw, hb = hess(pw[live], pb[live], active[live])
        alpha = rr[live] / ((pw[live] * hw).sum(-1) + pb[live] * hb).clamp_min(1e-300)
        dw[live] += alpha[:, None] * pw[live]
        db[live] += alpha * pb[live]
        rw[live] -= alpha[:, None] * hw
        rb[live] -= alpha * hb
        rr_new = (rw[live] ** 2).sum(-1) + rb[live] ** 2
        beta = rr_new / rr[live].clamp_min(1e-300)
        pw[live] = rw[live] + beta[:, None] * pw[live]
        pb[live] = rb[live] + beta * pb[live]
        rr[live] = rr_new
    return dw, db


def train_squared_hinge(
    x: Tensor, y: Tensor, s: Tensor, c: float, tol: float = 1e-6, max_iter: int = 100, cg_iter: int = 250
) -> tuple[Tensor, Tensor]:
    """Solve many squared-hinge linear SVM problems on shared examples at once.

    Args:
        x: examples ``(N, D)`` float64.
        y: signs ``(Q, N)`` in {-1, +1} per problem.
        s: float ``(Q, N)`` in {0, 1}: which examples each problem uses.
        c: the penalty ``C``.
        tol: stop a problem when ``|grad| <= tol * |grad at w = 0|``.
        max_iter, cg_iter: Newton iterations, conjugate-gradient iterations per Newton step.

    Returns:
        ``(w (Q, D), b (Q,))``. Only unconverged problems are computed on at each step.
    """
    q, d = y.shape[0], x.shape[1]
    w = x.new_zeros(q, d)
    b = x.new_zeros(q)

    def grad(w: Tensor, b: Tensor, y: Tensor, s: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        xi = (1 - y * (w @ x.T + b[:, None])).clamp_min(0) * s  # zero off the active set
        coef = -2 * c * y * xi
        return w + coef @ x, coef.sum(-1), (xi > 0).to(x.dtype)

    gw, gb, active = grad(w, b, y, s)
    g0 = torch.sqrt((gw * gw).sum(-1) + gb * gb)
    f = _objective(w, b, x, y, s, c)
    todo = torch.ones(q, dtype=torch.bool)
    for _ in range(max_iter):
        gnorm = torch.sqrt((gw * gw).sum(-1) + gb * gb)
        todo = todo & (gnorm > tol * g0)
        idx = todo.nonzero().squeeze(-1)
        if idx.numel() == 0:
            break
        yi, si, wi, bi, fi = y[idx], s[idx], w[idx], b[idx], f[idx]
        gwi, gbi, gn = gw[idx], gb[idx], gnorm[idx]
        rtol = (gn / g0[idx]).clamp_max(0.1) * gn  # forcing term: superlinear convergence
        dw, db = _cg(x, active[idx], gwi, gbi, c, rtol, cg_iter)
        # Armijo backtracking, every problem at once.
        slope = (gwi * dw).sum(-1) + gbi * db
        step = torch.ones_like(bi)
        pending = torch.ones_like(bi, dtype=torch.bool)
        for _ in range(30):
            f_new = _objective(wi + step[:, None] * dw, bi + step * db, x, yi, si, c)
            accept = pending & (f_new <= fi + 1e-4 * step * slope)
            wi = torch.where(accept[:, None], wi + step[:, None] * dw, wi)
            bi = torch.where(accept, bi + step * db, bi)
            fi = torch.where(accept, f_new, fi)
            pending = pending & ~accept
            if not pending.any():
                break
            step = torch.where(pending, step / 2, step)
        w[idx], b[idx], f[idx] = wi, bi, fi
        todo[idx[pending]] = False  # no descent left: at the numerical optimum
        gw[idx], gb[idx], active[idx] = grad(wi, bi, yi, si)
    return w, b


def _as_2d(x: Any, name: str) -> Tensor:
    if isinstance(x, np.ndarray):
        x = torch.from_numpy(x)
    if not isinstance(x, Tensor):
        raise TypeError(f"{name}: expected a (N, D) tensor or array, got {type(x).__name__}")
    if x.ndim != 2 or x.shape[0] == 0:
        raise ValueError(f"{name}: expected a non-empty (N, D) matrix, got shape {tuple(x.shape)}")
    if not x.is_floating_point():
        x = x.double()
    if not torch.isfinite(x).all():
        raise ValueError(f"{name}: contains NaN or inf")
    return x.double()


class OneVsOneSVC:
    """Multiclass linear SVM with Platt-scaled one-vs-one outputs and pairwise coupling.

    Args:
        C: penalty on the squared hinge loss (larger = less regularisation).
        cv: folds for the held-out decision values Platt's sigmoids are fitted on (libsvm uses 5).
        tol: relative gradient tolerance of the SVM solver.
        seed: seed of the cross-validation split.

    Attributes (after ``fit``):
        classes_: the sorted class labels (list).
        pairs_: ``(P, 2)`` long, class indices ``(i, j)``, ``i < j``, in sklearn's ``ovo`` order.
        coef_, intercept_: ``(P, D)`` and ``(P,)``: the pairwise SVMs (positive = class ``i``).
        prob_a_, prob_b_: ``(P,)`` Platt parameters, ``P(i | f) = 1 / (1 + exp(A f + B))``.
    """

    def __init__(self, C: float = 1.0, cv: int = 5, tol: float = 1e-6, seed: int = 0):
        if not C > 0:
            raise ValueError(f"C: expected > 0, got {C}")
        if int(cv) != cv or cv < 2:
            raise ValueError(f"cv: expected an integer >= 2, got {cv}")
        self.C = float(C)
        self.cv = int(cv)
        self.tol = float(tol)
        self.seed = int(seed)
        self.classes_: list | None = None

    # ---- training -------------------------------------------------------------------------------
    def _split(self, yi: np.ndarray) -> np.ndarray:
        """Stratified fold id per example (random within each class, seeded)."""
        rng = np.random.default_rng(self.seed)
        fold = np.empty(len(yi), dtype=np.int64)
        for k in np.unique(yi):
            idx = np.flatnonzero(yi == k)
            fold[rng.permutation(idx)] = np.arange(len(idx)) % self.cv
        return fold

    def fit(self, X: Any, y: Sequence | np.ndarray | Tensor) -> OneVsOneSVC:
        """Train on features ``X (N, D)`` and labels ``y (N,)`` (any sortable labels, >= 2 classes)."""
        x = _as_2d(X, "X")
        labels = np.asarray(y.detach().cpu().numpy() if isinstance(y, Tensor) else y)
        if labels.ndim != 1 or len(labels) != x.shape[0]:
            raise ValueError(f"y: expected shape ({x.shape[0]},), got {labels.shape}")
        classes, yi = np.unique(labels, return_inverse=True)
        m = len(classes)
        if m < 2:
            raise ValueError(f"y: expected at least 2 classes, got {m}")
        counts = np.bincount(yi, minlength=m)
        if counts.min() < self.cv:
            raise ValueError(f"y: every class needs >= cv={self.cv} examples, got counts {counts.tolist()}")
        pairs = torch.combinations(torch.arange(m), 2)
        yt = torch.from_numpy(yi)
        in_i = yt[None, :] == pairs[:, :1]  # (P, N)
        member = in_i | (yt[None, :] == pairs[:, 1:])
        sign = torch.where(in_i, 1.0, -1.0).double()
        fold = torch.from_numpy(self._split(yi))
        # Problems: every pair x (each CV fold held out, then all data).
        held = torch.stack([fold == k for k in range(self.cv)] + [torch.zeros_like(fold, dtype=torch.bool)])
        s = (member[None] & ~held[:, None]).double()  # (K + 1, P, N)
        num_p = pairs.shape[0]
        w, b = train_squared_hinge(
            x, sign.repeat(self.cv + 1, 1), s.reshape(-1, x.shape[0]), self.C, tol=self.tol
        )
        w, b = w.view(self.cv + 1, num_p, -1), b.view(self.cv + 1, num_p)
        # Held-out decision value of each example under the fold model that did not see it.
        dec_folds = torch.einsum("kpd,nd->kpn", w[: self.cv], x) + b[: self.cv, :, None]
        dec = dec_folds.gather(0, fold.view(1, 1, -1).expand(1, num_p, -1))[0]  # (P, N)
        self.prob_a_, self.prob_b_ = fit_platt(dec, in_i, member)
        self.classes_ = [c.item() if hasattr(c, "item") else c for c in classes]
        self.pairs_ = pairs
        self.coef_, self.intercept_ = w[-1], b[-1]
        return self

    # ---- prediction -----------------------------------------------------------------------------
    def _check_fitted(self) -> None:
        if self.classes_ is None:
            raise RuntimeError("OneVsOneSVC: call fit() or load() first")

    def decision_function(self, X: Any) -> Tensor:
        """One-vs-one decision values ``(N, P)``, pairs in ``pairs_`` order; > 0 favours the pair's first class."""
        self._check_fitted()
        x = _as_2d(X, "X")
        if x.shape[1] != self.coef_.shape[1]:
            raise ValueError(f"X: expected {self.coef_.shape[1]} features, got {x.shape[1]}")
        return x @ self.coef_.T + self.intercept_

    def pairwise_proba(self, X: Any) -> Tensor:
        """``r (N, M, M)`` with ``r[n, i, j] = P(i | i or j, x_n)`` from the Platt sigmoids."""
        p = platt_predict(self.decision_function(X), self.prob_a_, self.prob_b_).clamp(_PROB_FLOOR, 1 - _PROB_FLOOR)
        m = len(self.classes_)
        r = p.new_zeros(p.shape[0], m, m)
        i, j = self.pairs_[:, 0], self.pairs_[:, 1]
        r[:, i, j] = p
        r[:, j, i] = 1 - p
        return r

    def predict_proba(self, X: Any) -> Tensor:
        """Class probabilities ``(N, M)`` (float64, rows sum to 1), columns in ``classes_`` order."""
        return pairwise_coupling(self.pairwise_proba(X))

    def predict(self, X: Any) -> list:
        """The most probable class label per row (argmax of ``predict_proba``; ties -> lowest index)."""
        return [self.classes_[k] for k in self.predict_proba(X).argmax(-1).tolist()]

    # ---- storage --------------------------------------------------------------------------------
    def state(self) -> tuple[dict[str, Tensor], dict[str, Any]]:
        """Tensors and JSON metadata that :meth:`from_state` restores."""
        self._check_fitted()
        tensors = {"coef": self.coef_, "intercept": self.intercept_, "prob_a": self.prob_a_, "prob_b": self.prob_b_,
                   "pairs": self.pairs_}
        meta = {"classes": self.classes_, "C": self.C, "cv": self.cv, "tol": self.tol, "seed": self.seed}
        return tensors, meta

    @classmethod
    def from_state(cls, tensors: dict[str, Tensor], meta: dict[str, Any]) -> OneVsOneSVC:
        try:
            model = cls(C=meta["C"], cv=meta["cv"], tol=meta["tol"], seed=meta["seed"])
            model.classes_ = list(meta["classes"])
            model.coef_, model.intercept_ = tensors["coef"].double(), tensors["intercept"].double()
            model.prob_a_, model.prob_b_ = tensors["prob_a"].double(), tensors["prob_b"].double()
            model.pairs_ = tensors["pairs"].long()
        except (KeyError, TypeError) as exc:
            raise ValueError(f"state: missing or malformed entry {exc}") from exc
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
        return cls.from_state(*load_tensors(path, _KIND))
