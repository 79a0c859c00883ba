"""The camera value: every model's maps against OpenCV, round trips, Jacobians against autograd, cameras of several
models in one value, and the errors at its boundary."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import torch

from ccs_kornia.geometry.camera import Camera
from ccs_kornia.geometry.models import (
    FISHEYE,
    K1K2,
    OPENCV5,
    PINHOLE,
    RATIONAL,
    CentredRadialModel,
    camera_model,
)

F64 = torch.float64
K = torch.tensor([[510.0, 0.0, 322.0], [0.0, 505.0, 241.0], [0.0, 0.0, 1.0]], dtype=F64)
COEFFS = {
    PINHOLE: [],
    K1K2: [-0.25, 0.08, 0.0, 0.0, 0.0],
    OPENCV5: [-0.25, 0.08, 1e-3, -8e-4, -0.02],
    RATIONAL: [-0.25, 0.08, 1e-3, -8e-4, -0.02, 0.1, 0.01, 0.002],
    FISHEYE: [0.02, -0.01, 0.002, -0.0005],
}
MODELS = list(COEFFS)


def _camera(model, C=2, dtype=F64, device="cpu") -> Camera:
    Ks = K.expand(C, 3, 3).clone()
    Ks[1:, :2] *= 1.03
    d = torch.tensor(COEFFS[model], dtype=F64).expand(C, -1)
    return Camera.from_opencv(model, Ks, d, (640, 480)).to(device, dtype)


def _points(C=2, N=40, seed=0, wide=False) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    X = torch.randn(C, N, 3, generator=g, dtype=F64)
    X[..., :2] *= 0.8 if wide else 0.35
    X[..., 2] = X[..., 2].abs() * 0.2 + 1.0
    return X


def _pixels(C=2, N=40, seed=1) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    return torch.rand(C, N, 2, generator=g, dtype=F64) * torch.tensor([600.0, 440.0], dtype=F64) + 20.0


@pytest.mark.parametrize("model", MODELS, ids=str)
def test_maps_match_opencv(model):
    cam = _camera(model)
    X, px = _points(), _pixels()
    uv, xy = cam.project(X), cam.undistort(px)
    for c in range(2):
        Kc, Dc = cam.K[c].numpy(), cam.coeffs(c).numpy()
        if model == FISHEYE:
            ref = cv2.fisheye.projectPoints(X[c].numpy()[:, None], np.zeros(3), np.zeros(3), Kc, Dc)[0][:, 0]
            und = cv2.fisheye.undistortPoints(px[c].numpy()[:, None], Kc, Dc)[:, 0]
        else:
            D = model.opencv_coeffs(Dc) if Dc.size else np.zeros(5)
            ref = cv2.projectPoints(X[c].numpy(), np.zeros(3), np.zeros(3), Kc, D)[0][:, 0]
            und = cv2.undistortPoints(px[c].numpy()[:, None], Kc, D,
                                      criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-14))[:, 0]
        np.testing.assert_allclose(uv[c].numpy(), ref, atol=1e-9)
        np.testing.assert_allclose(xy[c].numpy(), und, atol=1e-7)


@pytest.mark.parametrize("model", MODELS, ids=str)
def test_round_trips(model, device, dtype):
    cam = _camera(model, dtype=dtype, device=device)
    tol = 1e-8 if dtype == F64 else 2e-3
    px = _pixels().to(device, dtype)
    torch.testing.assert_close(cam.distort(cam.undistort(px)), px, atol=tol, rtol=0)
    rays = cam.unproject(px)
    torch.testing.assert_close(rays.norm(dim=-1), torch.ones_like(rays[..., 0]), atol=tol, rtol=0)
    torch.testing.assert_close(cam.project(rays), px, atol=tol, rtol=0)
    ideal = cam.undistort(px, P=cam.K)
    assert ideal.shape == px.shape and ideal.dtype == dtype and ideal.device.type == torch.device(device).type


def test_fisheye_beyond_90_degrees():
    cam = _camera(FISHEYE, C=1)
    ray = torch.tensor([[[0.8, 0.1, -0.3]]], dtype=F64)
    ray = ray / ray.norm(dim=-1, keepdim=True)
    px = cam.project(ray)
    torch.testing.assert_close(cam.unproject(px), ray, atol=1e-10, rtol=0)


def _jac(fn, x):
    """Per-point Jacobian (C, N, out, in) of a map applied point-wise to x (C, N, in)."""
    J = torch.autograd.functional.jacobian(lambda y: fn(y).sum((0, 1)), x)  # (out, C, N, in)
    return J.permute(1, 2, 0, 3)


@pytest.mark.parametrize("model", MODELS, ids=str)
def test_jacobians_match_autograd(model):
    cam = _camera(model)
    X, px = _points(), _pixels()
    uv, Jp, Jx = cam.project(X, jacobians=True)
    torch.testing.assert_close(Jx, _jac(cam.project, X), rtol=1e-7, atol=1e-7)
    xy = cam.undistort(px)
    _, Jd = cam.distort(xy, jacobians=True)
    torch.testing.assert_close(Jd, _jac(cam.distort, xy), rtol=1e-7, atol=1e-7)
    _, Ju = cam.undistort(px, jacobians=True)
    torch.testing.assert_close(Ju, _jac(cam.undistort, px), rtol=1e-5, atol=1e-9)
    _, Jr = cam.unproject(px, jacobians=True)
    torch.testing.assert_close(Jr, _jac(cam.unproject, px), rtol=1e-5, atol=1e-9)
    Jparams = torch.autograd.functional.jacobian(lambda p: cam.with_params(p).project(X).sum(1), cam.params)
    torch.testing.assert_close(Jp.sum(1), torch.stack([Jparams[c, :, c] for c in range(2)]), rtol=1e-7, atol=1e-6)


def test_gradcheck_through_the_maps():
    cam = _camera(OPENCV5, C=1)
    params = cam.params.clone().requires_grad_()
    px = _pixels(C=1, N=5).requires_grad_()
    assert torch.autograd.gradcheck(lambda p, q: cam.with_params(p).undistort(q), (params, px))
    X = _points(C=1, N=5).requires_grad_()
    assert torch.autograd.gradcheck(lambda p, x: Camera(FISHEYE, p[:, :8]).project(x),
                                    (_camera(FISHEYE, C=1).params.clone().requires_grad_(), X))


def test_cameras_of_several_models_are_each_their_own():
    parts = [_camera(m, C=1) for m in MODELS]
    cams = Camera.cat(parts)
    assert len(cams) == 5 and cams.models == tuple(MODELS) and not cams.uniform
    assert cams.params.shape == (5, 12) and bool(cams.params[0, 4:].isnan().all())
    X, px = _points(C=5), _pixels(C=5)
    uv, Jp, Jx = cams.project(X, jacobians=True)
    rays = cams.unproject(px)
    for c, part in enumerate(parts):
        torch.testing.assert_close(uv[c], part.project(X[c : c + 1])[0], rtol=0, atol=0)
        torch.testing.assert_close(rays[c], part.unproject(px[c : c + 1])[0], rtol=0, atol=0)
        P = part.model.num_params
        torch.testing.assert_close(Jp[c, ..., :P], part.project(X[c : c + 1], jacobians=True)[1][0])
        assert bool((Jp[c, ..., P:] == 0).all())
        torch.testing.assert_close(cams.coeffs(c), part.coeffs(0))
    assert cams.dist.shape == (5, 8) and bool(cams.dist[0].isnan().all())
    sub = cams[torch.tensor([1, 3])]
    assert sub.models == (K1K2, RATIONAL) and sub.params.shape == (2, 12)
    assert cams[4].models == (FISHEYE,) and cams[4].params.shape == (1, 8)
    with pytest.raises(ValueError, match="several models"):
        _ = cams.model


def test_indexing_sizes_and_devices(device):
    cam = Camera.cat([_camera(K1K2, C=2), Camera.from_opencv(K1K2, K, None, (320, 240))]).to(device)
    assert cam.image_sizes == ((640, 480), (640, 480), (320, 240)) and cam.model == K1K2
    assert cam[0:2].image_size == (640, 480)
    with pytest.raises(ValueError, match="several image sizes"):
        _ = cam.image_size
    assert cam.K.shape == (3, 3, 3) and cam.dist.shape == (3, 5) and cam.device.type == torch.device(device).type
    assert cam.to(dtype=torch.float32).dtype == torch.float32 and "k1k2" in repr(cam)


def test_boundary_errors():
    with pytest.raises(TypeError, match="CameraModel"):
        Camera("opencv5", torch.zeros(1, 9))
    with pytest.raises(ValueError, match=r"params must be \(C, 9\) for opencv5, got \(1, 8\)"):
        Camera(OPENCV5, torch.zeros(1, 8))
    with pytest.raises(ValueError, match="place"):
        Camera.from_opencv(K1K2, K, torch.tensor([-0.2, 0.0, 0.01, 0.0, 0.0], dtype=F64))
    with pytest.raises(ValueError, match="K must be"):
        Camera.from_opencv(OPENCV5, torch.eye(2))
    with pytest.raises(ValueError, match="cameras first"):
        _camera(OPENCV5).undistort(torch.zeros(3, 4, 2, dtype=F64))
    with pytest.raises(ValueError, match="image sizes"):
        Camera(PINHOLE, torch.ones(1, 4), (0, 10))


def test_models_are_values():
    assert camera_model("opencv5") is OPENCV5 and str(FISHEYE) == "fisheye"
    assert CentredRadialModel((640, 480)) == CentredRadialModel((640, 480)) != CentredRadialModel((320, 240))
    assert len({OPENCV5, camera_model("opencv5"), K1K2}) == 2 and OPENCV5 != "opencv5"
    with pytest.raises(ValueError, match="Unknown camera model"):
        camera_model("auto")
