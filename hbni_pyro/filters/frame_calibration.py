"""Per-frame calibration of classifier outputs: the calibrated peer's first half.

A practitioner with labelled calibration frames first recalibrates each frame's probability
vector, then runs a Bayes filter on the calibrated frames (:class:`~hbni_pyro.StaticStateBayesFilter`
with ``calibration=``, ``make_filter("calibrated", ...)``). Both maps here are
``q = softmax(W log o + b)`` on an output ``o (M,)``:

- ``"temperature"`` (Guo et al., 2017): ``W = I / T``, ``b = 0``, one parameter ``T > 0``;
- ``"matrix"``, Dirichlet calibration in its matrix form (Kull et al., NeurIPS 2019): a full ``W (M, M)``
  and ``b (M,)``, i.e. multinomial logistic regression on the log-probabilities.

:func:`fit_frame_calibration` minimises the mean negative log-likelihood of the frames' labels
(plus ``l2 / 2 * ||W||_F^2`` for the matrix form, scikit-learn's ``LogisticRegression`` penalty with
``C = 1 / (l2 N)``) by L-BFGS in float64. It treats frames as independent; the evidence weight that
accounts for a sequence's correlated frames is the filter's temper (:func:`hbni_pyro.fit_temper`).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import torch
from torch import Tensor

from hbni_infra.checks import as_float, as_int, as_names
from hbni_infra.tensorfile import load_tensors, save_tensors
from hbni_pyro.validation import DTYPE, as_labels, as_outputs

__all__ = ["CALIBRATIONS", "FrameCalibration", "fit_frame_calibration"]

CALIBRATIONS = ("temperature", "matrix")
"""The per-frame calibration maps :func:`fit_frame_calibration` fits."""

_KIND = "FrameCalibration"


class FrameCalibration:
    """The map ``o -> softmax(W log o + b)`` of classifier outputs ``(..., M)``.

    Args:
        weight: ``(M, M)``.
        bias: ``(M,)``.
        kind: one of :data:`CALIBRATIONS` (what was fitted; the map is the same).
        class_names: the classes in column order, or ``None``.
        info: JSON-serialisable fit details (loss, iterations, temperature).
    """

    def __init__(
        self,
        weight: Any,
        bias: Any,
        kind: str = "matrix",
        class_names: Any = None,
        info: dict[str, Any] | None = None,
    ) -> None:
        if kind not in CALIBRATIONS:
            raise ValueError(f"kind: expected one of {CALIBRATIONS}, got {kind!r}")
        weight = torch.as_tensor(weight, dtype=DTYPE)
        bias = torch.as_tensor(bias, dtype=DTYPE)
        M = weight.shape[0] if weight.dim() == 2 else -1
        if weight.dim() != 2 or weight.shape != (M, M) or M < 2:
            raise ValueError(f"weight: expected a square (M, M) matrix with M >= 2, got {tuple(weight.shape)}")
        if bias.shape != (M,):
            raise ValueError(f"bias: expected shape ({M},), got {tuple(bias.shape)}")
        if not (torch.isfinite(weight).all() and torch.isfinite(bias).all()):
            raise ValueError("weight, bias: expected finite values")
        self.weight, self.bias, self.kind = weight, bias, kind
        self.num_classes = M
        self.class_names = as_names("class_names", class_names, M)
        self.info = dict(info or {})

    def to(self, device: str | torch.device) -> FrameCalibration:
        """This map with its tensors on ``device`` (itself when they are there already)."""
        if self.weight.device == torch.device(device):
            return self
        return FrameCalibration(self.weight.to(device), self.bias.to(device), self.kind, self.class_names, self.info)

    def log_probs(self, obs: Any) -> Tensor:
        """Calibrated log-probabilities ``(..., M)`` of outputs ``(..., M)`` (validated, floored), on the map's
        device."""
        obs = as_outputs(obs, self.num_classes, name="obs").to(self.weight.device)
        return torch.log_softmax(obs.log() @ self.weight.T + self.bias, -1)

    def __call__(self, obs: Any) -> Tensor:
        """Calibrated probabilities ``(..., M)``."""
        return self.log_probs(obs).exp()

    def save(self, path: str | os.PathLike) -> Path:
        """Write the map to one safetensors file, atomically."""
        meta = {"kind": self.kind, "info": self.info, "class_names": self.class_names and list(self.class_names)}
        return save_tensors(path, _KIND, {"weight": self.weight.cpu(), "bias": self.bias.cpu()}, meta)

    @classmethod
    def load(cls, path: str | os.PathLike) -> FrameCalibration:
        """Read a file written by :meth:`save`; a corrupt or foreign file raises ``ValueError``."""
        tensors, meta = load_tensors(path, _KIND)
        try:
            return cls(tensors["weight"], tensors["bias"], meta["kind"], meta.get("class_names"), meta.get("info"))
        except KeyError as exc:
            raise ValueError(f"path: {str(path)!r} is an incomplete saved {_KIND} (missing {exc})") from None
        except (TypeError, ValueError) as exc:
            raise ValueError(f"path: {str(path)!r} holds an invalid {_KIND} ({exc})") from None

    def __repr__(self) -> str:
        extra = f", temperature={self.info['temperature']:.3f}" if "temperature" in self.info else ""
        return f"FrameCalibration(kind={self.kind!r}, num_classes={self.num_classes}{extra})"


def fit_frame_calibration(
    outputs: Any,
    labels: Any,
    kind: str = "matrix",
    *,
    l2: float = 1e-4,
    max_iter: int = 500,
    class_names: Any = None,
) -> FrameCalibration:
    """Fit a per-frame calibration map on labelled outputs.

    Args:
        outputs: ``(..., M)`` classifier outputs (frames of any batch shape).
        labels: integer classes of the same batch shape, in ``[0, M)``.
        kind: ``"temperature"`` or ``"matrix"`` (:data:`CALIBRATIONS`).
        l2: ridge penalty ``l2 / 2 * ||W||_F^2`` added to the mean log loss (matrix form only; it keeps ``W``
            finite when the frames are separable).
        max_iter: L-BFGS iterations.
        class_names: the classes in column order, or ``None``.

    Returns:
        a :class:`FrameCalibration` on the outputs' device; ``info`` holds the fitted mean log loss (``loss``),
        that of the identity map (``raw_loss``) and, for ``"temperature"``, the ``temperature``.
    """
    if kind not in CALIBRATIONS:
        raise ValueError(f"kind: expected one of {CALIBRATIONS}, got {kind!r}")
    l2 = as_float("l2", l2, 0.0)
    max_iter = as_int("max_iter", max_iter, minimum=1)
    obs = as_outputs(outputs, name="outputs")
    M = obs.shape[-1]
    x = obs.reshape(-1, M).log()
    y = as_labels(torch.as_tensor(labels).reshape(-1), x.shape[0], M)
    if (y < 0).any():
        raise ValueError("labels: expected every frame's class, got -1 (unknown)")
    if torch.as_tensor(labels).numel() != x.shape[0]:
        raise ValueError(f"labels: expected one per output ({x.shape[0]}), got {torch.as_tensor(labels).numel()}")
    y = y.to(x.device)

    def nll(logits: Tensor) -> Tensor:
        return torch.nn.functional.cross_entropy(logits, y)

    eye = torch.eye(M, dtype=DTYPE, device=x.device)
    if kind == "temperature":
        params = [torch.zeros((), dtype=DTYPE, device=x.device, requires_grad=True)]  # log T

        def loss() -> Tensor:
            return nll(x * torch.exp(-params[0]))

    else:
        params = [eye.clone().requires_grad_(), torch.zeros(M, dtype=DTYPE, device=x.device, requires_grad=True)]

        def loss() -> Tensor:
            return nll(x @ params[0].T + params[1]) + 0.5 * l2 * params[0].square().sum()

    opt = torch.optim.LBFGS(
        params, lr=1.0, max_iter=max_iter, tolerance_grad=1e-10, tolerance_change=1e-14, line_search_fn="strong_wolfe"
    )

    def closure() -> Tensor:
        opt.zero_grad()
        value = loss()
        value.backward()
        return value

    opt.step(closure)
    with torch.no_grad():
        info = {"loss": float(loss()), "raw_loss": float(nll(x)), "frames": int(x.shape[0])}
        if kind == "temperature":
            temperature = float(params[0].exp())
            info["temperature"] = temperature
            weight, bias = eye / temperature, torch.zeros(M, dtype=DTYPE, device=x.device)
        else:
            weight, bias = params[0].detach().clone(), params[1].detach().clone()
    return FrameCalibration(weight, bias, kind, class_names, info)
