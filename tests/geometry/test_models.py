"""Camera models of the LM core: projection against OpenCV, analytic derivatives against autograd."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
import torch

from ccs_kornia.geometry.camera import Camera
from ccs_kornia.geometry.models import (
    CameraModel,
    CentredRadialModel,
    KannalaBrandtModel,
    OpenCVModel,
    camera_model,
)
from ccs_kornia.modules.calibration.centred_radial import centred_radial_distort

F64 = torch.float64
DEVICES = ["cpu"] + (["cuda"] if torch.cuda.is_available() else [])

OPENCV_PARAMS = {
    "none": [510.0, 505.0, 322.0, 241.0],
    "k1k2": [510.0, 505.0, 322.0, 241.0, -0.25, 0.08],
    "opencv5": [510.0, 505.0, 322.0, 241.0, -0.25, 0.08, 1e-3, -8e-4, -0.02],
    "rational": [510.0, 505.0, 322.0, 241.0, -0.25, 0.08, 1e-3, -8e-4, -0.02, 0.1, 0.01, 0.002],
}
KB_PARAMS = [300.0, 302.0, 321.0, 238.0, 0.02, -0.01, 0.002, -0.0005]
CR_PARAMS = [400.0, 405.0, 330.0, 232.0, -0.3, 0.08, 0.01, 6.0, -4.0]


def _points(C=2, V=3, N=7, seed=0, wide=False, dtype=F64, device="cpu"):
    g = torch.Generator().manual_seed(seed)
    if wide:  # any direction up to 115 degrees from the axis (beyond 90 included)
        X = torch.randn(8 * C * V * N, 3, generator=g, dtype=F64)
        X = X[torch.atan2(X[:, :2].norm(dim=-1), X[:, 2]) < 2.0][: C * V * N].reshape(C, V, N, 3)
        assert bool((X[..., 2] < 0).any())
    else:
        X = torch.randn(C, V, N, 3, generator=g, dtype=F64)
        X[..., :2] *= 0.4
        X[..., 2] = X[..., 2].abs() + 1.0
    return X.to(device=device, dtype=dtype)


def _models():
    out = [(OpenCVModel(v), p) for v, p in OPENCV_PARAMS.items()]
    return out + [(KannalaBrandtModel(), KB_PARAMS), (CentredRadialModel((640, 480)), CR_PARAMS)]


def _autograd_jacobians(model, X, params):
    C = params.shape[0]
    Jp = torch.autograd.functional.jacobian(lambda p: model.project(X, p, False)[0], params)
    Jp = torch.stack([Jp[c, ..., c, :] for c in range(C)])  # (C, *, 2, P)
    flat = X.reshape(C, -1, 3)
    Jx = torch.autograd.functional.jacobian(lambda q: model.project(q, params, False)[0].sum(1), flat)  # (C,2,C,M,3)
    Jx = torch.stack([Jx[c, :, c] for c in range(C)]).permute(0, 2, 1, 3).reshape(*X.shape[:-1], 2, 3)
    return Jp, Jx


@pytest.mark.parametrize("model,p", _models(), ids=lambda x: getattr(x, "name", ""))
def test_shapes_and_jacobians_match_autograd(model, p):
    X = _points(wide=isinstance(model, KannalaBrandtModel))
    params = torch.tensor([p, p], dtype=F64)
    params[1, :2] *= 1.05
    uv, J, Jx = model.project(X, params)
    P = model.num_params
    assert uv.shape == (*X.shape[:-1], 2) and J.shape == (*X.shape[:-1], 2, P) and Jx.shape == (*X.shape[:-1], 2, 3)
    Jp_ref, Jx_ref = _autograd_jacobians(model, X, params)
    torch.testing.assert_close(J, Jp_ref, rtol=1e-8, atol=1e-8)
    torch.testing.assert_close(Jx, Jx_ref, rtol=1e-8, atol=1e-8)
    uv2, none1, none2 = model.project(X, params, jacobians=False)
    assert none1 is None and none2 is None and torch.equal(uv, uv2)


@pytest.mark.parametrize("model,p", _models(), ids=lambda x: getattr(x, "name", ""))
def test_gradcheck(model, p):
    X = _points(C=1, V=1, N=3, wide=isinstance(model, KannalaBrandtModel)).requires_grad_(True)
    params = torch.tensor([p], dtype=F64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda a, b: model.project(a, b, False)[0], (X, params))


@pytest.mark.parametrize("variant", list(OPENCV_PARAMS))
def test_opencv_matches_cv2_project_points(variant):
    X = _points(C=1, V=1, N=50)
    p = torch.tensor([OPENCV_PARAMS[variant]], dtype=F64)
    uv = OpenCVModel(variant).project(X, p, False)[0].reshape(-1, 2).numpy()
    q = p[0].numpy()
    K = np.array([[q[0], 0, q[2]], [0, q[1], q[3]], [0, 0, 1]])
    dist = OpenCVModel(variant).dist8(p)[0].numpy()
    ref = cv2.projectPoints(X.reshape(-1, 3).numpy(), np.zeros(3), np.zeros(3), K, dist)[0].reshape(-1, 2)
    np.testing.assert_allclose(uv, ref, atol=1e-9, rtol=0)


def test_opencv_params_round_trip_and_jacobians_match_cv2_project_points():
    m = OpenCVModel("rational")
    p = torch.tensor([OPENCV_PARAMS["rational"]], dtype=F64)
    K = torch.tensor([[[510.0, 0, 322.0], [0, 505.0, 241.0], [0, 0, 1]]], dtype=F64)
    torch.testing.assert_close(m.params_from(K, m.dist8(p)), p)
    X = _points(C=1)
    uv, J, Jx = m.project(X, p)
    # OpenCV's own derivatives: columns rvec (3), tvec (3), fx fy, cx cy, k1 k2 p1 p2 k3 k4 k5 k6
    ref, jac = cv2.projectPoints(X.reshape(-1, 3).numpy(), np.zeros(3), np.zeros(3), K[0].numpy(), m.dist8(p)[0].numpy())
    jac = torch.from_numpy(jac).reshape(-1, 2, jac.shape[-1])
    torch.testing.assert_close(uv.reshape(-1, 2), torch.from_numpy(ref.reshape(-1, 2)), atol=1e-9, rtol=0)
    torch.testing.assert_close(J.reshape(-1, 2, 12), jac[..., 6:18], atol=1e-7, rtol=1e-9)
    torch.testing.assert_close(Jx.reshape(-1, 2, 3), jac[..., 3:6], atol=1e-7, rtol=1e-9)


def test_fisheye_matches_cv2_fisheye_in_front_and_is_continuous_beyond_90_degrees():
    m = KannalaBrandtModel()
    p = torch.tensor([KB_PARAMS], dtype=F64)
    X = _points(C=1, V=1, N=60)
    X[..., :2] *= 4  # up to ~80 degrees
    X[0, 0, 0] = torch.tensor([0.0, 0.0, 2.0], dtype=F64)  # on the optical axis
    X[0, 0, 1] = torch.tensor([1e-9, -2e-9, 1.0], dtype=F64)
    uv = m.project(X, p, False)[0].reshape(-1, 2).numpy()
    q = p[0].numpy()
    K = np.array([[q[0], 0, q[2]], [0, q[1], q[3]], [0, 0, 1]])
    ref = cv2.fisheye.projectPoints(X.reshape(1, -1, 3).numpy(), np.zeros(3), np.zeros(3), K, q[4:])[0].reshape(-1, 2)
    np.testing.assert_allclose(uv, ref, atol=1e-9, rtol=0)
    # at and beyond 90 degrees: theta = atan2(r, z), continuous through z = 0
    z = torch.tensor([1e-6, 0.0, -1e-6], dtype=F64)
    Xz = torch.stack([torch.ones(3, dtype=F64), 0.3 * torch.ones(3, dtype=F64), z], -1)[None]
    u = m.project(Xz, p, False)[0][0]
    assert (u[0] - u[2]).abs().max() < 1e-3 and u[1, 0] > p[0, 2] + p[0, 0] * math.pi / 2 * 0.9
    # the Jacobian on the optical axis (series branch) matches finite differences
    Xa = torch.tensor([[[0.0, 0.0, 1.5], [2e-5, -1e-5, 0.8]]], dtype=F64)
    _, _, Jx = m.project(Xa, p)
    h = 1e-6
    fd = torch.stack([(m.project(Xa + h * e, p, False)[0] - m.project(Xa - h * e, p, False)[0]) / (2 * h)
                      for e in torch.eye(3, dtype=F64)], -1)
    torch.testing.assert_close(Jx, fd, atol=1e-5, rtol=1e-7)


def test_centred_radial_matches_the_former_function():
    m = CentredRadialModel((640, 480))
    p = torch.tensor([CR_PARAMS], dtype=F64)
    X = _points(C=1, V=1, N=40)
    uv = m.project(X, p, False)[0].reshape(1, -1, 2)
    pin = torch.stack([p[0, 0] * X[..., 0] / X[..., 2] + p[0, 2], p[0, 1] * X[..., 1] / X[..., 2] + p[0, 3]], -1)
    ref = centred_radial_distort(pin.reshape(1, -1, 2), p[:, 4:7], (640, 480), p[:, 7:9])
    torch.testing.assert_close(uv, ref, atol=1e-9, rtol=0)
    assert m.default_free() == [True] * 7 + [False] * 2
    assert CentredRadialModel((640, 480), free_centre=True).default_free() == [True] * 9


@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_device_and_dtype(device, dtype):
    for model, p in _models():
        X = _points(device=device, dtype=dtype, wide=isinstance(model, KannalaBrandtModel))
        params = torch.tensor([p, p], dtype=dtype, device=device)
        uv, J, Jx = model.project(X, params)
        assert uv.dtype == dtype and uv.device.type == device and J.dtype == dtype and Jx.device.type == device
        ref = model.project(X.double().cpu(), params.double().cpu(), False)[0]
        tol = 1e-9 if dtype == F64 else 1e-2
        torch.testing.assert_close(uv.double().cpu(), ref, atol=tol, rtol=1e-5 if dtype == torch.float32 else 0)


def test_bad_shapes_and_names():
    m = OpenCVModel("opencv5")
    with pytest.raises(ValueError, match="points"):
        m.project(torch.zeros(2, 3, 2, dtype=F64), torch.zeros(2, 9, dtype=F64))
    with pytest.raises(ValueError, match="params"):
        m.project(torch.zeros(2, 3, 3, dtype=F64), torch.zeros(2, 5, dtype=F64))
    with pytest.raises(ValueError, match=r"params must be \(1, 9\) or \(C, 9\) with C=2, got \(3, 9\)"):
        m.project(torch.zeros(2, 3, 3, dtype=F64), torch.zeros(3, 9, dtype=F64))
    with pytest.raises(ValueError, match="variant"):
        OpenCVModel("fisheye5")
    with pytest.raises(ValueError, match="image_size"):
        CentredRadialModel((0, 480))
    with pytest.raises(ValueError, match="image_size"):
        camera_model("centred_radial")
    with pytest.raises(ValueError, match="Unknown camera model"):
        camera_model("mei")
    assert isinstance(camera_model("fisheye"), CameraModel) and camera_model("k1k2").num_params == 6
    with pytest.raises(NotImplementedError):
        CameraModel().project(torch.zeros(1, 1, 3), torch.zeros(1, 0))


# ---------------------------------------------------------------------------------------- capabilities and layout
def test_models_say_what_they_are():
    assert camera_model("fisheye").is_fisheye and camera_model("fisheye").opencv_family == "fisheye"
    for name in OPENCV_PARAMS:
        assert not camera_model(name).is_fisheye and camera_model(name).opencv_family == "opencv"
    assert not CentredRadialModel((640, 480)).is_fisheye
    with pytest.raises(NotImplementedError, match="layout"):
        CentredRadialModel((640, 480)).num_coeffs
    assert camera_model("k1k2") is camera_model("k1k2")  # stateless: one shared instance per name


def test_coefficient_layout_is_what_results_store():
    for name, n in {"none": 0, "k1k2": 5, "opencv5": 5, "rational": 8}.items():
        assert camera_model(name).num_coeffs == n and camera_model(name).max_coeffs == 8
    assert camera_model("fisheye").num_coeffs == camera_model("fisheye").max_coeffs == 4


@pytest.mark.parametrize("name", [*OPENCV_PARAMS, "fisheye"])
def test_coeffs_from_params_round_trip(name, device, dtype):
    m = camera_model(name)
    p = torch.tensor(KB_PARAMS if name == "fisheye" else OPENCV_PARAMS[name], device=device, dtype=dtype)[None]
    dist = m.coeffs_from(p.expand(3, -1))
    assert dist.shape == (3, m.num_coeffs) and dist.dtype == dtype and dist.device == p.device
    K = torch.tensor([[p[0, 0], 0, p[0, 2]], [0, p[0, 1], p[0, 3]], [0, 0, 1]], device=device, dtype=dtype)
    torch.testing.assert_close(m.params_from(K.expand(3, 3, 3), dist), p.expand(3, -1))


def test_opencv_coeffs_pads_to_what_opencv_takes():
    assert camera_model("k1k2").opencv_coeffs([-0.3, 0.1]).tolist() == [-0.3, 0.1, 0.0, 0.0, 0.0]
    assert camera_model("none").opencv_coeffs(None).tolist() == [0.0] * 5
    assert camera_model("rational").opencv_coeffs([0.1] * 6).shape == (8,)
    assert camera_model("fisheye").opencv_coeffs(np.array([0.1, 0.2])).tolist() == [0.1, 0.2, 0.0, 0.0]
    d = camera_model("opencv5").opencv_coeffs(torch.ones(2, 3, dtype=F64))  # a tensor stays one, batched
    assert isinstance(d, torch.Tensor) and d.shape == (2, 5) and d[:, 3:].eq(0).all()
    with pytest.raises(ValueError, match="4 coefficients"):
        camera_model("fisheye").opencv_coeffs([0.0] * 5)
    with pytest.raises(ValueError, match="at most 8"):
        camera_model("rational").opencv_coeffs([0.0] * 9)
    # what OpenCV's functions take: the padded coefficients project as the short ones mean
    K = np.array([[500.0, 0, 320], [0, 500, 240], [0, 0, 1]])
    X = np.array([[[0.2, -0.1, 1.0]]])
    uv = cv2.projectPoints(X, np.zeros(3), np.zeros(3), K, camera_model("k1k2").opencv_coeffs([-0.3, 0.1]))[0]
    x2 = 0.2**2 + 0.1**2
    np.testing.assert_allclose(uv[0, 0], [320 + 500 * 0.2 * (1 - 0.3 * x2 + 0.1 * x2**2),
                                          240 - 500 * 0.1 * (1 - 0.3 * x2 + 0.1 * x2**2)])


# ---------------------------------------------------------------------------------------- the monotonic range
# r_d = r (1 - 0.5 r^2) turns at r = 1 / sqrt(1.5); theta_d = theta (1 - 0.5 theta^2 + theta^4 / 60), of slope
# 1 - 1.5 theta^2 + theta^4 / 12, at theta^2 = 6 (1.5 - sqrt(2.25 - 1 / 3)) (47.7 degrees)
_KB_FOLD = math.tan(math.sqrt(6 * (1.5 - math.sqrt(2.25 - 1 / 3))))
FOLDS = [("opencv5", [500.0, 500.0, 320.0, 240.0, -0.5, 0.0, 0.0, 0.0, 0.0], 1 / math.sqrt(1.5), 2e-3),
         ("k1k2", [500.0, 500.0, 320.0, 240.0, -0.5, 0.0], 1 / math.sqrt(1.5), 2e-3),
         ("rational", [500.0, 500.0, 320.0, 240.0, -0.5, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0], 1 / math.sqrt(1.5), 2e-3),
         ("fisheye", [300.0, 300.0, 320.0, 240.0, -0.5, 1 / 60, 0.0, 0.0], _KB_FOLD, 2e-3)]


@pytest.mark.parametrize("name, params, fold, tol", FOLDS, ids=[f[0] for f in FOLDS])
def test_monotonic_radius_stops_just_before_a_known_turning_point(name, params, fold, tol, device, dtype):
    radius = camera_model(name).monotonic_radius(torch.tensor([params], device=device, dtype=dtype), math.radians(80))
    assert radius.shape == (1,) and radius.dtype == dtype and radius.device.type == device.type
    assert fold - tol < float(radius[0]) <= fold * (1 + 1e-6)  # conservative: a sample before the turn


def test_monotonic_radius_is_the_cap_without_a_turn_and_per_camera():
    cap = math.radians(80)
    p = torch.tensor([OPENCV_PARAMS["opencv5"], [500.0, 500.0, 320.0, 240.0, -0.5, 0.0, 0.0, 0.0, 0.0]], dtype=F64)
    r = camera_model("opencv5").monotonic_radius(p, cap)
    assert torch.equal(r[:1], camera_model("opencv5").monotonic_radius(p[:1], cap))  # each camera its own
    assert float(r[0]) < math.tan(cap) and abs(float(r[1]) - 1 / math.sqrt(1.5)) < 2e-3
    mild = torch.tensor([[500.0, 500.0, 320.0, 240.0, 0.1, 0.0, 0.0, 0.0, 0.0]], dtype=F64)
    assert float(camera_model("opencv5").monotonic_radius(mild, cap)[0]) == math.tan(cap)
    assert float(KannalaBrandtModel().monotonic_radius(torch.tensor([KB_PARAMS], dtype=F64), cap)[0]) == math.tan(cap)
    assert float(camera_model("none").monotonic_radius(torch.tensor([OPENCV_PARAMS["none"]]), 0.5)[0]) == \
        pytest.approx(math.tan(0.5))
    # a rational denominator reaching zero ends the range too: 1 + k4 r^2 = 0 at r = 1 / sqrt(2)
    pole = torch.tensor([[500.0, 500.0, 320.0, 240.0, 0.0, 0.0, 0.0, 0.0, 0.0, -2.0, 0.0, 0.0]], dtype=F64)
    assert float(camera_model("rational").monotonic_radius(pole, cap)[0]) < 1 / math.sqrt(2)


# ---------------------------------------------------------------------------------------- a fisheye Camera against cv2.fisheye
def _kb():
    K = torch.tensor([[300.0, 0, 400.0], [0, 310.0, 250.0], [0, 0, 1]], dtype=F64)
    D = torch.tensor([0.01, -0.002, 3e-4, -1e-4], dtype=F64)  # monotonic up to about 150 degrees
    return K, D, Camera.from_opencv(camera_model("fisheye"), K, D)


def test_camera_kb_projection_matches_cv2():
    K, D, camera = _kb()
    X = _points(C=1, V=1, N=50)[0, 0]
    X[:, :2] *= 3
    uv = camera.project(X[None])[0]
    ref = cv2.fisheye.projectPoints(X.numpy()[None], np.zeros(3), np.zeros(3), K.numpy(), D.numpy())[0][0]
    np.testing.assert_allclose(uv.numpy(), ref, atol=1e-9, rtol=0)
    torch.testing.assert_close(camera.distort((X[:, :2] / X[:, 2:])[None])[0], uv, atol=1e-9, rtol=0)
    rv, tv = torch.tensor([[0.1, -0.2, 0.3]], dtype=F64), torch.tensor([[0.05, 0.0, 0.2]], dtype=F64)
    ref = cv2.fisheye.projectPoints(X.numpy()[None], rv.numpy(), tv.numpy(), K.numpy(), D.numpy())[0][0]
    np.testing.assert_allclose(camera.project(X[None], rv, tv)[0].numpy(), ref, atol=1e-9, rtol=0)
    with pytest.raises(ValueError, match="tvec"):
        camera.project(X[None], rv)
    with pytest.raises(ValueError, match="fisheye"):
        Camera.from_opencv(camera_model("fisheye"), K, torch.zeros(5, dtype=F64))


def test_camera_kb_unprojection_matches_cv2_and_inverts_beyond_90_degrees():
    K, D, camera = _kb()
    X = _points(C=1, V=1, N=50)[0, 0]
    X[:, :2] *= 3
    uv = camera.project(X[None])
    ref = cv2.fisheye.undistortPoints(uv.numpy(), K.numpy(), D.numpy())[0]
    np.testing.assert_allclose(camera.undistort(uv)[0].numpy(), ref, atol=1e-9, rtol=0)
    P = torch.tensor([[200.0, 0, 300.0], [0, 210.0, 200.0], [0, 0, 1]], dtype=F64)
    ref = cv2.fisheye.undistortPoints(uv.numpy(), K.numpy(), D.numpy(), P=P.numpy())[0]
    np.testing.assert_allclose(camera.undistort(uv, P[None])[0].numpy(), ref, atol=1e-7, rtol=0)
    # rays over the whole monotonic range of the lens, beyond 90 degrees
    g = torch.Generator().manual_seed(3)
    Y = torch.randn(400, 3, generator=g, dtype=F64)
    Y = Y[torch.atan2(Y[:, :2].norm(dim=-1), Y[:, 2]) < 2.0]
    rays = camera.unproject(camera.project(Y[None]))[0]
    torch.testing.assert_close(rays, Y / Y.norm(dim=-1, keepdim=True), atol=1e-10, rtol=0)
    assert bool((Y[:, 2] < 0).any())


def test_centred_radial_monotonic_radius_follows_the_focal_length_in_its_pixel_units(device, dtype):
    # rho = r f / max(W, H); rho (1 - 0.5 rho^2) turns at rho = 1 / sqrt(1.5)
    model = CentredRadialModel((640, 480))
    p = torch.tensor([[640.0, 640.0, 319.5, 239.5, -0.5, 0.0, 0.0, 0.0, 0.0],
                      [320.0, 300.0, 319.5, 239.5, -0.5, 0.0, 0.0, 0.0, 0.0]], device=device, dtype=dtype)
    radius = model.monotonic_radius(p, math.radians(80))
    assert radius.shape == (2,) and radius.dtype == dtype and radius.device.type == device.type
    for got, fold in zip(radius.tolist(), (1 / math.sqrt(1.5), 2 / math.sqrt(1.5))):
        assert fold - 4e-3 < got <= fold * (1 + 1e-6)
    mild = torch.tensor([[640.0, 640.0, 319.5, 239.5, 0.1, 0.0, 0.0, 0.0, 0.0]], device=device, dtype=dtype)
    assert float(model.monotonic_radius(mild, 0.5)[0]) == pytest.approx(math.tan(0.5))
