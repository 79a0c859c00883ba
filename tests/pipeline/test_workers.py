"""Batches of views in forked worker processes (ccs_kornia/pipeline/workers.py): the same batches and results with any
number of workers, failures and errors reported, the pipeline's detections unchanged."""

from __future__ import annotations

import os
import sys
import time

import cv2
import numpy as np
import pytest
import torch

from ccs_kornia.pipeline.sources import FileSource, TensorSource
from ccs_kornia.pipeline.workers import (
    MAX_AUTO_WORKERS,
    chunks,
    default_workers,
    map_batches,
)

linux = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="worker processes are forked on Linux only")


def _sum_and_pid(images: torch.Tensor, keys: list):
    assert len(keys) == images.shape[0]
    return images.sum((1, 2, 3)), os.getpid(), torch.get_num_threads()


#: a folder where each worker process leaves its pid (set by a test before the workers are forked)
MEETING: list[str] = []


def _slow_sum_and_pid(images: torch.Tensor, keys: list):
    # a batch waits (10 s at most) until a second process has taken one too, so that however slowly the machine
    # starts the second worker, the batches are shared out
    if MEETING:
        open(os.path.join(MEETING[0], str(os.getpid())), "w").close()
        deadline = time.monotonic() + 10.0
        while len(os.listdir(MEETING[0])) < 2 and time.monotonic() < deadline:
            time.sleep(0.01)
    return _sum_and_pid(images, keys)


@pytest.fixture
def meeting(tmp_path):
    folder = tmp_path / "meeting"
    folder.mkdir()
    MEETING[:] = [str(folder)]
    yield folder
    MEETING.clear()


def test_chunks_and_default_workers():
    assert chunks(range(7), 3) == [[0, 1, 2], [3, 4, 5], [6]]
    assert chunks([], 4) == []
    with pytest.raises(ValueError, match="size must be >= 1"):
        chunks([1], 0)
    assert 1 <= default_workers("cpu") <= MAX_AUTO_WORKERS
    assert default_workers("cuda") == 1


@linux
def test_workers_give_the_batches_and_values_of_one_process(meeting):
    images = torch.rand(2, 5, 1, 12, 16, generator=torch.Generator().manual_seed(0))
    source = TensorSource(images)
    serial = list(map_batches(_sum_and_pid, source, batch_size=2))
    parallel = list(map_batches(_slow_sum_and_pid, source, batch_size=2, workers=2))
    assert [o.keys for o in serial] == [o.keys for o in parallel]
    assert [o.keys for o in serial][:3] == [[(0, 0), (0, 1)], [(0, 2), (0, 3)], [(0, 4), (1, 0)]]
    for a, b in zip(serial, parallel):
        assert a.size == b.size == (16, 12)
        assert torch.equal(a.value[0], b.value[0])
    # the batches really ran in two other processes, one thread each
    pids = {o.value[1] for o in parallel}
    assert os.getpid() not in pids and len(pids) == 2
    assert {o.value[2] for o in parallel} == {1}
    assert {o.value[1] for o in serial} == {os.getpid()}


@linux
def test_views_that_load_alone_are_shared_out_one_by_one(tmp_path, meeting):
    """Views known (from their size or their file's header) to load as a batch of their own each go to the workers
    one at a time (ten large photographs were chunks of 8 and 2: one process worked while the other waited); the
    batches are the ones of one process."""
    paths = []
    for k in range(5):
        paths.append(str(tmp_path / f"v{k}.{'png' if k % 2 else 'jpg'}"))
        cv2.imwrite(paths[-1], np.full((10, 14), 40 * k, dtype=np.uint8))
    for source in (FileSource([paths]), TensorSource(torch.rand(5, 1, 10, 14))):
        serial = list(map_batches(_sum_and_pid, source, batch_size=4, max_pixels=200))  # 140 px each: alone
        for left in meeting.iterdir():
            left.unlink()
        parallel = list(map_batches(_slow_sum_and_pid, source, batch_size=4, max_pixels=200, workers=2))
        assert [o.keys for o in serial] == [o.keys for o in parallel] == [[(0, k)] for k in range(5)]
        assert len({o.value[1] for o in parallel}) == 2
        for a, b in zip(serial, parallel):
            assert torch.equal(a.value[0], b.value[0])
        together = list(map_batches(_sum_and_pid, source, batch_size=4, max_pixels=280, workers=2))
        assert [o.keys for o in together] == [[(0, 0), (0, 1)], [(0, 2), (0, 3)], [(0, 4)]]  # chunks of 4 kept
    (tmp_path / "v9.tif").write_bytes(b"II*\x00")
    assert FileSource([[str(tmp_path / "v9.tif"), paths[0]]]).pixels(0, 0) is None  # not read from a header
    assert FileSource([paths]).pixels(0, 1) == 140


@linux
def test_unreadable_files_are_reported_by_the_workers_too(tmp_path):
    paths = []
    for k in range(4):
        path = tmp_path / f"v{k}.png"
        cv2.imwrite(str(path), np.full((10, 14), 40 * k, dtype=np.uint8))
        paths.append(str(path))
    (tmp_path / "broken.png").write_bytes(b"not an image")
    paths.insert(1, str(tmp_path / "broken.png"))
    for workers in (1, 2):
        out = list(map_batches(_sum_and_pid, FileSource([paths]), batch_size=2, workers=workers))
        assert [k for o in out for k, _ in o.failed] == [(0, 1)]
        assert [k for o in out for k in o.keys] == [(0, 0), (0, 2), (0, 3), (0, 4)]
        sums = torch.cat([o.value[0] for o in out if o.size is not None])
        torch.testing.assert_close(sums, torch.tensor([0.0, 40, 80, 120]) / 255 * 140)


def _fail_on_bright(images: torch.Tensor, keys: list):
    if float(images.max()) > 0.5:
        raise RuntimeError("too bright")
    return images.shape[0]


@linux
def test_an_error_in_a_worker_is_raised_here():
    images = torch.cat([torch.zeros(3, 1, 8, 8), torch.ones(1, 1, 8, 8)])
    with pytest.raises(RuntimeError, match="too bright"):
        list(map_batches(_fail_on_bright, TensorSource(images), batch_size=1, workers=2))
    with pytest.raises(ValueError, match="workers must be >= 1"):
        list(map_batches(_fail_on_bright, TensorSource(images), workers=0))


@linux
def test_pipeline_detects_the_same_corners_with_two_workers(tmp_path):
    from ccs_kornia.data.scenes.scenes import make_calibration_set
    from ccs_kornia.pipeline.calibration_pipeline import CalibrationPipeline

    K = torch.tensor([[300.0, 0, 159.5], [0, 300, 119.5], [0, 0, 1]], dtype=torch.float64)
    views = make_calibration_set(K, (6, 4), 0.03, (320, 240), num_views=5, seed=3, supersample=1)
    paths = []
    for k, im in enumerate(views.images):
        paths.append(str(tmp_path / f"v{k}.png"))
        cv2.imwrite(paths[-1], (im[0] * 255).round().byte().numpy())
    results = []
    for workers in (1, 2):
        pipe = CalibrationPipeline("learned", detection_batch_size=2, workers=workers, distortion_correction=False)
        with torch.inference_mode():
            results.append(pipe.detect_views(FileSource([paths]), (6, 4)).detections)
    one, two = results
    assert bool(one.found.all())
    assert torch.equal(one.found, two.found) and torch.equal(one.corners, two.corners)
    assert torch.equal(one.sigma, two.sigma) and one.reasons == two.reasons
    with pytest.raises(ValueError, match="workers must be an int >= 1 or 'auto'"):
        CalibrationPipeline("opencv", workers=0)


@linux
def test_worker_pool_maps_in_order_in_other_processes():
    from ccs_kornia.pipeline.workers import worker_pool

    offset = torch.arange(3.0)  # inherited by the fork, not pickled

    def work(x: torch.Tensor):
        return x + offset, os.getpid()

    items = [torch.full((3,), float(k)) for k in range(6)]
    with worker_pool(work, workers=2) as run:
        out = list(run(items))
        again = list(run(items[:2]))
        with pytest.raises(RuntimeError, match="cannot be nested"):
            with worker_pool(work, workers=2):
                pass
    assert [o[0].tolist() for o in out] == [[k, k + 1, k + 2] for k in range(6)]
    assert os.getpid() not in {o[1] for o in out} and len(again) == 2
    with worker_pool(work, workers=1) as run:
        assert {o[1] for o in run(items)} == {os.getpid()}


def _die_on_three(x: int) -> int:
    if x == 3:
        os._exit(9)  # as the kernel's out-of-memory killer would
    return x


@linux
def test_a_worker_that_dies_is_an_error_that_says_what_to_do():
    from ccs_kornia.pipeline.workers import worker_pool

    with pytest.raises(RuntimeError, match="worker process stopped unexpectedly.*--jobs"):
        with worker_pool(_die_on_three, workers=2) as run:
            list(run(range(6)))
    with worker_pool(_die_on_three, workers=2) as run:  # the next pool starts afresh
        assert list(run([1, 2])) == [1, 2]
