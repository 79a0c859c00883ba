"""Tests of the video input steps: the screening pass, the frame choice, pairing a rig's frames (time, index, table)
and the VideoSource the pipeline reads."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from _videos import BOARD, board_frames, write_video

from ccs_kornia.io.timestamps import TimestampRow
from ccs_kornia.io.video import FrameSpan, VideoInfo, VideoReader
from ccs_kornia.modules.detection.screening import BoardScreen, Sighting
from ccs_kornia.pipeline.frame_candidates import (
    MAX_MOTION,
    MIN_STILL,
    board_motion,
    choose_frames,
    outline_distance,
)
from ccs_kornia.pipeline.frame_matching import (
    match_by_index,
    match_by_table,
    match_by_time,
)
from ccs_kornia.pipeline.screening import ScreenedFrame, ScreenedVideo, screen_video
from ccs_kornia.pipeline.sources import VideoFrameRef, VideoSource
from ccs_kornia.pipeline.video_input import (
    camera_frames,
    default_tolerance,
    pair_videos,
    rig_frames,
)
from ccs_kornia.pipeline.workers import map_batches


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    return write_video(str(tmp_path_factory.mktemp("rec") / "board.avi"), board_frames(24, blank=(5, 6)), fps=10.0)


# ----------------------------------------------------------------------------------------------
# the screening pass and the VideoSource
# ----------------------------------------------------------------------------------------------


def test_screening_pass_sees_the_boards(recording):
    seen = screen_video(recording, BoardScreen(BOARD))
    assert [f.index for f in seen.frames] == list(range(24))
    assert not seen.frames[5].found and not seen.frames[6].found
    assert seen.found >= 18
    assert seen.timestamps_usable and seen.length == 24 and seen.stopped == ""


def test_screening_pass_is_the_same_with_workers(recording):
    one = screen_video(recording, BoardScreen(BOARD), FrameSpan(every=2), workers=1, batch_size=3)
    two = screen_video(recording, BoardScreen(BOARD), FrameSpan(every=2), workers=2, batch_size=3)
    assert [f.index for f in one.frames] == [f.index for f in two.frames] == list(range(0, 24, 2))
    for a, b in zip(one.frames, two.frames):
        assert a.found == b.found
        assert (a.sighting.outline is None) == (b.sighting.outline is None)
        if a.found:
            assert np.allclose(a.sighting.outline, b.sighting.outline)


def test_screening_progress(recording):
    calls = []
    screen_video(recording, BoardScreen(BOARD), progress=lambda frames, boards: calls.append((frames, boards)),
                 batch_size=10)
    assert [c[0] for c in calls] == [10, 10, 4]
    assert sum(c[1] for c in calls) >= 18


def test_video_source_loads_the_frames(recording):
    frames = {f.index: f for f in VideoReader(recording).frames()}
    refs = [VideoFrameRef(recording, k, frames[k].timestamp) for k in (2, 3, 20, 7)]
    source = VideoSource([refs], sizes={recording: (320, 240)})
    assert source.counts == [4] and source.describe(0, 2) == f"{recording}#20" and source.pixels(0, 0) == 320 * 240
    batches = list(source.batches(batch_size=3))
    assert [b.keys for b in batches] == [[(0, 0), (0, 1), (0, 2)], [(0, 3)]]
    images = torch.cat([b.images for b in batches])
    assert images.shape == (4, 1, 240, 320) and images.dtype == torch.float32
    for image, k in zip(images, (2, 3, 20, 7)):
        assert torch.equal(image[0], torch.from_numpy(frames[k].image).float() / 255)


def test_video_source_batches_are_the_same_in_workers(recording):
    refs = [VideoFrameRef(recording, k) for k in range(0, 24, 3)]
    source = VideoSource([refs, refs[::-1]])
    def levels(x, keys):  # integer sums: exact whatever the threads
        return (x * 255).round().long().flatten(1).sum(1).tolist()

    sums = [[(o.keys, o.value) for o in map_batches(levels, source, batch_size=3, workers=w)] for w in (1, 2)]
    assert sums[0] == sums[1]


def test_video_source_reports_a_missing_frame(recording):
    source = VideoSource([[VideoFrameRef(recording, 500)]])
    (batch,) = list(source.batches())
    assert batch.images is None and batch.failed == [((0, 0), "frame 500 could not be decoded")]


# ----------------------------------------------------------------------------------------------
# the frame choice
# ----------------------------------------------------------------------------------------------

BOX = np.array([[0.0, 0.0], [40.0, 0.0], [40.0, 30.0], [0.0, 30.0]])


def test_outline_distance_ignores_the_corner_numbering():
    assert outline_distance(BOX, np.roll(BOX, 1, axis=0)) == 0.0
    assert outline_distance(BOX, BOX + [3.0, 4.0]) == pytest.approx(5.0)


def test_board_motion_per_frame_period():
    seen = [Sighting(True, BOX), Sighting(True, BOX + [6.0, 0.0]), Sighting(True, BOX + [6.0, 0.0])]
    assert board_motion([0, 3, 4], seen) == [2.0, 2.0, 0.0]  # 6 px over 3 frames, then still


def _line(shifts, motion=None):
    seen = [Sighting(True, BOX + [dx, 0.0]) if dx is not None else Sighting(False) for dx in shifts]
    motion = motion or [0.0 if dx is not None else None for dx in shifts]
    return seen, [str(k) for k in range(len(shifts))], motion


def test_short_recordings_keep_every_frame():
    seen, labels, motion = _line([0, None, 0])
    choice = choose_frames([seen], [labels], [motion], [(640, 480)], max_frames=3)
    assert choice.chosen == [0, 1, 2] and choice.reasons == [["", "", ""]]


def test_the_choice_is_bounded_spread_and_skips_copies():
    shifts = [20.0 * k for k in range(40)] + [1.0, 2.0, None]
    seen, labels, motion = _line(shifts)
    choice = choose_frames([seen], [labels], [motion], [(640, 480)], max_frames=5)
    assert len(choice.chosen) == 5
    assert 0 in choice.chosen and 39 in choice.chosen  # the two ends of the sweep
    assert choice.reasons[0][40] == "near copy of frame 0" and choice.reasons[0][42] == "no board at screening"
    assert sum(r == "over --max-frames" for r in choice.reasons[0]) == 40 - 5 + 0


def test_moving_frames_stay_out_while_enough_are_still():
    shifts = [20.0 * k for k in range(30)]
    motion = [50.0 if k % 2 else 0.5 for k in range(30)]
    seen, labels, _ = _line(shifts)
    choice = choose_frames([seen], [labels], [motion], [(640, 480)], max_frames=20)
    assert all(k % 2 == 0 for k in choice.chosen)
    assert choice.reasons[0][1] == "moving (50.0 px/frame)"


def test_copies_fill_the_budget_after_every_new_pose():
    shifts = [20.0 * k for k in range(10)] + [20.0 * k + 1.0 for k in range(10)]  # ten poses, each seen twice
    seen, labels, motion = _line(shifts)
    filled = choose_frames([seen], [labels], [motion], [(640, 480)], max_frames=15)
    assert len(filled.chosen) == 15 and set(range(10)) <= set(filled.chosen)  # every new pose, then copies
    left = [k for k in range(10, 20) if k not in filled.chosen]
    assert len(left) == 5 and all(filled.reasons[0][k] == f"near copy of frame {k - 10}" for k in left)
    kept_out = choose_frames([seen], [labels], [motion], [(640, 480)], max_frames=15, copies=False)
    assert sorted(k % 10 for k in kept_out.chosen) == list(range(10))  # one frame of each pose
    assert all(kept_out.reasons[0][k].startswith("near copy of frame") for k in range(20) if k not in kept_out.chosen)


def test_the_still_gate_is_a_tenth_of_a_percent_of_the_diagonal():
    assert MAX_MOTION * np.hypot(1280, 720) == pytest.approx(1.47, abs=0.01)  # px per frame period at 720p
    shifts = [20.0 * k for k in range(30)]
    motion = [2.0 if k % 2 else 1.0 for k in range(30)]  # px a frame at 1280x720: half still, half moving
    seen, labels, _ = _line(shifts)
    choice = choose_frames([seen], [labels], [motion], [(1280, 720)], max_frames=20)
    assert all(k % 2 == 0 for k in choice.chosen) and choice.reasons[0][1] == "moving (2.0 px/frame)"


def test_moving_frames_fill_in_when_too_few_are_still():
    shifts = [20.0 * k for k in range(30)]
    motion = [50.0 + k for k in range(30)]
    seen, labels, _ = _line(shifts)
    choice = choose_frames([seen], [labels], [motion], [(640, 480)], max_frames=20)
    assert sorted(choice.chosen) == list(range(MIN_STILL))  # the stillest


def test_no_board_at_screening_spreads_the_frames():
    seen = [Sighting(False)] * 100
    choice = choose_frames([seen], [[str(k) for k in range(100)]], [[None] * 100], [(640, 480)], max_frames=5)
    assert choice.chosen == [0, 25, 50, 74, 99]


def test_rig_instants_seen_by_more_cameras_come_first():
    c0 = [Sighting(True, BOX + [20.0 * k, 0.0]) for k in range(10)]
    c1 = [Sighting(True, BOX + [20.0 * k, 0.0]) if k in (3, 7) else Sighting(False) for k in range(10)]
    labels = [[str(k) for k in range(10)]] * 2
    choice = choose_frames([c0, c1], labels, [[0.0] * 10] * 2, [(640, 480)] * 2, max_frames=2)
    assert choice.chosen == [3, 7]


def test_choice_refuses_bad_arguments():
    with pytest.raises(ValueError, match="max_frames"):
        choose_frames([[]], [[]], [[]], [(10, 10)], max_frames=0)
    with pytest.raises(ValueError, match="one entry per instant"):
        choose_frames([[None], []], [[None], []], [[None], []], [(10, 10)] * 2)


def test_camera_frames_names_and_records(recording):
    seen = screen_video(recording, BoardScreen(BOARD))
    frames = camera_frames([seen], max_frames=8)
    (refs,) = frames.refs
    assert len(refs) <= 8 and [r.index for r in refs] == sorted(r.index for r in refs)
    assert frames.names()[0][0] == f"{recording}#{refs[0].index}"
    (record,) = frames.records(0)
    assert record["frames_screened"] == 24 and record["chosen"] == len(refs)
    assert [f["chosen"] for f in record["frames"]].count(True) == len(refs)
    assert all(("reason" in f) != f["chosen"] for f in record["frames"])


# ----------------------------------------------------------------------------------------------
# pairing a rig's frames
# ----------------------------------------------------------------------------------------------


def test_match_by_time_with_different_rates_and_lengths():
    t30 = [k / 30 for k in range(9)]
    t15 = [k / 15 + 0.004 for k in range(3)]
    table = match_by_time([t30, t15], tolerance=1 / 60)
    paired = [f for f in range(table.num_frames) if None not in (table.index[0][f], table.index[1][f])]
    assert [table.index[0][f] for f in paired] == [0, 2, 4]
    assert table.contributed(0) == 9 and table.contributed(1) == 3
    assert table.largest_spread() == pytest.approx(0.004)


def test_match_by_time_tolerance_zero_pairs_only_equal_times():
    table = match_by_time([[0.0, 1.0], [0.0, 1.001]], tolerance=0.0)
    assert table.index == [[0, 1, None], [0, None, 1]]
    with pytest.raises(ValueError, match="tolerance"):
        match_by_time([[0.0]], tolerance=-1.0)


def test_match_by_index():
    table = match_by_index([[0, 1, 2], [1, 2, 3]], [[0.0, 0.1, 0.2], [0.5, 0.6, 0.7]])
    assert table.labels == ["0", "1", "2", "3"] and table.by == "index"
    assert table.index == [[0, 1, 2, None], [None, 0, 1, 2]]
    assert table.times[1][1] == 0.5


def test_match_by_table_with_and_without_frame_index():
    rows = [TimestampRow(5, 0, 2, 10.0), TimestampRow(5, 1, 0, 10.01), TimestampRow(6, 0, 3, 10.5)]
    table = match_by_table(rows, [[0, 2, 3], [0, 1]], [4, 2])
    assert table.labels == ["5", "6"] and table.index == [[1, 2], [0, None]]
    assert table.largest_spread() == pytest.approx(0.01)
    rows = [TimestampRow(1, 0, None, 2.0), TimestampRow(0, 0, None, 1.0), TimestampRow(0, 1, None, 1.0)]
    table = match_by_table(rows, [[0, 1], [0]], [2, 1])  # without frame_index: a camera's rows in time order
    assert table.labels == ["0", "1"] and table.index == [[0, 1], [0, None]]


@pytest.mark.parametrize("rows, counts, phrase", [
    ([TimestampRow(0, 0, 0, 1.0), TimestampRow(0, 2, 0, 1.0)], [1, 1], "names camera 2 but 2 videos"),
    ([TimestampRow(0, 0, 0, 1.0)], [1, 1], "no row for camera 1"),
    ([TimestampRow(0, 0, 0, 1.0), TimestampRow(0, 0, 1, 1.0), TimestampRow(0, 1, 0, 1.0)], [2, 1],
     "sync_index 0 names camera 0 twice"),
    ([TimestampRow(0, 0, 5, 1.0), TimestampRow(0, 1, 0, 1.0)], [2, 1], "frame_index 5 of camera 0 is past the end"),
    ([TimestampRow(0, 0, None, 1.0), TimestampRow(0, 1, None, 1.0)], [3, 1], "1 rows for camera 0 but its video has 3"),
])
def test_tables_that_do_not_match_the_videos(rows, counts, phrase):
    with pytest.raises(ValueError, match=phrase):
        match_by_table(rows, [list(range(n)) for n in counts], counts)


def _screened(path, fps, times, found=True, count=None):
    frames = [ScreenedFrame(k, t, Sighting(found, BOX if found else None)) for k, t in enumerate(times)]
    return ScreenedVideo(VideoInfo(path, 640, 480, fps, count or len(times)), FrameSpan(), frames, length=len(times))


def test_pair_videos_by_time_by_default():
    a = _screened("a.mp4", 30.0, [k / 30 for k in range(30)])
    b = _screened("b.mp4", 15.0, [k / 15 for k in range(15)])
    assert default_tolerance([a, b]) == pytest.approx(1 / 60)
    table = pair_videos([a, b])
    assert table.by == "time" and table.contributed(1) == 15
    frames = rig_frames([a, b], table, max_frames=100)
    assert [len(r) for r in frames.refs] == [30, 15]
    assert frames.table.index[1][:3] == [0, None, 1]


def test_recordings_that_do_not_overlap_are_refused():
    a = _screened("a.mp4", 30.0, [k / 30 for k in range(30)])
    b = _screened("b.mp4", 30.0, [20 + k / 30 for k in range(30)])
    with pytest.raises(ValueError, match="do not overlap in time"):
        pair_videos([a, b])


def test_videos_without_timestamps_pair_by_index_at_one_rate_only():
    a = _screened("a.mp4", 30.0, [0.0] * 5)
    b = _screened("b.mp4", 30.0, [0.0] * 4)
    assert pair_videos([a, b]).by == "index"
    c = _screened("c.mp4", 15.0, [0.0] * 4)
    with pytest.raises(ValueError, match="frame rates differ"):
        pair_videos([a, c])


def test_rig_frames_follow_the_table_and_keep_its_times():
    a = _screened("a.mp4", 30.0, [k / 30 for k in range(4)])
    b = _screened("b.mp4", 30.0, [k / 30 for k in range(4)])
    rows = [TimestampRow(s, c, s + c, 100.0 + s + 0.01 * c) for s in range(3) for c in range(2)]
    table = pair_videos([a, b], table=rows)
    frames = rig_frames([a, b], table, max_frames=10)
    assert frames.table.labels == ["0", "1", "2"]
    assert [r.index for r in frames.refs[1]] == [1, 2, 3]
    assert frames.table.times[1][0] == pytest.approx(100.01)
    record = frames.records(0)[0]
    assert record["frames"][3]["reason"] == "not in the timestamps table"
