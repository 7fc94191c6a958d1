"""The keys every experiment has (:class:`Root`), the root of every experiment's schema."""

from __future__ import annotations

from dataclasses import dataclass, field

from omegaconf import MISSING

from experiments.schemas.blocks import HBNIBlock


@dataclass
class Paths:
    """``paths``: where runs, sweeps and caches go (``conf/config.yaml``)."""

    root: str = MISSING  # the values are conf/config.yaml's
    outputs: str = MISSING
    multirun: str = MISSING
    cache: str = MISSING


@dataclass
class Root:
    """Keys every experiment has."""

    paths: Paths = field(default_factory=Paths)
    name: str = MISSING
    entry: str = MISSING
    headline: list[str] = MISSING  # metrics a sweep report shows (paths into metrics.json)
    seed: int = MISSING
    progress: bool = MISSING
    hbni: HBNIBlock = field(default_factory=HBNIBlock)

    def unread(self) -> dict[str, str]:
        """Key -> why the experiment never reads it (refused when set: :func:`experiments.schemas.check_overrides`).
        The settings a planner ignores are added there."""
        return {}

    def noise_models(self) -> tuple[str, ...]:
        """The noise models the experiment fits (their hyperprior fields are the ones it reads)."""
        return (self.hbni.model,)


NO_NOISE_MODEL = "it fits no noise model"


@dataclass
class NoPerception(Root):
    """A study that plans on a domain and fits no noise model: the ``hbni`` block is not read."""

    def unread(self) -> dict[str, str]:
        return {"hbni": NO_NOISE_MODEL}

    def noise_models(self) -> tuple[str, ...]:
        return ()


@dataclass
class PaperStudy(Root):
    """A study of the paper's own noise model: ``hbni.model`` is not read."""

    def unread(self) -> dict[str, str]:
        return {"hbni.model": "the study fits the paper's model"}

    def noise_models(self) -> tuple[str, ...]:
        return ("paper",)
