"""Frame sources: a video file written here, folders of frames in name order, cameras, and the errors."""

import cv2
import numpy as np
import pytest

from classifiers.data import render_sequence
from classifiers.sources import Camera, FrameFolder, VideoFile, open_source


@pytest.fixture(scope="module")
def frames():
    return render_sequence("ambulance", 12, "mission", seed=4)


def _write_video(path, frames, fps=10.0):
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), fps, (frames.shape[2], frames.shape[1]))
    for f in frames:
        writer.write(f)
    writer.release()
    return path


def test_video_file_gives_every_frame_in_order(tmp_path, frames):
    path = _write_video(tmp_path / "clip.mp4", frames)
    source = open_source(path)
    assert isinstance(source, VideoFile) and source.num_frames == 12 and source.fps == pytest.approx(10.0)
    first = list(source)
    second = list(source)  # a file can be read again from the start
    assert len(first) == len(second) == 12
    for a, b, ref in zip(first, second, frames):
        assert a.dtype == np.uint8 and a.shape == ref.shape and np.array_equal(a, b)
    # lossy codec (and sensor noise of sd up to 12 it cannot keep): each decoded frame is nearest to the frame
    # written at its position
    errors = np.array([[np.abs(a.astype(int) - ref).mean() for ref in frames] for a in first])
    assert (errors.argmin(1) == np.arange(12)).all()
    with source:  # a context manager
        pass


def test_folder_of_frames_in_natural_name_order(tmp_path, frames):
    for i, f in enumerate(frames):
        cv2.imwrite(str(tmp_path / f"frame_{i}.png"), f)  # frame_10 must come after frame_9
    (tmp_path / "notes.txt").write_text("not a frame")
    source = open_source(str(tmp_path))
    assert isinstance(source, FrameFolder) and source.num_frames == 12
    assert [p.name for p in source.files][-3:] == ["frame_9.png", "frame_10.png", "frame_11.png"]
    read = list(source)
    assert all(np.array_equal(a, b) for a, b in zip(read, frames))  # PNG is lossless


def test_grey_and_alpha_frames_become_bgr(tmp_path, frames):
    cv2.imwrite(str(tmp_path / "a.png"), cv2.cvtColor(frames[0], cv2.COLOR_BGR2GRAY))
    cv2.imwrite(str(tmp_path / "b.png"), cv2.cvtColor(frames[1], cv2.COLOR_BGR2BGRA))
    grey, bgra = list(FrameFolder(tmp_path))
    assert grey.shape == bgra.shape == frames[0].shape
    assert np.array_equal(bgra, frames[1]) and (grey[..., 0] == grey[..., 2]).all()


def test_bad_sources_are_clear_errors(tmp_path, frames):
    with pytest.raises(FileNotFoundError, match="source: no such video file or folder"):
        open_source(tmp_path / "missing.mp4")
    with pytest.raises(TypeError, match="source: expected a video file, a folder of frames or a camera index"):
        open_source(1.5)
    with pytest.raises(ValueError, match="could not be opened as a video"):
        VideoFile((tmp_path / "fake.mp4").write_text("not a video") and tmp_path / "fake.mp4")
    labelled = tmp_path / "labelled"
    (labelled / "ambulance").mkdir(parents=True)
    cv2.imwrite(str(labelled / "ambulance" / "0.png"), frames[0])
    with pytest.raises(ValueError, match="holds <class>/ folders of images, not a flat folder of frames"):
        open_source(labelled)
    broken = tmp_path / "only_broken"
    broken.mkdir()
    (broken / "x.png").write_bytes(b"\x89PNG not really")
    with pytest.raises(ValueError, match="could not be decoded"):
        list(FrameFolder(broken))
    with pytest.raises(ValueError, match="source: camera 97 could not be opened"):
        open_source("97")  # digits that name no path: a camera index
    with pytest.raises(ValueError, match="source: expected a camera index >= 0"):
        Camera(-1)
    with pytest.raises(ValueError, match="max_frames: expected an int >= 1, got 0"):
        Camera(0, max_frames=0)


@pytest.mark.parametrize("kind", ["video", "folder"])
def test_max_frames_is_honoured_by_every_source(tmp_path, frames, kind):
    if kind == "video":
        path = tmp_path / "clip.mp4"
        _write_video(path, frames)
    else:
        path = tmp_path / "frames"
        path.mkdir()
        for i, frame in enumerate(frames):
            cv2.imwrite(str(path / f"f{i}.png"), frame)
    source = open_source(path, max_frames=5)
    assert len(list(source)) == 5 == source.num_frames
    assert len(list(open_source(path))) == len(frames) > 5
    with pytest.raises(ValueError, match="max_frames: expected an int >= 1, got -3"):
        open_source(path, max_frames=-3)
    with pytest.raises(TypeError, match="max_frames: expected an int"):
        open_source(path, max_frames=2.5)


def test_an_image_folder_on_a_file_says_so(tmp_path):
    from classifiers.data import ImageFolder

    (tmp_path / "x.png").write_bytes(b"")
    with pytest.raises(NotADirectoryError, match="is a file, expected a folder of images"):
        ImageFolder(tmp_path / "x.png")


def test_fit_without_labels_names_the_argument(frame_classifier):
    from classifiers import FrameClassifier

    with pytest.raises(TypeError, match="labels: expected one class name per image"):
        FrameClassifier().fit([np.zeros((8, 8, 3), np.uint8)], None)
