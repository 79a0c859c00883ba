"""Tests of ccs_kornia.fleet.predict: image sets through Lightning's Trainer.predict (calibrate-many)."""

from __future__ import annotations

import json
import os

import cv2
import numpy as np
import pytest
import torch

from ccs_kornia.data.scenes.scenes import make_calibration_set
from ccs_kornia.fleet.predict import (
    CalibrationLitModule,
    ImageSetDataModule,
    ImageSetDataset,
    calibrate_many,
    find_image_sets,
)
from ccs_kornia.fleet.shards import shard_files
from ccs_kornia.geometry.metrics import e_ip
from ccs_kornia.io.images import write_image
from ccs_kornia.pipeline.calibration_pipeline import CalibrationPipeline

BOARD = (9, 6)
K_TRUE = torch.tensor([[560.0, 0.0, 322.0], [0.0, 555.0, 236.0], [0.0, 0.0, 1.0]], dtype=torch.float64)


@pytest.fixture(scope="module")
def camera_dirs(tmp_path_factory):
    """cams/a: 6 views, cams/b: 5 views + a junk file + one odd-size image, cams/c: 2 views, cams/d: junk only."""
    batch = make_calibration_set(K_TRUE, BOARD, 0.025, (640, 480), num_views=7, seed=5,
                                 dist=torch.tensor([-0.12, 0.02, 0.0, 0.0, 0.0], dtype=torch.float64))
    root = tmp_path_factory.mktemp("cams")
    layout = {"a": range(0, 6), "b": range(2, 7), "c": range(0, 2), "d": []}
    for name, views in layout.items():
        (root / name).mkdir()
        for k in views:
            assert write_image(root / name / f"v{k}.png", batch.images[k, 0])
    (root / "b" / "junk.png").write_bytes(b"not an image")
    cv2.imwrite(str(root / "b" / "odd.png"), np.zeros((100, 120), np.uint8))
    (root / "d" / "junk.jpg").write_bytes(b"")
    return root


def test_find_image_sets(camera_dirs, tmp_path):
    sets, problems = find_image_sets([str(camera_dirs)])
    assert [os.path.basename(n) for n, _ in sets] == ["a", "b", "c", "d"] and problems == []
    assert len(dict(sets)[str(camera_dirs / "a")]) == 6
    sets, _ = find_image_sets([str(camera_dirs / "a"), str(camera_dirs / "[ab]"), str(camera_dirs / "a")])
    assert [os.path.basename(n) for n, _ in sets] == ["a", "b"]  # duplicates removed
    (tmp_path / "empty").mkdir()
    sets, problems = find_image_sets([str(tmp_path / "empty"), str(tmp_path / "none"), str(tmp_path / "*.zzz"),
                                      str(camera_dirs / "a" / "v0.png")])
    assert sets == [] and len(problems) == 4
    assert "directory of images" in problems[3][1]


def test_dataset_items(camera_dirs):
    sets, _ = find_image_sets([str(camera_dirs)])
    ds = ImageSetDataset(sets)
    item = ds[1]  # b: decoded images in file order, the reason where a file is unreadable
    images = dict(zip(item["files"], item["images"]))
    assert len(item["files"]) == 7
    assert images[str(camera_dirs / "b" / "v2.png")].shape == (1, 480, 640)
    assert images[str(camera_dirs / "b" / "v2.png")].dtype == torch.float32
    assert "not a readable image" in images[str(camera_dirs / "b" / "junk.png")]
    assert images[str(camera_dirs / "b" / "odd.png")].shape == (1, 100, 120)
    assert all(isinstance(i, str) for i in ds[3]["images"])
    loader = ImageSetDataModule(sets, sets_per_batch=3).predict_dataloader()
    assert [len(b) for b in loader] == [3, 1]


def test_predict_step_batches_cameras(camera_dirs):
    sets, _ = find_image_sets([str(camera_dirs)])
    module = CalibrationLitModule(CalibrationPipeline("opencv"), BOARD, 0.025)
    ds = ImageSetDataset(sets)
    records = module.predict_step([ds[i] for i in range(len(ds))], 0)
    assert [r["success"] for r in records] == [True, True, False, False]
    for r in records[:2]:
        assert float(e_ip(torch.tensor(r["K"]), K_TRUE)) < 2.0, r["K"]
        assert r["rms"] < 0.2 and len(r["views"]) == len(r["views"]) and r["num_views"]["used"] >= 5
    # the same set calibrated alone (no padding, no other camera in the batch) agrees
    alone = module.predict_step([ds[0]], 0)[0]
    np.testing.assert_allclose(alone["K"], records[0]["K"], atol=1e-3)
    b = records[1]
    reasons = {os.path.basename(s["path"]): s["reason"] for s in b["skipped"]}
    assert "unreadable" in reasons["junk.png"] and "not found" in reasons["odd.png"]
    assert "at least 3" in records[2]["error"] and records[3]["error"] == "no readable image"


def test_calibrate_many_writes_jsonl(camera_dirs, tmp_path):
    sets, _ = find_image_sets([str(camera_dirs)])
    out = tmp_path / "results.jsonl"
    summary = calibrate_many(sets, BOARD, str(out), square=0.025, sets_per_batch=2, progress=False)
    assert summary["sets"] == 4 and summary["succeeded"] == 2 and summary["failed"] == 2
    lines = [json.loads(line) for line in out.read_text().splitlines()]
    assert [os.path.basename(r["set"]) for r in lines] == ["a", "b", "c", "d"]
    first = lines[0]
    assert set(first) >= {"set", "success", "error", "image_size", "K", "distortion", "rms", "views", "std", "skipped"}
    assert [r["error"] is None for r in lines] == [r["success"] for r in lines]  # every line has ``error``
    assert all(list(r)[:3] == ["set", "success", "error"] for r in lines)
    assert first["image_size"] == [640, 480] and len(first["distortion"]["coeffs"]) == 5
    assert all(v["used"] for v in first["views"])


def test_pipeline_imports_no_lightning():
    import subprocess
    import sys

    code = "import sys, ccs_kornia.pipeline.calibration_pipeline; print(sorted(m for m in sys.modules if m.split('.')[0] == 'lightning'))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0 and out.stdout.strip() == "[]", out.stdout + out.stderr


def test_calibrate_many_appends_resumes_and_overwrites(camera_dirs, tmp_path):
    sets, _ = find_image_sets([str(camera_dirs)])
    out = tmp_path / "results.jsonl"
    first = calibrate_many(sets[:2], BOARD, str(out), square=0.025, progress=False)
    assert first["succeeded"] == 2 and first["skipped"] == 0
    # an interrupted write left half a line: it is cut, and its set is done again
    with open(out, "a", encoding="utf-8") as handle:
        handle.write('{"set": "half')
    again = calibrate_many(sets, BOARD, str(out), square=0.025, progress=False)
    assert again["skipped"] == 2 and again["succeeded"] + again["failed"] == 2
    names = [os.path.basename(json.loads(line)["set"]) for line in out.read_text().splitlines()]
    assert names == ["a", "b", "c", "d"]
    nothing = calibrate_many(sets, BOARD, str(out), square=0.025, progress=False)
    assert nothing["skipped"] == 4 and nothing["succeeded"] == nothing["failed"] == 0
    (tmp_path / "results.jsonl.rank3").write_text('{"set": "left by a stopped run"}\n')
    fresh = calibrate_many(sets[:1], BOARD, str(out), square=0.025, progress=False, overwrite=True)
    assert fresh["succeeded"] == 1 and len(out.read_text().splitlines()) == 1
    assert shard_files(str(out)) == []  # --overwrite starts the shards again too


def test_calibrate_many_ctrl_c_keeps_finished_lines(camera_dirs, tmp_path, monkeypatch, capsys):
    from ccs_kornia.cli import main

    sets, _ = find_image_sets([str(camera_dirs)])
    out = tmp_path / "results.jsonl"
    calls = {"n": 0}
    original = CalibrationLitModule.predict_step

    def interrupted(self, batch, batch_idx=0):
        calls["n"] += 1
        if calls["n"] == 2:
            raise KeyboardInterrupt
        return original(self, batch, batch_idx)

    monkeypatch.setattr(CalibrationLitModule, "predict_step", interrupted)
    code = main(["calibrate-many", str(camera_dirs), "--board", "9x6", "--output", str(out), "--sets-per-batch", "1",
                 "--detector", "opencv"])
    assert code == 130 and "interrupted" in capsys.readouterr().err
    lines = [json.loads(line) for line in out.read_text().splitlines()]
    assert [os.path.basename(r["set"]) for r in lines] == ["a"] and lines[0]["success"]


def test_calibrate_many_keeps_partial_boards_of_one_camera_in_a_batch(tmp_path):
    """Two cameras calibrated in one batch by the default path, saturated spots over a corner of two views of the
    second: its record has those corners null and counts them; the clean camera's record has none; both cameras
    agree with the truth."""
    batch = make_calibration_set(K_TRUE, BOARD, 0.025, (640, 480), num_views=7, seed=5,
                                 dist=torch.tensor([-0.12, 0.02, 0.0, 0.0, 0.0], dtype=torch.float64))
    h, w = batch.images.shape[-2:]
    yy, xx = torch.meshgrid(torch.arange(h), torch.arange(w), indexing="ij")
    glared = {1: 21, 4: 31}
    for name in ("clean", "glare"):
        (tmp_path / name).mkdir()
        for v in range(7):
            image = batch.images[v, 0]
            if name == "glare" and v in glared:
                x, y = (float(c) for c in batch.corners[v, glared[v]])
                r = 0.4 * float((batch.corners[v, glared[v] + 1] - batch.corners[v, glared[v]]).norm())
                image = (image + 2.0 * torch.exp(-((xx - x) ** 2 + (yy - y) ** 2) / (2 * r**2))).clamp(max=1.0)
            assert write_image(tmp_path / name / f"v{v}.png", image)
    sets, _ = find_image_sets([str(tmp_path / "clean"), str(tmp_path / "glare")])
    out = tmp_path / "results.jsonl"
    summary = calibrate_many(sets, BOARD, str(out), square=0.025, sets_per_batch=2, progress=False)
    assert summary["succeeded"] == 2
    clean, glare = (json.loads(line) for line in out.read_text().splitlines())
    assert clean["num_views"]["partial"] == 0 and glare["num_views"]["partial"] == 2
    for v, k in glared.items():
        assert glare["views"][v]["hidden_corners"] >= 1 and glare["views"][v]["corners"][k] == [None, None]
    for record in (clean, glare):
        assert record["num_views"]["used"] == 7
        assert float(e_ip(torch.tensor(record["K"]), K_TRUE)) < 2.0, record["K"]


@pytest.mark.parametrize(("world", "per_batch"), [(1, 2), (2, 1), (3, 2), (5, 2)])
def test_rank_shares_are_disjoint_whole_batches(world, per_batch):
    """Each rank takes whole batches strided over the ranks: together every set once, no padding repeats, and each
    batch is the one a single process forms; a rank beyond the batches gets none."""
    from types import SimpleNamespace

    sets = [(f"s{i}", []) for i in range(7)]
    single = [[item["name"] for item in b] for b in ImageSetDataModule(sets, per_batch).predict_dataloader()]
    seen = []
    for rank in range(world):
        data = ImageSetDataModule(sets, per_batch)
        data.trainer = SimpleNamespace(global_rank=rank, world_size=world)
        batches = [[item["name"] for item in b] for b in data.predict_dataloader()]
        assert batches == single[rank::world]
        seen += [n for b in batches for n in b]
    assert sorted(seen) == sorted(n for n, _ in sets) and len(seen) == len(sets)


def test_fewer_batches_than_processes_are_said_with_the_remedy(tmp_path, capsys, monkeypatch):
    """Two processes, one batch of two sets: one process has nothing to do; the command says so and which
    --sets-per-batch gives every process a batch (the batches stay those of one process: the same lines)."""
    import ccs_kornia.fleet.predict as predict
    from ccs_kornia import cli

    for name in ("a", "b", "c"):
        (tmp_path / "sets" / name).mkdir(parents=True)
        assert write_image(tmp_path / "sets" / name / "v0.png", np.full((48, 64), 0.5, np.float32))
    out = tmp_path / "out.jsonl"
    out.write_text(json.dumps({"set": str(tmp_path / "sets" / "c"), "success": True}) + "\n")  # done before
    monkeypatch.setattr(predict, "calibrate_many", lambda *args, **kwargs: {"rank": 1})
    argv = ["calibrate-many", str(tmp_path / "sets"), "--board", "7x5", "--output", str(out), "--detector", "opencv",
            "--no-distortion-correction", "--devices", "2", "--accelerator", "cpu"]
    assert cli.main(argv) == 0
    err = capsys.readouterr().err
    assert ("2 sets left to do make 1 batch (--sets-per-batch 4) for 2 processes: 1 process will have nothing to do "
            "(each process takes whole batches, so the lines are those one process writes); --sets-per-batch 1 gives "
            "every process a batch") in err
    assert cli.main(argv + ["--sets-per-batch", "1"]) == 0
    assert "nothing to do" not in capsys.readouterr().err
    assert cli.main(argv[:-4]) == 0  # one process: nothing to say
    assert "nothing to do" not in capsys.readouterr().err


def test_data_module_leaves_out_sets_written_in_the_output_or_a_shard(tmp_path):
    out = tmp_path / "x.jsonl"
    out.write_text(json.dumps({"set": "s1", "success": True}) + "\n")
    (tmp_path / "x.jsonl.rank1").write_text(json.dumps({"set": "s3", "success": False}) + "\n")
    sets = [(f"s{i}", []) for i in range(5)]
    data = ImageSetDataModule(sets, 2, output=str(out))
    data.setup("predict")
    assert [n for n, _ in data.todo] == ["s0", "s2", "s4"]
    data = ImageSetDataModule(sets, 2, output=str(out), overwrite=True)
    data.setup("predict")
    assert len(data.todo) == 5


def test_calibrate_many_resumes_from_shards_and_merges_them(camera_dirs, tmp_path):
    """A stopped distributed run left shards: their sets are skipped, their lines merged into the output once, in the
    order of the sets, and the shards removed; with every set written, the shards are merged without a Trainer."""
    sets, _ = find_image_sets([str(camera_dirs)])
    a, b, c, d = (str(n) for n, _ in sets)
    out = tmp_path / "x.jsonl"
    (tmp_path / "x.jsonl.rank1").write_text(json.dumps({"set": a, "success": True, "error": None}) + "\n"
                                            + '{"set": "cut sho')
    pipe = CalibrationPipeline("opencv", distortion_correction=False)
    summary = calibrate_many([s for s in sets if s[0] != b], BOARD, str(out), square=0.025, pipeline=pipe,
                             progress=False)
    assert (summary["skipped"], summary["succeeded"], summary["failed"], summary["missing"]) == (1, 0, 2, 0)
    assert (summary["file_succeeded"], summary["file_failed"], summary["world_size"]) == (1, 2, 1)
    assert [json.loads(line)["set"] for line in out.read_text().splitlines()] == [c, d, a]
    assert shard_files(str(out)) == []
    (tmp_path / "x.jsonl.rank0").write_text(json.dumps({"set": b, "success": False, "error": "x"}) + "\n")
    again = calibrate_many(sets, BOARD, str(out), square=0.025, pipeline=pipe, progress=False)
    assert again["skipped"] == 4 and again["succeeded"] == again["failed"] == 0 and shard_files(str(out)) == []
    assert sorted(json.loads(line)["set"] for line in out.read_text().splitlines()) == [a, b, c, d]


def test_calibrate_many_refuses_an_output_that_is_not_jsonl(camera_dirs, tmp_path):
    sets, _ = find_image_sets([str(camera_dirs)])
    out = tmp_path / "calibration.json"
    out.write_text(json.dumps({"K": [[1, 0, 0], [0, 1, 0], [0, 0, 1]]}, indent=1) + "\n")
    before = out.read_text()
    with pytest.raises(ValueError, match="not calibrate-many's JSON Lines"):
        calibrate_many(sets[2:3], BOARD, str(out), progress=False)
    assert out.read_text() == before
