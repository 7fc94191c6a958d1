"""The paper's G-DICE as this project ran it before G-DICE became a preset of ``decpomdp.search`` (frozen copy of
the former ``decpomdp.gdice`` algorithm, without its checkpoints): the reference the preset must reproduce."""

from __future__ import annotations

import math

import torch

from decpomdp.controller import JointController


def sample_controllers(action_probs, next_probs, count, generator):
    a, nn, m = action_probs.shape
    o = next_probs.shape[2]
    act = torch.multinomial(action_probs.reshape(-1, m), count, replacement=True, generator=generator)
    nxt = torch.multinomial(next_probs.reshape(-1, nn), count, replacement=True, generator=generator)
    return JointController(act.T.reshape(count, a, nn).contiguous(), nxt.T.reshape(count, a, nn, o).contiguous())


def frequencies(values, categories):
    return torch.nn.functional.one_hot(values, categories).to(torch.float64).mean(0)


def transition_mask(nn, w):
    if w is None:
        return torch.ones(nn, nn, dtype=torch.bool)
    layer = torch.cat([torch.zeros(1, dtype=torch.long), torch.arange(nn - 1) // w + 1])
    target = torch.clamp(layer + 1, max=int(layer[-1]))
    return layer[None, :] == target[:, None]


def inject(p, uniform, weight, threshold):
    allowed = (uniform > 0).sum(-1)
    h = -(p * torch.log(p.clamp_min(1e-300))).sum(-1) / torch.log(allowed.clamp_min(2).to(p.dtype))
    collapsed = ((h < threshold) & (allowed > 1))[..., None]
    return torch.where(collapsed, (1 - weight) * p + weight * uniform, p)


def gdice(
    score,
    a,
    m,
    o,
    *,
    num_nodes=13,
    iterations=100,
    samples=100,
    elites=10,
    alpha=0.1,
    injection_weight=0.0,
    injection_threshold=0.05,
    injection_until=0.5,
    layer_width=None,
    threshold_rule="paper",
    seed=0,
):
    """Returns (best controller, its sampled value, the per-iteration best-so-far values); ``score(ctrl, generator)``
    gives the K controllers' values."""
    nn = num_nodes
    mask = transition_mask(nn, layer_width).to(torch.float64)
    next_uniform = (mask / mask.sum(-1, keepdim=True))[None, :, None, :].expand(a, nn, o, nn)
    action_uniform = torch.full((a, nn, m), 1.0 / m, dtype=torch.float64)
    action_probs, next_probs = action_uniform.clone(), next_uniform.clone()
    g = torch.Generator().manual_seed(seed)
    threshold, best, best_value, history = -math.inf, None, -math.inf, []
    for it in range(iterations):
        ctrl = sample_controllers(action_probs, next_probs, samples, g)
        values = score(ctrl, g).to(torch.float64)
        top = int(values.argmax())
        if float(values[top]) > best_value:
            best_value, best = float(values[top]), ctrl[top]
        order = torch.sort(values, descending=True, stable=True).indices
        thr = threshold
        if threshold_rule == "capped":
            thr = min(thr, float(values[order[elites - 1]]))
        order = order[values[order] >= thr][:elites]
        if order.numel() > 0:
            threshold = float(values[order[-1]])
            elite = ctrl[order]
            action_probs = alpha * frequencies(elite.action, m) + (1 - alpha) * action_probs
            next_probs = alpha * frequencies(elite.next_node, nn) + (1 - alpha) * next_probs
        if injection_weight > 0 and it < injection_until * iterations:
            action_probs = inject(action_probs, action_uniform, injection_weight, injection_threshold)
            next_probs = inject(next_probs, next_uniform, injection_weight, injection_threshold)
        history.append(best_value)
    return best, best_value, history
