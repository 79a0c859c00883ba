"""View sources (ccs_kornia/pipeline/sources.py): files decoded by two threads come back in order, failures reported."""

from __future__ import annotations

import time

import cv2
import numpy as np
import pytest
import torch

from ccs_kornia.pipeline.sources import FileSource, _ordered_map, prefetched


def test_ordered_map_keeps_the_order_and_runs_ahead_a_bounded_amount():
    started = []

    def slow(k):
        started.append(k)
        time.sleep(0.01 * (k % 3))  # out-of-order completion
        return k * k

    out = _ordered_map(slow, list(range(10)), 2)
    assert next(out) == 0
    assert len(started) <= 2  # at most one per worker submitted before the first result is taken
    assert [0] + list(out) == [k * k for k in range(10)]
    assert list(_ordered_map(lambda k: k + 1, [1, 2], 1)) == [2, 3]


def test_ordered_map_raises_the_error_at_its_item():
    def fail_at_three(k):
        if k == 3:
            raise RuntimeError("three")
        return k

    out = _ordered_map(fail_at_three, list(range(6)), 2)
    assert [next(out) for _ in range(3)] == [0, 1, 2]
    with pytest.raises(RuntimeError, match="three"):
        next(out)


def test_file_source_decodes_in_order_and_reports_unreadable_files(tmp_path):
    rng = np.random.default_rng(0)
    paths, arrays = [], []
    for k in range(7):
        img = rng.integers(0, 256, size=(24, 32), dtype=np.uint8)
        path = tmp_path / f"v{k}.png"
        cv2.imwrite(str(path), img)
        paths.append(str(path))
        arrays.append(img)
    (tmp_path / "broken.png").write_bytes(b"not an image")
    paths.insert(3, str(tmp_path / "broken.png"))
    source = FileSource([paths])
    assert source.decode_workers == 2
    batches = list(prefetched(source.batches(batch_size=3)))
    keys = [k for b in batches for k in b.keys]
    images = torch.cat([b.images for b in batches if b.images is not None])
    failed = [key for b in batches for key, _ in b.failed]
    assert keys == [(0, v) for v in range(8) if v != 3] and failed == [(0, 3)]
    expected = torch.from_numpy(np.stack(arrays)).float()[:, None] / 255.0
    torch.testing.assert_close(images, expected)
