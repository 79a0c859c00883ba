"""undistort_image: images of any model to pinhole views, against cv2.undistort and cv2.fisheye.undistortImage."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
import torch

from ccs_kornia.data.scenes.scenes import make_calibration_set
from ccs_kornia.geometry.camera import Camera
from ccs_kornia.geometry.models import FISHEYE, OPENCV5, RATIONAL
from ccs_kornia.modules.undistort.undistort_image import (
    UndistortImage,
    undistort_image,
    undistortion_map,
)
from ccs_kornia.modules.undistort.valid_field import valid_radius
from ccs_kornia.modules.undistort.view_camera import view_camera_matrix

F64 = torch.float64
SIZE = (640, 480)
K = torch.tensor([[420.0, 0.0, 322.0], [0.0, 415.0, 236.0], [0.0, 0.0, 1.0]], dtype=F64)
K_FISH = torch.tensor([[200.0, 0, 322.0], [0, 201.0, 236.0], [0, 0, 1]], dtype=F64)
CAMERAS = {
    "opencv5": Camera.from_opencv(OPENCV5, K, torch.tensor([-0.3, 0.1, 0.001, -0.0005, 0.0]), SIZE),
    "rational": Camera.from_opencv(RATIONAL, K, torch.tensor([-0.3, 0.1, 0.001, -0.0005, 0.0, 0.02, 0.0, 0.0]), SIZE),
    "fisheye": Camera.from_opencv(FISHEYE, K_FISH, torch.tensor([-0.02, -0.005, 0.001, 0.0]), SIZE),
}


def _cv2_undistort(camera: Camera, image: np.ndarray, P: np.ndarray) -> np.ndarray:
    """OpenCV's resampling for the camera's model (the two APIs: cv2 and cv2.fisheye)."""
    K_, d = camera.K[0].numpy(), camera.dist[0].numpy()
    if camera.model.opencv_family == "fisheye":
        return cv2.fisheye.undistortImage(image, K_, d, Knew=P)
    return cv2.undistort(image, K_, d, newCameraMatrix=P)


def _smooth_image(seed: int = 0) -> np.ndarray:
    g = np.random.default_rng(seed)
    return cv2.GaussianBlur(g.random((SIZE[1], SIZE[0])), (0, 0), 3.0)  # smooth: interpolation differences small


@pytest.mark.parametrize("name", list(CAMERAS))
@pytest.mark.parametrize("balance", [None, 0.0, 1.0])
def test_matches_opencv(name, balance):
    camera = CAMERAS[name]
    P = camera.K if balance is None else view_camera_matrix(camera, SIZE, balance)
    img = _smooth_image()
    ours = undistort_image(torch.from_numpy(img)[None, None], camera, P)[0, 0].numpy()
    ref = _cv2_undistort(camera, img, P[0].numpy())
    # where the source lies 2 px inside the image (at the border cv2's 1/32-px maps blend in the black differently)
    src = undistortion_map(camera, SIZE, P)[0].numpy()
    deep = (src[..., 0] >= 2) & (src[..., 0] <= SIZE[0] - 3) & (src[..., 1] >= 2) & (src[..., 1] <= SIZE[1] - 3)
    assert deep.mean() > 0.5 and np.abs(ours - ref)[deep].max() < 2e-3
    assert ((ours == 0) != (ref == 0)).mean() < 1e-3  # the same black border


def test_a_rendered_board_matches_cv2_undistort():
    camera = CAMERAS["opencv5"]
    s = make_calibration_set(K.float(), (9, 6), 0.025, SIZE, num_views=1, supersample=1, seed=3)
    for balance in (0.0, 1.0):
        P = view_camera_matrix(camera, SIZE, balance)
        ours = undistort_image(s.images.double(), camera, P)[0, 0].numpy()
        ref = cv2.undistort(s.images[0, 0].numpy().astype(np.float32), K.numpy(), camera.dist[0].numpy(),
                            newCameraMatrix=P[0].numpy())
        inner = (slice(40, 440), slice(40, 600))
        assert np.abs(ours[inner] - ref[inner]).mean() < 2e-3
        assert (ours == 0).mean() > 0.01 if balance == 1.0 else (ours == 0).mean() == 0.0  # black corners at 1 only


@pytest.mark.parametrize("name", list(CAMERAS))
def test_rays_beyond_the_valid_field_are_black(name):
    camera = CAMERAS[name]
    radius = torch.tensor([math.tan(math.radians(30.0 if name == "fisheye" else 25.0))], dtype=F64)
    P = view_camera_matrix(camera, SIZE, 1.0, max_radius=radius * 1.5)  # a view wider than the field
    out = undistort_image(torch.ones(1, 1, SIZE[1], SIZE[0], dtype=F64), camera, P, radius)[0, 0]
    src = undistortion_map(camera, SIZE, P)[0]
    v, u = torch.meshgrid(torch.arange(SIZE[1], dtype=F64), torch.arange(SIZE[0], dtype=F64), indexing="ij")
    r = torch.hypot((u - P[0, 0, 2]) / P[0, 0, 0], (v - P[0, 1, 2]) / P[0, 1, 1])
    in_image = (src[..., 0] >= 1) & (src[..., 0] <= SIZE[0] - 2) & (src[..., 1] >= 1) & (src[..., 1] <= SIZE[1] - 2)
    assert bool((out[r > radius[0] + 1e-9] == 0).all()) and int((r > radius[0]).sum()) > 1000
    kept = out[(r < radius[0] - 1e-9) & in_image]
    assert kept.numel() > 1000 and bool(((kept - 1).abs() < 1e-9).all())


@pytest.mark.parametrize("name", list(CAMERAS))
def test_the_map_inverts_the_camera_undistort(name):
    camera = CAMERAS[name]
    P = view_camera_matrix(camera, SIZE, 0.0)
    src = undistortion_map(camera, SIZE, P, valid_radius(camera))
    assert src.shape == (1, SIZE[1], SIZE[0], 2) and src.dtype == F64
    pixels = camera.undistort(src.reshape(1, -1, 2), P).reshape(src.shape)
    grid = torch.stack(torch.meshgrid(torch.arange(SIZE[0], dtype=F64), torch.arange(SIZE[1], dtype=F64),
                                      indexing="xy"), -1)
    torch.testing.assert_close(pixels[0], grid, atol=1e-6, rtol=0)


def test_batch_one_camera_for_many_images_and_cameras_of_several_models():
    imgs = torch.rand(3, 2, 48, 64, dtype=F64)
    small = {n: Camera(c.models, torch.cat([c.params[:, :4] / 10, c.params[:, 4:]], -1), (64, 48))
             for n, c in CAMERAS.items()}
    alone = [undistort_image(imgs[i:i + 1], small[n]) for i, n in enumerate(small)]
    both = undistort_image(imgs, Camera.cat(list(small.values())))
    torch.testing.assert_close(both, torch.cat(alone), atol=1e-12, rtol=0)
    one = undistort_image(imgs, small["fisheye"])  # one camera, three images
    torch.testing.assert_close(one[2:], alone[2], atol=1e-12, rtol=0)
    assert not torch.allclose(one[0], alone[0])


def test_module_keeps_its_map_and_matches_the_function():
    camera = CAMERAS["fisheye"]
    radius = valid_radius(camera)
    P = view_camera_matrix(camera, SIZE, 0.5, max_radius=radius)
    undistort = UndistortImage(camera, P, radius)
    imgs = torch.rand(2, 1, SIZE[1], SIZE[0], dtype=F64)
    out = undistort(imgs)
    assert torch.equal(out, undistort_image(imgs, camera, P, radius))
    assert len(undistort._maps) == 1 and torch.equal(undistort(imgs[1:]), out[1:])


def test_device_and_dtype(device, dtype):
    camera = CAMERAS["opencv5"]
    img = torch.rand(1, 3, 48, 64, dtype=dtype, device=device)
    small = Camera(camera.models, torch.cat([camera.params[:, :4] / 10, camera.params[:, 4:]], -1), (64, 48))
    out = undistort_image(img, small.to(device=device, dtype=dtype))
    assert out.shape == img.shape and out.dtype == dtype and out.device.type == device.type
    ref = undistort_image(img.cpu().double(), small)
    torch.testing.assert_close(out.cpu().double(), ref, atol=1e-5 if dtype == torch.float32 else 1e-12, rtol=0)
    as_bytes = undistort_image((img * 255).to(torch.uint8), small)
    assert as_bytes.dtype == torch.float32


def test_errors():
    camera = CAMERAS["opencv5"]
    with pytest.raises(ValueError, match="images"):
        undistort_image(torch.rand(1, 48, 64), camera)
    with pytest.raises(ValueError, match="cameras"):
        undistort_image(torch.rand(3, 1, 48, 64), Camera.cat([camera, camera]))
    with pytest.raises(ValueError, match="new_K"):
        undistort_image(torch.rand(1, 1, 48, 64), camera, K)
    with pytest.raises(ValueError, match="max_radius"):
        undistort_image(torch.rand(1, 1, 48, 64), camera, max_radius=torch.ones(2, dtype=F64))
    with pytest.raises(TypeError, match="Camera"):
        undistort_image(torch.rand(1, 1, 48, 64), K[None])
    with pytest.raises(ValueError, match="new_K"):
        UndistortImage(camera, K)
