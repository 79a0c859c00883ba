"""One policy for the two paths of a marker board: agreeing corners kept, disputed ones dropped, one path's alone
kept, two ids at one place dropped, vetoed ids dropped."""

from __future__ import annotations

import pytest
import torch

from ccs_kornia.modules.detection.markers.corner_merge import (
    AGREE_PX,
    MarkerPaths,
    merge_corners,
)

NAN = float("nan")


def _grid(device, dtype) -> torch.Tensor:
    y, x = torch.meshgrid(torch.arange(3.0), torch.arange(4.0), indexing="ij")
    return (torch.stack([x, y], -1).reshape(1, 12, 2) * 20 + 10).to(device, dtype)


def test_policy(device, dtype):
    truth = _grid(device, dtype)
    first, second = truth.clone(), truth.clone()
    second[0, 0] += 0.3 * AGREE_PX  # agree: the first path's kept
    second[0, 1] += 5.0  # disagree: dropped
    first[0, 2] = NAN  # only the second path: kept
    second[0, 3] = NAN  # only the first path: kept
    first[0, 4] = NAN
    second[0, 4] = NAN  # neither
    merged, disputed = merge_corners(first, second)
    assert merged.shape == (1, 12, 2) and merged.dtype == dtype and merged.device.type == device.type
    torch.testing.assert_close(merged[0, 0], truth[0, 0])
    assert not merged[0, 1].isfinite().any() and bool(disputed[0, 1])
    torch.testing.assert_close(merged[0, 2], truth[0, 2])
    torch.testing.assert_close(merged[0, 3], truth[0, 3])
    assert not merged[0, 4].isfinite().any() and not bool(disputed[0, 4])
    assert int(disputed.sum()) == 1


def test_two_ids_at_one_place_are_both_dropped(device, dtype):
    first = _grid(device, dtype)
    second = torch.full_like(first, NAN)
    second[0, 11] = first[0, 5]  # the second path names corner 5's place as corner 11
    first[0, 11] = NAN
    merged, disputed = merge_corners(first, second)
    assert not merged[0, [5, 11]].isfinite().any()
    assert disputed[0].nonzero().flatten().tolist() == [5, 11]


def test_veto_drops_an_id_from_both_paths(device, dtype):
    first = _grid(device, dtype)
    veto = torch.zeros(1, 12, dtype=torch.bool, device=device)
    veto[0, 7] = True
    merged, disputed = merge_corners(first, first.clone(), veto)
    assert not merged[0, 7].isfinite().any() and bool(disputed[0, 7]) and int(merged.isfinite().all(-1).sum()) == 11


def test_batch_is_per_view(device, dtype):
    first = _grid(device, dtype).repeat(3, 1, 1)
    second = first.clone()
    second[1, 2] += 4.0
    merged, disputed = merge_corners(first, second)
    for k in range(3):
        one, d = merge_corners(first[k:k + 1], second[k:k + 1])
        torch.testing.assert_close(merged[k:k + 1], one, equal_nan=True)
        assert torch.equal(disputed[k:k + 1], d)


def test_paths_and_exceptions():
    assert MarkerPaths.BOTH.markers and MarkerPaths.BOTH.lattice
    assert MarkerPaths.MARKERS.markers and not MarkerPaths.MARKERS.lattice
    assert MarkerPaths.LATTICE.lattice and not MarkerPaths.LATTICE.markers
    assert MarkerPaths("lattice") is MarkerPaths.LATTICE
    with pytest.raises(ValueError):
        merge_corners(torch.zeros(1, 4, 2), torch.zeros(1, 5, 2))
    with pytest.raises(ValueError):
        merge_corners(torch.zeros(4, 2), torch.zeros(4, 2))
