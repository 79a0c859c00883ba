"""CalibrationPipeline(differentiable=True): the usual values, with gradients of the corners to the images and of the
camera to the images and the heatmap network; gradcheck of a small refine -> solve pipeline in double."""

from __future__ import annotations

import pytest
import torch

from ccs_kornia.data.scenes.scenes import make_calibration_set
from ccs_kornia.geometry.board_points import board_object_points
from ccs_kornia.geometry.models import K1K2
from ccs_kornia.modules.calibration.solver import CalibrationSolver
from ccs_kornia.modules.detection.refine.differentiable_refine import symmetry_refine
from ccs_kornia.pipeline.calibration_pipeline import CalibrationPipeline

BOARD, SQUARE = (6, 4), 0.025
K_TRUE = torch.tensor([[300.0, 0, 160], [0, 300, 120], [0, 0, 1]], dtype=torch.float64)


@pytest.fixture(scope="module")
def views():
    return make_calibration_set(K_TRUE, BOARD, SQUARE, (320, 240), num_views=5, seed=1, supersample=1)


@pytest.fixture(scope="module")
def usual(views):
    return CalibrationPipeline("learned", model=K1K2)(views.images, BOARD, SQUARE)


def test_values_identical_to_the_usual_pipeline(views, usual):
    pipe = CalibrationPipeline("learned", model=K1K2, differentiable=True)
    out = pipe(views.images.clone().requires_grad_(), BOARD, SQUARE)
    assert bool(usual.found.all()) and not usual.K.requires_grad
    assert out.K.requires_grad and out.dist.requires_grad
    for name in ("K", "dist"):
        assert torch.equal(getattr(out, name).detach(), getattr(usual, name)), name
    assert torch.equal(out.detections.corners.detach(), usual.detections.corners)
    assert out.detections.gap.abs().max() < 0.1  # the differentiated estimator's value, px from the usual corners
    off = CalibrationPipeline("learned", model=K1K2, differentiable=False)(views.images, BOARD, SQUARE)
    assert torch.equal(off.K, usual.K) and not off.K.requires_grad


def test_detected_corners_have_gradients_to_the_images(views, usual):
    pipe = CalibrationPipeline("learned", model=K1K2, differentiable=True)
    images = views.images.clone().requires_grad_()
    det = pipe.detect(images, BOARD)
    assert torch.equal(det.corners.detach(), usual.detections.corners) and det.found.all()
    det.corners[det.found].sum().backward()
    assert images.grad.isfinite().all()
    assert (images.grad.abs().sum((1, 2, 3)) > 0).all()  # every view with a board


def test_fx_gradient_to_the_heatmap_network(views):
    pipe = CalibrationPipeline("learned", model=K1K2, differentiable=True)
    images = views.images.clone().requires_grad_()
    out = pipe(images, BOARD, SQUARE)
    out.K[0, 0].backward()
    grads = [p.grad for p in pipe.detector.net.parameters() if p.grad is not None]
    assert grads and all(g.isfinite().all() for g in grads)
    assert sum(float(g.abs().sum()) for g in grads) > 0
    assert images.grad.isfinite().all() and images.grad.abs().sum() > 0


def test_calibrate_is_differentiable(usual):
    pipe = CalibrationPipeline("opencv", model=K1K2, differentiable=True)
    corners = usual.detections.corners.clone().requires_grad_()
    calib = pipe.calibrate(corners, usual.found, BOARD, SQUARE, (320, 240))
    calib.K[0, 0].backward()
    assert corners.grad.isfinite().all() and corners.grad.abs().sum() > 0


def test_gradcheck_small_refine_solve_pipeline(views, usual):
    """fx, fy, cx, cy of the solver on corners refined on the images, as functions of three smooth image changes."""
    images = views.images[:4].double()
    start = usual.detections.corners[:4].double()
    h, w = images.shape[-2:]
    ys, xs = torch.meshgrid(torch.arange(h, dtype=torch.float64), torch.arange(w, dtype=torch.float64), indexing="ij")
    basis = torch.stack([torch.sin(xs / 17.0), torch.cos(ys / 13.0), torch.sin((xs + ys) / 11.0)])  # (3, H, W)
    obj = board_object_points(*BOARD, SQUARE, dtype=torch.float64)
    solver = CalibrationSolver(model=K1K2, use_ransac=False, reject_outliers=False, checks=False, ftol=1e-15,
                               max_iters=300, stall_tol=0.0)

    def fn(a):
        x = images + 0.01 * (a[:, None, None] * basis).sum(0)
        corners = symmetry_refine(x, start, 3.0, steps=2)
        r = solver(corners, None, obj, (w, h))
        return torch.stack([r.K[0, 0], r.K[1, 1], r.K[0, 2], r.K[1, 2]])

    a = torch.zeros(3, dtype=torch.float64, requires_grad=True)
    # steps that move the corners by ~1e-4 px: well above the solver's convergence, within the refinement's linear range
    assert torch.autograd.gradcheck(fn, (a,), eps=1e-2, atol=1e-4, rtol=1e-3)
