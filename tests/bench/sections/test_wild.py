"""The ``wild`` benchmark section at its tiny size: runs, writes its tables, counts false boards, rescales photos."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import torch

from ccs_kornia.bench.__main__ import main
from ccs_kornia.bench.sections.wild import WILD_CONDITIONS, wild_spec

FAST = ("opencv_saddle", "opencv_subpix")


def _real_dir() -> Path | None:
    for parent in Path(__file__).resolve().parents:
        cand = parent / "shared" / "data" / "real"
        if cand.is_dir():
            return cand
    return None


@pytest.fixture(autouse=True)
def _one_thread():
    n = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(n)


def test_every_condition_has_a_valid_spec():
    for name in WILD_CONDITIONS:
        spec, board = wild_spec(name)
        assert spec.board_cols == (board[0], board[0]) and spec.psf_sigma == (0.3, 1.0)


def test_peak_memory_sees_an_allocation():
    # in a fresh interpreter: what earlier tests left in the allocator must not hide the allocation
    import subprocess
    import sys

    code = ("import numpy as np; from ccs_kornia.bench.sections.wild import PeakMemory\n"
            "with PeakMemory() as m:\n    x = np.ones(256 * 2**20 // 8); del x\nprint(m.mb)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                         cwd=Path(__file__).resolve().parents[3])
    mb = float(out.stdout.strip())
    assert math.isnan(mb) or mb > 128


def test_tiny_wild_run_writes_its_table(tmp_path):
    out, md = tmp_path / "bench", tmp_path / "benchmarks.md"
    real = _real_dir()
    argv = ["--tiny", "--sections", "wild", "--out", str(out), "--markdown", str(md), "--no-cuda", "--methods", *FAST]
    if real is not None:
        argv += ["--real-dir", str(real)]
    assert main(argv) == 0
    sec = json.loads((out / "results.json").read_text())["sections"]["wild"]
    assert set(sec["conditions"]) == {"img320", "cut"}
    for cond in sec["conditions"].values():
        for r in cond["methods"].values():
            assert r["images"] == 1 and 0.0 <= r["detection_rate"] <= 1.0 and r["seconds_per_image"] >= 0
    assert sec["conditions"]["img320"]["methods"]["opencv_subpix"]["detected"] == 1
    assert sec["conditions"]["img320"]["visible_images"] == 1  # a clean render shows every corner
    free = sec["board_free"]
    assert free["images"] == 2 and all(r["false_boards"] == 0 for r in free["methods"].values())
    if real is not None:
        assert "0.5" in sec["real"]["sets"]["boofcv_bumblebee2_left"]["scales"]
    else:
        assert sec["real"]["skipped"]
    text = md.read_text()
    assert "## 6. Detection in the wild" in text and "*Detected (wrong boards)*" in text
    assert "Board-free images" in text and "img320 (320x240, 9x6, 1)" in text


def test_unknown_wild_condition_is_a_usage_error(tmp_path, capsys):
    assert main(["--tiny", "--sections", "wild", "--out", str(tmp_path), "--wild-conditions", "nope"]) == 2
    assert "unknown wild condition" in capsys.readouterr().err


def test_corners_under_a_saturating_glare_are_not_visible():
    """Both colours clipped to white around a corner: no detector can see it; a bright but unclipped lobe leaves it."""
    from ccs_kornia.bench.sections.wild import corners_visible

    yy, xx = np.mgrid[0:64, 0:64]
    checker = (((xx // 16) + (yy // 16)) % 2).astype(np.float64) * 0.9 + 0.05
    corners = np.array([[15.5, 15.5], [31.5, 31.5], [47.5, 47.5]])
    lobe = np.exp(-((xx - 47.5) ** 2 + (yy - 47.5) ** 2) / 8.0**2)
    assert corners_visible(np.clip(checker + 3.0 * lobe, 0, 1), corners, 16.0).tolist() == [True, True, False]
    assert corners_visible(np.clip(checker + 0.03 * lobe, 0, 1), corners, 16.0).all()
    assert not corners_visible(checker, np.array([[-3.0, 5.0], [np.nan, 1.0]]), 16.0).any()


def test_visible_column_appears_only_where_renders_hide_corners():
    from ccs_kornia.bench.report.wild_report import wild_markdown

    def cond(visible):
        return {"description": "d", "board": [9, 6], "image_size": [640, 480], "visible_images": visible,
                "methods": {"learned": {"images": 20, "detected": 11, "wrong_boards": 0, "detected_visible": 11,
                                        "mean_px": 0.05, "mean_common_px": 0.05, "common_images": 5,
                                        "seconds_per_image": 0.2, "peak_mb_per_image": 50.0}}}

    text = "\n".join(wild_markdown({"conditions": {"glare": cond(11)}}))
    assert "| visible |" in text and "11/20 (0) [11/11]" in text
    text = "\n".join(wild_markdown({"conditions": {"noise": cond(20)}}))
    assert "| visible |" not in text and "11/20 (0) |" in text
