"""Every output of every command is checked before any work: a file or folder that could not be written stops the
command at once with one line naming the option (exit status 2), nothing written, no internal error after the run."""

from __future__ import annotations

import json
import os
import stat

import numpy as np
import pytest

from ccs_kornia import cli
from ccs_kornia.commands import demo, imu_noise, rectify, undistort
from ccs_kornia.io.images import write_image
from ccs_kornia.pipeline.calibration_pipeline import CalibrationPipeline
from ccs_kornia.runtime.errors import EXIT_USAGE

#: a folder where no file can be created although it exists (root may "access" /proc for writing)
NOWHERE = "/proc"


def _no_work(*args, **kwargs):
    raise AssertionError("the command started its work before checking its outputs")


@pytest.fixture()
def folders(tmp_path):
    for name in ("a", "b"):
        (tmp_path / name).mkdir()
        assert write_image(tmp_path / name / f"{name}01.png", np.full((48, 64), 0.5, np.float32))
    rig = tmp_path / "rig.json"
    rig.write_text(json.dumps({"cameras": [{}, {}], "extrinsics": [{}, {}]}))
    return tmp_path


def _commands(root) -> list[tuple[list[str], str]]:
    a, b = str(root / "a"), str(root / "b")
    out = str(root / "out.json")
    board = ["--board", "9x6"]
    cases = [(["detect", a, *board, "--output", f"{NOWHERE}/c.json"], "--output")]
    for option, path in (("--output", f"{NOWHERE}/c.json"), ("--opencv-yaml", f"{NOWHERE}/c.yml"),
                         ("--ros-yaml", f"{NOWHERE}/c.yaml"), ("--report", f"{NOWHERE}/report")):
        extra = [] if option == "--output" else ["--output", out]
        cases.append((["calibrate", a, *board, *extra, option, path], option))
    for option, path in (("--output", f"{NOWHERE}/rig.json"), ("--opencv-yaml", f"{NOWHERE}/s.yml"),
                         ("--kalibr-yaml", f"{NOWHERE}/chain.yaml"), ("--ros-yaml-dir", f"{NOWHERE}/ros"),
                         ("--report", f"{NOWHERE}/report")):
        extra = [] if option == "--output" else ["--output", out]
        cases.append((["calibrate-rig", a, b, *board, "--model", "k1k2", *extra, option, path], option))
    cases += [
        (["undistort", a, "--calibration", str(root / "calib.json"), "--out-dir", f"{NOWHERE}/und"], "--out-dir"),
        (["rectify", a, b, "--calibration", str(root / "rig.json"), "--out-dir", f"{NOWHERE}/rect"], "--out-dir"),
        (["calibrate-many", str(root), *board, "--output", f"{NOWHERE}/m.jsonl"], "--output"),
        (["demo", "--out-dir", f"{NOWHERE}/demo"], "--out-dir"),
        (["imu-noise", str(root / "imu.csv"), "--output", f"{NOWHERE}/imu.yaml"], "--output"),
        (["imu-noise", str(root / "imu.csv"), "--output", str(root / "imu.yaml"), "--plot", f"{NOWHERE}/a.png"],
         "--plot"),
    ]
    return cases


@pytest.mark.parametrize("case", range(16))
def test_every_output_is_checked_before_any_work(folders, capsys, monkeypatch, case):
    argv, option = _commands(folders)[case]
    monkeypatch.setattr(CalibrationPipeline, "run", _no_work)
    monkeypatch.setattr(demo, "make_calibration_set", _no_work)
    for command in (undistort, rectify):
        monkeypatch.setattr(command, "read_image", _no_work)
    monkeypatch.setattr(imu_noise, "read_imu_csv", _no_work)
    calib = {"K": [[100.0, 0, 32], [0, 100, 24], [0, 0, 1]], "distortion": {"model": "k1k2", "coeffs": [0.0] * 5},
             "image_size": [64, 48]}
    (folders / "calib.json").write_text(json.dumps(calib))
    code = cli.main(argv)
    err = capsys.readouterr().err
    errors = [line for line in err.splitlines() if "error" in line]
    assert code == EXIT_USAGE, err
    assert len(errors) == 1 and option in errors[0] and "internal error" not in err, err
    assert not (folders / "out.json").exists() and not (folders / "imu.yaml").exists()


def test_the_cases_cover_every_command(folders):
    commands = {argv[0] for argv, _ in _commands(folders)}
    assert commands == {"detect", "calibrate", "calibrate-rig", "undistort", "rectify", "calibrate-many", "demo",
                        "imu-noise"}
    assert len(_commands(folders)) == 16


def _collisions(root) -> list[tuple[list[str], str]]:
    a, b = str(root / "a"), str(root / "b")
    board = ["--board", "9x6"]
    c, same = str(root / "c.json"), str(root / "same")
    link = root / "alias.json"
    link.symlink_to(root / "c.json")
    poses = str(root / "poses.csv")
    return [
        (["calibrate", a, *board, "--output", c, "--opencv-yaml", c], "--opencv-yaml"),
        (["calibrate", a, *board, "--output", same, "--report", same], "--report"),
        (["calibrate", a, *board, "--output", c, "--ros-yaml", str(link)], "--ros-yaml"),
        (["calibrate", a, *board, "--output", c, "--report", same, "--save-frames", same], "--save-frames"),
        (["calibrate-rig", a, b, *board, "--output", c, "--kalibr-yaml", c], "--kalibr-yaml"),
        (["calibrate-rig", a, b, *board, "--output", same, "--ros-yaml-dir", same], "--ros-yaml-dir"),
        (["calibrate-hand-eye", a, *board, "--robot-poses", poses, "--eye-in-hand", "--output", c, "--ros-tf", c],
         "--ros-tf"),
        (["calibrate-hand-eye", a, *board, "--robot-poses", poses, "--eye-in-hand", "--output", same,
          "--report", same], "--report"),
    ]


@pytest.mark.parametrize("case", range(8))
def test_two_outputs_naming_one_path_are_refused_before_any_work(folders, capsys, monkeypatch, case):
    argv, option = _collisions(folders)[case]
    monkeypatch.setattr(CalibrationPipeline, "run", _no_work)
    before = sorted(p.name for p in folders.iterdir())
    code = cli.main(argv)
    err = capsys.readouterr().err
    assert code == EXIT_USAGE, err
    assert len(err.strip().splitlines()) == 1 and option in err and "same path" in err, err
    assert sorted(p.name for p in folders.iterdir()) == before  # nothing written


def test_an_output_that_is_not_a_regular_file_is_refused_before_any_work(folders, capsys, monkeypatch):
    fifo = folders / "pipe.json"
    os.mkfifo(fifo)
    monkeypatch.setattr(CalibrationPipeline, "run", _no_work)
    for option in ("--output", "--opencv-yaml"):
        extra = [] if option == "--output" else ["--output", str(folders / "out.json")]
        code = cli.main(["calibrate", str(folders / "a"), "--board", "9x6", *extra, option, str(fifo)])
        err = capsys.readouterr().err
        assert code == EXIT_USAGE and option in err and "not a regular file" in err, err
        assert stat.S_ISFIFO(os.lstat(fifo).st_mode)
