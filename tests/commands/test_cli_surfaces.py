"""What a user of the command line touches: outputs (checked before the work, never stale, readable modes, reports
that replace only their own files), messages (what to fix, distinct exit statuses, unknown options named) and the
layout of the ``detect`` JSON."""

from __future__ import annotations

import json
import os
import re
import shutil

import numpy as np
import pytest
import torch
from _real_data import REAL_DATA
from test_cli import assert_one_line_error, rendered, run  # noqa: F401 (``rendered``: the shared fixture)

import ccs_kornia
from ccs_kornia import cli
from ccs_kornia.commands import _one_camera as calibrate_command
from ccs_kornia.commands import _output_paths, _wrong_board
from ccs_kornia.geometry.models import PINHOLE
from ccs_kornia.io.files import write_json
from ccs_kornia.io.images import expand_inputs, natural_key, write_image
from ccs_kornia.outputs.calibration_file import read_calibration
from ccs_kornia.runtime.errors import EXIT_NO_RESULT, EXIT_OK, EXIT_USAGE


def _no_work(*args, **kwargs):
    raise AssertionError("the command started its work before checking its outputs")


def _fast(*extra: str) -> tuple[str, ...]:
    return ("--jobs", "1", "--no-diagnostics", "--model", "opencv5", "--no-distortion-correction", *extra)


# ----------------------------------------------------------------------------------------------
# outputs
# ----------------------------------------------------------------------------------------------


def test_unwritable_output_is_refused_before_the_work(rendered, tmp_path, capsys, monkeypatch):
    folder, _, _ = rendered
    monkeypatch.setattr(calibrate_command, "make_pipeline", _no_work)
    # a folder where no file can be created although it exists (root may "access" /proc for writing)
    code, _, err = run(capsys, "calibrate", str(folder), "--board", "9x6", "--output", "/proc/c.json")
    assert code == EXIT_USAGE
    assert_one_line_error(err, "--output /proc/c.json")
    assert "internal error" not in err
    # an existing file that is not writable (simulated: chmod does not stop root)
    locked = tmp_path / "c.json"
    locked.write_text("{}")
    real_access = os.access
    monkeypatch.setattr(_output_paths.os, "access", lambda p, mode: False if str(p) == str(locked) else real_access(p, mode))
    code, _, err = run(capsys, "calibrate", str(folder), "--board", "9x6", "--output", str(locked))
    assert code == EXIT_USAGE
    assert_one_line_error(err, "the existing file is not writable")


def test_failed_run_says_it_left_the_earlier_calibration(rendered, tmp_path, capsys):
    _, files, _ = rendered
    out, report = tmp_path / "c.json", tmp_path / "report"
    out.write_text('{"earlier": true}\n')
    code, _, err = run(capsys, "calibrate", *files[:2], "--board", "9x6", "--output", str(out),
                       "--report", str(report), *_fast())
    assert code == EXIT_NO_RESULT
    assert_one_line_error(err, "the existing c.json was left as it was (not from this run)")
    assert json.loads(out.read_text()) == {"earlier": True}
    assert (tmp_path / "c.failed.json").is_file()
    assert not report.exists()  # nothing to report: the folder is not created


def test_report_replaces_only_its_own_files(rendered, tmp_path, capsys):
    _, files, _ = rendered
    out, report = tmp_path / "c.json", tmp_path / "report"
    report.mkdir()
    (report / "notes.txt").write_text("mine")
    (tmp_path / "c.failed.json").write_text("{}")  # an earlier failure's record
    code, _, _ = run(capsys, "calibrate", *files[:4], "--board", "9x6", "--output", str(out), "--report", str(report),
                     *_fast())
    assert code == 0 and not (tmp_path / "c.failed.json").exists()  # stale once a calibration is written
    first = sorted(p.name for p in (report / "views").iterdir())
    assert len(first) == 4
    (report / "views" / "my_drawing.png").write_bytes(b"x")
    code, _, _ = run(capsys, "calibrate", *files[3:], "--board", "9x6", "--output", str(out), "--report", str(report),
                     *_fast())
    assert code == 0
    views = sorted(p.name for p in (report / "views").iterdir())
    # the second report's overlays only (the shared view's name changed with its index), and the user's files
    assert len(views) == len(files) - 3 + 1 and "my_drawing.png" in views
    assert not set(first) & set(views)
    assert (report / "notes.txt").read_text() == "mine"
    listed = json.loads((report / ".ccs_report_files").read_text())
    assert "index.html" in listed and "notes.txt" not in listed


@pytest.mark.parametrize("umask, mode", [(0o022, 0o644), (0o077, 0o600)])
def test_json_gets_the_mode_of_the_umask(tmp_path, umask, mode):
    old = os.umask(umask)
    try:
        write_json(tmp_path / "a.json", {"v": 1})
    finally:
        os.umask(old)
    assert os.stat(tmp_path / "a.json").st_mode & 0o777 == mode
    # an existing file keeps its own mode, as an ordinary write leaves it
    os.chmod(tmp_path / "a.json", 0o640)
    write_json(tmp_path / "a.json", {"v": 2})
    assert os.stat(tmp_path / "a.json").st_mode & 0o777 == 0o640


# ----------------------------------------------------------------------------------------------
# messages
# ----------------------------------------------------------------------------------------------


def test_board_larger_than_given_is_said_on_the_console(rendered, tmp_path, capsys, monkeypatch):
    # the refusals the image-based test gives a sub-board (on these renders the organiser already finds no 8x6 board:
    # its verdict is forced, as the real set below shows without forcing)
    from ccs_kornia.modules.detection.learned.learned_detector import (
        LearnedChessboardDetector,
    )

    real = LearnedChessboardDetector.forward

    def refused(self, images, board_size, *args, **kwargs):
        out = real(self, images, board_size, *args, **kwargs)
        out.reasons = ["board refused: the checker pattern continues past its left side"] * len(out.reasons)
        return out

    monkeypatch.setattr(LearnedChessboardDetector, "forward", refused)
    monkeypatch.setattr(_wrong_board, "board_grid_in", lambda image: None)  # no early stop: the whole run's hint
    _, files, _ = rendered
    code, _, err = run(capsys, "calibrate", *files[:3], "--board", "8x6", "--output", str(tmp_path / "c.json"),
                       *_fast())
    assert code == EXIT_NO_RESULT
    lines = [line for line in err.splitlines() if "looks larger" in line]
    assert lines == ["ccs_kornia calibrate: warning: the board looks larger than 8x6 in 3 images: check --board "
                     "(COLSxROWS counts inner corners, where four squares meet)"]
    assert "cover" not in err  # no quality warning about a camera that was not computed


def test_board_larger_on_a_real_set(tmp_path, capsys, monkeypatch):
    folder = REAL_DATA / "opencv_left"
    if not folder.is_dir():
        pytest.skip(f"real data set not present at {folder}")
    monkeypatch.setattr(_wrong_board, "board_grid_in", lambda image: None)  # every view looked at (no early stop)
    code, _, err = run(capsys, "calibrate", str(folder), "--board", "8x6", "--output", str(tmp_path / "c.json"),
                       "--jobs", "1", "--no-diagnostics")
    assert code == EXIT_NO_RESULT
    assert "warning: the board looks larger than 8x6 in " in err and "cover" not in err
    failed = json.loads((tmp_path / "c.failed.json").read_text())
    # a 9x6 board: no view is taken for 8x6 (left14's sub-board was once, the network missing its ninth column)
    assert failed["num_views"]["found"] == 0
    assert_one_line_error(err, "board 8x6 not found in any of 13 images")


def _counting_detection(monkeypatch) -> list[int]:
    """The views the pipeline's first look detects (in this process: ``--jobs 1``)."""
    from ccs_kornia.pipeline.calibration_pipeline import CalibrationPipeline

    seen: list[int] = []
    real = CalibrationPipeline._detect_batch

    def counting(self, images, keys, *args, **kwargs):
        seen.extend(v for _, v in keys)
        return real(self, images, keys, *args, **kwargs)

    monkeypatch.setattr(CalibrationPipeline, "_detect_batch", counting)
    return seen


def test_wrong_board_is_named_after_the_first_views(rendered, tmp_path, capsys, monkeypatch):
    _, files, _ = rendered
    folder = tmp_path / "views"
    folder.mkdir()
    for k in range(12):
        shutil.copy(files[k % len(files)], folder / f"view_{k:02d}.png")
    seen = _counting_detection(monkeypatch)
    out = tmp_path / "c.json"
    code, _, err = run(capsys, "calibrate", str(folder), "--board", "10x7", "--output", str(out), "--batch-size", "2",
                       *_fast("--detector", "opencv"))
    assert code == EXIT_NO_RESULT  # as when the whole run finds no board
    assert_one_line_error(err, "board 10x7 not found in the first 6 images, but a 9x6 board is in 6 of them: check "
                               "--board")
    assert sorted(seen) == list(range(6))  # the other six views were never detected
    assert not out.exists() and not (tmp_path / "c.failed.json").exists()
    code, _, err = run(capsys, "detect", str(folder), "--board", "7x10", "--output", str(out), "--batch-size", "4",
                       "--jobs", "1", "--detector", "opencv", "--no-distortion-correction")
    assert code == EXIT_NO_RESULT  # said the way round the board was given
    assert_one_line_error(err, "board 7x10 not found in the first 6 images, but a 6x9 board is in 6 of them")
    assert not out.exists()


def test_views_without_a_board_first_do_not_stop_the_run(rendered, tmp_path, capsys, monkeypatch):
    _, files, _ = rendered
    folder = tmp_path / "views"
    folder.mkdir()
    for k in range(6):  # six views of a blank wall before the board's
        assert write_image(folder / f"view_{k:02d}.png", np.full((480, 640), 0.6, np.float32))
    for k, path in enumerate(files):
        shutil.copy(path, folder / f"view_{k + 6:02d}.png")
    seen = _counting_detection(monkeypatch)
    code, _, err = run(capsys, "calibrate", str(folder), "--board", "9x6", "--output", str(tmp_path / "c.json"),
                       "--batch-size", "2", *_fast("--detector", "opencv"))
    assert code == 0, err
    assert sorted(seen) == list(range(6 + len(files)))


CHARUCO_TUTORIAL = REAL_DATA / "charuco_opencv_tutorial"


@pytest.mark.skipif(not CHARUCO_TUTORIAL.is_dir(), reason=f"real data set not present at {CHARUCO_TUTORIAL}")
def test_allow_weak_calibrates_near_parallel_views_as_not_reliable(tmp_path, capsys):
    """OpenCV's ChArUco tutorial: four views within 6 degrees of each other. Refused (saying --allow-weak would
    calibrate them); with --allow-weak calibrated, the verdict not reliable and the 1-sigma that shows why."""
    views = sorted(str(p) for p in CHARUCO_TUTORIAL.glob("img_0*.jpg"))
    board = ("--charuco", "5x7", "--square", "0.04", "--marker", "0.02", "--jobs", "1")
    out = tmp_path / "c.json"
    code, _, err = run(capsys, "calibrate", *views, *board, "--output", str(out))
    assert code == EXIT_NO_RESULT
    assert_one_line_error(err, "nearly parallel")
    assert "--allow-weak calibrates anyway (verdict not reliable)" in err
    code, stdout, err = run(capsys, "calibrate", *views, *board, "--output", str(out), "--allow-weak")
    assert code == 0, err
    data = json.loads(out.read_text())
    assert data["success"] and data["allow_weak"] and "pose_diversity" in {e["check"] for e in data["errors"]}
    assert data["diagnostics"]["verdict"].startswith("not reliable: ")
    assert "verdict: not reliable: " in stdout and "warning: calibrated with --allow-weak although the board planes" \
        in err
    sigma = next(line for line in stdout.splitlines() if line.startswith("1-sigma of the intrinsics (px): fx "))
    assert f"± {data['std']['fx']:.1f}" in sigma and data["std"]["fx"] > 0.02 * data["K"][0][0]  # why: fx is weak


def test_allow_weak_without_diagnostics_still_says_not_reliable(tmp_path, capsys):
    from ccs_kornia.data.scenes.scenes import make_calibration_set

    K = torch.tensor([[400.0, 0.0, 160.0], [0.0, 400.0, 120.0], [0.0, 0.0, 1.0]], dtype=torch.float64)
    views = make_calibration_set(K, (7, 5), 0.025, (320, 240), num_views=5, seed=3, supersample=1, max_tilt_deg=2.0)
    for k in range(5):
        assert write_image(tmp_path / f"v{k}.png", views.images[k, 0])
    argv = ("calibrate", str(tmp_path), "--board", "7x5", "--output", str(tmp_path / "c.json"), "--jobs", "1",
            "--detector", "opencv", "--no-distortion-correction", "--model", "k1k2", "--no-diagnostics")
    code, _, err = run(capsys, *argv)
    assert code == EXIT_NO_RESULT and "--allow-weak calibrates anyway" in err
    code, stdout, err = run(capsys, *argv, "--allow-weak")
    assert code == 0, err
    assert "verdict: not reliable: " in stdout and "1-sigma of the intrinsics (px): fx" in stdout


def test_version(capsys):
    code, out, _ = run(capsys, "--version")
    assert code == EXIT_OK and out.strip() == f"ccs_kornia {ccs_kornia.__version__}"


def test_unknown_option_is_named(tmp_path, capsys):
    code, _, err = run(capsys, "calibrate", str(tmp_path), "--bord", "9x6", "--output", str(tmp_path / "c.json"))
    assert code == EXIT_USAGE
    assert_one_line_error(err, "unrecognized option --bord (did you mean --board?)")
    assert "required" not in err
    # values that look like options are not taken for unknown ones; a missing option is still reported as such
    code, _, err = run(capsys, "calibrate", str(tmp_path), "--seed", "-1", "--output", str(tmp_path / "c.json"))
    assert code == EXIT_USAGE
    assert_one_line_error(err, "the following arguments are required: --board")


def test_exit_statuses_are_listed_in_the_help(capsys):
    code, out, _ = run(capsys, "calibrate", "--help")
    assert code == 0
    listed = {int(line.split()[0]) for line in out.split("exit status:")[1].splitlines() if line.strip()}
    assert listed == {code for code, _ in cli.EXIT_CODES}
    assert len(listed) == len(cli.EXIT_CODES) and EXIT_USAGE != EXIT_NO_RESULT


def test_undistort_refuses_a_failed_calibration(rendered, tmp_path, capsys):
    _, files, _ = rendered
    failed = tmp_path / "c.failed.json"
    write_json(failed, {"success": False, "K": None, "distortion": None, "image_size": [640, 480],
                        "error": "board 9x6 not found in any of 3 images"})
    code, _, err = run(capsys, "undistort", files[0], "--calibration", str(failed), "--out-dir", str(tmp_path / "o"))
    assert code == EXIT_USAGE
    assert_one_line_error(err, "this is a failed calibration: board 9x6 not found")
    assert "TypeError" not in err and not (tmp_path / "o").exists()


def _calibration(**change):
    data = {"success": True, "image_size": [640, 480], "K": [[500.0, 0, 320], [0, 500.0, 240], [0, 0, 1]],
            "distortion": {"model": "opencv5", "coeffs": [0.1, 0.0, 0.0, 0.0, 0.0]}}
    data.update(change)
    return data


@pytest.mark.parametrize(
    "data, phrase",
    [
        ({"K": [[1, 0, 0], [0, 1, 0], [0, 0, 1]]}, '"distortion" is missing'),
        (_calibration(image_size=None), '"image_size" is missing'),
        (_calibration(K=[[1, 0], [0, 1]]), "K must be a 3x3 matrix"),
        (_calibration(K=[[-500.0, 0, 320], [0, 500.0, 240], [0, 0, 1]]), "focal lengths fx -500, fy 500"),
        (_calibration(distortion={"model": "brown", "coeffs": [0.1]}), "unknown distortion model 'brown'"),
        (_calibration(distortion={"model": "fisheye", "coeffs": [0.1, 0.0, 0.0, 0.0, 0.0]}),
         "the fisheye model has 4 finite distortion coefficients, the file gives 5"),
        (_calibration(image_size=[640]), "image_size must be [width, height]"),
        ({"success": False, "error": "only 2 usable view(s)"}, "this is a failed calibration: only 2 usable"),
    ],
)
def test_calibration_file_checks(tmp_path, data, phrase):
    path = tmp_path / "c.json"
    write_json(path, data)
    with pytest.raises(ValueError, match=re.escape(phrase)):
        read_calibration(path)


def test_calibration_file_reads_what_calibrate_writes(tmp_path):
    write_json(tmp_path / "c.json", _calibration(distortion={"model": "none", "coeffs": []}))
    camera = read_calibration(tmp_path / "c.json").camera
    assert camera.model == PINHOLE and camera.image_size == (640, 480)
    assert camera.K.shape == (1, 3, 3) and camera.coeffs(0).numel() == 0


# ----------------------------------------------------------------------------------------------
# the detect JSON and the order of the files
# ----------------------------------------------------------------------------------------------


def test_files_in_natural_order(tmp_path):
    names = [f"calibration{k}.png" for k in (10, 2, 1, 11, 3)]
    for name in names:
        (tmp_path / name).write_bytes(b"")
    files, _ = expand_inputs([str(tmp_path)])
    assert [os.path.basename(f) for f in files] == [f"calibration{k}.png" for k in (1, 2, 3, 10, 11)]
    files, _ = expand_inputs([str(tmp_path / "*.png")])
    assert [os.path.basename(f) for f in files] == [f"calibration{k}.png" for k in (1, 2, 3, 10, 11)]
    assert sorted(["b1", "a10", "a9"], key=natural_key) == ["a9", "a10", "b1"]


def test_detect_json_is_compact_and_in_natural_order(rendered, tmp_path, capsys):
    _, files, _ = rendered
    folder = tmp_path / "set"
    folder.mkdir()
    for k in range(1, 11):  # calibration1 ... calibration10, copies of the rendered views
        shutil.copy(files[(k - 1) % len(files)], folder / f"calibration{k}.png")
    out = tmp_path / "corners.json"
    code, _, _ = run(capsys, "detect", str(folder), "--board", "9x6", "--output", str(out), "--jobs", "1",
                     "--no-distortion-correction")
    assert code == 0
    text = out.read_text()
    data = json.loads(text)
    assert [os.path.basename(im["path"]) for im in data["images"]] == [f"calibration{k}.png" for k in range(1, 11)]
    assert len(text.splitlines()) < 10 * len(data["images"])  # a few lines an image, not one a coordinate
    for im in data["images"]:
        assert im["found"] and not {"used", "rms"} & set(im)
        xy = np.array(im["corners"])
        np.testing.assert_array_equal(xy, np.round(xy, 4))  # 1e-4 px
        # one line, a point as [x, y]
        assert f'"corners": {json.dumps(im["corners"])}' in {line.strip().rstrip(",") for line in text.splitlines()}
