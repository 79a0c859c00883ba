"""calibrate-many on two CPU processes (Lightning DDP over gloo) against one process.

The command line is run as a subprocess, so Lightning's launcher starts the second process (it runs the same command
again with its rank in the environment).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch

from ccs_kornia.data.scenes.scenes import make_calibration_set
from ccs_kornia.io.images import write_image

REPO = Path(__file__).resolve().parents[2]
K_TRUE = torch.tensor([[280.0, 0.0, 161.0], [0.0, 277.0, 118.0], [0.0, 0.0, 1.0]], dtype=torch.float64)
FAST = ("--board", "7x5", "--square", "0.025", "--detector", "opencv", "--no-distortion-correction",
        "--model", "opencv5", "--sets-per-batch", "1")
TWO = ("--devices", "2", "--accelerator", "cpu", "--strategy", "ddp")


@pytest.fixture(scope="module")
def cameras(tmp_path_factory):
    """Three small rendered cameras and a folder of noise images (no board: the set fails)."""
    batch = make_calibration_set(K_TRUE, (7, 5), 0.025, (320, 240), num_views=7, seed=5,
                                 dist=torch.tensor([-0.12, 0.02, 0.0, 0.0, 0.0], dtype=torch.float64))
    root = tmp_path_factory.mktemp("fleet")
    for name, views in {"a": range(0, 5), "b": range(1, 6), "c": range(2, 7)}.items():
        (root / name).mkdir()
        for k in views:
            assert write_image(root / name / f"v{k}.png", batch.images[k, 0])
    (root / "noise").mkdir()
    rng = np.random.default_rng(0)
    for k in range(3):
        cv2.imwrite(str(root / "noise" / f"n{k}.png"), rng.integers(0, 255, (240, 320), dtype=np.uint8))
    return root


def _cli(*args: str) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if k not in ("RANK", "LOCAL_RANK", "NODE_RANK", "WORLD_SIZE")}
    env["PYTHONPATH"] = str(REPO) + os.pathsep + env.get("PYTHONPATH", "")
    return subprocess.run([sys.executable, "-m", "ccs_kornia", "calibrate-many", *args], capture_output=True,
                          text=True, timeout=600, cwd=REPO, env=env)


def _lines(path: Path) -> list[dict]:
    return [json.loads(line) for line in path.read_text().splitlines()]


@pytest.mark.slow
def test_two_processes_write_the_lines_of_one(cameras, tmp_path):
    one, two = tmp_path / "one.jsonl", tmp_path / "two.jsonl"
    done = _cli(str(cameras), "--output", str(one), *FAST)
    assert done.returncode == 0, done.stderr[-2000:]
    done = _cli(str(cameras), "--output", str(two), *FAST, *TWO)
    assert done.returncode == 0, done.stderr[-2000:]
    assert "calibrated 3 of 4 sets" in done.stdout and "2 processes" in done.stdout
    assert "holds 4 of the 4 sets: 3 calibrated, 1 failed" in done.stdout
    assert done.stderr.count("calibrating 4 image sets") == 1  # rank 0 alone says what the run does
    # each set exactly once, in the order given, the shards merged and removed
    ref, got = _lines(one), _lines(two)
    assert [os.path.basename(r["set"]) for r in got] == ["a", "b", "c", "noise"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["one.jsonl", "two.jsonl"]
    # the noise set failed on rank 1 (batches a, c on rank 0; b, noise on rank 1): b beside it and rank 0 went on
    for r, s in zip(ref, got):
        assert r["set"] == s["set"] and r["success"] == s["success"] and r["error"] == s["error"]
        if r["success"]:
            np.testing.assert_allclose(s["K"], r["K"], rtol=1e-6)
            np.testing.assert_allclose(s["distortion"]["coeffs"], r["distortion"]["coeffs"], rtol=1e-6, atol=1e-9)
    assert [r["success"] for r in got] == [True, True, True, False] and "board found in 0" in got[3]["error"]
    # a rerun on two processes adds nothing
    before = two.read_bytes()
    done = _cli(str(cameras), "--output", str(two), *FAST, *TWO)
    assert done.returncode == 0, done.stderr[-2000:]
    assert "nothing to do" in done.stdout and two.read_bytes() == before


@pytest.mark.slow
def test_two_processes_complete_what_a_stopped_run_left(cameras, tmp_path):
    """A run stopped with one set in rank 1's shard: two processes skip it, do the rest, and merge it once."""
    one, two = tmp_path / "one.jsonl", tmp_path / "two.jsonl"
    assert _cli(str(cameras / "b"), "--output", str(one), *FAST).returncode == 0
    (tmp_path / "two.jsonl.rank1").write_bytes(one.read_bytes() + b'{"set": "cut sh')
    done = _cli(str(cameras), "--output", str(two), *FAST, *TWO)
    assert done.returncode == 0, done.stderr[-2000:]
    assert "calibrated 2 of 3 sets" in done.stdout and "1 set(s) already in" in done.stderr
    got = _lines(two)
    assert [os.path.basename(r["set"]) for r in got] == ["a", "b", "c", "noise"]
    assert got[1] == _lines(one)[0]  # the stopped run's line, merged as it was
    assert not (tmp_path / "two.jsonl.rank1").exists() and not (tmp_path / "two.jsonl.rank0").exists()
