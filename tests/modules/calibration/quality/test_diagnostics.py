"""Results a user can trust: degenerate input refused or flagged, honest uncertainty,
projection uncertainty, cross-validation, verdict.

Corners are projected analytically (``project_points``) with Gaussian noise: no rendering, so the statistical
tests run many cameras in one batched solver call.
"""

from __future__ import annotations

import doctest
import json
import math

import pytest
import torch
from _real_data import REAL_DATA

from ccs_kornia.geometry.board_points import board_object_points
from ccs_kornia.geometry.camera import (
    axis_angle_to_rotation_matrix,
    project_points,
    rotation_matrix_to_axis_angle,
)
from ccs_kornia.geometry.models import K1K2, OPENCV5, PINHOLE, RATIONAL
from ccs_kornia.modules.calibration.quality import (
    coverage,
    degeneracy,
    diagnostics,
    uncertainty,
)
from ccs_kornia.modules.calibration.quality.degeneracy import (
    CHECKS,
    check_degeneracy,
    duplicate_views,
    pose_spread,
)
from ccs_kornia.modules.calibration.quality.diagnostics import (
    cross_validation,
    diagnose,
    verdict,
)
from ccs_kornia.modules.calibration.quality.uncertainty import (
    image_points,
    projection_uncertainty,
)
from ccs_kornia.modules.calibration.result import ViewReason
from ccs_kornia.modules.calibration.solver import CalibrationSolver

F64 = torch.float64
SIZE = (640, 480)
REAL = REAL_DATA


def views(C=20, V=10, tilt=(10.0, 40.0), axis="random", signed=True, roll=30.0, noise=(0.1, 0.5), seed=0,
          board=(9, 6), square=0.025, fill=(0.35, 0.7), offset=0.25, dist_scale=1.0, fx=(400.0, 1000.0), nv=None):
    """C random cameras (fx, fy, cx, cy, opencv5 distortion) each seeing V board poses; analytic noisy corners.

    tilt: range of the board tilt (deg) against the image plane; axis: ``random`` tilt axis per view, ``x``
    (about the image x axis only) or a fixed angle (rad); signed: random tilt sign; fill: board width / image
    width; offset: board centre within +-offset of the image size from the centre; nv: (lo, hi) views used
    per camera (the rest invalid).
    """
    g = torch.Generator().manual_seed(seed)
    r = lambda *s: torch.rand(*s, generator=g, dtype=F64)  # noqa: E731
    W, H = SIZE
    f = fx[0] + (fx[1] - fx[0]) * r(C)
    K = torch.zeros(C, 3, 3, dtype=F64)
    K[:, 0, 0], K[:, 1, 1] = f, f * (0.97 + 0.06 * r(C))
    K[:, 0, 2], K[:, 1, 2], K[:, 2, 2] = (W - 1) / 2 + 40 * (r(C) - 0.5), (H - 1) / 2 + 30 * (r(C) - 0.5), 1
    dist = torch.zeros(C, 5, dtype=F64)
    dist[:, 0], dist[:, 1] = dist_scale * (-0.3 + 0.4 * r(C)), dist_scale * 0.1 * (r(C) - 0.5)
    dist[:, 2:4] = dist_scale * 2e-3 * (r(C, 2) - 0.5)
    obj = board_object_points(*board, square, dtype=F64)
    th = torch.deg2rad(tilt[0] + (tilt[1] - tilt[0]) * r(C, V))
    if signed:
        th = th * torch.where(r(C, V) < 0.5, -1.0, 1.0)
    phi = {"random": 2 * math.pi * r(C, V), "x": torch.zeros(C, V, dtype=F64)}.get(axis) if isinstance(axis, str) \
        else torch.full((C, V), float(axis), dtype=F64)
    ax = torch.stack([phi.cos(), phi.sin(), torch.zeros_like(phi)], -1) * th[..., None]
    psi = math.radians(roll) * (2 * r(C, V) - 1)
    rz = torch.stack([torch.zeros_like(psi), torch.zeros_like(psi), psi], -1)
    R = axis_angle_to_rotation_matrix(ax.reshape(-1, 3)) @ axis_angle_to_rotation_matrix(rz.reshape(-1, 3))
    R = R.reshape(C, V, 3, 3)
    Z = f[:, None] * (board[0] - 1) * square / ((fill[0] + (fill[1] - fill[0]) * r(C, V)) * W)
    u = (W - 1) / 2 + offset * W * (2 * r(C, V) - 1)
    v = (H - 1) / 2 + offset * H * (2 * r(C, V) - 1)
    ray = torch.stack([(u - K[:, None, 0, 2]) / K[:, None, 0, 0], (v - K[:, None, 1, 2]) / K[:, None, 1, 1],
                       torch.ones_like(u)], -1)
    tvec = ray * Z[..., None] - R @ obj.mean(0)
    rvec = rotation_matrix_to_axis_angle(R.reshape(-1, 3, 3)).reshape(C, V, 3)
    N = obj.shape[0]
    clean = project_points(obj.expand(C, V, N, 3), K[:, None].expand(C, V, 3, 3), dist[:, None].expand(C, V, 5), rvec,
                           tvec)
    sigma = noise[0] + (noise[1] - noise[0]) * r(C)
    uv = clean + sigma[:, None, None, None] * torch.randn(clean.shape, generator=g, dtype=F64)
    valid = (uv[..., 0] >= 0) & (uv[..., 0] <= W - 1) & (uv[..., 1] >= 0) & (uv[..., 1] <= H - 1)
    if nv is not None:
        n = nv[0] + ((nv[1] - nv[0] + 1) * r(C)).long().clamp(max=nv[1] - nv[0])
        valid = valid & (torch.arange(V)[None] < n[:, None])[..., None]
    return dict(K=K, dist=dist, rvec=rvec, tvec=tvec, obj=obj, uv=uv, clean=clean, valid=valid, sigma=sigma)


def rel_fx_error(res, d):
    return ((res.K[:, 0, 0] - d["K"][:, 0, 0]).abs() / d["K"][:, 0, 0]).nan_to_num(float("inf"))


def assert_never_confidently_wrong(res, d, tol=0.05):
    """Never ``success`` with an fx error above ``tol`` and no warning."""
    warned = (res.check_severity > 0).any(-1)
    silent_wrong = res.success & ~warned & (rel_fx_error(res, d) > tol)
    assert not bool(silent_wrong.any()), f"{int(silent_wrong.sum())} confidently wrong cameras"


def checks_of(res, c=0, severity=None):
    names = [CHECKS[k] for k in range(len(CHECKS)) if int(res.check_severity[c, k]) > 0]
    if severity is not None:
        names = [CHECKS[k] for k in range(len(CHECKS)) if int(res.check_severity[c, k]) == severity]
    return names


# ------------------------------------------------------------------------------------------ degenerate input
def test_three_copies_of_one_synthetic_view_are_refused():
    """The issue's case: three copies of one view gave success, fx 922 instead of 620 and a std of 14.8 px."""
    d = views(C=1, V=1, fx=(620.0, 620.0), seed=3)
    uv = d["uv"][0, 0].expand(3, -1, -1)
    res = CalibrationSolver()(uv, None, d["obj"], SIZE)
    assert not bool(res.success) and res.K.isnan().all()
    assert res.view_reason.tolist() == [ViewReason.USED, ViewReason.DUPLICATE, ViewReason.DUPLICATE]
    issue = next(i for i in res.issues()[0] if i["check"] == "duplicate_views")
    assert issue["severity"] == "error" and issue["views"] == [1, 2] and "copies" in issue["message"]


@pytest.fixture(scope="module")
def left02_corners():
    cv2 = pytest.importorskip("cv2")
    path = REAL / "opencv_left" / "left02.jpg"
    if not path.is_file():
        pytest.skip(f"real image not available at {path}")
    ok, c = cv2.findChessboardCornersSB(cv2.imread(str(path), cv2.IMREAD_GRAYSCALE), (9, 6))
    assert ok
    return torch.tensor(c.reshape(-1, 2), dtype=F64)


@pytest.mark.parametrize("model", [OPENCV5, K1K2])
def test_four_copies_of_one_photo_are_refused(left02_corners, model):
    """Four copies of left02.jpg: was success with fx 316-612 (true ~533) and no warning."""
    obj = board_object_points(9, 6, 0.025, dtype=F64)
    res = CalibrationSolver(model=model)(left02_corners.expand(4, -1, -1), None, obj, SIZE)
    assert not bool(res.success)
    errors = [i for i in res.issues()[0] if i["severity"] == "error"]
    assert errors[0]["check"] == "duplicate_views" and errors[0]["views"] == [1, 2, 3]
    assert "only 1 distinct view" in errors[0]["message"]


def test_four_copies_of_one_photo_cli(tmp_path, capsys):
    import shutil

    from ccs_kornia import cli

    src = REAL / "opencv_left" / "left02.jpg"
    if not src.is_file():
        pytest.skip(f"real image not available at {src}")
    for i in range(4):
        shutil.copy(src, tmp_path / f"copy{i}.jpg")
    code = cli.main(["calibrate", str(tmp_path / "copy*.jpg"), "--board", "9x6", "--detector", "opencv",
                     "--no-distortion-correction", "--output", str(tmp_path / "calib.json")])
    err = capsys.readouterr().err
    assert code != 0 and not (tmp_path / "calib.json").exists()
    assert "refused" in err and "copies" in err and "Traceback" not in err


def test_copies_are_dropped_before_the_covariance():
    """Copies among good views: the result and its std are those of the distinct views, with a warning."""
    d = views(C=1, V=8, seed=4)
    uv, valid = d["uv"][0], d["valid"][0]
    dup = torch.cat([uv, uv[[2, 5]]]), torch.cat([valid, valid[[2, 5]]])
    solver = CalibrationSolver()
    ref, res = solver(uv, valid, d["obj"], SIZE), solver(*dup, d["obj"], SIZE)
    assert bool(res.success) and res.view_reason[8:].tolist() == [ViewReason.DUPLICATE] * 2
    torch.testing.assert_close(res.K, ref.K)
    torch.testing.assert_close(res.std_intrinsics, ref.std_intrinsics)
    issue = next(i for i in res.issues()[0] if i["check"] == "duplicate_views")
    assert issue["severity"] == "warning" and issue["views"] == [8, 9]
    # a copy detected rotated by 180 degrees (reversed grid order) is a copy too
    assert duplicate_views(torch.stack([uv[0], uv[1], uv[0].flip(0)])).tolist() == [-1, -1, 0]


def test_near_identical_views_warn():
    d = views(C=1, V=6, seed=5)
    uv, valid = d["uv"][0], d["valid"][0]
    near = uv[[1]] + torch.tensor([1.5, -1.0], dtype=F64)  # the board moved by ~2 px: not a copy, no new pose
    res = CalibrationSolver()(torch.cat([uv, near]), torch.cat([valid, valid[[1]]]), d["obj"], SIZE)
    assert bool(res.success) and res.view_reason[6] == ViewReason.USED
    issue = next(i for i in res.issues()[0] if i["check"] == "near_identical_views")
    assert issue["severity"] == "warning" and issue["views"] == [1, 6]


@pytest.mark.parametrize("max_tilt", [0.5, 2.0])
def test_fronto_parallel_views_are_refused(max_tilt):
    """Tilts below a few degrees: the focal length trades off against the distance (Zhang is degenerate)."""
    d = views(C=20, V=10, tilt=(0.0, max_tilt), seed=6)
    res = CalibrationSolver()(d["uv"], d["valid"], d["obj"], SIZE)
    assert not bool(res.success.any())
    for c in range(20):
        assert {"pose_diversity", "focal_uncertainty"} & set(checks_of(res, c, degeneracy.ERROR))


def test_weak_cameras_are_kept_with_refuse_weak_off():
    """``refuse_weak=False``: the nearly parallel cameras are calibrated, their checks stay errors (the verdict says
    not reliable and why), the uncertainty that says it is there; copies of one view are refused all the same."""
    d = views(C=20, V=10, tilt=(0.0, 2.0), seed=6)
    weak = degeneracy.DegeneracyThresholds(refuse_weak=False)
    res = CalibrationSolver(thresholds=weak)(d["uv"], d["valid"], d["obj"], SIZE)
    assert bool(res.success.all()) and bool(res.K.isfinite().all())
    for c in range(20):
        assert {"pose_diversity", "focal_uncertainty"} & set(checks_of(res, c, degeneracy.ERROR))
    assert (res.std_intrinsics[:, 0] / res.K[:, 0, 0] > weak.focal_std_error).any()  # why: fx barely determined
    fig = diagnose(res, d["uv"], d["valid"], d["obj"], SIZE)[0]
    assert fig["verdict"].startswith("not reliable: ")
    copies = d["uv"][0, :1].expand(4, -1, -1)
    assert not bool(CalibrationSolver(thresholds=weak)(copies, None, d["obj"], SIZE).success)


def test_fronto_parallel_without_noise_is_refused_by_geometry():
    """Noise-free data leave the covariance at 0: the pose check must refuse on its own."""
    d = views(C=5, V=8, tilt=(0.0, 1.0), noise=(0.0, 0.0), seed=7)
    res = CalibrationSolver()(d["clean"], d["valid"], d["obj"], SIZE)
    assert not bool(res.success.any())
    assert all("pose_diversity" in checks_of(res, c, degeneracy.ERROR) for c in range(5))


def test_parallel_boards_are_refused():
    """Every board tilted by the same 30 degrees about the same axis: parallel planes, degenerate."""
    d = views(C=10, V=10, tilt=(30.0, 30.0), axis=0.3, signed=False, seed=8)
    res = CalibrationSolver()(d["uv"], d["valid"], d["obj"], SIZE)
    assert not bool(res.success.any())
    assert all("pose_diversity" in checks_of(res, c, degeneracy.ERROR) for c in range(10))


@pytest.mark.parametrize("tilt", [(0.0, 5.0), (0.0, 10.0), (3.0, 8.0), (5.0, 15.0)])
def test_weak_tilt_is_never_confidently_wrong(tilt):
    d = views(C=30, V=8, tilt=tilt, seed=9)
    res = CalibrationSolver()(d["uv"], d["valid"], d["obj"], SIZE)
    assert_never_confidently_wrong(res, d)


def test_one_tilt_direction_warns():
    d = views(C=20, V=10, tilt=(0.0, 40.0), axis="x", roll=0.0, seed=10)
    res = CalibrationSolver()(d["uv"], d["valid"], d["obj"], SIZE)
    assert_never_confidently_wrong(res, d)
    flagged = torch.tensor(["tilt_direction" in checks_of(res, c) or not bool(res.success[c]) for c in range(20)])
    assert flagged.all()
    assert float(res.check_value[:, CHECKS.index("tilt_direction")].max()) < 1.0  # degrees across the axis


@pytest.mark.parametrize("board,model,severity", [((2, 2), K1K2, degeneracy.ERROR),
                                                  ((3, 2), OPENCV5, degeneracy.WARNING),
                                                  ((3, 2), RATIONAL, degeneracy.WARNING)])
def test_too_few_corners_per_unknown(board, model, severity):
    d = views(C=20, V=3, board=board, seed=11)
    res = CalibrationSolver(model=model)(d["uv"], d["valid"], d["obj"], SIZE)
    k = CHECKS.index("corners_per_unknown")
    assert (res.check_severity[:, k] >= severity).all()
    if severity == degeneracy.ERROR:
        assert not bool(res.success.any())
    assert_never_confidently_wrong(res, d)


def test_small_coverage_warns_and_says_where():
    d = views(C=10, V=10, fill=(0.2, 0.3), offset=0.05, seed=12)
    solver = CalibrationSolver()
    res = solver(d["uv"], d["valid"], d["obj"], SIZE)
    assert_never_confidently_wrong(res, d)
    k = CHECKS.index("image_coverage")
    assert (res.check_severity[:, k] == degeneracy.WARNING).all()
    assert (res.check_value[:, k] < 0.2).all()
    fig = diagnose(res, d["uv"], d["valid"], d["obj"], SIZE)[0]
    assert fig["verdict"] != "good"
    assert any("image corners" in r for r in fig["reasons"])


def test_good_sets_pass_every_check():
    d = views(C=20, V=12, seed=13)
    res = CalibrationSolver()(d["uv"], d["valid"], d["obj"], SIZE)
    assert bool(res.success.all()) and (res.check_severity == 0).all()
    assert rel_fx_error(res, d).max() < 0.02


def test_checks_can_be_disabled():
    d = views(C=1, V=1, seed=3)
    uv = d["uv"][0, 0].expand(3, -1, -1)
    res = CalibrationSolver(checks=False)(uv, None, d["obj"], SIZE)
    assert bool(res.success) and res.check_severity is None and res.issues() == [[]]


def test_pose_spread_measures():
    rv = torch.tensor([[[0.0, 0, 0], [0.3, 0, 0], [-0.3, 0, 0]], [[0.0, 0, 0], [0.3, 0, 0], [0, 0.3, 0]]], dtype=F64)
    s = pose_spread(rv, torch.ones(2, 3, dtype=torch.bool))
    assert s[0, 0] == pytest.approx(math.degrees(0.6)) and s[0, 1] < 1e-6  # one axis
    assert s[1, 1] > 5  # two axes


# ------------------------------------------------------------------------------------------ honest uncertainty
def test_fx_std_is_calibrated_over_200_trials():
    """An honest fx std: |fx error| within 1 std in 55-80 % and within 2 std in >= 90 % of 200 trials."""
    d = views(C=200, V=20, nv=(5, 20), tilt=(5.0, 50.0), noise=(0.1, 0.5), seed=2024)
    res = CalibrationSolver()(d["uv"], d["valid"], d["obj"], SIZE)
    assert bool(res.success.all())
    z = (res.K[:, 0, 0] - d["K"][:, 0, 0]).abs() / res.std_intrinsics[:, 0]
    one, two = float((z <= 1).double().mean()), float((z <= 2).double().mean())
    assert 0.55 <= one <= 0.80, one
    assert two >= 0.90, two


def test_cov_camera_matches_the_reported_std():
    d = views(C=4, V=8, seed=14)
    for model in (OPENCV5, K1K2, PINHOLE):
        res = CalibrationSolver(model=model)(d["uv"], d["valid"], d["obj"], SIZE)
        D = res.dist.shape[-1]
        assert res.cov_camera.shape == (4, 4 + D, 4 + D)
        std = res.cov_camera.diagonal(dim1=-2, dim2=-1).sqrt()
        torch.testing.assert_close(std[:, :4], res.std_intrinsics)
        torch.testing.assert_close(std[:, 4:], res.std_dist)
        torch.testing.assert_close(res.cov_camera, res.cov_camera.transpose(-1, -2))


def test_std_grows_when_the_data_do_not_constrain_fx():
    good = views(C=10, V=10, tilt=(20.0, 45.0), seed=15)
    weak = views(C=10, V=10, tilt=(0.0, 5.0), seed=15)
    solver = CalibrationSolver(checks=False)
    s_good = solver(good["uv"], good["valid"], good["obj"], SIZE).std_intrinsics[:, 0] / good["K"][:, 0, 0]
    s_weak = solver(weak["uv"], weak["valid"], weak["obj"], SIZE).std_intrinsics[:, 0] / weak["K"][:, 0, 0]
    assert float(s_weak.median()) > 10 * float(s_good.median())


# ------------------------------------------------------------------------------------------ projection uncertainty
def _monte_carlo(model, V, sigma, M=100, seed=16):
    d = views(C=1, V=V, noise=(0.0, 0.0), seed=seed)
    g = torch.Generator().manual_seed(1)
    uv = d["clean"].expand(M, -1, -1, -1) + sigma * torch.randn((M,) + d["clean"].shape[1:], generator=g, dtype=F64)
    res = CalibrationSolver(model=model)(uv, d["valid"].expand(M, -1, -1), d["obj"], SIZE)
    return d, res


@pytest.mark.parametrize("compensate", [False, True])
def test_projection_uncertainty_matches_monte_carlo(compensate):
    from ccs_kornia.geometry.camera import Camera
    from ccs_kornia.modules.calibration.quality.uncertainty import (
        image_rays,
        remove_rotation,
        storage_jacobians,
    )

    d, res = _monte_carlo(OPENCV5, 12, 0.3)
    assert bool(res.success.all())
    grid = image_points(SIZE, (16, 12))
    px = torch.cat([grid, image_points(SIZE)])
    fit = (torch.arange(px.shape[0]) < grid.shape[0]) if compensate else None
    pred = projection_uncertainty(res.camera, res.cov_camera, px, compensate_rotation=fit)[:, -5:].nanmedian(0).values
    truth = Camera.from_opencv(OPENCV5, d["K"], d["dist"], SIZE)
    q, _, A = storage_jacobians(res.camera, image_rays(truth, px).expand(res.K.shape[0], -1, -1))
    dq = (q - px)[..., None]
    if compensate:
        dq = remove_rotation(dq, A, fit)
    dq = dq[..., 0][:, -5:]
    dq = dq - dq.mean(0)
    emp = torch.linalg.eigvalsh(torch.einsum("mgi,mgj->gij", dq, dq) / (dq.shape[0] - 1))[:, -1].sqrt()
    ratio = pred / emp
    assert ((ratio > 0.7) & (ratio < 1.3)).all(), ratio


def test_projection_uncertainty_grows_with_noise_and_fewer_views():
    solver = CalibrationSolver()
    out = {}
    for key, V, noise in (("base", 16, (0.2, 0.2)), ("noisy", 16, (0.6, 0.6)), ("few", 5, (0.2, 0.2))):
        d = views(C=8, V=V, noise=noise, seed=17)
        res = solver(d["uv"], d["valid"], d["obj"], SIZE)
        out[key] = projection_uncertainty(res.camera, res.cov_camera, image_points(SIZE)).nanmedian(0).values
    assert (out["noisy"] > 2 * out["base"]).all() and (out["few"] > out["base"]).all()


# ------------------------------------------------------------------------------------------ cross-validation
def test_cross_validation_is_consistent_with_the_noise():
    d = views(C=6, V=16, seed=18)
    solver = CalibrationSolver()
    res = solver(d["uv"], d["valid"], d["obj"], SIZE)
    cv = cross_validation(solver, d["uv"], d["valid"], d["obj"], SIZE, res)
    assert cv["cv_rms_px"].isfinite().all() and cv["heldout_rms_px"].isfinite().all()
    ratio = cv["cv_rms_px"] / cv["cv_expected_rms_px"]
    assert (ratio < 3).all(), ratio  # no systematic error: the halves differ by what the noise explains
    assert (cv["heldout_views"] == 16).all()
    held = cv["heldout_rms_px"] / res.rms
    assert ((held > 0.95) & (held < 1.3)).all(), held
    # noise-free: the halves agree
    res0 = solver(d["clean"], d["valid"], d["obj"], SIZE)
    cv0 = cross_validation(solver, d["clean"], d["valid"], d["obj"], SIZE, res0)
    assert (cv0["cv_max_px"] < 1e-3).all() and (cv0["heldout_rms_px"] < 1e-4).all()


def test_cross_validation_exposes_a_model_that_does_not_fit():
    """A pinhole model on a lens with k1 = -0.3: the halves disagree far beyond the noise."""
    d = views(C=6, V=16, dist_scale=0.0, seed=19)
    d["dist"][:, 0] = -0.3
    N = d["obj"].shape[0]
    d["uv"] = project_points(d["obj"].expand(6, 16, N, 3), d["K"][:, None].expand(6, 16, 3, 3),
                             d["dist"][:, None].expand(6, 16, 5), d["rvec"], d["tvec"])
    d["uv"] = d["uv"] + 0.2 * torch.randn(d["uv"].shape, generator=torch.Generator().manual_seed(0), dtype=F64)
    ratios = {}
    for model in (PINHOLE, K1K2):
        solver = CalibrationSolver(model=model)
        res = solver(d["uv"], d["valid"], d["obj"], SIZE)
        figs = diagnose(res, d["uv"], d["valid"], d["obj"], SIZE, solver)
        ratios[model] = torch.tensor([f["cv_rms_px"] / f["cv_expected_rms_px"] for f in figs])
        verdicts = [f["verdict"] for f in figs]
        if model == PINHOLE:  # never "good"; mostly refused as not reliable
            assert "good" not in verdicts and sum(v.startswith("not reliable") for v in verdicts) >= 4, verdicts
        else:  # the right model: at most one camera (weak geometry) not reliable
            assert sum(v.startswith("not reliable") for v in verdicts) <= 1, verdicts
    assert float(ratios[PINHOLE].median()) > 2 * float(ratios[K1K2].median()), ratios


# ------------------------------------------------------------------------------------------ diagnose / verdict
def test_diagnose_is_json_and_documented_keys():
    d = views(C=2, V=12, seed=20)
    solver = CalibrationSolver()
    res = solver(d["uv"], d["valid"], d["obj"], SIZE)
    figs = diagnose(res, d["uv"], d["valid"], d["obj"], SIZE, solver)
    json.dumps(figs, allow_nan=False)
    keys = {"success", "rms_px", "errors", "warnings", "checks", "std", "uncertainty_centre_px",
            "uncertainty_corners_px", "uncertainty_max_px", "uncertainty_covered_px", "uncertainty_grid_px",
            "uncertainty_fixed_ray_px", "cv_rms_px", "cv_max_px", "cv_expected_rms_px", "cv_covered_rms_px",
            "cv_covered_expected_rms_px", "heldout_rms_px", "heldout_views", "covered_fraction", "unprojectable_fraction",
            "unprojectable_covered", "residual_structure", "verdict", "reasons"}
    assert all(set(f) == keys for f in figs), set(figs[0]) ^ keys
    for key in sorted(keys):
        assert f"``{key}``" in diagnose.__doc__, key
    assert len(figs[0]["uncertainty_grid_px"]) == 12 and len(figs[0]["uncertainty_corners_px"]) == 4
    # unbatched input gives the same figures as camera 0
    one = diagnose(type(res)(**{k: (v[0] if isinstance(v, torch.Tensor) else v) for k, v in res.__dict__.items()}),
                   d["uv"][0], d["valid"][0], d["obj"], SIZE, solver)
    assert one[0]["verdict"] == figs[0]["verdict"]
    assert one[0]["uncertainty_centre_px"] == pytest.approx(figs[0]["uncertainty_centre_px"], rel=1e-6)


def test_diagnose_of_a_refused_calibration():
    d = views(C=1, V=1, seed=3)
    uv = d["uv"][0, 0].expand(3, -1, -1)
    solver = CalibrationSolver()
    fig = diagnose(solver(uv, None, d["obj"], SIZE), uv, None, d["obj"], SIZE, solver)[0]
    json.dumps(fig, allow_nan=False)
    assert fig["success"] is False and fig["verdict"].startswith("not reliable: ")
    assert "remove duplicate views 1, 2" in fig["verdict"] and fig["errors"]


def test_verdict_levels():
    base = {"rms_px": 0.3, "uncertainty_covered_px": 0.3, "uncertainty_max_px": 1.0, "cv_rms_px": 0.4,
            "cv_covered_rms_px": 0.3, "cv_expected_rms_px": 0.4, "cv_covered_expected_rms_px": 0.3,
            "heldout_rms_px": 0.31}
    assert verdict(base, []) == ("good", [])
    assert verdict({**base, "uncertainty_covered_px": 1.0}, [])[0] == "usable"
    assert verdict({**base, "uncertainty_max_px": 9.0}, [])[0] == "usable"
    assert verdict({**base, "uncertainty_covered_px": 5.0}, [])[0].startswith("not reliable: add views")
    assert verdict({**base, "cv_rms_px": 4.0, "cv_covered_rms_px": 3.0}, [])[0].startswith("not reliable: the lens")
    assert verdict({**base, "rms_px": 3.0, "heldout_rms_px": 3.1}, [])[0].startswith("not reliable: check the corner")
    warn = [{"check": "tilt_direction", "severity": "warning", "message": "all views ...: tilt", "views": []}]
    assert verdict(base, warn) == ("usable", ["all views ...: tilt"])


def test_the_verdict_says_what_the_halves_say():
    base = {"rms_px": 0.15, "uncertainty_covered_px": 0.2, "uncertainty_max_px": 1.5, "cv_rms_px": 2.0,
            "cv_covered_rms_px": 0.2, "cv_expected_rms_px": 3.0, "cv_covered_expected_rms_px": 0.2,
            "heldout_rms_px": 0.16}
    assert verdict(base, []) == ("good", [])
    # halves 25.5 px apart over the image, as the covariances predict: outside the boards the views say nothing
    far = verdict({**base, "cv_rms_px": 25.5, "cv_expected_rms_px": 30.0}, [])
    assert far[0] == "usable" and any("two halves of the views disagree by 25.5 px" in r for r in far[1])
    runner = {"model": "opencv5", "halves_rms_px": 20.5, "tied": True}
    tied = verdict({**base, "runner_up": runner}, [])  # said, not graded: the chosen model's own halves agree
    assert tied[0] == "good" and "the runner-up model opencv5" in tied[1][0] and "20.5 px" in tied[1][0]
    assert verdict({**base, "runner_up": {**runner, "tied": False}}, []) == ("good", [])
    assert verdict({**base, "runner_up": {**runner, "halves_rms_px": 5.0}}, []) == ("good", [])
    # the limit scales with the image as the other pixel limits
    wide = {**base, "cv_rms_px": 15.0, "cv_expected_rms_px": 30.0}
    assert verdict(wide, [], diagnostics.VerdictThresholds().scaled(2.0)) == ("good", [])
    assert verdict(wide, [])[0] == "usable"


@pytest.mark.parametrize("module", [degeneracy, coverage, uncertainty, diagnostics])
def test_doctests(module):
    result = doctest.testmod(module, optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE)
    assert result.failed == 0 and result.attempted > 0


def test_check_degeneracy_unbatched_matches_batched():
    d = views(C=1, V=6, seed=21)
    res = CalibrationSolver(checks=False)(d["uv"], d["valid"], d["obj"], SIZE)
    a = check_degeneracy(d["uv"], d["valid"], d["obj"], SIZE, res.used, res.rvec, res.K, res.std_intrinsics)
    b = check_degeneracy(d["uv"][0], d["valid"][0], d["obj"], SIZE, res.used[0], res.rvec[0], res.K[0],
                         res.std_intrinsics[0])
    assert torch.equal(a.severity[0], b.severity) and torch.allclose(a.value[0], b.value, equal_nan=True)
    assert a.issues() == b.issues()


@pytest.mark.parametrize("scale", [2.0, 4.0])
def test_the_same_camera_at_a_higher_resolution_gets_the_same_verdict(scale):
    """Every pixel figure of a set photographed at ``scale`` times the resolution is ``scale`` times larger; the
    verdict's pixel limits scale with the image (``pixel_scale``), so the verdict is the same."""
    d = views(C=4, V=12, noise=(0.9, 1.5), seed=23)
    solver = CalibrationSolver()
    big = (int(SIZE[0] * scale), int(SIZE[1] * scale))
    levels = {}
    for s, size in ((1.0, SIZE), (scale, big)):
        uv = d["uv"] * s
        res = solver(uv, d["valid"], d["obj"], size)
        figs = diagnose(res, uv, d["valid"], d["obj"], size, solver)
        levels[s] = [f["verdict"].split(":")[0] for f in figs]
        rms = [f["rms_px"] for f in figs]
        assert all(r > 0.8 * s for r in rms), rms  # the figures did grow with the image
    assert levels[1.0] == levels[scale], levels
    assert "good" not in levels[1.0]  # a set whose verdict depends on the pixel limits
    assert diagnostics.pixel_scale((320, 240)) == 1.0 and diagnostics.pixel_scale(big) == scale
    limits = diagnostics.VerdictThresholds().scaled(scale)
    assert limits.good_rms_px == scale and limits.cv_ratio == diagnostics.VerdictThresholds().cv_ratio
