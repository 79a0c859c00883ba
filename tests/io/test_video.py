"""Tests of ccs_kornia.io.video and ccs_kornia.io.timestamps: streamed decoding, frame indices and timestamps, the frame
span, reading by index, damaged and unreadable files, timestamps tables."""

from __future__ import annotations

import os

import numpy as np
import pytest
from _videos import FORMATS, board_frames, truncated, write_video

from ccs_kornia.io.timestamps import TimestampRow, read_timestamps
from ccs_kornia.io.video import (
    FrameSpan,
    VideoReader,
    frame_name,
    is_video,
    open_video,
    split_frame_name,
)


def _counter(num: int = 30) -> np.ndarray:
    """Frames whose mean level encodes their index (8 grey levels apart, robust to compression)."""
    return np.stack([np.full((48, 64), 8 * k + 10, np.uint8) for k in range(num)])


@pytest.fixture(scope="module", params=FORMATS, ids=[f[0] for f in FORMATS])
def clip(request, tmp_path_factory):
    fourcc, ext = request.param
    return write_video(str(tmp_path_factory.mktemp("clip") / f"counter{ext}"), _counter(), fps=10.0, fourcc=fourcc)


def _level(image: np.ndarray) -> int:
    return int(round((float(image.mean()) - 10) / 8))


def test_open_video_describes_the_container(clip):
    info, reason = open_video(clip)
    assert reason == ""
    assert (info.width, info.height, info.fps, info.frame_count) == (64, 48, 10.0, 30)
    assert info.duration == pytest.approx(3.0) and info.period == pytest.approx(0.1)


def test_frames_in_order_with_index_and_timestamp(clip):
    reader = VideoReader(clip)
    frames = list(reader.frames())
    assert [f.index for f in frames] == list(range(30))
    assert [_level(f.image) for f in frames] == list(range(30))
    assert np.allclose([f.timestamp for f in frames], np.arange(30) / 10.0)
    assert all(f.image.dtype == np.uint8 and f.image.shape == (48, 64) for f in frames)
    assert reader.stopped == "" and reader.length == 30


def test_every_start_end(clip):
    frames = list(VideoReader(clip).frames(FrameSpan(every=4, start=0.5, end=2.0)))
    assert [f.index for f in frames] == [5, 9, 13, 17]
    assert [_level(f.image) for f in frames] == [5, 9, 13, 17]


def test_downscaled_frames(clip):
    frame = next(iter(VideoReader(clip).frames(max_side=32)))
    assert frame.image.shape == (24, 32)


@pytest.mark.parametrize("order", [[3, 4, 29, 2, 17, 0], [25, 5, 6, 28]])
def test_read_by_index_forward_and_back(clip, order):
    reader = VideoReader(clip)
    times = {f.index: f.timestamp for f in VideoReader(clip).frames()}
    for index in order:
        frame = reader.read(index, times[index])
        assert frame.index == index and _level(frame.image) == index
        assert frame.timestamp == pytest.approx(times[index])
    assert reader.read(30) is None  # past the end


def test_read_with_a_wrong_timestamp_decodes_forward(clip):
    reader = VideoReader(clip)
    assert reader.read(20, timestamp=99.0) is not None  # a seek that cannot be confirmed: decoded from the start
    assert _level(reader.read(21).image) == 21


def test_frame_span_refuses_bad_bounds():
    with pytest.raises(ValueError, match="every"):
        FrameSpan(every=0)
    with pytest.raises(ValueError, match="start"):
        FrameSpan(start=-1.0)
    with pytest.raises(ValueError, match="after start"):
        FrameSpan(start=2.0, end=1.0)


def test_names():
    assert is_video("a/B.MKV") and is_video("x.mov") and not is_video("x.png")
    assert frame_name("cam.mp4", 7) == "cam.mp4#7"
    assert split_frame_name("dir#1/cam.mp4#12") == ("dir#1/cam.mp4", 12)
    assert split_frame_name("cam.mp4#x") is None and split_frame_name("img#3.png") is None


def test_truncated_avi_gives_the_frames_before_the_damage(tmp_path):
    full = write_video(str(tmp_path / "full.avi"), board_frames(20), fourcc="MJPG")
    cut = truncated(full, str(tmp_path / "cut.avi"), keep=0.5)
    reader = VideoReader(cut)
    frames = list(reader.frames())
    assert 0 < len(frames) < 20
    assert [f.index for f in frames] == list(range(len(frames)))
    assert f"the {len(frames)} frames before are used" in reader.stopped
    assert "damaged or truncated" in reader.stopped


@pytest.mark.parametrize("make, phrase", [
    (lambda d: truncated(write_video(str(d / "a.mp4"), _counter(), fourcc="mp4v"), str(d / "cut.mp4")),
     "not a readable video"),
    (lambda d: (d / "noise.mp4").write_bytes(os.urandom(5000)) and str(d / "noise.mp4"), "not a readable video"),
    (lambda d: (d / "empty.avi").write_bytes(b"") is not None and str(d / "empty.avi"), "not a readable video"),
    (lambda d: str(d / "missing.mp4"), "no such file"),
    (lambda d: str(d), "not a file"),
])
def test_unreadable_videos_say_why(tmp_path, make, phrase):
    path = make(tmp_path)
    info, reason = open_video(path)
    assert info is None and phrase in reason
    with pytest.raises(ValueError, match=phrase):
        VideoReader(path)


def test_unreadable_video_prints_nothing(tmp_path, capfd):
    path = truncated(write_video(str(tmp_path / "a.mp4"), _counter(), fourcc="mp4v"), str(tmp_path / "cut.mp4"))
    assert open_video(path)[0] is None
    out, err = capfd.readouterr()
    assert out == "" and err == ""  # FFmpeg's and OpenCV's own lines are silenced


# ----------------------------------------------------------------------------------------------
# timestamps tables
# ----------------------------------------------------------------------------------------------


def test_read_timestamps_with_and_without_frame_index(tmp_path):
    a = tmp_path / "a.csv"
    a.write_text("sync_index,cam_id,frame_index,frame_time\n3,0,10,100.5\n3,1,11,100.51\n")
    assert read_timestamps(a) == [TimestampRow(3, 0, 10, 100.5), TimestampRow(3, 1, 11, 100.51)]
    b = tmp_path / "b.csv"
    b.write_text("frame_time,cam_id,sync_index\n1.0,0,0\n\n1.1,1,0\n")  # any column order, blank lines skipped
    assert read_timestamps(b) == [TimestampRow(0, 0, None, 1.0), TimestampRow(0, 1, None, 1.1)]


@pytest.mark.parametrize("text, phrase", [
    ("sync_index,cam_id\n0,0\n", "no column frame_time"),
    ("sync_index,cam_id,frame_time\n0,zero,1.0\n", "line 2: cam_id 'zero' is not a number"),
    ("sync_index,cam_id,frame_time\n0,-1,1.0\n", "not a whole number"),
    ("sync_index,cam_id,frame_time\n0,0,nan\n", "not a finite number"),
    ("sync_index,cam_id,frame_time\n", "has no rows"),
    ("sync_index,cam_id,frame_index,frame_time\n0,0,1,1.0\n0,1,,1.0\n", "frame_index is given on some rows"),
])
def test_bad_timestamps_tables(tmp_path, text, phrase):
    path = tmp_path / "t.csv"
    path.write_text(text)
    with pytest.raises(ValueError, match=phrase):
        read_timestamps(path)


def test_missing_timestamps_table(tmp_path):
    with pytest.raises(ValueError, match="cannot read"):
        read_timestamps(tmp_path / "none.csv")
