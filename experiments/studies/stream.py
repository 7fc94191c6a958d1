"""Live macro-observations: frames from a ROS bag, a video file, a folder or a camera, classified and filtered.

:func:`run` reads as its stages:

1. :func:`read_settings`: the settings, checked before anything is loaded (the source and the
   saved models exist, every range holds: ``experiments.schemas``).
2. :func:`load_models`: the saved :class:`~classifiers.FrameClassifier` and
   :class:`~hbni_pyro.HBNIPosterior` (from a finished mission run, ``stream.run``, or from files),
   the posterior's class order and the HBNI temper; the macro-observation process built on them.
   :func:`load_controller`: a saved controller's executor, when ``stream.controller`` is given.
3. :func:`stream_frames`: every stamped frame through the classifier (batches of ``stream.batch``) and
   the process, which restarts after each macro-observation (:func:`hbni_pyro.live_macro_observations`,
   the per-frame code of the ROS 2 node too); each complete one is the observation that completes the
   controller's current macro-action. The annotated video and the ROS output bag
   (:class:`hbni_pyro.runtime.ros_messages.MacroObservationBag`: a bag source's default) are written as frames go.
4. :func:`write_outputs`: ``macro_observations.jsonl`` (one record per macro-observation: frame
   range, label, confidence, frames used, timed out, stream ended, first and last stamps, the
   controller's decision), ``strip.png`` and the metrics (frames, macro-observations, frames per
   second end to end).
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
from tqdm.auto import tqdm

import hbni_pyro
from hbni_pyro import live_macro_observations, noise_model
from hbni_pyro.runtime import MacroObservationBag
from classifiers import FrameClassifier, class_columns
from classifiers.bags import is_bag
from classifiers.sources import FrameSource, open_source
from classifiers.stamped import classify_stamped
from decpomdp import ControllerExecutor, JointController
from experiments.runs.artifacts import latest_run, load_run
from experiments.runs.outputs import save_figure
from experiments.schemas.noise_studies import Stream
from experiments.steps.annotate import AnnotatedVideo, FrameAnnotator, max_confidence, strip_figure, thumbnail
from hbni_infra.files import atomic_write_text


class Settings(NamedTuple):
    """The stream's settings resolved for the run: the source, the files (``stream.run=latest`` found), tuples."""

    source: str | int
    max_input_frames: int | None
    run: Path | None
    classifier: Path | None
    posterior: Path | None
    classes: list[str] | None
    temper: float | None
    threshold: float
    max_frames: int
    batch: int
    annotate: tuple[str, ...]
    progress: bool
    topic: str | None = None  # a bag source's image topic and time window
    window: tuple[float, float | None] | None = None
    bag: bool = False  # write the ROS output bag
    controller: Path | None = None  # a saved JointController, its robot and the class -> observation names
    agent: int = 0
    observations: dict[str, str] | None = None
    mode: str | None = None  # the HBNI filter's mode (None: HBNIFilter's default)


class Models(NamedTuple):
    classifier: FrameClassifier
    process: hbni_pyro.MacroObservationProcess
    classes: list[str]
    temper: float


class Streamed(NamedTuple):
    """What :func:`stream_frames` saw: segments, their running confidences and deciding frames, timing."""

    segments: list[hbni_pyro.Segment]
    records: list[dict]
    beliefs: list[Any]
    thumbs: list[np.ndarray]
    frames: int
    seconds: float
    cpu_seconds: float
    video: Path | None
    bag: MacroObservationBag | None


def run(settings: Stream, run_dir: Path) -> dict:
    resolved = read_settings(settings)
    models = load_models(resolved)
    controller = load_controller(resolved)
    streamed = stream_frames(resolved, models, run_dir, controller)
    return write_outputs(resolved, models, streamed, run_dir)


def read_settings(settings: Stream) -> Settings:
    """The stream's settings resolved from the typed ``settings`` (checked against their schema,
    :mod:`experiments.schemas`).

    ``stream.run=latest`` is the newest completed mission run under the project's ``outputs/mission`` (from any
    working directory, :mod:`experiments.runs.paths`); it is not read
    when both ``stream.classifier`` and ``stream.posterior`` are given.
    """
    st = settings.stream
    source = st.source if isinstance(st.source, int) else str(st.source)
    run = st.run
    if run == "latest":
        try:
            run = None if st.classifier and st.posterior else latest_run("mission")
        except FileNotFoundError as exc:
            raise FileNotFoundError(f"stream.run: {str(exc).removeprefix('name: ')}") from None
    return Settings(
        source,
        st.max_input_frames,
        _path(run),
        _path(st.classifier),
        _path(st.posterior),
        None if st.classes is None else [str(c) for c in st.classes],
        st.temper,
        st.threshold,
        st.max_frames,
        st.batch,
        tuple(st.annotate),
        settings.progress,
        topic=st.topic,
        window=None if st.window is None else tuple(None if t is None else float(t) for t in st.window),
        bag=is_bag(source) if st.bag is None and not isinstance(source, int) else bool(st.bag),
        controller=_path(st.controller),
        agent=st.agent,
        observations=None if st.observations is None else {str(k): str(v) for k, v in st.observations.items()},
        mode=settings.hbni.filter.mode,
    )


def _path(value: Any) -> Path | None:
    return None if value is None else Path(str(value))


def load_models(settings: Settings) -> Models:
    """The classifier, the HBNI process and the class order (a mission run's, overridden by explicit files)."""
    finished = load_run(settings.run) if settings.run is not None else None
    if finished is not None:
        lacking = [name for name in ("classifier", "posterior") if not hasattr(finished, name)]
        lacking += [f"metrics['{key}']" for key in ("classes", "hbni_temper") if key not in finished.metrics]
        if lacking:
            raise ValueError(
                f"stream.run: {str(settings.run)!r} is not a mission run (it lacks {', '.join(lacking)}); "
                "expected a run of experiment=mission, or give stream.classifier and stream.posterior"
            )
    clf = FrameClassifier.load(settings.classifier) if settings.classifier else finished.classifier
    posterior = hbni_pyro.HBNIPosterior.load(settings.posterior) if settings.posterior else finished.posterior
    given = settings.classes
    if given is None and posterior.class_names is None and finished is not None and not settings.posterior:
        given = list(finished.metrics["classes"])  # a run's posterior saved before posteriors kept their names
    posterior = posterior.match_names(given, "stream.classes")
    classes = list(posterior.class_names)
    class_columns(clf, classes, "stream.classifier")  # its columns are read in the posterior's order
    temper = settings.temper
    if temper is None:
        temper = float(finished.metrics["hbni_temper"]["value"]) if finished is not None else 1.0
    mode = {} if settings.mode is None else {"mode": settings.mode}
    filt = hbni_pyro.HBNIFilter(posterior, **mode, temper=temper)
    process = hbni_pyro.MacroObservationProcess(filt, threshold=settings.threshold, max_frames=settings.max_frames)
    return Models(clf, process, classes, temper)


def load_controller(settings: Settings) -> ControllerExecutor | None:
    """The executor of robot ``stream.agent``'s controller in ``stream.controller`` (``None`` without one), named
    after the domain the controller was planned for."""
    if settings.controller is None:
        return None
    controller = JointController.load(settings.controller)
    return ControllerExecutor(controller, settings.agent, controller.action_names, controller.obs_names)


def stream_frames(
    settings: Settings, models: Models, run_dir: Path, controller: ControllerExecutor | None = None
) -> Streamed:
    """Classify and filter every frame of the source, tell the controller each macro-observation; write the
    annotated video and the ROS output bag as macro-observations complete."""
    source: FrameSource = open_source(  # the source stops at max_input_frames
        settings.source, max_frames=settings.max_input_frames, topic=settings.topic, window=settings.window
    )
    total = source.num_frames if source.num_frames is not None else settings.max_input_frames  # a camera: the limit
    annotator = None
    if {"video", "bag"} & set(settings.annotate):
        annotator = FrameAnnotator(models.classes, settings.threshold, settings.max_frames)
    video = AnnotatedVideo(run_dir / "annotated.mp4", source.fps or 30.0) if "video" in settings.annotate else None
    bag = MacroObservationBag(run_dir / "macro_observations", models.classes) if settings.bag else None
    items = classify_stamped(source.stamped(), models.classifier, models.classes, settings.batch)
    live = live_macro_observations(
        items, models.process, models.classes, controller, settings.observations, keep_frames=True
    )
    segments, records, beliefs, thumbs = [], [], [], []
    bar = tqdm(total=total, desc="stream", unit="frame", disable=not settings.progress)
    tic, cpu = time.perf_counter(), time.process_time()
    try:
        for obs in live:
            seg = obs.segment
            images = [frame.image for frame in seg.frames]
            if annotator is not None:
                for frame, img in zip(seg.frames, annotator.draw(seg, obs.running, images)):
                    if video is not None:
                        video.write(img)
                    if bag is not None and "bag" in settings.annotate:
                        bag.write_frame(img, frame.stamp, frame.received, frame.frame_id)
            if bag is not None:
                bag.write(obs)
            segments.append(seg._replace(frames=[]))
            records.append(obs.record())
            beliefs.append(max_confidence(obs.running))
            thumbs.append(thumbnail(images[-1]))
            bar.update(seg.frames_used)
            bar.set_postfix(macro=len(segments), label=seg.name)
    except KeyboardInterrupt:  # a camera runs until stopped: keep what was seen
        tqdm.write("[stream] interrupted: writing the macro-observations so far")
    finally:
        seconds, cpu_seconds = time.perf_counter() - tic, time.process_time() - cpu
        bar.close()
        source.close()
        written = video.close() if video is not None else None
        if bag is not None:
            bag.close()
    count = sum(s.frames_used for s in segments)
    if not count:
        raise ValueError(f"stream.source: {settings.source!r} gave no frames")
    return Streamed(segments, records, beliefs, thumbs, count, seconds, cpu_seconds, written, bag)


def _model_label(models: Models) -> str:
    """The noise model and, for a frame-level one, its temper (the sequence model uses none)."""
    model = noise_model(models.process.filter.model)
    return f"{model.name} model" if model.sequences else f"{model.name} model, temper {models.temper:g}"


def write_outputs(settings: Settings, models: Models, streamed: Streamed, run_dir: Path) -> dict:
    """``macro_observations.jsonl``, ``strip.png``; prints where they are and returns the metrics."""
    records = streamed.records
    jsonl = atomic_write_text(run_dir / "macro_observations.jsonl", "".join(json.dumps(r) + "\n" for r in records))
    written = {"records": str(jsonl)}
    if "strip" in settings.annotate:
        fig = strip_figure(
            streamed.segments,
            streamed.beliefs,
            streamed.thumbs,
            models.classes,
            settings.threshold,
            f"{settings.source}: HBNI macro-observations ({_model_label(models)})",
        )
        written["strip"] = str(save_figure(fig, run_dir / "strip.png"))
    if streamed.video is not None:
        written["video"] = str(streamed.video)
    if streamed.bag is not None:
        written["bag"] = str(streamed.bag.path)
    labels = [s.name for s in streamed.segments]
    metrics = {
        "source": str(settings.source),
        "frames": streamed.frames,
        "macro_observations": len(records),
        "labels": {name: labels.count(name) for name in models.classes},
        "mean_frames_used": streamed.frames / len(records),
        "timed_out": sum(s.timed_out for s in streamed.segments),
        "decisions": sum("decision" in r for r in records),
        "seconds": streamed.seconds,
        "cpu_seconds": streamed.cpu_seconds,
        "fps": streamed.frames / max(streamed.seconds, 1e-9),
        "process": repr(models.process),
        "classes": models.classes,
        "outputs": written,
    }
    if streamed.bag is not None:
        metrics["bag_topics"] = {
            streamed.bag.topics[role]: count for role, count in streamed.bag.counts.items() if count
        }
    print(
        f"[stream] {streamed.frames} frames -> {len(records)} macro-observations at {metrics['fps']:.1f} fps; "
        f"wrote {', '.join(written.values())}"
    )
    return metrics
