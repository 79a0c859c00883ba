"""Tests of CalibrationPipeline: detection + solver, batched over cameras, stages alone."""

from __future__ import annotations

import pytest
import torch

from ccs_kornia.data.scenes.scenes import make_calibration_set
from ccs_kornia.geometry.metrics import e_ip
from ccs_kornia.geometry.models import FISHEYE, K1K2, OPENCV5, PINHOLE, RATIONAL
from ccs_kornia.modules.calibration.model_selection import ModelChoice
from ccs_kornia.modules.detection.opencv_detector import OpenCVChessboardDetector
from ccs_kornia.pipeline.calibration_pipeline import CalibrationPipeline, PipelineResult

BOARD = (9, 6)
SQUARE = 0.025
CAMERAS = [
    (torch.tensor([[620.0, 0.0, 322.0], [0.0, 610.0, 236.0], [0.0, 0.0, 1.0]], dtype=torch.float64),
     torch.tensor([-0.28, 0.09, 0.0005, -0.0008, 0.0], dtype=torch.float64)),
    (torch.tensor([[540.0, 0.0, 310.0], [0.0, 545.0, 250.0], [0.0, 0.0, 1.0]], dtype=torch.float64),
     torch.tensor([-0.1, 0.02, 0.0, 0.0, 0.0], dtype=torch.float64)),
]
VIEWS = 10


@pytest.fixture(scope="module")
def sets():
    return [make_calibration_set(K, BOARD, SQUARE, (640, 480), num_views=VIEWS, dist=d, seed=11 + c, supersample=2)
            for c, (K, d) in enumerate(CAMERAS)]


@pytest.fixture(scope="module")
def images(sets):
    return torch.stack([s.images for s in sets])  # (C, V, 1, H, W)


@pytest.fixture(scope="module")
def batched_result(images):
    # the detection + solver plumbing; the distortion correction has its own tests below
    return CalibrationPipeline("opencv", model=OPENCV5, seed=0, distortion_correction=False)(images, BOARD, SQUARE)


def test_batched_shapes(batched_result):
    assert isinstance(batched_result, PipelineResult)
    det, cal = batched_result.detections, batched_result.calibration
    assert det.corners.shape == (2, VIEWS, 54, 2) and det.found.shape == (2, VIEWS)
    assert cal.K.shape == (2, 3, 3) and cal.dist.shape == (2, 5)
    assert cal.rvec.shape == (2, VIEWS, 3) and cal.view_rms.shape == (2, VIEWS)
    assert cal.camera.model == OPENCV5


def test_batched_accuracy(batched_result):
    det, cal = batched_result.detections, batched_result.calibration
    assert bool(det.found.all())
    assert bool(cal.success.all())
    K_true = torch.stack([K for K, _ in CAMERAS])
    err = e_ip(cal.K.double(), K_true)
    print("E_IP per camera (px):", err.tolist(), "RMS:", cal.rms.tolist())
    assert float(err.max()) < 2.0, err
    assert float(cal.rms.max()) < 0.1
    k1_true = torch.stack([d[0] for _, d in CAMERAS])
    assert float((cal.dist[:, 0].double() - k1_true).abs().max()) < 0.02


def test_unbatched_equals_batched_camera(images, batched_result):
    pipe = CalibrationPipeline(OpenCVChessboardDetector(), model=OPENCV5, seed=0, distortion_correction=False)
    single = pipe(images[1], BOARD, SQUARE)
    assert single.calibration.K.shape == (3, 3) and single.detections.corners.shape == (VIEWS, 54, 2)
    torch.testing.assert_close(single.detections.corners, batched_result.detections.corners[1])
    torch.testing.assert_close(single.calibration.K, batched_result.calibration.K[1], atol=1e-3, rtol=1e-6)


def test_stages_alone(images, batched_result):
    pipe = CalibrationPipeline("opencv", model=K1K2, detection_batch_size=3, distortion_correction=False)
    det = pipe.detect(images[0], BOARD)
    torch.testing.assert_close(det.corners, batched_result.detections.corners[0])
    # per-view validity is expanded to every corner
    cal = pipe.calibrate(det.corners, det.found, BOARD, SQUARE, (640, 480))
    assert cal.dist.shape[-1] == 5 and float(cal.dist[2:].abs().max()) == 0.0  # k1k2: p1 = p2 = k3 = 0
    assert abs(float(cal.K[0, 0]) - 620.0) < 5.0


@pytest.mark.parametrize("model", [OPENCV5, ModelChoice()], ids=str)
def test_stages_alone_reproduce_the_whole_call_with_the_corner_precision(sets, model):
    """``detect`` then ``calibrate`` with the detection's ``sigma`` weighs the corners as the whole call does."""
    pipe = CalibrationPipeline("opencv", model=model, seed=0, distortion_correction=False)
    imgs = sets[0].images[:6]
    whole = pipe(imgs, BOARD, SQUARE)
    det = pipe.detect(imgs, BOARD)
    assert det.sigma is not None and det.sigma.shape == det.corners.shape[:-1]
    cal = pipe.calibrate(det.corners, det.found, BOARD, SQUARE, (640, 480), det.correction, det.correction_tried,
                         sigma=det.sigma)
    torch.testing.assert_close(cal.K, whole.K)
    unweighted = pipe.calibrate(det.corners, det.found, BOARD, SQUARE, (640, 480), det.correction,
                                det.correction_tried)
    assert not torch.equal(unweighted.K, whole.K)
    with pytest.raises(ValueError, match="sigma"):
        pipe.calibrate(det.corners, det.found, BOARD, SQUARE, (640, 480), sigma=det.sigma[:, :5])


def test_auto_models_are_the_candidates_of_auto():
    pipe = CalibrationPipeline("opencv", model=ModelChoice((K1K2, OPENCV5, FISHEYE)), distortion_correction=False)
    assert list(pipe.solvers) == [K1K2, OPENCV5, FISHEYE] and pipe.solver.model == OPENCV5
    assert list(CalibrationPipeline("opencv", model=ModelChoice(), distortion_correction=False).solvers) == [
        K1K2, OPENCV5, RATIONAL, FISHEYE]
    assert list(CalibrationPipeline("opencv", model=K1K2, distortion_correction=False).solvers) == [K1K2]
    assert CalibrationPipeline("opencv", model=ModelChoice((FISHEYE,)), distortion_correction=False).solver.model == FISHEYE
    for bad in ((), (PINHOLE,)):
        with pytest.raises(ValueError, match="candidates"):
            CalibrationPipeline("opencv", model=ModelChoice(bad), distortion_correction=False)


def test_ground_truth_corners_through_solver_stage(sets):
    # the solver stage alone on exact corners: the pipeline's plumbing adds no error
    pipe = CalibrationPipeline("opencv")
    s = sets[0]
    cal = pipe.calibrate(s.corners.double(), s.corner_valid, BOARD, SQUARE, s.image_size)
    assert float(e_ip(cal.K, CAMERAS[0][0])) < 1e-3


def test_input_validation(images):
    pipe = CalibrationPipeline("opencv")
    with pytest.raises(ValueError, match="grey images"):
        pipe.detect(torch.zeros(2, 3, 32, 32), BOARD)
    with pytest.raises(ValueError, match="corners"):
        pipe.calibrate(torch.zeros(4, 10, 2), torch.ones(4, dtype=torch.bool), BOARD, SQUARE, (640, 480))
    with pytest.raises(ValueError, match="square"):
        pipe.calibrate(torch.zeros(4, 54, 2), torch.ones(4, dtype=torch.bool), BOARD, 0.0, (640, 480))
    with pytest.raises(ValueError, match="detector"):
        CalibrationPipeline("magic")


def test_result_shortcuts_and_inference_mode(images):
    # the pipeline drops into other torch code: under inference_mode, on a tensor from elsewhere
    pipe = CalibrationPipeline("opencv")  # distortion correction on (the default)
    with torch.inference_mode():
        out = pipe(images[0, :6].clone(), BOARD, SQUARE)
    assert out.K.shape == (3, 3) and out.dist.shape == (5,) and out.std.shape == (9,)
    assert out.rvec.shape == (6, 3) and out.tvec.shape == (6, 3) and out.view_rms.shape == (6,)
    assert out.used.dtype == torch.bool and out.found.all() and bool(out.calibration.success)
    assert torch.equal(out.K, out.calibration.K) and float(out.rms) < 0.1
    assert bool((out.std[:4] > 0).all()) and bool(out.std.isfinite().all())


def test_large_images_detected_downscaled_and_refined(sets):
    # max_detection_side below the image size: detect on a half-size copy, refine at full size
    s = sets[1]
    full = CalibrationPipeline("opencv", max_detection_side=None).detect(s.images[:4], BOARD)
    small = CalibrationPipeline("opencv", max_detection_side=320).detect(s.images[:4], BOARD)
    assert bool(small.found.all())
    gt = s.corners[:4].double()

    def err(c):
        c = c.double()
        return (c - gt).norm(dim=-1).mean(-1)

    print("corner error full-res detection:", err(full.corners).tolist(), "downscaled+refined:", err(small.corners).tolist())
    assert float(err(small.corners).max()) < 0.1
    with pytest.raises(ValueError, match="max_detection_side"):
        CalibrationPipeline("opencv", max_detection_side=10)


# ----------------------------------------------------------------------------------------------
# distortion correction (the shipped DistortionNet)
# ----------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def corrected_result(images):
    return CalibrationPipeline("opencv", seed=0)(images, BOARD, SQUARE)


def test_correction_on_opencv_lenses(corrected_result):
    # OpenCV-model lenses (distortion centred on the principal point, with tangential terms): the corrected
    # path estimates the distortion centre, so it stays accurate where the paper's image-centred model is not
    out = corrected_result
    assert out.correction.shape == (2, 5) and out.corrected.shape == (2,) and out.corrected.dtype == torch.bool
    assert bool(out.found.all()) and bool(out.calibration.success.all())
    K_true = torch.stack([K for K, _ in CAMERAS])
    err = e_ip(out.K.double(), K_true)
    print("E_IP with correction (px):", err.tolist(), "applied:", out.corrected.tolist(), "RMS:", out.rms.tolist())
    assert float(err.max()) < 1.5, err
    assert float(out.rms.max()) < 0.1
    assert bool(out.std.isfinite().all()) and bool((out.std[:, :4] > 0).all())


def test_correction_unbatched_equals_batched(images, corrected_result):
    single = CalibrationPipeline("opencv", seed=0)(images[1], BOARD, SQUARE)
    assert single.correction.shape == (5,) and single.corrected.shape == ()
    # the network's float32 convolutions round differently with another batch composition (~1e-6)
    torch.testing.assert_close(single.correction, corrected_result.correction[1], atol=1e-5, rtol=0)
    torch.testing.assert_close(single.detections.corners, corrected_result.detections.corners[1], atol=1e-3, rtol=0)
    torch.testing.assert_close(single.K, corrected_result.K[1], atol=1e-2, rtol=0)


def test_correction_switch_and_errors(tmp_path):
    from ccs_kornia.modules.correction.distortion_net import DistortionNet

    assert CalibrationPipeline("opencv", distortion_correction=False).distortion_net is None
    from ccs_kornia.modules._fuse import has_batchnorm

    # a net with batch normalisation runs as a folded copy (the caller's is untouched) with the same output;
    # a net without it runs as it is
    net = DistortionNet(base_channels=4, input_size=64).eval()
    got = CalibrationPipeline("opencv", distortion_correction=net).distortion_net
    assert got is not net and has_batchnorm(net) and not has_batchnorm(got)
    x = torch.rand(2, 1, 64, 64, generator=torch.Generator().manual_seed(0))
    with torch.no_grad():
        torch.testing.assert_close(got(x), net(x), atol=1e-5, rtol=1e-5)
    assert CalibrationPipeline("opencv", distortion_correction=got).distortion_net is got
    with pytest.raises(FileNotFoundError, match="distortion_correction=False"):
        CalibrationPipeline("opencv", distortion_correction=str(tmp_path / "missing.pt"))
    with pytest.raises(ValueError, match="joint_iters"):
        CalibrationPipeline("opencv", joint_iters=-1)
    with pytest.raises(ValueError, match="min_correction"):
        CalibrationPipeline("opencv", min_correction=-1.0)
    with pytest.raises(RuntimeError, match="off"):
        CalibrationPipeline("opencv", distortion_correction=False).view_corrections(torch.zeros(1, 1, 32, 32))


def test_correction_on_severe_radial_distortion():
    # the case the correction is for: the paper's radial model, ~18 % at the image corner
    K = torch.tensor([[420.0, 0.0, 326.0], [0.0, 425.0, 236.0], [0.0, 0.0, 1.0]], dtype=torch.float64)
    rad = torch.tensor([1.0, -0.45, 0.05])
    s = make_calibration_set(K, BOARD, SQUARE, (640, 480), num_views=12, radial=rad, seed=5, supersample=2)
    on = CalibrationPipeline("learned")(s.images, BOARD, SQUARE)
    off = CalibrationPipeline("learned", distortion_correction=False)(s.images, BOARD, SQUARE)
    e_on, e_off = float(e_ip(on.K.double(), K)), float(e_ip(off.K.double(), K))
    print(f"E_IP with correction {e_on:.3f} px, without {e_off:.3f} px; applied {bool(on.corrected)}")
    assert bool(on.corrected) and int(on.found.sum()) >= 10
    assert e_on < 0.5 and e_on < e_off


def test_detect_corrected_large_images_downscaled_and_refined():
    # a photo above max_detection_side is warped and detected small, then refined at full resolution
    K = torch.tensor([[840.0, 0.0, 650.0], [0.0, 845.0, 470.0], [0.0, 0.0, 1.0]], dtype=torch.float64)
    s = make_calibration_set(K, BOARD, SQUARE, (1280, 960), num_views=2, radial=torch.tensor([1.0, -0.4, 0.0]),
                             seed=9, supersample=1)
    corr = torch.tensor([1.0, 0.0, 0.35, 0.0, 0.1], dtype=torch.float64)
    from ccs_kornia.modules.detection.warps.corrected_copy import detect_on_corrected

    pipes = [CalibrationPipeline("opencv", max_detection_side=side) for side in (None, 640)]
    full, small = (detect_on_corrected(p.tools.detect, p.tools.refine, s.images, corr, BOARD) for p in pipes)
    assert bool(full.found.all()) and bool(small.found.all())
    err_full = (full.corners.double() - s.corners.double()).norm(dim=-1)
    err_small = (small.corners.double() - s.corners.double()).norm(dim=-1)
    print("mean corner error full / downscaled:", float(err_full.mean()), float(err_small.mean()))
    assert float(err_small.mean()) < 0.1 and float(err_small.max()) < 0.5


def test_diagnostics_per_camera_and_select(sets):
    """``diagnostics=True``: each camera's quality figures, batched like the rest of the result; a camera without a
    calibration has ``None``."""
    imgs = torch.stack([sets[0].images, sets[1].images, torch.full_like(sets[1].images, 0.5)])
    out = CalibrationPipeline("opencv", seed=0, distortion_correction=False, diagnostics=True)(imgs, BOARD, SQUARE)
    assert out.calibration.success.tolist() == [True, True, False]
    assert len(out.diagnostics) == 3 and out.diagnostics[2] is None
    for q in out.diagnostics[:2]:
        assert q["success"] and q["heldout_rms_px"] < 0.5 and q["uncertainty_centre_px"] < 2.0
        assert q["verdict"].split(":")[0] in ("good", "usable", "not reliable")
    assert out.select(1).diagnostics == out.diagnostics[1]
    plain = CalibrationPipeline("opencv", seed=0, distortion_correction=False)(imgs[:1], BOARD, SQUARE)
    assert plain.diagnostics is None and torch.equal(plain.calibration.K, out.calibration.K[:1])


def test_diagnostics_after_the_second_look_equal_those_without_it(sets):
    """With the calibrated second look on, the first solve leaves the diagnostics to the final one (or computes them
    afterwards when nothing was recovered): the figures equal those of a pipeline without the look."""
    imgs = sets[1].images[None]
    kw = dict(seed=0, distortion_correction=False, diagnostics=True, model=FISHEYE)
    looked = CalibrationPipeline("opencv", calibrated_look=True, **kw)(imgs, BOARD, SQUARE)
    plain = CalibrationPipeline("opencv", calibrated_look=False, **kw)(imgs, BOARD, SQUARE)
    assert looked.diagnostics is not None and looked.diagnostics[0]["success"]
    assert looked.diagnostics == plain.diagnostics
    torch.testing.assert_close(looked.calibration.K, plain.calibration.K, atol=0, rtol=0)


def test_each_look_asks_the_detector_for_its_own_fallbacks(sets, monkeypatch):
    """The first look runs the learned detector without its costliest last resort (foreshortened levels); the
    calibrated look's virtual views without OpenCV's candidates, the octaves below the fallbacks and the finest level
    (they would only add their cost to every view without a board): first on the level each view picks, then on the
    finer fallback levels only. The detector's own fallbacks are a value passed per call, never changed."""
    imgs = sets[1].images.clone()
    imgs[3] = 0.5  # a view without a board: the look runs for it
    pipe = CalibrationPipeline("learned", seed=0, distortion_correction=False, model=FISHEYE)
    own = pipe.detector.fallbacks
    seen = []
    forward = pipe.detector.forward

    def spy(images, board, fallbacks=None):
        seen.append(fallbacks)
        if fallbacks is not None and not fallbacks.primary:
            raise RuntimeError("second pass")
        return forward(images, board, fallbacks)

    monkeypatch.setattr(pipe.detector, "forward", spy)
    with pytest.raises(RuntimeError, match="second pass"):
        pipe(imgs[None], BOARD, SQUARE)
    second = own.but(levels=(0.5, 0.25), finest=False, opencv=False, foreshortened=False, copies=False)
    assert seen[0] == own.but(foreshortened=False)
    assert set(seen[1:-1]) == {second.but(levels=())} and len(seen[1:-1]) == 19  # the wide lens's virtual views
    assert seen[-1] == second.but(primary=False)
    assert pipe.detector.fallbacks == own


def test_a_large_correction_is_tried_even_where_it_does_not_straighten():
    """A level-2 lens (the paper's radial model about the image centre, fx and fy far apart) that opencv5 cannot
    describe, with a network correction that is large but not this lens's (it does not straighten the boards, as on
    5 of 50 held-out level-2 cameras): the camera still goes to the corrected frame, which recovers it where the
    usual fit misses it by tens of px."""
    from ccs_kornia.bench.common import k0_scaled_intrinsics
    from ccs_kornia.data.scenes.sampling import sample_poses
    from ccs_kornia.geometry.board_points import board_object_points
    from ccs_kornia.geometry.camera import project_points
    from ccs_kornia.geometry.radial import radial_distort_points

    size = (640, 480)
    K = torch.tensor([[617.0, 0.0, 327.0], [0.0, 333.0, 232.0], [0.0, 0.0, 1.0]], dtype=torch.float64)
    radial = torch.tensor([0.80, -0.37, -0.13], dtype=torch.float64)
    g = torch.Generator().manual_seed(3)
    rvec, tvec = sample_poses(K, BOARD, SQUARE, size, 15, g, radial=radial)
    obj = board_object_points(*BOARD, SQUARE, dtype=torch.float64)
    ideal = project_points(obj.expand(15, -1, -1), K.expand(15, 3, 3), None, rvec, tvec)
    uv = radial_distort_points(ideal.reshape(1, -1, 2), radial[None], size).reshape(1, 15, -1, 2)
    uv = uv + 0.02 * torch.randn(uv.shape, generator=g, dtype=torch.float64)
    K_ref = torch.as_tensor(k0_scaled_intrinsics(K[None].numpy(), radial[None].numpy(), size)[0])
    per_view = torch.tensor([1.0, 0.0, 0.15, 0.0, 0.0], dtype=torch.float64).expand(1, 15, 5)
    pipe = CalibrationPipeline("opencv")
    given = PipelineResult.from_detections(uv, torch.ones(1, 15, dtype=torch.bool), size, per_view)
    out = pipe.finish(given, BOARD, SQUARE)
    before, after = out.straightness[0].tolist()
    assert after > 0.8 * before  # the network's correction hardly straightens these boards
    assert bool(out.correction_tried[0]) and bool(out.corrected[0])
    assert float(e_ip(out.calibration.K, K_ref[None])) < 0.2
    usual = pipe.calibrate(uv, torch.ones(1, 15, dtype=torch.bool), BOARD, SQUARE, size)
    assert float(e_ip(usual.K, K_ref[None])) > 10.0


def test_solve_after_the_second_look_keeps_the_chosen_model(sets, monkeypatch):
    """With ``model=ModelChoice()`` the models are compared once: the solve after a look that changed the views uses the
    model chosen before it (the table says on how many views), and calibrates on every view."""
    from ccs_kornia.modules.detection.base import DetectionResult
    from ccs_kornia.pipeline.looks import Look

    imgs = sets[1].images.clone()
    imgs[2] = 0.5  # missed by the detector; the (fake) look recovers it
    kw = dict(seed=0, distortion_correction=False, weigh_corners=False)  # (the fake look's corners have no precision)

    def recover(tools, out, images, keys, board, fallbacks):
        assert keys == [(0, 2)]
        return DetectionResult(sets[1].corners[2][None].float(), torch.ones(1, dtype=torch.bool), ["fake look"])

    look = Look("fake look", lambda out, detector: [(0, 2)], recover, needs_camera=True)
    pipe = CalibrationPipeline("opencv", model=ModelChoice(), looks=(look,), **kw)
    assert pipe.settings.looks == (look,)
    calls = []
    select = pipe.selection.forward
    monkeypatch.setattr(pipe.selection, "forward", lambda *a, **k: calls.append(1) or select(*a, **k))
    out = pipe(imgs[None], BOARD, SQUARE)
    assert len(calls) == 1
    table = out.model_selection[0]
    assert table["views"] == VIEWS - 1 and f"final calibration uses {VIEWS}" in table["note"]
    assert bool(out.calibration.success[0]) and int(out.calibration.used[0].sum()) == VIEWS
    assert str(out.calibration.camera.model) == table["chosen"]
    # the same camera as a fixed-model pipeline given the same views
    fixed = CalibrationPipeline("opencv", model=out.calibration.camera.model, **kw)
    given = PipelineResult.from_detections(out.detections.corners, out.detections.found, (640, 480))
    ref = fixed.finish(given, BOARD, SQUARE).calibration
    torch.testing.assert_close(out.calibration.K, ref.K)


@pytest.mark.parametrize("detector", ["opencv", "learned"])
@pytest.mark.parametrize("model", [PINHOLE, K1K2, OPENCV5, RATIONAL, FISHEYE, ModelChoice()], ids=str)
def test_no_crash_and_no_nan_without_a_reason(detector, model, sets):
    """Whatever the input, a result: success with finite values, or failure with a reason per camera."""
    g = torch.Generator().manual_seed(3)
    good = sets[0].images[:4]
    cases = {
        "noise": torch.rand(4, 1, 48, 64, generator=g),
        "blank": torch.zeros(3, 1, 48, 64),
        "tiny": torch.rand(3, 1, 8, 8, generator=g),
        "nan": torch.full((3, 1, 48, 64), float("nan")),
        "single view": good[:1],
        "two views": good[:2],
        "copies": good[:1].expand(4, -1, -1, -1).clone(),
    }
    pipe = CalibrationPipeline(detector, model=model, distortion_correction=False)
    for name, images in cases.items():
        with torch.inference_mode():
            out = pipe(images, BOARD, SQUARE)
        assert not bool(out.success), name
        assert isinstance(out.camera_reasons, str) and out.camera_reasons, name
    # a good camera beside a hopeless one, batched
    both = torch.stack([good, torch.rand(4, 1, 480, 640, generator=g)])
    with torch.inference_mode():
        out = pipe(both, BOARD, SQUARE)
    assert out.calibration.success.tolist() == [False, False] or not out.camera_reasons[1] == ""
    assert out.camera_reasons[1] and bool(out.calibration.K[1].isnan().all())


@pytest.mark.parametrize("detector", ["opencv", "learned"])
def test_huge_board_free_images_and_wrong_shapes(detector):
    """A 24 Mpx board-free image gives a failed result with a reason (bounded memory, see the pipeline's streaming);
    only malformed shapes raise, and they raise ValueError."""
    g = torch.Generator().manual_seed(4)
    huge = torch.rand(1, 1, 1, 3000, 4000, generator=g).expand(1, 3, 1, 3000, 4000)
    pipe = CalibrationPipeline(detector, distortion_correction=False)
    with torch.inference_mode():
        out = pipe(huge, BOARD, SQUARE)
    assert out.calibration.success.tolist() == [False] and out.camera_reasons[0]
    for bad in (torch.rand(3, 48, 64), torch.rand(2, 2, 1, 1, 48, 64)):
        with pytest.raises(ValueError):
            pipe(bad, BOARD, SQUARE)



def test_corner_precision_weights_the_solve(sets):
    """The pipeline measures every found corner's precision (``detections.sigma``) and weights the solve by it;
    ``weigh_corners=False`` is the plain least-squares fit on the same corners."""
    from ccs_kornia.geometry.board_points import board_object_points
    from ccs_kornia.modules.detection.refine.corner_uncertainty import corner_weights

    imgs = sets[0].images
    weighted = CalibrationPipeline("opencv", seed=0, distortion_correction=False)(imgs, BOARD, SQUARE)
    plain = CalibrationPipeline("opencv", seed=0, distortion_correction=False, weigh_corners=False)(imgs, BOARD, SQUARE)
    sigma, found = weighted.detections.sigma, weighted.detections.found
    assert sigma.shape == weighted.detections.corners.shape[:-1] and plain.detections.sigma is None
    assert bool(sigma[found].isfinite().all()) and bool(sigma[~found].isnan().all())
    torch.testing.assert_close(weighted.detections.corners, plain.detections.corners)
    obj = board_object_points(*BOARD, SQUARE, dtype=torch.float64)
    valid = found[:, None].expand(sigma.shape)
    w = corner_weights(sigma[None], valid[None])[0]
    direct = CalibrationPipeline("opencv", seed=0, distortion_correction=False).solver(
        plain.detections.corners.double(), valid, obj, (640, 480), weights=w)
    torch.testing.assert_close(weighted.K, direct.K)
    assert not torch.equal(weighted.K, plain.K)


def test_boards_at_a_grazing_angle_are_looked_for_after_the_other_looks(monkeypatch):
    """The learned detector's last resort for foreshortened boards (four detections more on each view without a
    board) is deferred to the views the other looks left: the streamed pass runs without it (and restores it), the
    end of the pipeline runs it once on what is still missed, corners as precise as the detector's."""
    from ccs_kornia.bench.scenes.scenes import quantize
    from ccs_kornia.bench.sections.wild import wild_spec
    from ccs_kornia.data.scenes.wild import WildChessboards
    from ccs_kornia.pipeline.sources import TensorSource

    spec, board = wild_spec("tilt75")  # a held-out render (the bench's seeds start at BENCH_SEED_BASE + 400000)
    # the render of test_foreshortening's grazing-angle test, found only on a compressed level
    batch = WildChessboards(spec).sample(1, torch.Generator().manual_seed(7_777_000 + 900 + 27))
    img, truth = quantize(batch.images), batch.corners[0, : board[0] * board[1]].double()
    pipe = CalibrationPipeline("learned", seed=0, distortion_correction=False)
    calls = []
    resort = pipe.detector.foreshortened
    monkeypatch.setattr(pipe.detector, "foreshortened", lambda im, b: calls.append(im.shape[0]) or resort(im, b))
    first = pipe.detect_views(TensorSource(img), board)
    assert not bool(first.detections.found.any()) and pipe.detector.fallbacks.foreshortened and calls == []
    out = pipe.run(TensorSource(img), board, calibrate=False)
    assert bool(out.detections.found[0, 0]) and "compressed along" in out.detections.reasons[0] and calls == [1]
    err = (out.detections.corners[0, 0] - truth).norm(dim=-1)
    measured = err.isfinite()  # two corners at the far, most foreshortened edge are left out
    assert int((~measured).sum()) <= 2 and float(err[measured].mean()) < 0.08
    assert bool(torch.isfinite(out.detections.sigma[0, 0][measured]).all())


def test_foreshortened_look_skips_strongly_distorted_cameras():
    """Cameras whose pooled correction is large are left to the corrected look (a grazing board's squares there are
    no affine compression of a lattice): only the other camera's missed view is looked at, and none where the
    detector's own fallbacks leave the last resort out."""
    from types import SimpleNamespace

    from ccs_kornia.modules.detection.base import DetectionResult, Fallbacks
    from ccs_kornia.pipeline.looks import FORESHORTENED

    det = DetectionResult(torch.zeros(2, 2, 12, 2), torch.tensor([[True, False], [True, False]]), [""] * 4)
    out = SimpleNamespace(detections=det, present=torch.ones(2, 2, dtype=torch.bool),
                          correction_tried=torch.tensor([True, False]))
    detector = SimpleNamespace(fallbacks=Fallbacks())
    assert FORESHORTENED.select(out, detector) == [(1, 1)]
    detector.fallbacks = Fallbacks(foreshortened=False)
    assert FORESHORTENED.select(out, detector) == []
    assert FORESHORTENED.select(out, SimpleNamespace(fallbacks=None)) == []


def test_partial_boards_are_calibrated_on_their_visible_corners(sets, tmp_path):
    """Saturated spots flatten a corner of three views: those boards are kept with the corner NaN (``valid`` leaves it
    out), the solver uses the others, and the JSON record writes null for it and counts it."""
    from ccs_kornia.io.files import write_json
    from ccs_kornia.outputs.records import camera_record

    s = sets[0]
    images = s.images.clone()
    h, w = images.shape[-2:]
    yy, xx = torch.meshgrid(torch.arange(h), torch.arange(w), indexing="ij")
    for v, k in ((1, 22), (4, 30), (7, 40)):  # an inner corner of each board
        x, y = (float(c) for c in s.corners[v, k])
        r = 0.4 * float((s.corners[v, k + 1] - s.corners[v, k]).norm())  # flat within about half a square
        spot = torch.exp(-((xx - x) ** 2 + (yy - y) ** 2) / (2 * r**2))
        images[v, 0] = (images[v, 0] + 2.0 * spot).clamp(max=1.0)
    out = CalibrationPipeline("learned", model=OPENCV5, seed=0, distortion_correction=False)(images, BOARD, SQUARE)
    det, cal = out.detections, out.calibration
    assert bool(det.found.all())
    hidden = ~det.valid
    assert sorted(hidden.any(-1).nonzero().flatten().tolist()) == [1, 4, 7]
    assert hidden[1, 22] and hidden[4, 30] and hidden[7, 40]
    assert bool(det.corners[hidden].isnan().all()) and int(hidden.sum()) <= 3 * 6
    err = (det.corners[det.valid].double() - s.corners[det.valid].double()).norm(dim=-1)
    assert float(err.mean()) < 0.03 and float(err.max()) < 0.5  # the largest beside a spot (measured 0.33)
    assert bool(cal.success) and bool(cal.used.all()) and bool(cal.view_rms.isfinite().all())
    assert float(e_ip(cal.K.double()[None], CAMERAS[0][0][None])) < 2.0
    record = camera_record(out, [f"v{i}.png" for i in range(VIEWS)], board=BOARD, square=SQUARE, detector="learned",
                           model=OPENCV5)
    assert record["num_views"]["partial"] == 3 and record["views"][4]["hidden_corners"] == int(hidden[4].sum())
    write_json(tmp_path / "calib.json", record)
    import json

    assert json.loads((tmp_path / "calib.json").read_text())["views"][4]["corners"][30] == [None, None]


def test_calibrated_look_tries_the_fallback_levels_in_a_second_pass_only():
    """The calibrated look: every virtual view on its first level, then the fallback levels for the images still
    without a board (one pass per entry of ``CALIBRATED.passes``)."""
    from types import SimpleNamespace

    from ccs_kornia.geometry.camera import Camera
    from ccs_kornia.modules.detection.base import DetectionResult, Fallbacks
    from ccs_kornia.pipeline.looks import CALIBRATED, Tools

    passes = []

    def detect(views, board, fallbacks):
        passes.append((fallbacks.levels, fallbacks.primary, views.shape[0]))
        # image 0 "shows" its board on the first level, image 1 only on a fallback level
        hit = torch.tensor([bool(v.max() < 0.5) or not fallbacks.primary for v in views])
        return DetectionResult(torch.full((views.shape[0], 6, 2), 239.5), hit, ["x"] * views.shape[0])

    tools = Tools(detect, lambda i, c, b: c, None, SimpleNamespace(fallbacks=Fallbacks()), 1)
    lens = Camera(FISHEYE, torch.tensor([200.0, 200, 159.5, 119.5, 0, 0, 0, 0], dtype=torch.float64))
    out = SimpleNamespace(detections=DetectionResult(torch.zeros(1, 2, 6, 2), torch.zeros(1, 2, dtype=torch.bool)),
                          calibration=SimpleNamespace(camera=lens))  # the calibration's field the look reads
    images = torch.stack([torch.full((1, 240, 320), 0.25), torch.full((1, 240, 320), 0.75)])
    got = CALIBRATED.run(tools, out, images, [(0, 0), (0, 1)], (3, 2))
    assert got.found.tolist() == [True, True]
    assert "view 0 " in got.reasons[0] and "view 0 " in got.reasons[1]
    # pass one: every view of the wide lens (19) without fallbacks while image 1 has no board; pass two: image 1 alone,
    # on the views of the first round (VIEWS_PER_ROUND: the second one's board is not taken)
    assert passes[0] == ((), True, 2) and all(p[:2] == ((), True) for p in passes[:19])
    assert passes[19:] == [((0.5, 0.25), False, 1)] * 2


def test_diagnostics_reuse_the_model_selections_cross_validation(images, monkeypatch):
    """``calibrate``'s path (model "auto", diagnostics after the second looks) on one camera: the verdict's
    cross-validation reuses the chosen model's solved subsets from the model selection instead of solving them again.
    (Cameras batched with others of another model are diagnosed in their own group, whose subsets are solved anew.)"""
    import ccs_kornia.modules.calibration.quality.diagnostics as diagnostics
    from ccs_kornia.modules.calibration.model_selection import AUTO_MODELS
    from ccs_kornia.pipeline.sources import TensorSource

    solved, real = [], diagnostics.solve_subsets
    monkeypatch.setattr(diagnostics, "solve_subsets", lambda *a, **k: (solved.append(a[0].model), real(*a, **k))[1])
    pipe = CalibrationPipeline("opencv", model=ModelChoice(), diagnostics=True, distortion_correction=False)
    out = pipe.run(TensorSource(images[:1]), BOARD, SQUARE)
    assert sorted(map(str, solved)) == sorted(map(str, AUTO_MODELS))  # the model selection's four solves, none for the diagnostics
    chosen = out.model_selection[0]["chosen"]
    assert out.diagnostics[0]["heldout_rms_px"] == out.model_selection[0]["heldout_rms_px"][chosen]
