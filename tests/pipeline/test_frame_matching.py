"""Frame matching across a rig's cameras (ccs_kornia.pipeline.frame_matching): by the last number in the names, else by order."""

from __future__ import annotations

from ccs_kornia.pipeline.frame_matching import (
    FrameTable,
    frame_number,
    match_frames,
    natural_key,
)


def test_frame_number_is_the_last_number_of_the_name():
    assert frame_number("cams/left07.jpg") == 7
    assert frame_number("/data/cam2/frame_0123.png") == 123  # the folder's number does not count
    assert frame_number("img_2024_0005.tif") == 5
    assert frame_number("board.png") is None


def test_match_by_number_pairs_left_and_right_names():
    left = [f"l/left{k:02d}.jpg" for k in (1, 2, 3)]
    right = [f"r/right{k:02d}.jpg" for k in (3, 1, 2)]  # another order on disk
    table = match_frames([left, right])
    assert table.by == "number" and table.labels == ["01", "02", "03"]
    assert table.files([left, right]) == [left, ["r/right01.jpg", "r/right02.jpg", "r/right03.jpg"]]


def test_match_by_number_in_per_camera_folders():
    paths = [[f"cam{c}/frame_{k:04d}.png" for k in (10, 11, 12)] for c in range(3)]
    table = match_frames(paths)
    assert table.labels == ["0010", "0011", "0012"] and table.index == [[0, 1, 2]] * 3


def test_missing_frames_are_allowed_and_reported():
    left = [f"left{k:02d}.jpg" for k in (1, 2, 3, 4)]
    right = [f"right{k:02d}.jpg" for k in (2, 4, 5)]
    table = match_frames([left, right])
    assert table.labels == ["01", "02", "03", "04", "05"]
    assert table.index == [[0, 1, 2, 3, None], [None, 0, None, 1, 2]]
    assert table.missing(0) == ["05"] and table.missing(1) == ["01", "03"]


def test_names_without_numbers_match_by_natural_order():
    left = ["a/b.png", "a/a.png", "a/c.png"]
    right = ["b/x.png", "b/y.png"]
    table = match_frames([left, right])
    assert table.by == "order" and table.labels == ["0", "1", "2"]
    assert table.files([left, right]) == [["a/a.png", "a/b.png", "a/c.png"], ["b/x.png", "b/y.png", None]]


def test_repeated_numbers_fall_back_to_order():
    # two files of one camera share the number 1: numbers cannot tell the frames apart
    table = match_frames([["x1.png", "y1.png"], ["x1.png", "x2.png"]])
    assert table.by == "order"
    assert sorted(["img10.png", "img9.png"], key=natural_key) == ["img9.png", "img10.png"]


def test_frame_table_of_one_frame():
    t = FrameTable(["0"], [[0], [None]], "order")
    assert t.num_frames == 1 and t.missing(1) == ["0"]
