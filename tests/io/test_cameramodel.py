"""mrcal's ``.cameramodel`` files: a splined camera and OpenCV's written and read back unchanged, mrcal's published
files read, the calibration reader and ``compare`` taking them, and a splined calibration record with its closest
OpenCV camera."""

from __future__ import annotations

import ast

import pytest
import torch

from ccs_kornia.geometry.camera import Camera
from ccs_kornia.geometry.models import (
    FISHEYE,
    K1K2,
    RATIONAL,
    SplinedStereographicModel,
)
from ccs_kornia.io.cameramodel import (
    cameramodel_text,
    read_cameramodel,
    write_cameramodel,
)
from ccs_kornia.outputs.calibration_file import (
    camera_from_record,
    camera_record_fields,
    read_calibration,
)
from ccs_kornia.outputs.camera_exports import opencv_record
from ccs_kornia.outputs.records import opencv_equivalent

F64 = torch.float64


def _splined() -> Camera:
    model = SplinedStereographicModel(8, 6, 150)
    g = torch.Generator().manual_seed(0)
    values = 0.01 * torch.randn(model.num_coeffs, generator=g, dtype=F64)
    return Camera(model, torch.cat([torch.tensor([300.0, 302, 319.5, 241], dtype=F64), values]), (640, 480))


def test_splined_round_trip(tmp_path):
    cam = _splined()
    path = tmp_path / "cam.cameramodel"
    write_cameramodel(path, cam, [0.1, 0, 0, 0.2, 0, 0], note="written by a test")
    data = ast.literal_eval(path.read_text()[path.read_text().index("{"):])  # mrcal's format: a Python literal
    assert data["lensmodel"] == "LENSMODEL_SPLINED_STEREOGRAPHIC_order=3_Nx=8_Ny=6_fov_x_deg=150"
    assert data["imagersize"] == [640, 480] and len(data["intrinsics"]) == 4 + 2 * 8 * 6
    back, extrinsics = read_cameramodel(path)
    assert back.model == cam.model and back.image_size == (640, 480) and extrinsics == [0.1, 0, 0, 0.2, 0, 0]
    torch.testing.assert_close(back.params, cam.params, rtol=0, atol=0)
    torch.testing.assert_close(read_calibration(path).camera.params, cam.params, rtol=0, atol=0)


def test_opencv_round_trip_and_fisheye_refused(tmp_path):
    K = torch.tensor([[500.0, 0, 320], [0, 505, 240], [0, 0, 1]], dtype=F64)
    for model, coeffs, name in ((K1K2, [-0.1, 0.01], "LENSMODEL_OPENCV4"),
                                (RATIONAL, [0.1, 0.02, 1e-4, -1e-4, 0.001, 0.2, 0.03, 0.001], "LENSMODEL_OPENCV8")):
        cam = Camera.from_opencv(model, K, torch.tensor(coeffs, dtype=F64), (640, 480))
        assert f"'{name}'" in cameramodel_text(cam)
        write_cameramodel(tmp_path / "c.cameramodel", cam)
        back, _ = read_cameramodel(tmp_path / "c.cameramodel")
        q = torch.tensor([[[10.0, 20.0], [600.0, 400.0]]], dtype=F64)
        torch.testing.assert_close(back.project(cam.unproject(q)), q)  # the same lens (k1k2 read as opencv5)
    with pytest.raises(ValueError, match="mrcal has no fisheye model"):
        cameramodel_text(Camera.from_opencv(FISHEYE, K, torch.zeros(4, dtype=F64), (640, 480)))


def test_splined_record_and_its_opencv_equivalent():
    cam = _splined()
    fields = camera_record_fields(cam)
    assert fields["distortion"]["model"] == cam.model.name
    torch.testing.assert_close(camera_from_record(fields).params, cam.params)
    equivalent = opencv_equivalent(cam)
    assert equivalent["distortion"]["model"] == "rational"
    assert 0 <= equivalent["departure_rms_px"] <= equivalent["departure_max_px"]
    assert len(equivalent["departure_grid_px"]) == 12 and len(equivalent["departure_grid_px"][0]) == 16
    record = opencv_record({**fields, "opencv_equivalent": equivalent})
    assert camera_from_record(record).model == RATIONAL  # what --opencv-yaml and --ros-yaml write
