"""``undistort``: the view framed within the lens's valid field, for pinhole and fisheye calibrations.

Synthetic calibrations check the options (``--balance`` for pinhole models, ``--fov`` clamped, the two exclusive);
the real fisheye sets check that the written view shows the board with straight rows and no black border.
"""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch
from _real_data import REAL_DATA

from ccs_kornia import cli
from ccs_kornia.geometry.camera import Camera
from ccs_kornia.geometry.models import FISHEYE
from ccs_kornia.modules.undistort import valid_radius, view_camera_matrix

SIZE = (320, 240)


def run(capsys, *argv: str) -> tuple[int, str, str]:
    code = cli.main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


@pytest.fixture
def white(tmp_path) -> str:
    path = tmp_path / "white.png"
    cv2.imwrite(str(path), np.full((SIZE[1], SIZE[0]), 255, np.uint8))
    return str(path)


def _calibration(tmp_path: Path, model: str, K: list, coeffs: list) -> str:
    path = tmp_path / f"{model}.json"
    path.write_text(json.dumps({"image_size": list(SIZE), "K": K, "distortion": {"model": model, "coeffs": coeffs}}))
    return str(path)


def _black(path: Path) -> float:
    return float((cv2.imread(str(path), cv2.IMREAD_GRAYSCALE) == 0).mean())


def test_no_image_undistorted_leaves_no_folder(tmp_path, capsys):
    calib = _calibration(tmp_path, "opencv5", [[210.0, 0, 161.0], [0, 208.0, 118.0], [0, 0, 1]], [0.0] * 5)
    (tmp_path / "broken.png").write_bytes(b"not a png")
    code, _, err = run(capsys, "undistort", str(tmp_path / "broken.png"), "--calibration", calib, "--out-dir",
                       str(tmp_path / "out"))
    assert code == 2 and "no image undistorted" in err, err
    assert not (tmp_path / "out").exists()  # a usage error writes nothing, not even an empty folder


def test_pinhole_calibration_honours_balance(white, tmp_path, capsys):
    calib = _calibration(tmp_path, "opencv5", [[210.0, 0, 161.0], [0, 208.0, 118.0], [0, 0, 1]], [-0.3, 0.1, 0, 0, 0])
    black = {}
    for balance in ("0", "0.5", "1"):
        code, _, err = run(capsys, "undistort", white, "--calibration", calib, "--out-dir", str(tmp_path / balance),
                           "--balance", balance)
        assert code == 0, err
        assert f"(--balance {balance})" in err
        black[balance] = _black(tmp_path / balance / "white.png")
    assert black["0"] == 0.0 < black["0.5"] < black["1"]


def test_fov_is_clamped_to_the_valid_field_with_a_warning(white, tmp_path, capsys):
    calib = _calibration(tmp_path, "fisheye", [[200.0, 0, 159.5], [0, 200.0, 119.5], [0, 0, 1]], [0.0, 0.0, 0.0, 0.0])
    code, _, err = run(capsys, "undistort", white, "--calibration", calib, "--out-dir", str(tmp_path / "a"), "--fov", "60")
    assert code == 0 and "horizontal field of view 60.0 degrees" in err and "clamped" not in err
    code, _, err = run(capsys, "undistort", white, "--calibration", calib, "--out-dir", str(tmp_path / "b"), "--fov", "175")
    warning = [line for line in err.splitlines() if "warning" in line]
    assert code == 0 and len(warning) == 1 and "--fov 175 clamped to" in warning[0], err
    # an equidistant lens (r = f theta): the image corners, 199.3 px = 0.9965 rad from the centre, reach farthest
    # sideways on the normalised plane, x = tan(0.9965) 159.5 / 199.3 = 1.237: 2 atan(1.237) = 102.1 degrees across
    assert "clamped to 102.1 degrees" in warning[0]


@pytest.mark.parametrize("argv", [("--fov", "0"), ("--fov", "180"), ("--fov", "wide"), ("--fov", "90", "--balance", "1")])
def test_bad_framing_options_are_refused(white, tmp_path, capsys, argv):
    calib = _calibration(tmp_path, "fisheye", [[100.0, 0, 159.5], [0, 100.0, 119.5], [0, 0, 1]], [0.0, 0.0, 0.0, 0.0])
    code, _, err = run(capsys, "undistort", white, "--calibration", calib, "--out-dir", str(tmp_path / "o"), *argv)
    assert code == 2 and "--fov" in err and not (tmp_path / "o").exists()


# ----------------------------------------------------------------------------------------------
# the real fisheye sets
# ----------------------------------------------------------------------------------------------

FISHEYE_SETS = {"ros_fisheye_mono": "8x6", "boofcv_fisheye_chessboard": "6x4", "udacity_gopro_wide": "8x6"}


@pytest.fixture(scope="module")
def fisheye_calibrations(tmp_path_factory):
    """One ``--model fisheye`` calibration per real fisheye set, computed once (the sets it cannot find are None)."""
    out = {}
    for name, board in FISHEYE_SETS.items():
        folder = REAL_DATA / name
        if not folder.is_dir():
            out[name] = None
            continue
        path = tmp_path_factory.mktemp(name) / "calib.json"
        code = cli.main(["calibrate", str(folder), "--board", board, "--model", "fisheye", "--no-diagnostics",
                         "--jobs", "1", "--output", str(path)])
        assert code == 0, name
        out[name] = path
    return out


def _line_deviation(grid: np.ndarray) -> float:
    """Largest distance (px) of a corner from the straight line fitted to its row or column."""
    worst = 0.0
    for line in list(grid) + list(grid.transpose(1, 0, 2)):
        line = line[np.isfinite(line).all(-1)]
        if len(line) < 3:
            continue
        centred = line - line.mean(0)
        normal = np.linalg.svd(centred)[2][1]
        worst = max(worst, float(np.abs(centred @ normal).max()))
    return worst


@pytest.mark.slow
@pytest.mark.parametrize("name", list(FISHEYE_SETS))
def test_fisheye_view_shows_the_board_straight_without_black_border(fisheye_calibrations, name, tmp_path, capsys):
    """At ``--balance 0`` the two most central boards are inside the view, their rows and columns straight within
    1 px, and under 5 % of the pixels black; ``--balance 1`` shows more. (The view holds the central field: a
    board at the rim of a 180-degree lens cannot be in it, which is why the central boards are the ones checked.)"""
    if fisheye_calibrations[name] is None:
        pytest.skip(f"real data set not present at {REAL_DATA / name} (set CCS_REAL_DATA to the real sets' folder)")
    data = json.loads(Path(fisheye_calibrations[name]).read_text())
    assert data["distortion"]["model"] == "fisheye"
    K, D = torch.tensor(data["K"], dtype=torch.float64), torch.tensor(data["distortion"]["coeffs"], dtype=torch.float64)
    size = tuple(data["image_size"])
    cols, rows = data["board"]
    used = [v for v in data["views"] if v["used"]]
    corners = [torch.tensor(np.array(v["corners"], dtype=np.float64)) for v in used]
    seen = torch.cat(corners)[None]
    # the boards nearest the axis: smallest largest corner angle
    camera = Camera.from_opencv(FISHEYE, K, D)
    reach = [float(torch.nan_to_num(valid_radius(camera, c[None]), nan=float("inf"))) for c in corners]
    chosen = sorted(range(len(used)), key=reach.__getitem__)[:2]
    field = valid_radius(camera, seen)
    focal = {}
    for balance in ("0", "1"):
        out_dir = tmp_path / balance
        code, out, err = run(capsys, "undistort", *[used[i]["path"] for i in chosen], "--calibration",
                             str(fisheye_calibrations[name]), "--out-dir", str(out_dir), "--balance", balance)
        assert code == 0 and "undistorted 2 of 2" in out, err
        P = view_camera_matrix(camera, size, float(balance), max_radius=field)
        focal[balance] = float(P[0, 0, 0])
        assert f"f = {focal[balance]:.1f} px" in err
        for i in chosen:
            view = camera.undistort(corners[i][None], P)[0].numpy()
            visible = np.isfinite(view).all(-1)
            inside = (view[visible] >= 0).all() and (view[visible, 0] <= size[0] - 1).all() and (
                view[visible, 1] <= size[1] - 1).all()
            assert inside, (name, used[i]["path"], balance)
            deviation = _line_deviation(view.reshape(rows, cols, 2))
            assert deviation < 1.0, (name, used[i]["path"], balance, deviation)
            written = cv2.imread(str(out_dir / Path(used[i]["path"]).name), cv2.IMREAD_UNCHANGED)
            black = float((written.reshape(size[1], size[0], -1) == 0).all(-1).mean())
            if balance == "0":
                assert black < 0.05, (name, black)
    assert focal["1"] < focal["0"]  # balance 1 shows more field
