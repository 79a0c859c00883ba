"""``compare``: two calibrations of one camera, their projection difference over the image beside what their
uncertainty predicts; refusals as one line."""

from __future__ import annotations

import json

import pytest
import torch

from ccs_kornia import cli
from ccs_kornia.geometry.camera import Camera
from ccs_kornia.geometry.models import OPENCV5
from ccs_kornia.io.files import write_json
from ccs_kornia.outputs.calibration_file import camera_record_fields


def _camera(k1: float = -0.2, cx: float = 320.0) -> Camera:
    K = torch.tensor([[500.0, 0.0, cx], [0.0, 500.0, 240.0], [0.0, 0.0, 1.0]], dtype=torch.float64)
    dist = torch.tensor([k1, 0.05, 0.0, 0.0, 0.0], dtype=torch.float64)
    return Camera.from_opencv(OPENCV5, K[None], dist[None], image_size=[(640, 480)])


def _write(path, camera: Camera, sigma: float | None = 0.1) -> None:
    record = {**camera_record_fields(camera[0]), "rms": 0.2}
    if sigma is not None:
        # a 1-sigma map of 16x12 cells: small in the middle (where boards were), large at the rim
        grid = [[sigma * (1 + 20 * (abs(i - 7.5) > 6 or abs(j - 5.5) > 4)) for i in range(16)] for j in range(12)]
        record["diagnostics"] = {"uncertainty_grid_px": grid, "uncertainty_covered_px": sigma}
    write_json(path, record)


def run(capsys, *argv):
    code = cli.main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def test_same_camera_agrees(capsys, tmp_path):
    _write(tmp_path / "a.json", _camera())
    _write(tmp_path / "b.json", _camera(cx=320.3))  # a centre shift: a small rotation of the camera frame
    code, out, err = run(capsys, "compare", tmp_path / "a.json", tmp_path / "b.json", "--output", tmp_path / "d.json",
                         "--plot", tmp_path / "d.png")
    assert code == 0, err
    d = json.loads((tmp_path / "d.json").read_text())
    assert d["region_rms_px"] < 0.05 and "agree within their uncertainty" in out
    assert d["rotation_fitted_over"] == "where both saw boards" and 0 < d["region_fraction"] < 1
    assert (tmp_path / "d.png").stat().st_size > 1000


def test_different_lens_is_found(capsys, tmp_path):
    _write(tmp_path / "a.json", _camera())
    _write(tmp_path / "b.json", _camera(k1=-0.25))
    code, out, err = run(capsys, "compare", tmp_path / "a.json", tmp_path / "b.json", "--output", tmp_path / "d.json")
    assert code == 0, err
    d = json.loads((tmp_path / "d.json").read_text())
    assert d["max_px"] > 5 * d["region_rms_px"] > 0 and d["ratio"] > 2 and "what their uncertainty explains" in out
    # the largest difference is at the image's rim, where the lens bends most
    x, y = d["max_at_px"]
    assert min(x, 639 - x) < 50 or min(y, 479 - y) < 50


def test_without_uncertainty_not_judged(capsys, tmp_path):
    _write(tmp_path / "a.json", _camera(), sigma=None)
    _write(tmp_path / "b.json", _camera(k1=-0.25), sigma=None)
    code, out, err = run(capsys, "compare", tmp_path / "a.json", tmp_path / "b.json")
    assert code == 0, err
    assert "over the image" in out and "not judged" in out


@pytest.mark.parametrize("case", ["size", "rig", "missing"])
def test_refusals(capsys, tmp_path, case):
    _write(tmp_path / "a.json", _camera())
    if case == "size":
        cam = camera_record_fields(_camera()[0])
        cam["image_size"] = [1280, 960]
        write_json(tmp_path / "b.json", {**cam, "rms": 0.2})
        phrase = "different sizes"
    elif case == "rig":
        cam = {**camera_record_fields(_camera()[0]), "name": "cam0", "rms": 0.2}
        write_json(tmp_path / "b.json", {"cameras": [cam], "extrinsics": [{"name": "cam0", "R": torch.eye(3).tolist(),
                                                                           "T": [0.0, 0.0, 0.0]}]})
        phrase = "--camera"
    else:
        phrase = "no such file"
    code, out, err = run(capsys, "compare", tmp_path / "a.json", tmp_path / "b.json", "--output", tmp_path / "d.json")
    lines = [line for line in err.splitlines() if "error" in line]
    assert code == 2 and len(lines) == 1 and phrase in lines[0] and "Traceback" not in err
    assert not (tmp_path / "d.json").exists()


def test_json_against_mrcal_cameramodel(capsys, tmp_path):
    from ccs_kornia.io.cameramodel import write_cameramodel

    _write(tmp_path / "a.json", _camera())
    write_cameramodel(tmp_path / "b.cameramodel", _camera(cx=320.3)[0])  # mrcal's format (LENSMODEL_OPENCV5)
    code, out, err = run(capsys, "compare", tmp_path / "a.json", tmp_path / "b.cameramodel", "--output",
                         tmp_path / "d.json")
    assert code == 0, err
    d = json.loads((tmp_path / "d.json").read_text())
    assert d["rms_px"] < 0.05  # the same lens, the shift fitted out as a rotation
