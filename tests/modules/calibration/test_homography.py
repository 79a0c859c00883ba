"""Tests of the batched homographies."""

from __future__ import annotations

import pytest
import torch
from _board_views import all_valid, synthetic

from ccs_kornia.geometry.board_points import board_object_points
from ccs_kornia.modules.calibration.homography import (
    BatchedHomography,
    find_homographies,
)

F64 = torch.float64


class TestHomography:
    def test_exact_and_shapes(self, device, dtype):
        K, obj, uv, rvec, tvec = synthetic(C=2, V=3)
        obj_d, uv_d = obj.to(device, dtype), uv.to(device, dtype)
        H, ok = find_homographies(obj_d[:, :2], uv_d, all_valid(uv).to(device), return_ok=True)
        assert H.dtype == dtype and H.device.type == device.type
        assert H.shape == (2, 3, 3, 3) and ok.shape == (2, 3) and ok.all()
        # unbatched and module form agree
        H1 = BatchedHomography()(obj_d[:, :2], uv_d[0, 1], None)
        assert torch.allclose(H1, H[0, 1], atol=1e-9 if dtype == F64 else 1e-4)
        H = H.cpu().double()
        xy1 = torch.cat([obj[:, :2], torch.ones(54, 1, dtype=F64)], -1)
        p = torch.einsum("cvij,nj->cvni", H, xy1)
        assert (p[..., :2] / p[..., 2:] - uv).abs().max() < (1e-8 if dtype == F64 else 0.05)

    def test_weights_ignore_masked_garbage(self):
        K, obj, uv, _, _ = synthetic(C=1, V=2)
        valid = all_valid(uv)
        bad = uv.clone()
        bad[0, 0, :10] = float("nan")
        bad[0, 1, :10] += 50.0
        valid[:, :, :10] = False
        H = find_homographies(obj[:, :2], bad, valid)
        H_ref = find_homographies(obj[:, :2], uv, all_valid(uv))
        assert H.isfinite().all() and torch.allclose(H, H_ref, atol=1e-7)

    def test_too_few_points_gives_identity_and_flag(self):
        K, obj, uv, _, _ = synthetic(C=1, V=3)
        valid = all_valid(uv)
        valid[0, 1, 3:] = False  # 3 points
        valid[0, 2] = False  # no points (padded view)
        uv[0, 2] = float("nan")
        H, ok = find_homographies(obj[:, :2], uv, valid, return_ok=True)
        assert ok.tolist() == [[True, False, False]]
        assert H.isfinite().all() and torch.equal(H[0, 1], torch.eye(3, dtype=F64))

    def test_exceptions(self):
        with pytest.raises(ValueError):
            find_homographies(torch.zeros(5, 2), torch.zeros(4, 2))
        with pytest.raises(ValueError):
            find_homographies(torch.zeros(3, 2), torch.zeros(3, 2))
        with pytest.raises(ValueError):
            find_homographies(torch.zeros(5, 2), torch.zeros(5, 3))

    def test_gradcheck(self):
        obj = board_object_points(3, 2, 1.0, dtype=F64)[:, :2]
        img = (obj * 40 + torch.tensor([100.0, 80.0], dtype=F64)).requires_grad_(True)
        img2 = img.detach() + torch.randn(6, 2, generator=torch.Generator().manual_seed(0), dtype=F64)
        img2.requires_grad_(True)
        assert torch.autograd.gradcheck(lambda p: find_homographies(obj, p), (img2,))
