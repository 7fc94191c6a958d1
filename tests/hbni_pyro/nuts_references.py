"""Stored NUTS posteriors for the MH-against-NUTS tests, and the script that writes them.

Pyro's NUTS takes 20-250 ms an iteration on these problems, a CPU minute or more for each comparison, so the tests
compare the MH kernels with longer NUTS runs stored in ``nuts_references.json``. Each reference holds its data, its
NUTS settings, the posterior summary (mean, sd and ESS of every scalar), the class probabilities of the training
units, and the Pyro model's potential energy at five fixed points. :func:`load_reference` recomputes those
potentials with the current code and refuses a reference whose model has changed since it was written. Then
regenerate it (about six CPU minutes for all three)::

    python tests/hbni_pyro/nuts_references.py [toy] [confusion] [sequence]
"""

from __future__ import annotations

import json
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pyro
import torch
from pyro.infer.mcmc.util import initialize_model
from torch import Tensor

import hbni_pyro
from hbni_infra.files import atomic_write_text
from hbni_pyro import HyperPrior, noise_model
from hbni_pyro.fit import _nuts_args
from hbni_pyro.validation import as_class_prior
from known_models import DT, confusion_data, sequences, toy_obs

PATH = Path(__file__).with_name("nuts_references.json")
NUM_POINTS = 5
"""Fixed points in the unconstrained space at which a reference's potential energy is stored."""
POTENTIAL_RTOL = 1e-9
"""Relative tolerance on a recomputed potential: float64 round-off between machines, far below any model change."""


@dataclass(frozen=True)
class Problem:
    """A fit's data and model: ``obs`` ``(N, M)``, ``labels`` ``(N,)`` (``-1`` unknown) or ``None``, and
    ``sequence_ids`` ``(N,)`` for a sequence model."""

    model: str
    obs: Tensor
    labels: Tensor | None = None
    sequence_ids: Tensor | None = None

    def fit(self, **settings: Any) -> hbni_pyro.HBNIPosterior:
        return hbni_pyro.fit(
            self.obs, self.labels, model=self.model, sequence_ids=self.sequence_ids, progress=False, **settings
        )

    def potential(self, points: dict[str, Tensor]) -> Tensor:
        """The Pyro model's potential energy (classes enumerated out) at unconstrained ``points``, each site
        ``(K, ...)``: ``(K,)``."""
        _, potential_fn, _, _ = self._model_parts()
        count = len(next(iter(points.values())))
        return torch.stack([potential_fn({k: v[i] for k, v in points.items()}) for i in range(count)])

    def draw_points(self, seed: int) -> dict[str, Tensor]:
        """``NUM_POINTS`` points of the unconstrained space, each site ``(NUM_POINTS, ...)``, drawn from the prior."""
        pyro.set_rng_seed(seed)
        init, _, _, _ = self._model_parts(num_chains=NUM_POINTS)
        return {k: v.to(DT) for k, v in init.items()}

    def _model_parts(self, num_chains: int = 1) -> tuple:
        spec = noise_model(self.model)
        x = hbni_pyro.as_outputs(self.obs)
        args = _nuts_args(spec, x, self.labels, self.sequence_ids)
        return initialize_model(
            spec.pyro_model,
            model_args=(*args, as_class_prior(None, x.shape[1]), HyperPrior()),  # fit's defaults
            max_plate_nesting=spec.max_plate_nesting,
            num_chains=num_chains,
            init_strategy=pyro.infer.autoguide.initialization.init_to_sample,
        )


def problems() -> dict[str, Problem]:
    """The three reference problems: the paper's toy (all unlabelled), a known confusion structure (a third
    unlabelled) and known sequence looks (two of six sequences unlabelled)."""
    obs, classes = confusion_data(4, seed=5)
    seqs, _ = sequences(6, 3, seed=6)
    return {
        "toy": Problem("paper", toy_obs(0)),
        "confusion": Problem("confusion", obs, torch.where(torch.arange(12) % 3 == 0, torch.tensor(-1), classes)),
        "sequence": Problem(
            "sequence",
            seqs.reshape(-1, 3),
            torch.tensor([0, -1, 1, 1, -1, 2]).repeat_interleave(3),
            torch.arange(6).repeat_interleave(3),
        ),
    }


SETTINGS = {
    "toy": dict(num_chains=4, num_samples=800, warmup_steps=300, seed=2),
    "confusion": dict(num_chains=2, num_samples=600, warmup_steps=200, seed=2),
    "sequence": dict(num_chains=2, num_samples=300, warmup_steps=100, seed=2),
}
"""NUTS settings of each stored run: at least twice the draws the tests once ran live."""


@dataclass(frozen=True)
class Reference:
    """A stored NUTS run: ``summary`` maps each scalar to its ``mean``, ``sd`` and ``ess``; ``label_probs`` is
    ``(N, M)``."""

    problem: Problem
    summary: dict[str, dict[str, float]]
    label_probs: Tensor
    divergences: int
    settings: dict[str, int]


def load_reference(name: str) -> Reference:
    """The stored reference ``name``, after checking that the current model gives its stored potentials.

    Raises:
        AssertionError: the model's potential energy differs from the stored one (regenerate the reference).
    """
    entry = json.loads(PATH.read_text())[name]
    data = entry["data"]
    labels, ids = (None if data[k] is None else torch.tensor(data[k]) for k in ("labels", "sequence_ids"))
    problem = Problem(entry["model"], torch.tensor(data["obs"], dtype=DT), labels, ids)
    points = {k: torch.tensor(v, dtype=DT) for k, v in entry["points"].items()}
    stored = torch.tensor(entry["potentials"], dtype=DT)
    now = problem.potential(points)
    assert torch.allclose(now, stored, rtol=POTENTIAL_RTOL, atol=0), (
        f"the {name!r} model's potential energy changed ({now.tolist()} != {stored.tolist()}): "
        f"regenerate its NUTS reference with `python tests/hbni_pyro/nuts_references.py {name}`"
    )
    return Reference(
        problem, entry["summary"], torch.tensor(entry["label_probs"], dtype=DT), entry["divergences"], entry["settings"]
    )


def write_reference(name: str) -> dict[str, Any]:
    """Run NUTS on problem ``name`` with ``SETTINGS[name]`` and return its JSON entry."""
    problem = problems()[name]
    post = problem.fit(method="nuts", **SETTINGS[name])
    points = problem.draw_points(seed=0)
    summary = {k: {s: v[s] for s in ("mean", "sd", "ess")} for k, v in post.summary().items()}
    return {
        "model": problem.model,
        "settings": SETTINGS[name],
        "data": {
            k: None if v is None else v.tolist()
            for k, v in dict(obs=problem.obs, labels=problem.labels, sequence_ids=problem.sequence_ids).items()
        },
        "summary": summary,
        "label_probs": post.label_probs.tolist(),
        "divergences": post.info["divergences"],
        "points": {k: v.tolist() for k, v in points.items()},
        "potentials": problem.potential(points).tolist(),
    }


def main(names: list[str]) -> None:
    entries = json.loads(PATH.read_text()) if PATH.is_file() else {}
    for name in names or list(SETTINGS):
        if name not in SETTINGS:
            raise SystemExit(f"nuts_references.py: expected names from {list(SETTINGS)}, got {name!r}")
        print(f"NUTS reference {name!r}: {SETTINGS[name]}", flush=True)
        entries[name] = write_reference(name)
    atomic_write_text(PATH, json.dumps(entries, indent=1) + "\n")
    print(f"wrote {PATH}")


if __name__ == "__main__":
    main(sys.argv[1:])
