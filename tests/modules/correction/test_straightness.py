"""Tests of the straightness RMS of board rows and columns."""

from __future__ import annotations

import pytest
import torch

from ccs_kornia.modules.correction.straightness import line_noise_rms, straightness_rms


def test_straightness_known_values_and_batch():
    cols, rows = 4, 3
    f64 = dict(dtype=torch.float64)
    j, i = torch.meshgrid(torch.arange(rows, **f64), torch.arange(cols, **f64), indexing="ij")
    grid = torch.stack([10 * i, 10 * j], -1).reshape(1, -1, 2)
    valid = torch.ones(1, cols * rows, dtype=torch.bool)
    rms, n = straightness_rms(grid, valid, (cols, rows))
    assert float(rms) == pytest.approx(0.0, abs=1e-9) and int(n) == 24
    bent = grid.clone()
    bent[0, 1, 1] += 1.0  # middle-ish point of row 0 moves off its row by 1 px
    rms1, _ = straightness_rms(bent, valid, (cols, rows))
    # row 0 (4 points): TLS residual of one point displaced by 1 on a 4-point line: 1 - 1/4 - (x-xbar)^2/Sxx
    # column 1 (3 points) is unaffected (the shift is along the column)
    sse = 1.0 - 0.25 - (10 - 15) ** 2 / 500.0
    assert float(rms1) == pytest.approx((sse / 24) ** 0.5, rel=1e-2)
    # batch with different board sizes, padding and invalid corners
    other = torch.zeros(1, cols * rows, 2, dtype=torch.float64)
    small = torch.stack([10 * i[:2, :3], 10 * j[:2, :3]], -1).reshape(1, 6, 2)
    other[:, :6] = small
    both = torch.cat([bent, other])
    v = torch.cat([valid, torch.arange(12).unsqueeze(0) < 6])
    r, m = straightness_rms(both, v, torch.tensor([[4, 3], [3, 2]]))
    assert float(r[0]) == pytest.approx(float(rms1)) and float(r[1]) == 0.0
    assert int(m[1]) == 6  # two rows of 3; columns of 2 do not count
    with pytest.raises(ValueError):
        straightness_rms(grid, valid[:, :5], (cols, rows))
    with pytest.raises(ValueError):
        straightness_rms(grid, valid, torch.tensor([[4, 3], [3, 2]]))


def _distorted_boards(num, noise, seed, device="cpu", dtype=torch.float64):
    """Boards seen in perspective through a strong barrel distortion (curved, unevenly spaced rows), plus noise."""
    from ccs_kornia.camera import board_object_points, project_points
    from ccs_kornia.modules.calibration.centred_radial import centred_radial_distort

    g = torch.Generator().manual_seed(seed)
    obj = board_object_points(9, 6, 0.025, dtype=torch.float64)
    K = torch.tensor([[420.0, 0, 320], [0, 420, 240], [0, 0, 1]], dtype=torch.float64)
    rvec = 0.8 * (torch.rand(num, 3, generator=g, dtype=torch.float64) - 0.5)
    tvec = torch.tensor([-0.1, -0.06, 0.3], dtype=torch.float64).expand(num, 3)
    ideal = project_points(obj.expand(num, -1, -1), K.expand(num, 3, 3), None, rvec, tvec)
    uv = centred_radial_distort(ideal, torch.tensor([[-0.4, 0.1, 0.0]], dtype=torch.float64).expand(num, 3), (640, 480))
    uv = uv + noise * torch.randn(uv.shape, generator=g, dtype=torch.float64)
    return uv.to(device=device, dtype=dtype)


def test_line_noise_rms_measures_the_noise_not_the_distortion(device, dtype):
    valid = torch.ones(8, 54, dtype=torch.bool, device=device)
    for noise in (0.0, 0.1):
        uv = _distorted_boards(8, noise, 0, device, dtype)
        sigma = line_noise_rms(uv, valid, (9, 6))
        assert sigma.shape == (8,) and sigma.dtype == torch.float64 and sigma.device == uv.device
        straight = straightness_rms(uv.double(), valid, (9, 6))[0]
        if noise == 0:
            # the straight lines see the curvature (0.2-0.5 px); the cubic curves leave a few hundredths of it
            assert bool((straight > 0.2).all()) and bool((sigma < 0.2 * straight).all()), (sigma, straight)
        else:  # the noise dominates: measured within its sampling spread
            assert float((sigma / noise - 1).abs().max()) < 0.3, sigma


def test_line_noise_rms_invalid_corners_and_short_lines():
    uv = _distorted_boards(2, 0.05, 1)
    valid = torch.ones(2, 54, dtype=torch.bool)
    base = line_noise_rms(uv, valid, (9, 6))
    bad, mask = uv.clone(), valid.clone()
    bad[0, 10] += 40.0  # a wrong corner, marked invalid, and a NaN one: ignored
    mask[0, 10] = False
    bad[1, 20] = float("nan")
    torch.testing.assert_close(line_noise_rms(bad, mask, (9, 6)), base, atol=0.01, rtol=0)
    # lines shorter than min_points do not count; a board without any line that counts gives NaN
    small = uv[:, :12]
    assert bool(line_noise_rms(small, valid[:, :12], (4, 3)).isnan().all())
    with pytest.raises(ValueError, match="points"):
        line_noise_rms(uv, valid, (8, 6))
    with pytest.raises(ValueError, match="valid"):
        line_noise_rms(uv, valid[:, :50], (9, 6))
    with pytest.raises(ValueError, match="min_points"):
        line_noise_rms(uv, valid, (9, 6), degree=5, min_points=6)
