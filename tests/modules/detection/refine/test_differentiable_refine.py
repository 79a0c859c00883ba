"""Differentiable corners: the point-symmetry refinement (gradcheck, agreement with the detector's polish and with
OpenCV), the network's Gaussian-fit seeds, and the straight-through corners (values kept, gradients non-zero)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import torch

from ccs_kornia.modules.detection.learned.learned_detector import load_corner_unet
from ccs_kornia.modules.detection.refine.differentiable_refine import (
    DifferentiableCorners,
    differentiable_corners,
    network_seeds,
    symmetry_refine,
)
from ccs_kornia.modules.detection.refine.saddle_refine import refine_corners

F64 = torch.float64


def _checker(size: int = 24, centre=(11.3, 12.6), angle: float = 0.3, blur: float = 1.2, dtype=torch.float32):
    """A smooth X-junction (a rotated checker corner, blurred edges) centred at ``centre`` (x, y)."""
    ys, xs = torch.meshgrid(torch.arange(size, dtype=F64), torch.arange(size, dtype=F64), indexing="ij")
    u = (xs - centre[0]) * np.cos(angle) + (ys - centre[1]) * np.sin(angle)
    v = -(xs - centre[0]) * np.sin(angle) + (ys - centre[1]) * np.cos(angle)
    img = 0.5 + 0.4 * torch.tanh(u / blur) * torch.tanh(v / blur)
    return img[None, None].to(dtype)


def test_smoke_converges_to_the_junction():
    img = _checker()
    out = symmetry_refine(img, torch.tensor([[[12.0, 12.0]]]), 5.0, steps=6)
    assert (out - torch.tensor([11.3, 12.6])).norm() < 0.02


def test_agrees_with_the_detector_polish_and_opencv():
    img = _checker(40, centre=(19.37, 20.81), angle=0.5)
    start = torch.tensor([[[20.0, 20.0]]])
    ours = symmetry_refine(img, start, 5.0, steps=6)
    usual = refine_corners(img, start, radius=5.0 / 1.5, method="symmetric")
    cv = cv2.cornerSubPix((img[0, 0].numpy() * 255).astype(np.float32), start[0].numpy().copy(), (5, 5), (-1, -1),
                          (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 50, 1e-4))
    assert (ours - usual).norm() < 0.02
    assert (ours[0] - torch.from_numpy(cv)).norm() < 0.05


def test_shapes_and_batch():
    imgs = torch.cat([_checker(centre=(11.3, 12.6)), _checker(centre=(12.2, 10.9), angle=-0.4)])
    start = torch.tensor([[[12.0, 12.0], [11.0, 13.0]], [[12.0, 11.0], [12.5, 11.5]]])
    both = symmetry_refine(imgs, start, 4.0)
    assert both.shape == (2, 2, 2) and both.dtype == start.dtype
    for b in range(2):
        assert torch.allclose(both[b], symmetry_refine(imgs[b : b + 1], start[b : b + 1], 4.0)[0], atol=1e-5)
    assert symmetry_refine(imgs, start, 4.0, steps=0) is start
    assert symmetry_refine(imgs, start[:, :0], 4.0).shape == (2, 0, 2)


def test_exceptions():
    img = _checker()
    with pytest.raises(ValueError, match="image"):
        symmetry_refine(img[0], torch.zeros(1, 1, 2))
    with pytest.raises(ValueError, match="corners"):
        symmetry_refine(img, torch.zeros(2, 1, 2))
    with pytest.raises(ValueError, match="steps"):
        symmetry_refine(img, torch.zeros(1, 1, 2), steps=-1)
    with pytest.raises(ValueError, match="valid"):
        differentiable_corners(torch.zeros(1, 3, 2), torch.ones(1, 2, dtype=torch.bool), img, (3, 1))


def test_gradcheck_refinement():
    img = _checker(16, centre=(7.3, 8.4), dtype=F64)
    img = img + 0.02 * torch.rand(img.shape, generator=torch.Generator().manual_seed(0), dtype=F64)
    start = torch.tensor([[[7.6, 8.1]]], dtype=F64)
    fn = lambda x, c: symmetry_refine(x, c, 3.0, steps=2)  # noqa: E731
    assert torch.autograd.gradcheck(fn, (img.requires_grad_(), start.requires_grad_()), eps=1e-6, atol=1e-5)


def test_gradient_matches_the_detector_refinement_under_a_change_of_the_pixels():
    """The gradient is the local derivative of the same estimator: a small change of the image moves the usual
    (no-grad) refinement as the gradient predicts."""
    img = _checker(40, centre=(19.37, 20.81), angle=0.5, dtype=F64)
    start = torch.tensor([[[19.4, 20.8]]], dtype=F64)
    ys, xs = torch.meshgrid(torch.arange(40, dtype=F64), torch.arange(40, dtype=F64), indexing="ij")
    bump = (0.05 * torch.exp(-((xs - 21.0) ** 2 + (ys - 19.0) ** 2) / 8.0))[None, None]
    x = img.clone().requires_grad_()
    out = symmetry_refine(x, start, 5.0, steps=8)
    jac = torch.stack([torch.autograd.grad(out[0, 0, i], x, retain_graph=True)[0] for i in range(2)])
    predicted = (jac * bump).sum((-1, -2, -3, -4))

    def usual(image):
        return refine_corners(image.float(), start.float(), radius=5.0 / 1.5, method="symmetric")[0, 0].double()

    moved = usual(img + bump) - usual(img - bump)
    assert predicted.norm() > 1e-3
    assert (moved / 2 - predicted).norm() < 0.2 * predicted.norm()


def _board(square: float = 12.0, size: int = 48, offset=(5.3, 6.6)):
    """A blurred checkerboard whose inner corners lie at ``offset + k * square``."""
    ys, xs = torch.meshgrid(torch.arange(size, dtype=F64), torch.arange(size, dtype=F64), indexing="ij")
    u, v = (xs - offset[0]) / square * np.pi, (ys - offset[1]) / square * np.pi
    return (0.5 + 0.45 * torch.tanh(3 * torch.sin(u)) * torch.tanh(3 * torch.sin(v)))[None, None]


def test_network_seeds_gradcheck_and_parameter_gradients():
    net, _ = load_corner_unet()
    net = net.double()
    img = _board()
    pts = torch.tensor([[[17.3, 18.6], [29.3, 30.6]]], dtype=F64)
    valid = torch.tensor([[True, True]])
    seeds = network_seeds(net, img, pts, valid)
    assert seeds.shape == (1, 2, 2) and seeds.requires_grad
    assert (seeds - pts).norm(dim=-1).max() < 0.5  # the shipped network's own estimate of the corners
    seeds.sum().backward()
    grads = [p.grad for p in net.parameters() if p.grad is not None]
    assert grads and all(g.isfinite().all() for g in grads) and sum(g.abs().sum() for g in grads) > 0
    crop = img[..., 10:26, 11:27]  # one corner, (6.3, 7.6) in the crop
    small_pts, one = torch.tensor([[[6.3, 7.6]]], dtype=F64), torch.tensor([[True]])
    assert torch.autograd.gradcheck(lambda x: network_seeds(net, x, small_pts, one), (crop.clone().requires_grad_(),),
                                    eps=1e-6, atol=1e-5)


def test_straight_through_corners_keep_values_and_carry_gradients():
    imgs = torch.cat([_checker(centre=(11.3, 12.6)), _checker(centre=(12.2, 10.9), angle=-0.4)]).requires_grad_()
    corners = torch.tensor([[[11.31, 12.58], [float("nan"), float("nan")]], [[12.2, 10.9], [3.0, 3.0]]])
    valid = torch.tensor([[True, True], [True, False]])
    out, gap = differentiable_corners(corners, valid, imgs, (2, 1))
    assert torch.equal(out.detach().nan_to_num(-1.0), corners.nan_to_num(-1.0))
    assert gap[0, 0].abs().max() < 0.05 and gap[0, 1].isnan().all() and gap[1, 1].isnan().all()
    (g,) = torch.autograd.grad(out[0, 0].sum() + out[1, 0].sum(), imgs, retain_graph=True)
    assert g.isfinite().all() and g[0].abs().sum() > 0 and g[1].abs().sum() > 0
    (g11,) = torch.autograd.grad(out[1, 1].sum(), imgs, allow_unused=True)
    assert g11 is None or g11.abs().sum() == 0


def test_module_with_a_network_gives_image_and_parameter_gradients():
    net, _ = load_corner_unet()
    img = _board().float().requires_grad_()
    corners = torch.tensor([[[17.3, 18.6], [29.3, 30.6]]])
    for steps in (0, 2):
        module = DifferentiableCorners(net, steps=steps)
        out, gap = module(img, corners, torch.ones(1, 2, dtype=torch.bool), (2, 1))
        assert torch.equal(out.detach(), corners) and gap.abs().max() < 0.5
        net.zero_grad()
        (g,) = torch.autograd.grad(out[0, 0, 0], img, retain_graph=True)
        out[0, 0, 0].backward()
        assert g.isfinite().all() and g.abs().sum() > 0
        assert sum(p.grad.abs().sum() for p in net.parameters() if p.grad is not None) > 0


def test_a_corner_the_estimator_does_not_reproduce_carries_no_gradient():
    img = _checker(40, centre=(19.37, 20.81), angle=0.5).requires_grad_()
    corners = torch.tensor([[[21.9, 20.8]]])  # 2.5 px off the junction: the refinement lands elsewhere
    out, gap = differentiable_corners(corners, torch.tensor([[True]]), img, (1, 1))
    assert torch.equal(out.detach(), corners) and gap.norm() > 1.0
    (g,) = torch.autograd.grad(out.sum(), img, allow_unused=True)
    assert g is None or g.abs().sum() == 0
    near, gap = differentiable_corners(torch.tensor([[[19.38, 20.8]]]), torch.tensor([[True]]), img, (1, 1))
    assert gap.norm() < 0.1 and near.requires_grad
