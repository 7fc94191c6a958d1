"""Running controllers on the compiled engine from Python: :func:`run`."""

from __future__ import annotations

import math
from concurrent.futures import ThreadPoolExecutor
from typing import Any, NamedTuple

import numpy as np
import torch
from torch import Tensor

from decpomdp.controller import JointController
from decpomdp.engine import loop
from decpomdp.engine.interface import EngineModel
from hbni_infra.threads import worker_threads

_EMPTY_INT = np.zeros(0, dtype=np.int64)
_EMPTY_FLOAT = np.zeros(0)
_MIN_CHUNK = 256  # rollouts below which a chunk is not worth a thread hand-off
_pool: tuple[int, ThreadPoolExecutor] | None = None


class EngineRun(NamedTuple):
    """What :func:`run` returns.

    Attributes:
        returns: float64 (K, R) discounted returns.
        counters: {name: long (K, R)} each counter's final value.
        visits: float64 (A, Nn, O) completions of agent ``a`` in node ``n`` observing ``o`` (summed over
            all rollouts of all controllers; zeros unless asked for).
        final_state: {entry name: long or float64 (K, R)} (empty unless asked for).
    """

    returns: Tensor
    counters: dict[str, Tensor]
    visits: Tensor
    final_state: dict[str, Tensor]


def engine_model(env: Any) -> EngineModel | None:
    """``env.engine_model()`` if the domain is written for the engine, else ``None``."""
    method = getattr(env, "engine_model", None)
    model = method() if callable(method) else None
    if model is not None and not isinstance(model, EngineModel):
        raise TypeError(f"env.engine_model(): expected an EngineModel or None, got {type(model).__name__}")
    return model


def _executor(threads: int) -> ThreadPoolExecutor:
    """A pool of ``threads`` worker threads, kept between calls."""
    global _pool
    if _pool is None or _pool[0] != threads:
        if _pool is not None:
            _pool[1].shutdown(wait=False)
        _pool = (threads, ThreadPoolExecutor(max_workers=threads, thread_name_prefix="decpomdp-engine"))
    return _pool[1]


def table_dtype(num_nodes: int, num_actions: int) -> type:
    """The integer type the compiled loop reads controllers in: int16 where every node and action index fits (a
    quarter of int64's cache footprint, so a call runs faster than on int32 or int64, the copy included), else
    int32."""
    return np.int16 if max(num_nodes, num_actions) <= np.iinfo(np.int16).max + 1 else np.int32


def _narrow(table: Tensor, dtype: type, threads: int) -> np.ndarray:
    """A contiguous copy of the long ``table`` (K, ...) in ``dtype``, its rows split among ``threads`` threads of
    the pool (numpy's copy releases the GIL): converting a call's controllers is a small share of the call."""
    source = table.numpy()
    if threads == 1 or source.shape[0] < 2 * threads:
        return np.ascontiguousarray(source, dtype=dtype)
    copy = np.empty(source.shape, dtype)
    rows = [i * source.shape[0] // threads for i in range(threads + 1)]
    parts = [slice(lo, hi) for lo, hi in zip(rows, rows[1:])]
    for future in [_executor(threads).submit(np.copyto, copy[p], source[p], casting="unsafe") for p in parts]:
        future.result()
    return copy


def _initial(
    initial_state: dict[str, float] | None, int_names: tuple[str, ...], float_names: tuple[str, ...]
) -> tuple[np.ndarray, np.ndarray]:
    """The state vectors every rollout starts from (empty: the domain's reset)."""
    if initial_state is None:
        return _EMPTY_INT, _EMPTY_FLOAT
    unknown = sorted(set(initial_state) - set(int_names) - set(float_names))
    if unknown:
        raise ValueError(f"initial_state: {unknown} are not entries of the state {int_names + float_names}")
    if not int_names:
        raise ValueError("initial_state: the domain's int state is empty; nothing to start from")
    return (
        np.array([int(initial_state.get(n, 0)) for n in int_names], dtype=np.int64),
        np.array([float(initial_state.get(n, 0.0)) for n in float_names], dtype=np.float64),
    )


def chunk_bounds(batch: int, threads: int) -> list[int]:
    """Bounds of the chunks of ``batch`` rollouts handed to ``threads`` threads, largest first (guided scheduling):
    each chunk takes ``1 / (2 * threads)`` of the rollouts left (at least ``_MIN_CHUNK``), so that the threads,
    taking chunks as they finish, end within one small chunk of each other (equal chunks left one thread idle for
    part of the call)."""
    bounds = [0]
    while True:  # at least one chunk, empty for an empty batch
        left = batch - bounds[-1]
        bounds.append(bounds[-1] + min(left, max(_MIN_CHUNK, left // (2 * threads))))
        if bounds[-1] == batch:
            return bounds


def _scratch(num_int: int, num_float: int, num_agents: int) -> loop.Scratch:
    """Fresh working arrays for one chunk."""
    return loop.Scratch(
        np.zeros(num_int, dtype=np.int64),
        np.zeros(num_float),
        np.zeros(num_agents, dtype=np.int64),
        np.zeros(num_agents, dtype=np.int64),
        np.zeros(num_agents),
        np.zeros(num_agents, dtype=np.int64),
        np.ones(num_agents, dtype=bool),
        np.zeros(1, dtype=np.uint64),
    )


def _arrays(value: Any) -> list[np.ndarray]:
    if isinstance(value, np.ndarray):
        return [value]
    if isinstance(value, tuple):
        return [a for v in value for a in _arrays(v)]
    return []


def _check_distinct(*values: Any) -> None:
    """Chunk functions declare their array arguments free of aliases: refuse two that share memory."""
    arrays = [a for a in _arrays(values) if a.size]
    for i, a in enumerate(arrays):
        for b in arrays[i + 1 :]:
            if np.may_share_memory(a, b):
                raise ValueError("env.engine_model(): two of its arrays share memory; give each table its own copy")


def run(
    env: Any,
    controller: JointController,
    rollouts: int,
    seed: int,
    *,
    first_controller: int = 0,
    common_streams: bool = False,
    visits: bool = False,
    initial_state: dict[str, float] | None = None,
    keep_state: bool = False,
) -> EngineRun:
    """Simulate ``rollouts`` rollouts of each of the K controllers on the engine, on
    :func:`hbni_infra.threads.worker_threads` threads.

    Args:
        env: a domain whose ``engine_model()`` is not ``None`` (sizes already checked by the caller).
        seed: the engine seed (any int in [0, 2**64)); rollout ``r`` of controller ``k`` draws from the
            stream keyed by ``(seed, first_controller + k, r)``.
        common_streams: common random numbers: rollout ``r`` of every controller draws from the stream
            ``(seed, first_controller, r)``, so that controllers which act alike have alike returns, and
            differences between controllers carry less noise.
        visits: count (agent, node, observation) completions.
        initial_state: start every rollout from these state entries (names of the domain's layout; the
            others 0) instead of the domain's reset.
        keep_state: return every rollout's final state.
    """
    model = engine_model(env)
    if model is None:
        raise ValueError(f"env: {type(env).__name__} is not written for the compiled engine (use backend='torch')")
    domain, a_count = model.domain, controller.num_agents
    int_names, float_names = domain.layout.int_names(a_count), domain.layout.float_names(a_count)
    init_int, init_float = _initial(initial_state, int_names, float_names)
    slots = np.array([int_names.index(c) for c in domain.counters], dtype=np.int64)
    threads = worker_threads()
    dtype = table_dtype(controller.num_nodes, env.num_actions)
    action, next_node = _narrow(controller.action, dtype, threads), _narrow(controller.next_node, dtype, threads)
    args = (
        model.params,
        model.tables,
        tuple(model.perception),
        action,
        next_node,
        np.int64(first_controller),
        np.int64(0 if common_streams else 1),
        np.int64(rollouts),
        np.uint64(seed % 2**64),
        float(env.horizon),
        math.log(float(env.gamma)),
        slots,
        visits,
        init_int,
        init_float,
        keep_state,
    )
    batch = controller.num_controllers * rollouts
    bounds = chunk_bounds(batch, threads)
    chunks = len(bounds) - 1
    kept = batch if keep_state else 0
    seen_shape = (chunks, a_count, controller.num_nodes, controller.num_obs) if visits else (chunks, 1, 1, 1)
    out = loop.Outputs(
        np.zeros(batch),
        np.zeros((len(slots), batch), dtype=np.int64),
        np.zeros(seen_shape),
        np.zeros((kept, len(int_names)), dtype=np.int64),
        np.zeros((kept, len(float_names))),
        np.zeros(chunks, dtype=np.int64),
    )
    _check_distinct(args, out)
    jobs = [
        (
            args,
            out,
            _scratch(len(int_names), len(float_names), a_count),
            c,
            bounds[c],
            bounds[c + 1],
        )
        for c in range(chunks)
    ]
    if chunks == 1 or threads == 1:
        for job in jobs:
            domain.chunk(*job)
    else:
        for future in [_executor(threads).submit(domain.chunk, *job) for job in jobs]:
            future.result()
    status = int(out.status.max())
    if status == loop.ZERO_DURATION:
        raise RuntimeError("env.start returned a completion time not after the start time (zero duration)")
    if status == loop.NOT_TWO_AGENTS:
        raise ValueError(f"controller: this domain's engine runs two agents, got {a_count}")
    shape = (controller.num_controllers, rollouts)
    counters = {name: torch.from_numpy(out.counters[j]).view(shape) for j, name in enumerate(domain.counters)}
    final: dict[str, Tensor] = {}
    if keep_state:
        final.update({n: torch.from_numpy(out.final_int[:, j].copy()).view(shape) for j, n in enumerate(int_names)})
        final.update({n: torch.from_numpy(out.final_float[:, j].copy()).view(shape) for j, n in enumerate(float_names)})
    seen = out.visits.sum(0) if visits else np.zeros((a_count, controller.num_nodes, controller.num_obs))
    return EngineRun(torch.from_numpy(out.returns).view(shape), counters, torch.from_numpy(seen), final)
