"""Graph-based direct cross-entropy policy search (G-DICE; Omidshafiei et al., ICRA 2016, Alg. 1).

Each agent's controller graph has ``num_nodes`` nodes. G-DICE keeps categorical distributions over
every node's MA, ``action_probs`` (A, Nn, |MA|), and every (node, observation)'s next node,
``next_probs`` (A, Nn, O, Nn), uniform at the start (or, warm-started from a given controller,
``(1 - init_weight) * uniform + init_weight * one_hot(that controller)``). Each iteration it

1. samples ``samples`` (N_s) joint controllers and scores them with a pluggable evaluator
   (Monte Carlo rollouts in one batched simulation, or exact values for tabular problems);
2. keeps the samples whose value is >= the threshold and takes the best ``elites`` (N_b) of them
   (ties broken by sample order). The threshold is the previous iteration's worst elite value
   (``threshold_rule="paper"``), or that value capped at this iteration's N_b-th best value
   (``"capped"``). Under Monte Carlo scores the paper's rule can stall: one lucky iteration sets a
   threshold no later sample reaches, nothing is kept and the distributions freeze. The cap keeps
   the rule whenever it admits N_b samples and otherwise falls back to this iteration's N_b best;
3. sets each distribution to ``alpha * frequency in the elites + (1 - alpha) * old`` (no change
   when nothing was kept);
4. optionally injects entropy: every categorical row whose normalised entropy fell below
   ``injection_threshold`` during the first ``injection_until`` fraction of iterations is mixed
   with ``injection_weight`` of the uniform distribution;
5. tracks the best controller ever sampled.

The best controller can finally be re-evaluated by an independent evaluator (e.g. 1000 fresh
rollouts), since the best sampled score is a biased maximum. Checkpoints (atomic safetensors +
JSON, with the generator state) let an interrupted run resume to exactly the same result.
"""

from __future__ import annotations

import math
import os
from dataclasses import asdict, dataclass, field
from pathlib import Path

import torch
from torch import Tensor
from tqdm.auto import tqdm

from decpomdp.checkpoints import load_checkpoint, read_count, read_history, read_number, save_checkpoint
from decpomdp.controller import JointController
from decpomdp.evaluate import Evaluator
from infra.checks import as_float, as_int
from decpomdp.identity import describe
from infra.fingerprint import digest

_KIND = "decpomdp.GDICECheckpoint"
_VERSION = 2
_THRESHOLD_RULES = ("paper", "capped")
_HISTORY = ("best", "iteration_best", "iteration_mean", "threshold", "kept", "entropy")


@dataclass(frozen=True)
class GDICEConfig:
    """G-DICE settings (defaults: the paper's package-delivery settings).

    Attributes:
        num_nodes: Nn, nodes per agent controller.
        iterations: N_k.
        samples: N_s joint controllers sampled per iteration.
        elites: N_b best samples used for the update.
        alpha: learning rate of the smoothed frequency update, in (0, 1].
        injection_weight: weight of uniform mixed into collapsed rows (0 disables entropy injection).
        injection_threshold: normalised entropy (entropy / log(categories)) below which a row counts
            as collapsed.
        injection_until: injection happens only in the first this-fraction of iterations.
        layer_width: None for a free graph; else W makes a layered graph for finite horizons: node 0
            is layer 0, then layers of W nodes (``num_nodes = 1 + W * (layers - 1)``); a node may only
            move to the next layer, and the last layer moves within itself.
        threshold_rule: ``"paper"`` (the previous iteration's worst elite) or ``"capped"`` (that,
            but never above the current iteration's N_b-th best value, so N_b elites are always kept).
        init_weight: weight of the warm-start controller passed to :func:`gdice` as ``init`` in the
            initial distributions, in [0, 1]; must be > 0 exactly when ``init`` is given.
    """

    num_nodes: int = 13
    iterations: int = 100
    samples: int = 100
    elites: int = 10
    alpha: float = 0.1
    injection_weight: float = 0.0
    injection_threshold: float = 0.05
    injection_until: float = 0.5
    layer_width: int | None = None
    threshold_rule: str = "paper"
    init_weight: float = 0.0

    def __post_init__(self) -> None:
        for name in ("num_nodes", "iterations", "samples", "elites"):
            object.__setattr__(self, name, as_int(name, getattr(self, name), 1))
        if self.elites > self.samples:
            raise ValueError(f"elites: expected <= samples ({self.samples}), got {self.elites}")
        object.__setattr__(self, "alpha", as_float("alpha", self.alpha, 0.0, 1.0, low_open=True))
        for name in ("injection_weight", "injection_threshold", "injection_until", "init_weight"):
            object.__setattr__(self, name, as_float(name, getattr(self, name), 0.0, 1.0))
        if self.threshold_rule not in _THRESHOLD_RULES:
            raise ValueError(f"threshold_rule: expected one of {_THRESHOLD_RULES}, got {self.threshold_rule!r}")
        if self.layer_width is not None:
            w = as_int("layer_width", self.layer_width, 1)
            if self.num_nodes < 1 + w or (self.num_nodes - 1) % w:
                raise ValueError(f"layer_width: expected W with num_nodes = 1 + W * k (k >= 1), got W = {w} "
                                 f"for num_nodes = {self.num_nodes}")
            object.__setattr__(self, "layer_width", w)

    def transition_mask(self) -> Tensor:
        """bool (Nn, Nn): which next nodes each node may move to."""
        nn, w = self.num_nodes, self.layer_width
        if w is None:
            return torch.ones(nn, nn, dtype=torch.bool)
        layer = torch.cat([torch.zeros(1, dtype=torch.long), torch.arange(nn - 1) // w + 1])
        last = int(layer[-1])
        target = torch.clamp(layer + 1, max=last)
        return layer[None, :] == target[:, None]


@dataclass
class GDICEResult:
    """Outcome of a G-DICE run.

    Attributes:
        best: the best joint controller sampled (K = 1).
        best_value: its score when it was sampled (a biased maximum under Monte Carlo evaluation).
        value, stderr: its re-evaluated value and standard error (None without a re-evaluator).
        history: per iteration, ``best`` (best ever so far), ``iteration_best``, ``iteration_mean``,
            ``threshold`` (worst elite used as the next threshold), ``kept`` (number of elites used)
            and ``entropy`` (mean normalised entropy of the distributions after the update).
        action_probs, next_probs: the final distributions.
    """

    best: JointController
    best_value: float
    value: float | None
    stderr: float | None
    history: dict[str, list[float]]
    action_probs: Tensor
    next_probs: Tensor
    config: GDICEConfig = field(default_factory=GDICEConfig)


def sample_controllers(action_probs: Tensor, next_probs: Tensor, count: int, generator: torch.Generator) -> JointController:
    """Draw ``count`` joint controllers from the node distributions (A, Nn, |MA|) and (A, Nn, O, Nn)."""
    a, nn, m = action_probs.shape
    o = next_probs.shape[2]
    act = torch.multinomial(action_probs.reshape(-1, m), count, replacement=True, generator=generator)
    nxt = torch.multinomial(next_probs.reshape(-1, nn), count, replacement=True, generator=generator)
    return JointController.trusted(act.T.reshape(count, a, nn).contiguous(), nxt.T.reshape(count, a, nn, o).contiguous())


def elite_frequencies(values: Tensor, categories: int) -> Tensor:
    """values (N, ...) -> (..., categories) empirical frequencies over the N samples (G-DICE's update target)."""
    return torch.nn.functional.one_hot(values, categories).to(torch.float64).mean(0)


def _normalised_entropy(p: Tensor) -> Tensor:
    h = -(p * torch.log(p.clamp_min(1e-300))).sum(-1)
    return h / math.log(p.shape[-1]) if p.shape[-1] > 1 else torch.ones_like(h)


def _inject(p: Tensor, uniform: Tensor, cfg: GDICEConfig) -> Tensor:
    """Mix ``injection_weight`` of ``uniform`` into the rows of ``p`` whose entropy has collapsed."""
    allowed = (uniform > 0).sum(-1)
    h = -(p * torch.log(p.clamp_min(1e-300))).sum(-1) / torch.log(allowed.clamp_min(2).to(p.dtype))
    collapsed = ((h < cfg.injection_threshold) & (allowed > 1))[..., None]
    return torch.where(collapsed, (1 - cfg.injection_weight) * p + cfg.injection_weight * uniform, p)


class _State:
    """Everything a G-DICE run carries between iterations (what a checkpoint stores)."""

    def __init__(self, a: int, m: int, o: int, cfg: GDICEConfig, init: JointController | None = None) -> None:
        nn = cfg.num_nodes
        self.iteration = 0
        mask = cfg.transition_mask().to(torch.float64)
        self.next_uniform = (mask / mask.sum(-1, keepdim=True))[None, :, None, :].expand(a, nn, o, nn)
        self.action_uniform = torch.full((a, nn, m), 1.0 / m, dtype=torch.float64)
        self.action_probs, self.next_probs = self.action_uniform.clone(), self.next_uniform.clone()
        if init is not None:
            w, ni = cfg.init_weight, init.num_nodes
            act = torch.nn.functional.one_hot(init.action[0], m).to(torch.float64)
            nxt = torch.nn.functional.one_hot(init.next_node[0], nn).to(torch.float64)
            self.action_probs[:, :ni] = (1 - w) * self.action_probs[:, :ni] + w * act
            self.next_probs[:, :ni] = (1 - w) * self.next_probs[:, :ni] + w * nxt
        self.threshold = -math.inf
        self.best = JointController(torch.zeros(1, a, nn, dtype=torch.long), torch.zeros(1, a, nn, o, dtype=torch.long))
        self.best_value = -math.inf
        self.history: dict[str, list[float]] = {k: [] for k in _HISTORY}

    def save(self, path: Path, fingerprint: dict, generator: torch.Generator) -> None:
        tensors = {
            "action_probs": self.action_probs,
            "next_probs": self.next_probs,
            "best_action": self.best.action,
            "best_next_node": self.best.next_node,
            "generator_state": generator.get_state(),
        }
        finite = lambda x: None if x == -math.inf else x  # noqa: E731
        state = {
            "iteration": self.iteration,
            "threshold": finite(self.threshold),
            "best_value": finite(self.best_value),
            "history": {k: [finite(v) for v in values] for k, values in self.history.items()},
        }
        save_checkpoint(path, _KIND, _VERSION, fingerprint, tensors, state)

    @classmethod
    def load(cls, path: Path, fingerprint: dict, cfg: GDICEConfig, shape: tuple[int, int, int],
             generator: torch.Generator) -> _State:
        tensors, meta = load_checkpoint(path, _KIND, _VERSION, fingerprint)
        state = cls(*shape, cfg)  # distributions are overwritten below, so no warm start is needed
        state.iteration = read_count(meta, "iteration", path, cfg.iterations)
        state.threshold = read_number(meta, "threshold", path)
        state.best_value = read_number(meta, "best_value", path)
        state.history = read_history(meta, _HISTORY, state.iteration, path)
        try:
            for name, like in (("action_probs", state.action_probs), ("next_probs", state.next_probs),
                               ("best_action", state.best.action), ("best_next_node", state.best.next_node)):
                if tensors[name].shape != like.shape or tensors[name].dtype != like.dtype:
                    raise ValueError(f"{name} has shape {tuple(tensors[name].shape)}, expected {tuple(like.shape)}")
            state.action_probs, state.next_probs = tensors["action_probs"], tensors["next_probs"]
            state.best = JointController(tensors["best_action"], tensors["best_next_node"])
            generator.set_state(tensors["generator_state"])
        except (KeyError, TypeError, ValueError, RuntimeError) as exc:
            raise ValueError(f"checkpoint: {str(path)!r} is inconsistent ({exc})") from None
        return state


def _check_init(init: JointController | None, cfg: GDICEConfig, agents: int, actions: int, obs: int) -> None:
    """Validate a warm-start controller against the problem and the configuration."""
    if init is None:
        if cfg.init_weight > 0:
            raise ValueError(f"init_weight: {cfg.init_weight} > 0 needs a warm-start controller (init)")
        return
    if not isinstance(init, JointController):
        raise TypeError(f"init: expected a JointController, got {type(init).__name__}")
    if cfg.init_weight == 0:
        raise ValueError("init: a warm-start controller has no effect with config.init_weight = 0")
    k, a, ni = init.action.shape
    if k != 1 or a != agents or init.num_obs != obs or ni > cfg.num_nodes:
        raise ValueError(f"init: expected shape (1, {agents}, <= {cfg.num_nodes} nodes, {obs} observations), "
                         f"got action {tuple(init.action.shape)}, next_node {tuple(init.next_node.shape)}")
    if bool((init.action >= actions).any()):
        raise ValueError(f"init: actions must lie in [0, {actions})")
    rows = torch.arange(ni)[None, None, :, None].expand_as(init.next_node)
    if not bool(cfg.transition_mask()[rows, init.next_node].all()):
        raise ValueError("init: transitions must respect the layered graph (layer_width)")


def _step(state: _State, evaluator: Evaluator, cfg: GDICEConfig, generator: torch.Generator) -> None:
    """One G-DICE iteration (Alg. 1, lines 4-17), updating ``state`` in place."""
    a, nn, m = state.action_probs.shape
    o = state.next_probs.shape[2]
    ctrl = sample_controllers(state.action_probs, state.next_probs, cfg.samples, generator)
    values, _ = evaluator(ctrl, generator)
    values = values.to(torch.float64)
    top = int(values.argmax())
    if float(values[top]) > state.best_value:
        state.best_value, state.best = float(values[top]), ctrl[top]
    order = torch.sort(values, descending=True, stable=True).indices
    threshold = state.threshold
    if cfg.threshold_rule == "capped":
        threshold = min(threshold, float(values[order[cfg.elites - 1]]))
    order = order[values[order] >= threshold][: cfg.elites]
    if order.numel() > 0:
        state.threshold = float(values[order[-1]])
        elite = ctrl[order]
        state.action_probs = cfg.alpha * elite_frequencies(elite.action, m) + (1 - cfg.alpha) * state.action_probs
        state.next_probs = cfg.alpha * elite_frequencies(elite.next_node, nn) + (1 - cfg.alpha) * state.next_probs
    if cfg.injection_weight > 0 and state.iteration < cfg.injection_until * cfg.iterations:
        state.action_probs = _inject(state.action_probs, state.action_uniform, cfg)
        state.next_probs = _inject(state.next_probs, state.next_uniform, cfg)
    entropy = torch.cat([_normalised_entropy(state.action_probs).ravel(), _normalised_entropy(state.next_probs).ravel()])
    h = state.history
    h["best"].append(state.best_value)
    h["iteration_best"].append(float(values[top]))
    h["iteration_mean"].append(float(values.mean()))
    h["threshold"].append(state.threshold)
    h["kept"].append(float(order.numel()))
    h["entropy"].append(float(entropy.mean()))
    state.iteration += 1


def _fingerprint(evaluator: Evaluator, shape: tuple[int, int, int], cfg: GDICEConfig, seed: int,
                 init: JointController | None) -> dict:
    """What a checkpoint records of the run that wrote it, after checking the evaluator and warm start."""
    if not callable(evaluator):
        raise TypeError(f"evaluator: expected a callable (controller, generator) -> (mean, stderr), got {evaluator!r}")
    _check_init(init, cfg, *shape)
    return {
        "sizes": dict(zip(("num_agents", "num_actions", "num_obs"), shape)),
        "problem": describe(evaluator),
        "config": asdict(cfg),
        "seed": seed,
        "init": None if init is None else digest(init.action, init.next_node),
    }


def gdice(
    evaluator: Evaluator,
    num_agents: int,
    num_actions: int,
    num_obs: int,
    config: GDICEConfig | None = None,
    seed: int = 0,
    init: JointController | None = None,
    reevaluator: Evaluator | None = None,
    checkpoint: str | os.PathLike | None = None,
    checkpoint_every: int = 10,
    progress: bool = False,
) -> GDICEResult:
    """Run G-DICE.

    Args:
        evaluator: scores K joint controllers, ``evaluator(controller, generator) -> (mean (K,), stderr (K,))``
            (e.g. :class:`~decpomdp.evaluate.MonteCarloEvaluator`, :class:`~decpomdp.dpomdp.ExactEvaluator`).
        num_agents, num_actions, num_obs: the problem's A, |MA| and O.
        config: the settings (default :class:`GDICEConfig`).
        seed: seeds the one generator used for sampling and evaluation.
        init: a warm-start controller (K = 1, A agents, at most Nn nodes, same MAs and observations):
            node ``n < init.num_nodes`` starts from ``(1 - w) * uniform + w * one_hot(init)`` with
            ``w = config.init_weight``, for its MA and for every next node. Nodes beyond
            ``init.num_nodes`` start uniform; since ``init`` never moves into them, they receive only
            the uniform share ``(1 - w) / Nn`` of each transition. At ``w = 1`` every first-iteration
            sample is ``init`` itself (extra nodes unreachable).
        reevaluator: if given, scores the final best controller independently (value +- stderr).
        checkpoint: file to write every ``checkpoint_every`` iterations and at the end; if it exists, the
            run resumes from it and reaches exactly the uninterrupted result. The file records what
            produced it (sizes, evaluator and problem, config, seed, warm start); resuming it with any of
            them different raises a ``ValueError`` naming the fields that differ.
        progress: show a tqdm progress bar.
    """
    cfg = GDICEConfig() if config is None else config
    if not isinstance(cfg, GDICEConfig):
        raise TypeError(f"config: expected a GDICEConfig, got {type(cfg).__name__}")
    shape = tuple(as_int(name, value, 1) for name, value in (
        ("num_agents", num_agents), ("num_actions", num_actions), ("num_obs", num_obs)))
    seed = as_int("seed", seed)
    checkpoint_every = as_int("checkpoint_every", checkpoint_every, 1)
    fingerprint = _fingerprint(evaluator, shape, cfg, seed, init)
    generator = torch.Generator().manual_seed(seed)
    path = None if checkpoint is None else Path(checkpoint)
    if path is not None and path.exists():
        state = _State.load(path, fingerprint, cfg, shape, generator)
    else:
        state = _State(*shape, cfg, init)
    bar = tqdm(total=cfg.iterations, initial=state.iteration, disable=not progress, desc="G-DICE")
    while state.iteration < cfg.iterations:
        _step(state, evaluator, cfg, generator)
        bar.update(1)
        bar.set_postfix(best=f"{state.best_value:.4g}", kept=int(state.history["kept"][-1]))
        if path is not None and (state.iteration % checkpoint_every == 0 or state.iteration == cfg.iterations):
            state.save(path, fingerprint, generator)
    bar.close()
    value = stderr = None
    if reevaluator is not None:
        mean, se = reevaluator(state.best, generator)
        value, stderr = float(mean[0]), float(se[0])
    return GDICEResult(state.best, state.best_value, value, stderr, state.history, state.action_probs,
                       state.next_probs, cfg)
