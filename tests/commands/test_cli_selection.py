"""The frame selection on the command line: ``--select`` for recordings and image folders, ``--max-frames`` as
its cap, the JSON's reasons for every candidate left out, ``--save-frames`` (the kept frames calibrate again as a
folder), a rig's frames judged across its cameras, and the bad uses (one line, exit status 2)."""

from __future__ import annotations

import json

import pytest
from _videos import BOARD, K_VIDEO, board_frames, write_video

from ccs_kornia import cli
from ccs_kornia.io.images import write_image

FAST = ["--board", f"{BOARD[0]}x{BOARD[1]}", "--detector", "opencv", "--no-distortion-correction", "--jobs", "1"]
SOLVE = ["--square", "0.025", "--model", "k1k2", "--no-ransac"]
ONE = [*SOLVE, "--no-diagnostics"]  # calibrate only


def run(capsys, *argv) -> tuple[int, str, str]:
    code = cli.main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


@pytest.fixture(scope="module")
def inputs(tmp_path_factory):
    """A recording, the same frames as a folder of images, and a rig's second camera 4 cm to the side."""
    root = tmp_path_factory.mktemp("selection")
    frames = board_frames(30, seed=6)
    folder = root / "images"
    folder.mkdir()
    for k, frame in enumerate(frames):
        assert write_image(folder / f"img{k:02d}.png", frame)
    return {"video": write_video(str(root / "cam.avi"), frames), "folder": str(folder),
            "right": write_video(str(root / "right.avi"), board_frames(30, seed=6, shift=(-0.04, 0.0, 0.0)))}


def test_a_recording_is_selected_on_request(inputs, tmp_path, capsys):
    code, out, err = run(capsys, "calibrate", inputs["video"], *FAST, *ONE, "--select", "--output",
                         tmp_path / "c.json")
    assert code == 0, err
    data = json.loads((tmp_path / "c.json").read_text())
    selection = data["selection"]
    used = [v for v in data["views"] if v["used"]]
    assert selection["kept"] >= len(used) >= 3 and selection["candidates"] == sum(v["found"] for v in data["views"])
    left = [v for v in data["views"] if v.get("reason", "").startswith("left out by the frame selection: ")]
    assert len(left) == selection["candidates"] - selection["kept"]
    assert {f["frame"] for f in selection["frames"] if not f["kept"]} == {v["path"] for v in left}
    assert all(f["reason"].split(" (")[0].split(" of ")[0] in ("adds nothing", "near copy", "moving", "blurred")
               for f in selection["frames"] if not f["kept"])
    assert abs(data["K"][0][0] - K_VIDEO[0, 0]) < 3
    assert f"frame selection: kept {selection['kept']} of {selection['candidates']} candidate frames" in out


@pytest.mark.parametrize("flag", [(), ("--no-select",)], ids=["default", "no-select"])
def test_without_the_selection_every_frame_counts(inputs, tmp_path, capsys, flag):
    code, out, err = run(capsys, "calibrate", inputs["video"], *FAST, *ONE, *flag, "--output", tmp_path / "c.json")
    assert code == 0, err
    data = json.loads((tmp_path / "c.json").read_text())
    assert "selection" not in data and "frame selection" not in out
    assert sum(v["used"] for v in data["views"]) == sum(v["found"] for v in data["views"])


def test_max_frames_caps_the_frames_kept(inputs, tmp_path, capsys):
    code, _out, err = run(capsys, "calibrate", inputs["video"], *FAST, *ONE, "--select", "--max-frames", "4", "--output",
                         tmp_path / "c.json")
    assert code == 0, err
    data = json.loads((tmp_path / "c.json").read_text())
    assert data["selection"]["kept"] <= 4 and data["selection"]["candidates"] <= 6  # the detector saw 1.5 x 4
    assert sum(v["used"] for v in data["views"]) == data["selection"]["kept"]
    left = [f["reason"] for f in data["selection"]["frames"] if not f["kept"]]
    assert len(left) == data["selection"]["candidates"] - data["selection"]["kept"]
    assert all(r == "over --max-frames" or r.split(" (")[0].split(" of ")[0] in ("adds nothing", "near copy", "moving",
               "blurred") for r in left)


def test_a_folder_with_select_and_its_frames_saved(inputs, tmp_path, capsys):
    saved = tmp_path / "kept"
    code, out, err = run(capsys, "calibrate", inputs["folder"], *FAST, *ONE, "--select", "--save-frames", saved,
                         "--output", tmp_path / "c.json")
    assert code == 0, err
    data = json.loads((tmp_path / "c.json").read_text())
    used = sorted(v["path"].rsplit("/", 1)[1] for v in data["views"] if v["used"])
    assert sorted(p.name for p in saved.iterdir()) == used and data["saved_frames"]["files"] == len(used)
    assert f"wrote the {len(used)} frames used to {saved}" in out
    # the frames kept, calibrated again as a folder, give the same camera
    code, out, err = run(capsys, "calibrate", saved, *FAST, *ONE, "--output", tmp_path / "again.json")
    assert code == 0, err
    again = json.loads((tmp_path / "again.json").read_text())
    flat = [[x for row in d["K"] for x in row] for d in (again, data)]
    assert flat[0] == pytest.approx(flat[1], rel=1e-6) and "selection" not in again


def test_save_frames_of_a_recording_and_of_a_rig(inputs, tmp_path, capsys):
    code, _out, err = run(capsys, "calibrate", inputs["video"], *FAST, *ONE, "--select", "--save-frames",
                         tmp_path / "one", "--output", tmp_path / "c.json")
    assert code == 0, err
    names = sorted(p.name for p in (tmp_path / "one").iterdir())
    assert names and all(n.startswith("cam_") and n.endswith(".png") for n in names)
    rig = tmp_path / "rig"
    code, _out, err = run(capsys, "calibrate-rig", inputs["video"], inputs["right"], *FAST, *SOLVE, "--select",
                          "--save-frames", rig, "--output", tmp_path / "rig.json")
    assert code == 0, err
    data = json.loads((tmp_path / "rig.json").read_text())
    selection = data["selection"]
    assert len(data["frame_labels"]) == selection["kept"] and selection["candidates"] >= selection["kept"]
    left, right = (sorted(p.name for p in (rig / n).iterdir()) for n in ("cam0", "cam1"))
    # one name per instant kept, the same in every camera (the folders pair again by number); a view blurred in one
    # camera only is left out of that camera's folder
    assert len(set(left) | set(right)) == selection["kept"] and len(set(left) & set(right)) >= 3
    assert len(left) + len(right) == data["saved_frames"]["files"] == \
        sum(v["used"] for cam in data["cameras"] for v in cam["views"])
    code, _out, err = run(capsys, "calibrate-rig", rig / "cam0", rig / "cam1", *FAST, *SOLVE, "--output",
                         tmp_path / "again.json")
    assert code == 0, err
    again = json.loads((tmp_path / "again.json").read_text())
    assert abs(again["pairs"][0]["baseline"] - data["pairs"][0]["baseline"]) < 1e-3


def test_save_frames_needs_the_selection(inputs, tmp_path, capsys):
    code, _out, err = run(capsys, "calibrate", inputs["folder"], *FAST, *ONE, "--save-frames", tmp_path / "f",
                         "--output", tmp_path / "c.json")
    lines = [line for line in err.splitlines() if "error" in line]
    assert code == 2 and len(lines) == 1 and "--save-frames" in lines[0] and "--select" in lines[0]
    assert not (tmp_path / "c.json").exists() and not (tmp_path / "f").exists()
