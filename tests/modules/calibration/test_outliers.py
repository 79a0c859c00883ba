"""The one outlier rule: threshold max(abs, rel * median of the used), candidates re-admitted, the fallbacks."""

from __future__ import annotations

import torch

from ccs_kornia.modules.calibration.outliers import drop_outliers


def test_threshold_and_readmission(device):
    rms = torch.tensor([[0.3, 0.4, 0.35, 9.0, 0.5, 3.0], [1.0, 1.2, 0.8, 1.1, 30.0, 7.0]], device=device)
    used = torch.tensor([[True, True, True, True, False, False], [True, True, True, True, True, False]], device=device)
    keep = drop_outliers(rms, used, torch.ones_like(used), 2.0, 5.0, 3)
    # camera 0: threshold max(2, 5 * 0.35) = 2: the 9 px view out, the unused 0.5 px view back in, 3 px stays out
    # camera 1: threshold 5 * 1.1 = 5.5: the 30 px view out, the unused 7 px view stays out
    assert keep.tolist() == [[True, True, True, False, True, False], [True, True, True, True, False, False]]
    only_used = drop_outliers(rms, used, used, 2.0, 5.0, 3)
    assert not only_used[0, 4] and not only_used[0, 3]  # a non-candidate never comes back


def test_too_few_left_or_no_median_keeps_the_used(device):
    rms = torch.tensor([[5.0, 6.0, 0.1, 0.1], [0.2, 0.3, 0.2, 0.2]], device=device)
    used = torch.tensor([[True, True, True, True], [False, False, False, False]], device=device)
    keep = drop_outliers(rms, used, torch.ones_like(used), 0.5, 2.0, 3)
    assert torch.equal(keep[0], used[0])  # only 2 views would remain: nothing dropped
    assert torch.equal(keep[1], used[1])  # no used view, no median: as it was


def test_rig_observations_need_enough_per_camera(device):
    # (B, C, F): camera x frame observations; a rig keeps its observations when any camera would fall below 2 frames
    rms = torch.tensor([[[0.2, 0.3, 9.0], [0.2, 8.0, 9.0]], [[0.2, 0.3, 9.0], [0.2, 0.3, 9.0]]], device=device)
    used = torch.ones_like(rms, dtype=torch.bool)
    keep = drop_outliers(rms, used, used, 1.0, 5.0, 2)
    assert torch.equal(keep[0], used[0])
    assert keep[1].tolist() == [[True, True, False], [True, True, False]]
