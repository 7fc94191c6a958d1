"""The compiled event loop: K joint controllers x R rollouts, one plain loop per rollout.

Each rollout runs its events in order: the next completion time ``t = min_a end[a]`` (stop past the
horizon), the completing agents' ``complete`` rule (reward, observation), each of them moves along
its controller, and their ``start`` rule begins the next MA. Rollouts are split into chunks that
threads run in parallel (the chunk functions release the GIL, :func:`decpomdp.engine.runner.run`);
each rollout draws from its own counter-based stream keyed by ``(seed, first_controller + k, r)`` (with
common random numbers, ``(seed, first_controller, r)`` for every controller ``k``)
(:mod:`hbni_infra.counter_random`), so the returns do not depend on the thread count or the chunking.

A domain's rules are three compiled scalar functions on one rollout's state, an int64 vector ``si``
and a float64 vector ``sf`` (see :class:`decpomdp.engine.EngineDomain`), marked
``@njit(inline="always")`` so that they compile into the loop (a call that passes a dozen arrays costs
more than most rules):

* ``reset(si, sf, params, tables, perception, num_agents, rng)``: the initial state (``si``, ``sf``
  arrive zeroed);
* ``start(si, sf, params, tables, perception, agents, actions, t, end, rng)``: flagged agents begin
  ``actions[a]`` at ``t`` and get ``end[a] > t`` (a rule may also move a partner's ``end``);
* ``complete(si, sf, params, tables, perception, agents, actions, t, obs, rng) -> reward``: flagged
  agents finish at ``t``; it writes their observations to ``obs`` and returns the undiscounted reward.

With two agents, each kind of event runs in its own copy of the rules, with ``agents`` the constant tuple
``ONLY_0``, ``ONLY_1`` (one agent completes alone) or ``BOTH`` (they complete together, as after a joint MA):
the rules' tests of ``agents[a]``, coin flips for the branch predictor, fold away (each of the three makes
package delivery's loop faster). Rules therefore read ``agents`` (a bool array or such a tuple) and count agents
with ``len``.

The small helpers the rules call at many sites (an index into the state, a table lookup) are plain ``@njit``
functions, which LLVM inlines: numba's own inlining copies a helper's IR at every call site of every copy of the
rules, and typing and SSA passes then run over the whole copy: a domain's loop compiles in about half the time
without, at the same speed and with the same returns. The random stream's helpers
(:mod:`hbni_infra.counter_random`) stay inlined by numba: HBNI's compiled MH class move runs faster so, for a
slightly longer first compile of package delivery.

:func:`event_loop` is inlined into each domain's own compiled (and cached) chunk function, three lines
long, which :func:`decpomdp.engine.runner.run` calls on chunks of rollouts in parallel::

    @chunk_function
    def chunk(args, out, scratch, index, lo, hi):
        return event_loop(reset, start, complete, args, out, scratch, index, lo, hi)
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit
from numba.core.compiler import Compiler

from hbni_infra.counter_random import stream_key

ZERO_DURATION = 1  # error flag: a rule returned an end time not after the event that started it
NOT_TWO_AGENTS = 2  # error flag: a loop compiled for two agents got controllers of another number
ONLY_0, ONLY_1 = (True, False), (False, True)  # the flags of an event where one of two agents completes alone
BOTH = (True, True)  # the flags of an event where both of two agents complete


class Outputs(NamedTuple):
    """What a run writes, one entry per rollout (``B = K * R``): ``returns`` float64 (B,), ``counters`` int64
    (C, B) (a row per counter, handed out without a copy), ``visits`` float64 (chunks, A, Nn, O) (per chunk:
    summed afterwards; (chunks, 1, 1, 1) when not counted), final states int64 (B or 0, num_int) and float64
    (B or 0, num_float), and ``status`` int64 (chunks,) error flags (0: none)."""

    returns: np.ndarray
    counters: np.ndarray
    visits: np.ndarray
    final_int: np.ndarray
    final_float: np.ndarray
    status: np.ndarray


class Scratch(NamedTuple):
    """One chunk's working arrays: the rollout's int64 and float64 state ``si`` (num_int,) and ``sf``
    (num_float,), each agent's controller node, current MA, completion time and last observation (A,), the
    completing agents (bool (A,)), and the random stream's state (uint64 (1,))."""

    si: np.ndarray
    sf: np.ndarray
    node: np.ndarray
    act: np.ndarray
    end: np.ndarray
    obs: np.ndarray
    agents: np.ndarray
    rng: np.ndarray


class _NoAliasCompiler(Compiler):
    """numba's compiler with every pointer argument marked ``noalias`` (as numba does for the bodies of its
    parallel loops), so that LLVM keeps the rollout's state in registers across the rules' stores."""

    def define_pipelines(self):
        self.state.flags.noalias = True
        return super().define_pipelines()


_CHUNK_OPTIONS = {"nogil": True, "pipeline_class": _NoAliasCompiler, "_nrt": False, "error_model": "numpy"}


def chunk_function(fn):
    """The decorator of a domain's chunk function: compiled, releasing the GIL, its array arguments declared free
    of aliases, and cached on disk when its source is a file (not when typed into an interpreter). Every array
    passed to a chunk function must therefore be its own buffer (:func:`decpomdp.engine.runner.run` checks it).

    It uses numpy's error model: a division by zero gives inf or nan instead of raising, so the loop carries no
    checks for it (the loop runs faster; no rule divides by a value that may be zero). Lookups whose index is
    never negative are faster with an unsigned index, which numba does not wrap around (the controller step here,
    package delivery's start-table index).

    It compiles without numba's reference counting (``_nrt=False``): every array the loop and the rules touch
    comes from the caller, and with counting on, each array or tuple of arrays handed to an inlined rule costs an
    atomic increment and decrement, which took about half of package delivery's event loop. Rules therefore may not
    allocate arrays (numba then stops with "NRT required but not enabled")."""
    try:
        return njit(cache=True, **_CHUNK_OPTIONS)(fn)
    except RuntimeError:  # no file to cache against
        return njit(**_CHUNK_OPTIONS)(fn)


@njit(inline="always")
def _event(start, complete, rules, controller, log_gamma, track_visits, out, scratch, chunk, k, t, agents):
    """One event at ``t`` of a rollout of controller ``k``: the ``agents`` flagged (a bool array, or a tuple of
    constants) complete, step along ``controller = (action, next_node)`` and start (``rules = (params, tables,
    perception)``); returns the discounted reward."""
    params, tables, perception = rules
    action, next_node = controller
    si, sf, node, act, end, obs, _, rng = scratch
    n_obs = next_node.shape[3]
    reward = complete(si, sf, params, tables, perception, agents, act, t, obs, rng)
    for a in range(len(agents)):
        if agents[a]:
            o = min(max(obs[a], 0), n_obs - 1)
            if track_visits:
                out.visits[chunk, a, node[a], o] += 1.0
            # unsigned indices (every one is >= 0): numba adds no negative-index wraparound to them
            n = next_node[np.uint64(k), np.uint64(a), np.uint64(node[a]), np.uint64(o)]
            node[a] = n
            act[a] = action[np.uint64(k), np.uint64(a), np.uint64(n)]
    start(si, sf, params, tables, perception, agents, act, t, end, rng)
    return reward * math.exp(t * log_gamma) if reward != 0.0 else 0.0


def _event_loop(two_agents: bool):
    """:func:`event_loop`, or with ``two_agents`` the loop for exactly two agents (:data:`event_loop_two_agents`)."""

    @njit(inline="always")
    def event_loop(reset, start, complete, args, out, scratch, chunk, lo, hi):
        """Simulate rollouts ``lo .. hi - 1`` (rollout ``b`` is rollout ``b % R`` of controller ``b // R``) into
        ``out`` (row ``chunk`` of its per-chunk arrays) with the working arrays ``scratch``; see the module doc.

        Args:
            args: the tuple ``(params, tables, perception, action, next_node, first_controller, stride, rollouts,
                seed, horizon, log_gamma, counter_slots, track_visits, init_int, init_float, keep_state)``
                (:func:`decpomdp.engine.runner.run` builds it): ``action`` int16 or int32 (K, A, Nn),
                ``next_node`` the same type (K, A, Nn, O); ``stride`` 1 (controller ``k`` keyed
                ``first_controller + k``) or 0 (common random numbers); ``init_int``/``init_float`` a state every
                rollout starts from instead of ``reset`` (length 0: reset); ``keep_state``: keep every rollout's final
                state.
        """
        (
            params,
            tables,
            perception,
            action,
            next_node,
            first_controller,
            stride,
            rollouts,
            seed,
            horizon,
            log_gamma,
            counter_slots,
            track_visits,
            init_int,
            init_float,
            keep_state,
        ) = args
        a_count = action.shape[1]
        if two_agents and a_count != 2:
            out.status[chunk] = NOT_TWO_AGENTS
            return
        rules, controller = (params, tables, perception), (action, next_node)
        si, sf, node, act, end, obs, agents, rng = scratch
        use_init = init_int.shape[0] > 0
        for b in range(lo, hi):
            k = b // rollouts
            rng[0] = stream_key(seed, first_controller + stride * k, b - k * rollouts)
            if use_init:
                for i in range(si.shape[0]):
                    si[i] = init_int[i]
                for i in range(sf.shape[0]):
                    sf[i] = init_float[i]
            else:
                si[:] = 0
                sf[:] = 0.0
                reset(si, sf, params, tables, perception, a_count, rng)
            for a in range(a_count):
                node[a] = 0
                act[a] = action[k, a, 0]
                agents[a] = True
                end[a] = 0.0
            start(si, sf, params, tables, perception, agents, act, 0.0, end, rng)
            value, t_prev = 0.0, 0.0
            while True:
                # the next completion without a loop over agents (a tenth of package delivery's time)
                if two_agents or a_count == 2:
                    t = min(end[0], end[1])
                else:
                    t = end[0]
                    for a in range(1, a_count):
                        t = min(t, end[a])
                if t > horizon:
                    break
                if not t > t_prev:
                    out.status[chunk] = ZERO_DURATION
                    break
                if not (two_agents or a_count == 2):
                    for a in range(a_count):
                        agents[a] = end[a] == t
                    value += _event(
                        start, complete, rules, controller, log_gamma, track_visits, out, scratch, chunk, k, t, agents
                    )
                # two robots: a copy of the rules for each of the three events, flags constant
                elif end[0] < end[1]:
                    value += _event(
                        start, complete, rules, controller, log_gamma, track_visits, out, scratch, chunk, k, t, ONLY_0
                    )
                elif end[1] < end[0]:
                    value += _event(
                        start, complete, rules, controller, log_gamma, track_visits, out, scratch, chunk, k, t, ONLY_1
                    )
                else:
                    value += _event(
                        start, complete, rules, controller, log_gamma, track_visits, out, scratch, chunk, k, t, BOTH
                    )
                t_prev = t
            out.returns[b] = value
            for j in range(counter_slots.shape[0]):
                out.counters[j, b] = si[counter_slots[j]]
            if keep_state:
                for i in range(si.shape[0]):
                    out.final_int[b, i] = si[i]
                for i in range(sf.shape[0]):
                    out.final_float[b, i] = sf[i]

    return event_loop


event_loop = _event_loop(False)
event_loop_two_agents = _event_loop(True)
"""The event loop of a domain whose every instance has two agents: numba removes the loop over any number of
agents (``two_agents`` is a constant of its code) before it inlines the loop, so the chunk function compiles three
copies of the rules instead of four (package delivery's: 23-24 s instead of 29, at the same speed). It stops a
chunk with the status :data:`NOT_TWO_AGENTS` when the controllers have another number of agents."""
