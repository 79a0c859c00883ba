"""One intra-op thread for small problems (ccs_kornia/runtime/threads.py)."""

from __future__ import annotations

import pytest
import torch

from ccs_kornia.runtime.threads import SINGLE_THREAD_ELEMENTS, small_problem_threads


@pytest.fixture
def two_threads():
    old = torch.get_num_threads()
    torch.set_num_threads(2)
    yield
    torch.set_num_threads(old)


def test_small_problem_runs_on_one_thread_and_restores(two_threads):
    with small_problem_threads(SINGLE_THREAD_ELEMENTS, torch.device("cpu")):
        assert torch.get_num_threads() == 1
    assert torch.get_num_threads() == 2


def test_large_problem_and_other_devices_keep_the_threads(two_threads):
    with small_problem_threads(SINGLE_THREAD_ELEMENTS + 1, torch.device("cpu")):
        assert torch.get_num_threads() == 2
    with small_problem_threads(10, torch.device("cuda")):
        assert torch.get_num_threads() == 2


def test_threads_restored_when_the_block_raises(two_threads):
    with pytest.raises(RuntimeError), small_problem_threads(10, torch.device("cpu")):
        raise RuntimeError("inside")
    assert torch.get_num_threads() == 2


def test_light_stages_run_on_one_thread_under_passive_waits_and_the_network_on_all(two_threads, monkeypatch):
    from ccs_kornia.runtime.threads import full_threads, light_stages_single_thread

    monkeypatch.setenv("OMP_WAIT_POLICY", "passive")
    with light_stages_single_thread(torch.device("cpu")):
        assert torch.get_num_threads() == 1
        with full_threads():
            assert torch.get_num_threads() == 2
        assert torch.get_num_threads() == 1
    assert torch.get_num_threads() == 2
    with full_threads():  # outside: no change
        assert torch.get_num_threads() == 2


def test_light_stages_keep_the_threads_with_spinning_waits(two_threads, monkeypatch):
    from ccs_kornia.runtime.threads import light_stages_single_thread

    monkeypatch.setenv("OMP_WAIT_POLICY", "ACTIVE")
    with light_stages_single_thread(torch.device("cpu")):
        assert torch.get_num_threads() == 2
    monkeypatch.delenv("OMP_WAIT_POLICY")
    with light_stages_single_thread(torch.device("cpu")):
        assert torch.get_num_threads() == 2


def test_detector_refines_at_full_resolution_on_all_threads_under_passive_waits(two_threads, monkeypatch):
    """Under passive waits the level's refinement runs on one thread and the full-resolution refinement, whose regions
    are large, on all (measured faster at 640x480 and on 1280x960 photos)."""
    import ccs_kornia.modules.detection.learned.learned_detector as learned
    from ccs_kornia.data.scenes.scenes import make_calibration_set
    from ccs_kornia.modules.detection.refine.saddle_refine import CornerRefiner

    monkeypatch.setenv("OMP_WAIT_POLICY", "PASSIVE")
    seen = {"full": [], "level": []}
    full, level = learned.refine_from_level, CornerRefiner.forward

    def full_spy(*args, **kwargs):
        seen["full"].append(torch.get_num_threads())
        return full(*args, **kwargs)

    def level_spy(self, *args, **kwargs):
        seen["level"].append(torch.get_num_threads())
        return level(self, *args, **kwargs)

    monkeypatch.setattr(learned, "refine_from_level", full_spy)
    monkeypatch.setattr(CornerRefiner, "forward", level_spy)
    K = torch.tensor([[800.0, 0, 319.5], [0, 800, 239.5], [0, 0, 1]])
    views = make_calibration_set(K, (9, 6), 0.025, (640, 480), num_views=1, seed=0, supersample=1)  # ~15 px squares
    out = learned.LearnedChessboardDetector()(views.images, (9, 6))
    assert bool(out.found.all()) and seen["full"] and seen["level"]
    assert set(seen["full"]) == {2} and set(seen["level"]) == {1}
    assert torch.get_num_threads() == 2
