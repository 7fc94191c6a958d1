"""How a domain sees perception: sample a class label and the frames it took, given the true class.

A Dec-POSMDP domain with an "infer object class" macro-action asks a
:class:`PerceptionModel` for the label the robot reports and the number of camera frames the
inference used; the domain turns frames into MA duration. Any object with ``num_classes`` and a
matching ``sample`` plugs in (a tabulated HBNI or SSBF characterisation, or
:class:`PerfectPerception`); this module never imports the perception packages.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Protocol, runtime_checkable

import torch
from torch import Tensor

from hbni_infra.checks import as_int


@runtime_checkable
class PerceptionModel(Protocol):
    """The planner's model of perception: for a true class, the label an inference reports and the
    frames it took (e.g. ``hbni_pyro.MacroObservationModel``, a tabulated macro-observation process).

    Attributes:
        num_classes: C, the number of object classes (labels lie in ``[0, C)``).

    A model that knows its classes' names has ``class_names`` (C names in label order, or ``None``); a domain
    compares them with its own (:func:`check_class_names`).

    A model that is a finite law of outcomes per class (every model this project ships) also has
    ``outcomes() -> (probs, label, frames)``, each (C, K): the compiled engine samples from that table
    (:mod:`decpomdp.engine.outcomes`); a model without it runs on the torch simulator.
    """

    num_classes: int

    def sample(self, true_class: Tensor, generator: torch.Generator) -> tuple[Tensor, Tensor]:
        """Labels and frame counts for a batch of objects.

        Args:
            true_class: long (B,), each object's class in ``[0, C)``.
            generator: the only source of randomness.

        Returns:
            label long (B,) in ``[0, C)``, frames long (B,) >= 1, on the device of ``true_class`` (the
            torch simulator's device, that of ``generator``).
        """
        ...


def check_true_class(true_class: Tensor, num_classes: int) -> None:
    """Raise ``TypeError``/``ValueError`` unless ``true_class`` is a long (B,) tensor in ``[0, num_classes)``."""
    if not isinstance(true_class, Tensor) or true_class.dtype != torch.long:
        got = type(true_class).__name__ if not isinstance(true_class, Tensor) else f"tensor of {true_class.dtype}"
        raise TypeError(f"true_class: expected a torch.long tensor, got {got}")
    if true_class.dim() != 1:
        raise ValueError(f"true_class: expected shape (B,), got {tuple(true_class.shape)}")
    if true_class.numel() and (int(true_class.min()) < 0 or int(true_class.max()) >= num_classes):
        raise ValueError(f"true_class: entries must lie in [0, {num_classes})")


def check_class_names(perception: PerceptionModel, classes: Sequence[str]) -> None:
    """Raise ``ValueError`` naming both lists unless a perception model with ``class_names`` (a table or a replay
    of a named posterior) names the domain's ``classes`` in the domain's order; a model without names (or
    ``None``) is taken as in the domain's order."""
    names = getattr(perception, "class_names", None)
    if names is None:
        return
    if isinstance(names, str) or tuple(names) != tuple(classes):
        same = not isinstance(names, str) and sorted(names) == sorted(classes)
        hint = ""
        if same:
            hint = "; the same classes in another order: reorder the model" + (
                f", perception.reordered({list(classes)})" if hasattr(perception, "reordered") else ""
            )
        raise ValueError(
            f"perception: its classes {list(names) if not isinstance(names, str) else names!r} are not the "
            f"domain's classes {list(classes)} in that order{hint}"
        )


class PerfectPerception:
    """Always reports the true class, after a fixed number of frames.

    Args:
        num_classes: C >= 1.
        frames: frames each inference takes (int >= 1).
    """

    def __init__(self, num_classes: int, frames: int = 1) -> None:
        self.num_classes = as_int("num_classes", num_classes, minimum=1)
        self.frames = as_int("frames", frames, minimum=1)

    def sample(self, true_class: Tensor, generator: torch.Generator) -> tuple[Tensor, Tensor]:
        """Return ``(true_class, frames)``; the generator is not consumed."""
        check_true_class(true_class, self.num_classes)
        return true_class.clone(), torch.full_like(true_class, self.frames)

    def outcomes(self) -> tuple[Tensor, Tensor, Tensor]:
        """The law of ``(label, frames)`` per true class for the compiled engine: one sure outcome each,
        ``(probs, label, frames)``, each (C, 1)."""
        classes = torch.arange(self.num_classes)[:, None]
        return torch.ones(self.num_classes, 1, dtype=torch.float64), classes, torch.full_like(classes, self.frames)

    def __repr__(self) -> str:
        return f"PerfectPerception(num_classes={self.num_classes}, frames={self.frames})"
