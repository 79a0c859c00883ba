"""The corners file ``detect`` writes, read back: every field it holds, and one-line refusals of other files."""

from __future__ import annotations

import json
import math
import re

import pytest
import torch

from ccs_kornia.io.corners_file import CornersFile, read_corners_file
from ccs_kornia.runtime.errors import UserError


def _write(tmp_path, data, name="corners.json"):
    path = tmp_path / name
    path.write_text(json.dumps(data) if not isinstance(data, str) else data)
    return str(path)


def _detect_json():
    return {
        "board": [3, 2],
        "detector": "charuco",
        "charuco": {"squares": [4, 3], "dictionary": "DICT_4X4_50"},
        "images": [
            {"path": "cam.mp4#0", "found": True, "image_size": [640, 480], "timestamp": 0.0333,
             "corners": [[1.5, 2.25], [3, 4], [None, None], [5, 6], [7, 8], [9.125, 10]],
             "corner_sigma": [0.01, 0.02, None, 0.03, 0.04, 0.05], "method": "learned", "hidden_corners": 1},
            {"path": "cam.mp4#7", "found": False, "image_size": [640, 480], "timestamp": 0.2333,
             "reason": "board not found"},
            {"path": "broken.png", "found": False, "reason": "unreadable: not an image"},
        ],
        "distortion_correction": {"enabled": True, "correction": [1.0, 0.0, 0.1, 0.0, 0.0]},
    }


def test_every_field_is_read(tmp_path):
    cf = read_corners_file(_write(tmp_path, _detect_json()))
    assert isinstance(cf, CornersFile)
    assert cf.board == (3, 2) and cf.image_size == (640, 480)
    assert cf.charuco == {"squares": [4, 3], "dictionary": "DICT_4X4_50"} and cf.aprilgrid is None
    assert cf.timestamps == [0.0333, 0.2333, None]
    first, missed, broken = cf.views
    assert first.path == "cam.mp4#0" and first.found and first.reason == "learned" and first.readable
    assert first.corners.dtype == torch.float64 and first.corners.shape == (6, 2)
    assert first.corners[0].tolist() == [1.5, 2.25] and first.corners[5].tolist() == [9.125, 10.0]
    assert first.corners[2].isnan().all() and first.corners[[0, 1, 3, 4, 5]].isfinite().all()
    assert first.sigma[1].item() == 0.02 and math.isnan(first.sigma[2].item())
    assert not missed.found and missed.corners.isnan().all() and missed.reason == "board not found"
    assert missed.image_size == (640, 480) and missed.readable
    assert not broken.readable and broken.image_size is None and broken.timestamp is None
    assert cf.corners.shape == (3, 6, 2)
    assert cf.correction.tolist() == [1.0, 0.0, 0.1, 0.0, 0.0]


def test_image_size_from_the_views_or_none(tmp_path):
    data = _detect_json()
    data["images"][1]["image_size"] = [320, 240]
    assert read_corners_file(_write(tmp_path, data)).image_size == (640, 480)  # the views with a board decide
    data["image_size"] = [800, 600]
    assert read_corners_file(_write(tmp_path, data)).image_size == (800, 600)  # the file's own first
    for image in data["images"]:
        image.pop("image_size", None)
    del data["image_size"]
    assert read_corners_file(_write(tmp_path, data)).image_size is None


@pytest.mark.parametrize(
    "data, phrase",
    [
        ("{not json", "not a JSON file"),
        ([1, 2], "not the corners file detect writes"),
        ({"K": [[1, 0, 0]], "board": [9, 6], "views": []}, "a calibration, not the corners file detect writes"),
        ({"board": [9], "images": []}, "board is [9], not [cols, rows]"),
        ({"board": [3, 2], "images": {}}, "images is not a list"),
        ({"board": [3, 2], "images": [{"path": "a.png"}]}, "images[0] is not a view of detect's"),
        ({"board": [3, 2], "images": [{"path": "a.png", "found": True, "corners": [[1, 2]]}]},
         "images[0] (a.png): 1 corners for a board of 6"),
        ({"board": [2, 2], "images": [{"path": "a.png", "found": True, "corners": [[1, "x"], [1, 2], [1, 2], [1, 2]]}]},
         "a corner is not [x, y]"),
        ({"board": [2, 2], "images": [{"path": "a.png", "found": False, "timestamp": "soon"}]}, "timestamp 'soon'"),
        ({"board": [2, 2], "image_size": [640], "images": []}, "image_size is [640]"),
    ],
)
def test_other_files_are_refused_in_one_line(tmp_path, data, phrase):
    path = _write(tmp_path, data)
    with pytest.raises(UserError) as err:
        read_corners_file(path)
    message = str(err.value)
    assert message.startswith(f"--corners {path}: ") and phrase in message and "\n" not in message


def test_a_missing_file_is_one_line(tmp_path):
    with pytest.raises(UserError, match=r"cannot read \(No such file"):
        read_corners_file(str(tmp_path / "none.json"))


def _vnl(rows):
    return "# filename x y level\n" + "\n".join(rows) + "\n"


def test_mrcal_vnl_is_read_with_its_levels(tmp_path):
    rows = [f"f0.jpg {x} {y} {lv}" for x, y, lv in ((1, 2, 0), (3, 4, 1), (5, 6, "-"), (7, 8, 2))]
    rows += ["f1.jpg - -", "f2.jpg 1.5 2 0", "f2.jpg 3 4 0", "f2.jpg 5 6 0", "f2.jpg 7 8.25 0"]
    cf = read_corners_file(_write(tmp_path, _vnl(rows), "corners.vnl"), (2, 2))
    assert cf.board == (2, 2) and cf.image_size is None
    assert [v.path for v in cf.views] == ["f0.jpg", "f1.jpg", "f2.jpg"]
    assert [v.found for v in cf.views] == [True, False, True]
    assert cf.views[0].corners[:2].tolist() == [[1.0, 2.0], [3.0, 4.0]]
    assert cf.views[0].corners[2].isnan().all() and cf.views[1].corners.isnan().all()
    # mrcal weighs a residual by 0.5 ** level: a standard deviation of 2 ** level
    assert cf.views[0].sigma[[0, 1, 3]].tolist() == [1.0, 2.0, 4.0] and math.isnan(cf.views[0].sigma[2])
    assert cf.views[2].corners[3].tolist() == [7.0, 8.25]


@pytest.mark.parametrize("rows, phrase", [
    (["a.jpg 1 2 0", "a.jpg 3 4 0", "a.jpg 5 6 0"], "3 corners for a 2x2 board"),
    (["a.jpg 1 2 0", "b.jpg 1 2 0", "a.jpg 3 4 0"], "the corners of a.jpg are not together"),
    (["a.jpg 1 x 0", "a.jpg 3 4 0", "a.jpg 5 6 0", "a.jpg 7 8 0"], "'x' is not a number"),
    (["a.jpg 1 2 0 9 9"], "expected filename x y [level]"),
])
def test_bad_vnl_is_refused_in_one_line(tmp_path, rows, phrase):
    with pytest.raises(UserError, match="--corners .*" + re.escape(phrase)):
        read_corners_file(_write(tmp_path, _vnl(rows), "corners.vnl"), (2, 2))


def test_vnl_needs_the_board(tmp_path):
    with pytest.raises(UserError, match="does not say its board"):
        read_corners_file(_write(tmp_path, _vnl(["a.jpg - -"]), "corners.vnl"))
