"""The robot-side loop: stamped macro-observations with the filter's posterior and a controller's decisions,
checked against the plain segments, the batched filter and a brute-force replay of the controller's table."""

from types import SimpleNamespace

import pytest
import torch

import hbni_pyro
from decpomdp import ControllerExecutor, JointController
from hbni_pyro import live_macro_observations, sample_outputs
from hbni_pyro.runtime import observation_names

NAMES = ("ambulance", "food_crate", "police_car")
THETA = torch.tensor([3.0, 4.0, 5.0], dtype=torch.float64)
T0 = 1_700_000_000_000_000_000


def _items(n=40, seed=0):
    """A stream of three objects in turn, frames stamped every 100 ms and received 7 ms later."""
    truth = torch.arange(3).repeat_interleave(n // 3 + 1)[:n]
    outputs = sample_outputs(THETA, truth, torch.Generator().manual_seed(seed))
    frames = [
        SimpleNamespace(stamp=T0 + i * 10**8, received=T0 + i * 10**8 + 7 * 10**6, frame_id=f"cam{i}", index=i)
        for i in range(n)
    ]
    return list(zip(frames, outputs))


def _process():
    return hbni_pyro.MacroObservationProcess(hbni_pyro.StaticStateBayesFilter(3), threshold=0.99, max_frames=5)


def _controller():
    """One robot: node 0 runs 'infer'; a macro-observation of class c sends it to node 1 + c ('go_<c>'), any
    observation there back to node 0."""
    next_node = torch.tensor([[1, 2, 3], [0, 0, 0], [0, 0, 0], [0, 0, 0]])
    action = torch.tensor([0, 1, 2, 3])
    names = ("infer", *(f"go_{c}" for c in NAMES))
    obs = tuple(f"saw_{c}" for c in NAMES)
    return JointController(action[None, None], next_node[None, None], names, obs)


def test_stamps_posterior_and_segments_match_the_plain_stream():
    items = _items()
    plain = list(hbni_pyro.macro_observations(items, _process(), NAMES))
    process = _process()
    live = list(live_macro_observations(items, process, NAMES))
    assert [o.segment._replace(frames=[], outputs=None) for o in live] == [
        s._replace(frames=[], outputs=None) for s in plain
    ]
    for obs in live:
        seg = obs.segment
        assert seg.frames == [] and obs.decision is None
        assert obs.first_stamp == T0 + seg.start * 10**8 and obs.last_stamp == T0 + seg.end * 10**8
        assert obs.received == obs.last_stamp + 7 * 10**6 and obs.frame_id == f"cam{seg.end}"
        # the running posterior is the batched filter's, and its last row gave the decision
        assert torch.equal(obs.running, process.filter.run(seg.outputs[None])[0])
        assert obs.running.shape == (seg.frames_used, 3) and int(obs.posterior.argmax()) == seg.label
        assert float(obs.posterior.max()) == pytest.approx(seg.confidence, abs=1e-12)
        record = obs.record()
        assert record["first_stamp"] == obs.first_stamp and record["last_stamp"] == obs.last_stamp
        assert "decision" not in record
    kept = list(live_macro_observations(items, _process(), NAMES, keep_frames=True))
    assert [f.index for f in kept[1].segment.frames] == list(range(kept[1].segment.start, kept[1].segment.end + 1))


def test_the_controller_decides_on_every_complete_macro_observation():
    items = _items()
    plain = list(hbni_pyro.macro_observations(items, _process(), NAMES))
    items = items[: plain[-2].end + 2]  # the stream ends one frame into a macro-observation
    executor = ControllerExecutor(_controller(), 0, _controller().action_names, _controller().obs_names)
    mapping = {c: f"saw_{c}" for c in NAMES}
    live = list(live_macro_observations(items, _process(), NAMES, executor, mapping))
    assert live[-1].segment.stream_ended and live[-1].decision is None  # cut short by the stream's end: no decision
    node = 0
    for obs in live[:-1]:
        d = obs.decision
        assert d.agent == 0 and d.observation == f"saw_{obs.segment.name}"
        assert d.completed == ("infer", "go_ambulance", "go_food_crate", "go_police_car")[node]
        node = [[1, 2, 3], [0, 0, 0], [0, 0, 0], [0, 0, 0]][node][obs.segment.label]
        assert d.node == node and d.action_index == node and d.action == _controller().action_names[node]
        assert obs.record()["decision"] == d._asdict()
    assert executor.steps == len(live) - 1


def test_observation_names_are_checked_against_the_controller():
    obs = [f"saw_{c}" for c in NAMES]
    assert observation_names(NAMES, obs, {c: f"saw_{c}" for c in NAMES}) == obs
    assert observation_names(NAMES, list(NAMES) + ["none"]) == list(NAMES)
    with pytest.raises(
        ValueError,
        match=r"observations: the classes \['ambulance', 'food_crate', 'police_car'\] are reported to the controller "
        r"as \['ambulance', 'food_crate', 'police_car'\], but it has no observation \['ambulance', 'food_crate', "
        r"'police_car'\]; its observations are \['saw_ambulance'",
    ):
        observation_names(NAMES, obs)
    with pytest.raises(ValueError, match=r"observations: \['truck'\] are not classes"):
        observation_names(NAMES, obs, {"truck": "saw_ambulance"})
    executor = ControllerExecutor(_controller(), 0, _controller().action_names, _controller().obs_names)
    with pytest.raises(ValueError, match="but it has no observation"):
        next(live_macro_observations(_items(), _process(), NAMES, executor))
    plain = [(None, output) for _, output in _items()]
    with pytest.raises(TypeError, match="items: expected frames with stamp, received and frame_id attributes"):
        next(live_macro_observations(plain, _process(), NAMES))
