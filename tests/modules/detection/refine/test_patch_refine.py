"""Full-resolution refinement of whole boards near the image's border."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
import torch

from ccs_kornia.modules.detection.refine.patch_refine import (
    MIN_BORDER_RADIUS,
    refine_from_level,
    refine_on_patches,
)

BOARD = (3, 2)


def _rotated_checker(top: float) -> tuple[torch.Tensor, np.ndarray]:
    """A checker of 48 px squares rotated 25 degrees (area-sampled, blurred 1 px), its corner 0 ``top`` px below the
    image's top edge: ``(1, 1, 200, 260)`` image and the ``(6, 2)`` corners of a 3x2 board in grid order."""
    s, a, sq, h, w = 8, math.radians(25.0), 48.0, 200, 260
    origin = np.array([60.0, top])
    u, v = np.array([math.cos(a), math.sin(a)]) * sq, np.array([-math.sin(a), math.cos(a)]) * sq
    ys, xs = np.mgrid[0:h * s, 0:w * s] / s - 0.5 + 0.5 / s
    g = np.stack([xs - origin[0], ys - origin[1]], -1) @ np.linalg.inv(np.stack([u, v], 1)).T
    img = ((np.floor(g[..., 0]) + np.floor(g[..., 1])) % 2).astype(np.float32)
    img = cv2.GaussianBlur(cv2.resize(img, (w, h), interpolation=cv2.INTER_AREA), (0, 0), 1.0)
    pts = np.array([origin + i * u + j * v for j in range(2) for i in range(3)])
    return torch.from_numpy(img)[None, None], pts


@pytest.mark.parametrize("top", [5.0, 7.0])
def test_a_corner_near_the_border_is_not_pulled_by_it(top):
    # a window over the border sees its row repeated: a false junction pulled the fit 0.35-0.58 px off here
    img, truth = _rotated_checker(top)
    out, ok = refine_on_patches(img, torch.from_numpy(truth + 0.8).float()[None], BOARD, return_ok=True)
    err = np.linalg.norm(out[0].numpy() - truth, axis=-1)
    assert bool(ok.all()) and err[0] < 0.2 and err[1:].max() < 0.01, err


def test_a_corner_out_of_its_window_at_the_border_is_tried_from_its_neighbours():
    img, truth = _rotated_checker(9.0)
    start = torch.from_numpy(truth).float()[None].clone()
    start[0, 0] += torch.tensor([1.5, -12.0])  # the level's peak cut off by the border: beyond the window
    alone, ok_alone = refine_on_patches(img, start, BOARD, return_ok=True)
    assert not bool(ok_alone[0, 0])
    out, ok = refine_from_level(img, start, BOARD, 1.0, return_ok=True)
    err = np.linalg.norm(out[0].numpy() - truth, axis=-1)
    assert bool(ok.all()) and err[0] < 0.15 and err[1:].max() < 0.01, err


def test_the_smallest_window_at_the_border():
    img, truth = _rotated_checker(5.0)
    start = torch.from_numpy(truth).float()[None].clone()
    start[0, 0, 1] = 0.5  # half a px inside: the window cannot shrink below MIN_BORDER_RADIUS
    out, ok = refine_on_patches(img, start, BOARD, return_ok=True)
    assert MIN_BORDER_RADIUS >= 1.0 and out.shape == (1, 6, 2) and bool(torch.isfinite(out).all())


def test_a_failed_corner_inside_the_image_stays_failed():
    """Away from the border a failed fit is a corner the image does not show as a junction: not guessed again."""
    img, truth = _rotated_checker(30.0)
    start = torch.from_numpy(truth).float()[None].clone()
    start[0, 4] += torch.tensor([9.0, -7.0])
    _, ok = refine_from_level(img, start, BOARD, 1.0, return_ok=True)
    assert not bool(ok[0, 4]) and bool(ok[0, :4].all())
