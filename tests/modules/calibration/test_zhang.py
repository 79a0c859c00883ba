"""Tests of Zhang's closed-form intrinsics and the poses from homographies."""

from __future__ import annotations

import pytest
import torch
from _board_views import all_valid, synthetic

from ccs_kornia.modules.calibration.homography import find_homographies
from ccs_kornia.modules.calibration.zhang import (
    ZhangInit,
    extrinsics_from_homography,
    zhang_intrinsics,
)

F64 = torch.float64
IMAGE_SIZE = (640, 480)


class TestZhang:
    def test_exact_batch(self, device):
        K, obj, uv, rvec, tvec = synthetic(C=3, V=10)
        H = find_homographies(obj[:, :2].to(device), uv.to(device), all_valid(uv).to(device))
        K0, ok = zhang_intrinsics(H, image_size=IMAGE_SIZE, return_ok=True)
        assert K0.device.type == device.type
        H, K0, ok = H.cpu(), K0.cpu(), ok.cpu()
        assert ok.all() and (K0 - K).abs().max() < 1e-6
        # float32 homographies still give a usable K
        K32 = zhang_intrinsics(H.float(), image_size=IMAGE_SIZE)
        assert K32.dtype == torch.float32 and (K32.double() - K).abs().max() < 1.0
        r, t = extrinsics_from_homography(K0, H)
        assert (r - rvec).abs().max() < 1e-8 and (t - tvec).abs().max() < 1e-8

    def test_few_views_and_modes(self):
        K, obj, uv, _, _ = synthetic(C=2, V=4, seed=3)
        H = find_homographies(obj[:, :2], uv, all_valid(uv))
        K2 = zhang_intrinsics(H[:, :2], image_size=IMAGE_SIZE, principal_point="estimate")
        assert (K2 - K).abs().max() < 1e-5  # zero skew: two views determine the camera
        # one view: principal point assumed at the centre, focal lengths still sensible
        K1, ok = zhang_intrinsics(H[:, :1], image_size=IMAGE_SIZE, return_ok=True)
        assert ok.all() and torch.allclose(K1[:, :2, 2], torch.tensor([319.5, 239.5], dtype=F64).expand(2, 2))
        assert ((K1[:, 0, 0] / K[:, 0, 0]) - 1).abs().max() < 0.2
        # fixed aspect ratio
        Kfa = zhang_intrinsics(H, image_size=IMAGE_SIZE, fix_aspect_ratio=True)
        assert torch.allclose(Kfa[:, 0, 0], Kfa[:, 1, 1])
        # both fixed: one view gives the one focal length of a camera centred, fx = fy
        Kc = torch.tensor([[500.0, 0, 319.5], [0, 500.0, 239.5], [0, 0, 1]], dtype=F64)
        c, s_ = 0.8, 0.6  # a board turned about 37 degrees about the x axis, 2 m away
        Hc = Kc @ torch.tensor([[1.0, 0, -0.1], [0, c, -0.05], [0, s_, 2.0]], dtype=F64)
        K1c = zhang_intrinsics(Hc[None], image_size=IMAGE_SIZE, principal_point="centre", fix_aspect_ratio=True)
        assert torch.allclose(K1c, Kc, atol=1e-6)
        # the mask removes garbage views; no views at all -> finite fallback, not ok
        Hg = H.clone()
        Hg[:, 3] = torch.randn(2, 3, 3, dtype=F64)
        mask = torch.tensor([[True, True, True, False], [False, False, False, False]])
        Km, okm = zhang_intrinsics(Hg, mask, image_size=IMAGE_SIZE, return_ok=True)
        assert okm.tolist() == [True, False] and Km.isfinite().all()
        assert (Km[0] - K[0]).abs().max() < 1e-5
        with pytest.raises(ValueError):
            zhang_intrinsics(H, principal_point="centre")
        with pytest.raises(ValueError):
            zhang_intrinsics(H[0, 0])

    def test_module_and_board_in_front(self):
        K, obj, uv, rvec, tvec = synthetic(C=1, V=5)
        H = find_homographies(obj[:, :2], uv, all_valid(uv))
        K0, r, t, ok = ZhangInit()(-H, image_size=IMAGE_SIZE)  # homographies are defined up to sign
        assert ok.all() and (t[..., 2] > 0).all() and (t - tvec).abs().max() < 1e-8
