"""The robot-side executor against the batched simulator, its state round trip and its error paths."""

import json

import pytest
import torch

from decpomdp import ControllerExecutor, DecPOSMDP, JointController, MacroAction, random_controllers, simulate
from decpomdp.domains import DisasterRelief, PackageDelivery
from decpomdp.domains.disaster_relief import greedy_controller

_ROW = "_executor_test_row"


class Trace(DecPOSMDP):
    """Delegates to ``env`` and records, per rollout and agent, the MAs started and the observations received."""

    def __init__(self, env: DecPOSMDP) -> None:
        self.env = env
        self.num_agents, self.num_actions, self.num_obs = env.num_agents, env.num_actions, env.num_obs
        self.gamma, self.horizon = env.gamma, env.horizon
        self.action_names, self.obs_names = env.action_names, env.obs_names

    def reset(self, batch, generator):
        state = self.env.reset(batch, generator)
        state[_ROW] = torch.arange(batch)
        self.actions = [[[] for _ in range(self.num_agents)] for _ in range(batch)]
        self.obs = [[[] for _ in range(self.num_agents)] for _ in range(batch)]
        return state

    def start(self, state, agents, actions, t, end_time, generator):
        for row, a in agents.nonzero().tolist():
            self.actions[int(state[_ROW][row])][a].append(int(actions[row, a]))
        return self.env.start(state, agents, actions, t, end_time, generator)

    def complete(self, state, agents, actions, t, generator):
        reward, obs = self.env.complete(state, agents, actions, t, generator)
        for row, a in agents.nonzero().tolist():
            self.obs[int(state[_ROW][row])][a].append(int(obs[row, a]))
        return reward, obs


@pytest.mark.parametrize("domain", ["disaster_relief", "package_delivery"])
@pytest.mark.parametrize("source", ["greedy", "random"])
def test_executor_chooses_the_simulators_macro_actions(domain, source):
    env = DisasterRelief() if domain == "disaster_relief" else PackageDelivery()
    if source == "greedy" and domain == "disaster_relief":
        ctrl = greedy_controller(2)
    else:  # random 6-node controllers: every node and transition exercised
        ctrl = random_controllers(
            1,
            num_agents=env.num_agents,
            num_nodes=6,
            num_actions=env.num_actions,
            num_obs=env.num_obs,
            generator=torch.Generator().manual_seed(3),
        )
    trace = Trace(env)
    simulate(trace, ctrl, 40, torch.Generator().manual_seed(0))
    checked = 0
    for rollout in range(40):
        for agent in range(env.num_agents):
            actions, obs = trace.actions[rollout][agent], trace.obs[rollout][agent]
            assert len(actions) == len(obs) + 1  # the first MA, then one per processed completion
            ex = ControllerExecutor.for_domain(ctrl, agent, env)
            assert ex.action == MacroAction(actions[0], env.action_names[actions[0]])
            for k, o in enumerate(obs):
                # alternate indices and names: both must give the same MA
                ma = ex.observe(o if k % 2 else env.obs_names[o])
                assert ma.index == actions[k + 1] and ma.name == env.action_names[actions[k + 1]]
                checked += 1
            assert ex.steps == len(obs)
    assert checked > 500


def test_state_round_trips_through_json_and_reset():
    env = DisasterRelief()
    ctrl = greedy_controller(2)
    ex = ControllerExecutor.for_domain(ctrl, 1, env)
    assert ex.action.name == "infer" and ex.node == 0
    assert ex.observe("saw_hospital_high").name == "pick_up"
    assert ex.observe(torch.tensor(3 * 5 + 0)).name == "go_hospital"  # loaded_hospital_high as a 0-d tensor
    saved = json.loads(json.dumps(ex.state_dict()))
    other = ControllerExecutor.for_domain(ctrl, 1, env)
    other.load_state_dict(saved)
    assert (other.node, other.steps, other.action) == (ex.node, ex.steps, ex.action)
    assert ex.reset() == MacroAction(6, "infer") and ex.steps == 0
    assert "agent=1" in repr(other)


def test_executor_of_a_saved_controller(tmp_path):
    ctrl = greedy_controller(2)
    loaded = JointController.load(ctrl.save(tmp_path / "controller.safetensors"))
    a = ControllerExecutor.for_domain(loaded, 0, DisasterRelief())
    b = ControllerExecutor.for_domain(ctrl, 0, DisasterRelief())
    for obs in ("at_base_high", "saw_airport_low", "loaded_airport_low", "at_site_loaded_medium", "away_low"):
        assert a.observe(obs) == b.observe(obs)
    assert a.action.name == "go_repair"


def test_state_of_another_controller_or_agent_is_refused():
    env = DisasterRelief()
    ex = ControllerExecutor.for_domain(greedy_controller(2), 0, env)
    ex.observe("at_base_high")
    other_agent = ControllerExecutor.for_domain(greedy_controller(2), 1, env)
    with pytest.raises(ValueError, match="agent was 0 there, is 1 here"):
        other_agent.load_state_dict(ex.state_dict())
    rand = random_controllers(
        1,
        num_agents=2,
        num_nodes=8,
        num_actions=env.num_actions,
        num_obs=env.num_obs,
        generator=torch.Generator().manual_seed(0),
    )
    with pytest.raises(ValueError, match="controller was"):
        ControllerExecutor.for_domain(rand, 0, env).load_state_dict(ex.state_dict())
    bad = ex.state_dict() | {"node": 8}
    with pytest.raises(ValueError, match=r"state\['node'\]: expected an index in \[0, 8\)"):
        ControllerExecutor.for_domain(greedy_controller(2), 0, env).load_state_dict(bad)
    with pytest.raises(ValueError, match="state: expected a dict written by"):
        ex.load_state_dict({"node": 0})
    with pytest.raises(ValueError, match="steps"):
        ex.load_state_dict(ex.state_dict() | {"steps": -1})


def test_bad_input_is_a_clear_error():
    env = DisasterRelief()
    ctrl = greedy_controller(2)
    ex = ControllerExecutor.for_domain(ctrl, 0, env)
    with pytest.raises(ValueError, match=r"observation: expected an index in \[0, 30\), got 30"):
        ex.observe(30)
    with pytest.raises(ValueError, match="observation: unknown name 'saw_moon_high'"):
        ex.observe("saw_moon_high")
    with pytest.raises(TypeError, match="observation: expected an integer index or a name, got float"):
        ex.observe(1.0)
    with pytest.raises(TypeError, match="observation: expected an integer index or a name, got bool"):
        ex.observe(True)
    with pytest.raises(TypeError, match="observation: expected an integer or a name, got a tensor"):
        ex.observe(torch.tensor([1, 2]))
    assert ex.steps == 0 and ex.node == 0  # a rejected observation changes nothing
    with pytest.raises(ValueError, match=r"agent: expected an index in \[0, 2\), got 2"):
        ControllerExecutor(ctrl, 2)
    with pytest.raises(TypeError, match="controller: expected a JointController"):
        ControllerExecutor(ctrl.action, 0)
    with pytest.raises(ValueError, match=r"controller: expected one joint controller \(K = 1\), got K = 2"):
        ControllerExecutor(JointController.cat([ctrl, ctrl]), 0)
    with pytest.raises(ValueError, match="action_names: the controller uses MA 8, but only 3 names"):
        ControllerExecutor(ctrl, 0, action_names=["a", "b", "c"])
    with pytest.raises(ValueError, match="obs_names: expected 30 strings"):
        ControllerExecutor(ctrl, 0, obs_names=["x"])
    with pytest.raises(ValueError, match="controller: has 2 agents and 30 observations, env has 2 and 13"):
        ControllerExecutor.for_domain(ctrl, 0, PackageDelivery())


def test_default_names_index_only():
    ctrl = JointController(torch.tensor([[[1, 0]]]), torch.tensor([[[[1, 0], [0, 1]]]]))
    ex = ControllerExecutor(ctrl, 0)
    assert ex.action == MacroAction(1, "ma1") and ex.obs_names == ["obs0", "obs1"]
    assert ex.observe(0) == MacroAction(0, "ma0")
    assert ex.observe("obs1") == MacroAction(0, "ma0")


def test_names_travel_with_the_controller_and_are_checked(tmp_path):
    env = DisasterRelief()
    ctrl = greedy_controller(2).named(env.action_names, env.obs_names)
    loaded = JointController.load(ctrl.save(tmp_path / "c.safetensors"))
    assert loaded.action_names == tuple(env.action_names) and loaded.obs_names == tuple(env.obs_names)
    assert loaded[0].obs_names == loaded.obs_names  # selecting controllers keeps the names
    ControllerExecutor.for_domain(loaded, agent=0, env=env)
    swapped = list(env.obs_names)
    swapped[0], swapped[1] = swapped[1], swapped[0]
    with pytest.raises(
        ValueError,
        match=r"controller: planned for other obs_names than env's \(first difference at "
        r"index 0",
    ):
        ControllerExecutor.for_domain(loaded.named(env.action_names, swapped), agent=0, env=env)
    with pytest.raises(ValueError, match="obs_names: expected .* distinct names"):
        loaded.named(env.action_names, env.obs_names[:-1])


def test_reachable_nodes_match_every_observation_sequence_replayed():
    """Brute force: every sequence of up to 6 observations replayed through a fresh executor reaches exactly the
    nodes ``reachable`` lists, and each listed way there leads to its node; a node whose MA is not in ``through``
    is reached but not left."""
    import itertools

    controller = random_controllers(
        1, num_agents=1, num_nodes=7, num_actions=4, num_obs=5, generator=torch.Generator().manual_seed(3)
    )
    executor = ControllerExecutor(controller, 0)
    allowed = [1, 3]
    found = executor.reachable(allowed)
    replayed = set()
    for length in range(7):
        for path in itertools.product(allowed, repeat=length):
            executor.reset()
            replayed.add(executor.node)
            for obs in path:
                executor.observe(obs)
                replayed.add(executor.node)
    assert set(found) == replayed and next(iter(found)) == 0
    for node, (action, path) in found.items():
        executor.reset()
        for name in path:
            executor.observe(name)
        assert executor.node == node and executor.action == action
    stop = executor.action_names[0]
    through = [name for name in executor.action_names if name != stop]
    limited = executor.reachable(allowed, through)
    assert set(limited) <= set(found)
    for node, (action, path) in limited.items():
        executor.reset()
        for name in path[:-1]:  # every node on the way has an MA of `through`
            assert executor.action.name in through
            executor.observe(name)
    with pytest.raises(ValueError, match="observations: unknown name 'nope'"):
        executor.reachable(["nope"])
