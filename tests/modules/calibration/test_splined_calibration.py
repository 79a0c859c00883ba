"""The splined stereographic camera: it recovers a rendered lens no OpenCV model fits (a local bump), its sparse normal
equations are the dense ones, and the projection it fits unprojects back."""

from __future__ import annotations

import torch

from ccs_kornia.geometry.board_points import board_object_points
from ccs_kornia.geometry.board_warp import board_warp_basis
from ccs_kornia.geometry.camera import Camera
from ccs_kornia.geometry.models import RATIONAL, SplinedStereographicModel
from ccs_kornia.geometry.so3 import exp_so3
from ccs_kornia.modules.calibration import lm
from ccs_kornia.modules.calibration.quality.uncertainty import projection_difference
from ccs_kornia.modules.calibration.solver import CalibrationSolver

SIZE = (640, 480)
F64 = torch.float64


TRUTH = SplinedStereographicModel(16, 12, 120)


def _truth() -> Camera:
    """A lens no polynomial fits: stereographic with a barrel term and a local bump of about 3 px, as a spline."""
    x = (torch.arange(TRUTH.nx, dtype=F64) - (TRUTH.nx - 1) / 2) / TRUTH.segments_per_u
    y = (torch.arange(TRUTH.ny, dtype=F64) - (TRUTH.ny - 1) / 2) / TRUTH.segments_per_u
    u = torch.stack(torch.meshgrid(y, x, indexing="ij")[::-1], -1)  # control points' places (x, y)
    bump = 0.008 * torch.exp(-((u - torch.tensor([0.25, 0.1], dtype=F64)) ** 2).sum(-1, keepdim=True) / 0.03)
    knots = -0.1 * (u * u).sum(-1, keepdim=True) * u + bump * torch.tensor([1.0, -0.6], dtype=F64)
    return Camera(TRUTH, torch.cat([torch.tensor([400.0, 400, 320, 240], dtype=F64), knots.reshape(-1)]), SIZE)


def _views(V=24, noise=0.02, seed=0):
    obj = board_object_points(10, 8, 0.03, dtype=F64)
    g = torch.Generator().manual_seed(seed)
    rvec = 0.8 * (torch.rand(V, 3, generator=g, dtype=F64) - 0.5)
    centre = torch.stack([0.5 * (torch.rand(V, generator=g, dtype=F64) - 0.5),
                          0.4 * (torch.rand(V, generator=g, dtype=F64) - 0.5),
                          0.35 + 0.15 * torch.rand(V, generator=g, dtype=F64)], -1)
    R = exp_so3(rvec)
    tvec = centre - (R @ obj.mean(0)[:, None])[..., 0]
    uv = _truth().project((obj @ R.transpose(-1, -2) + tvec[:, None])[None])[0]
    uv = uv + noise * torch.randn(uv.shape, generator=g, dtype=F64)
    inside = (uv[..., 0] > 0) & (uv[..., 0] < 639) & (uv[..., 1] > 0) & (uv[..., 1] < 479)
    return obj, torch.where(inside[..., None], uv, torch.nan), inside


def test_spline_recovers_a_lens_no_opencv_model_fits():
    obj, uv, valid = _views()
    spline = CalibrationSolver(model=TRUTH)(uv, valid, obj, SIZE)
    rational = CalibrationSolver(model=RATIONAL)(uv, valid, obj, SIZE)
    assert bool(spline.success) and spline.camera.model == TRUTH
    assert float(rational.rms) > 0.2  # the bump stays in the rational model's residuals
    assert rational.residual_structure()["model_fit"] != "fits"
    assert float(spline.rms) < 0.035  # the spline's are the corners' noise (0.02 px per coordinate)
    assert spline.residual_structure()["model_fit"] == "fits"
    # the lens itself, after the rotation a calibration cannot tell from its lens, where boards were
    q = uv[valid][::5]
    d = projection_difference(_truth(), spline.camera, q, torch.ones(len(q), dtype=torch.bool))
    assert float(d.square().mean().sqrt()) < 0.05


class _Dense(SplinedStereographicModel):
    """The same spline with every control point as a column of its own (the dense normal equations)."""

    @property
    def local_support(self) -> bool:
        return False


def test_sparse_normal_equations_are_the_dense_ones():
    model = SplinedStereographicModel(6, 5, 120)

    g = torch.Generator().manual_seed(1)
    C, V, N, P = 2, 3, 12, model.num_params
    x = torch.zeros(C, P + 2, dtype=F64)
    x[:, :4] = torch.tensor([300.0, 310, 320, 240])
    x[:, 4:] = 0.02 * torch.randn(C, P - 2, generator=g, dtype=F64)
    obj = 0.2 * torch.randn(C, N, 3, generator=g, dtype=F64)
    obj[..., 2] = 0
    R = exp_so3(0.2 * torch.randn(C, V, 3, generator=g, dtype=F64))
    t = torch.tensor([0, 0, 1.0], dtype=F64).expand(C, V, 3)
    obs = 600 * torch.rand(C, V, N, 2, generator=g, dtype=F64)
    sw = torch.rand(C, V, N, generator=g, dtype=F64)
    basis = torch.eye(P + 2, dtype=F64)[:, [0, 1, *range(4, P + 2)]].expand(C, -1, -1)  # cx, cy fixed
    args = (R, t, x, obj, obs, sw, basis, torch.ones(C, V, dtype=torch.bool), torch.eye(6, dtype=F64))
    sparse = lm._normal_equations(model, *args, {}, board_warp_basis(obj))
    dense = lm._normal_equations(_Dense(6, 5, 120), *args, {}, board_warp_basis(obj))
    for a, b in zip(sparse, dense):
        torch.testing.assert_close(a, b, rtol=1e-12, atol=1e-9)


def test_sparse_normal_equations_at_the_grids_edges():
    # points past the grid's field take its edge patches (the last control points' rows), views without weight
    model = SplinedStereographicModel(5, 4, 40)

    g = torch.Generator().manual_seed(4)
    C, V, N, P = 1, 4, 30, model.num_params
    x = torch.zeros(C, P, dtype=F64)
    x[:, :4] = torch.tensor([300.0, 300, 320, 240])
    x[:, 4:] = 0.01 * torch.randn(C, P - 4, generator=g, dtype=F64)
    obj = torch.zeros(C, N, 3, dtype=F64)
    obj[..., :2] = 2.0 * (torch.rand(C, N, 2, generator=g, dtype=F64) - 0.5)  # up to 45 degrees off the axis
    R = exp_so3(0.05 * torch.randn(C, V, 3, generator=g, dtype=F64))
    t = torch.tensor([0, 0, 1.0], dtype=F64).expand(C, V, 3)
    obs = 600 * torch.rand(C, V, N, 2, generator=g, dtype=F64)
    sw = torch.rand(C, V, N, generator=g, dtype=F64)
    sw[:, 1] = 0  # a view without weight
    used = torch.tensor([[True, False, True, True]])
    basis = torch.eye(P, dtype=F64)[:, 4:].expand(C, -1, -1)  # the core fixed, as the spline's fit has it
    args = (R, t, x, obj, obs, sw, basis, used, torch.eye(6, dtype=F64))
    index = model.local_columns(obj[:, None] @ R.transpose(-1, -2) + t[:, :, None], x)[2]
    assert int(index.amax()) == P - 2  # the grid's last control point is reached
    sparse = lm._normal_equations(model, *args, {})
    dense = lm._normal_equations(_Dense(5, 4, 40), *args, {})
    for a, b in zip(sparse, dense):
        torch.testing.assert_close(a, b, rtol=1e-12, atol=1e-9)


def test_projection_derivatives_and_round_trip():
    model = SplinedStereographicModel(7, 5, 200)  # beyond 180 degrees
    g = torch.Generator().manual_seed(2)
    params = torch.zeros(1, model.num_params, dtype=F64)
    params[0, :4] = torch.tensor([300.0, 310, 320, 240])
    params[0, 4:] = 0.05 * torch.randn(model.num_params - 4, generator=g, dtype=F64)
    theta = torch.rand(20, generator=g, dtype=F64) * 1.65  # up to 95 degrees off the axis: inside the grid's field
    phi = torch.rand(20, generator=g, dtype=F64) * 6.283
    rho = 0.5 + torch.rand(20, generator=g, dtype=F64)
    points = (rho[:, None] * torch.stack([theta.sin() * phi.cos(), theta.sin() * phi.sin(), theta.cos()], -1))[None]
    uv, J, Jx = model.project(points, params)
    eps = 1e-6
    for k in [0, 1, 2, 3, *torch.randint(4, model.num_params, (12,), generator=g).tolist()]:
        d = torch.zeros(model.num_params, dtype=F64)
        d[k] = eps
        num = (model.project(points, params + d, False)[0] - model.project(points, params - d, False)[0]) / (2 * eps)
        torch.testing.assert_close(J[..., k], num, rtol=1e-6, atol=1e-6)
    for k in range(3):
        d = torch.zeros(3, dtype=F64)
        d[k] = eps
        num = (model.project(points + d, params, False)[0] - model.project(points - d, params, False)[0]) / (2 * eps)
        torch.testing.assert_close(Jx[..., k], num, rtol=1e-5, atol=1e-5)
    cam = Camera(model, params, SIZE)
    rays = cam.unproject(uv)
    torch.testing.assert_close(rays, torch.nn.functional.normalize(points, dim=-1), rtol=0, atol=1e-9)
    assert bool((rays[..., 2] < 0).any())  # directions beyond 90 degrees come back


def test_auto_takes_the_spline_only_where_held_out_views_prefer_it():
    from ccs_kornia.geometry.camera import project_points
    from ccs_kornia.geometry.models import OPENCV5
    from ccs_kornia.modules.calibration.splined_choice import choose_splined

    # an ordinary lens the chosen model fits: the spline is not even tried
    obj = board_object_points(10, 8, 0.03, dtype=F64)
    K = torch.tensor([[400.0, 0, 320], [0, 400, 240], [0, 0, 1]], dtype=F64)
    g = torch.Generator().manual_seed(3)
    rvec = 0.6 * (torch.rand(12, 3, generator=g, dtype=F64) - 0.5)
    tvec = torch.tensor([-0.13, -0.1, 0.45], dtype=F64) + 0.05 * torch.rand(12, 3, generator=g, dtype=F64)
    plain = project_points(obj.expand(12, -1, -1), K.expand(12, 3, 3),
                           torch.tensor([-0.2, 0.05, 0, 0, 0], dtype=F64).expand(12, 5), rvec, tvec)
    plain = (plain + 0.02 * torch.randn(plain.shape, generator=g, dtype=F64))[None]
    ok = torch.ones(plain.shape[:-1], dtype=torch.bool)
    solver = CalibrationSolver(model=OPENCV5)
    chosen = solver(plain, ok, obj, SIZE)
    assert chosen.residual_structure(0)["model_fit"] == "fits"
    keep, records = choose_splined(solver, chosen, plain, ok, obj, SIZE)
    assert keep == [None] and records == [None]
    # the bumpy lens: the rational model leaves structure, the spline predicts the other half's views better
    obj, uv, valid = _views(V=16)
    solver = CalibrationSolver(model=RATIONAL)
    chosen = solver(uv[None], valid[None], obj, SIZE)
    keep, records = choose_splined(solver, chosen, uv[None], valid[None], obj, SIZE)
    figures = records[0]["heldout_median_px"]
    assert records[0]["kept"] and figures["splined"] < 0.8 * figures["rational"]
    assert keep[0].camera.model.name.startswith("splined_stereographic") and float(keep[0].rms) < 0.05


def test_points_without_a_ray_project_to_nan():
    # a view that was not posed (NaN pose) or a point behind the camera: NaN out, never an index out of range
    camera = _truth()
    points = torch.tensor([[[0.01, 0.02, 0.4], [float("nan"), 0.0, 0.4], [0.0, 0.0, -0.4]]], dtype=F64)
    uv = camera.project(points)[0]
    assert uv[0].isfinite().all() and uv[1:].isnan().all()
