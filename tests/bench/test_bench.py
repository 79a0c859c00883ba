"""Tests of the benchmark package (``python -m ccs_kornia.bench``) on its tiniest configuration."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from _real_data import REAL_DATA

from ccs_kornia.bench import BenchConfig, run_bench
from ccs_kornia.bench.__main__ import main
from ccs_kornia.bench.common import ccs_calibrate, cv2_calibrate, summary
from ccs_kornia.bench.methods.methods import make_methods
from ccs_kornia.bench.report.report import (
    HONEST_END,
    HONEST_START,
    draw_boxplot,
    write_markdown,
)
from ccs_kornia.bench.scenes.scenes import corner_errors, orient_grid, render_scenes
from ccs_kornia.geometry.board_points import board_object_points
from ccs_kornia.geometry.camera import project_points
from ccs_kornia.geometry.models import K1K2

REAL = REAL_DATA
FAST_METHODS = ("opencv_saddle", "opencv_subpix")


def _grid(cols: int, rows: int) -> np.ndarray:
    i, j = np.meshgrid(np.arange(cols), np.arange(rows))
    return np.stack([40.0 + 20 * i + 2 * j, 30.0 + 18 * j + 1 * i], -1).reshape(-1, 2)


# ----------------------------------------------------------------------------------------------
# corner bookkeeping
# ----------------------------------------------------------------------------------------------


@pytest.mark.parametrize("board", [(5, 4), (4, 4)])
def test_corner_errors_allow_board_symmetries(board):
    cols, rows = board
    truth = _grid(cols, rows)
    g = truth.reshape(rows, cols, 2)
    for variant in (g[::-1, ::-1], g[:, ::-1], g[::-1, :]):
        assert np.allclose(corner_errors(variant.reshape(-1, 2), truth, board), 0.0)
    if cols == rows:
        assert np.allclose(corner_errors(g.transpose(1, 0, 2).reshape(-1, 2), truth, board), 0.0)
    # a board shifted by one square is wrong whatever the ordering
    shifted = truth + np.array([20.0, 0.0])
    assert corner_errors(shifted, truth, board).min() > 5.0


def test_orient_grid_fixes_handedness_and_origin():
    board = (5, 4)
    truth = _grid(*board)
    g = truth.reshape(4, 5, 2)
    mirrored = g[:, ::-1].reshape(-1, 2)
    out = orient_grid(mirrored, board)
    np.testing.assert_allclose(out, truth)  # canonical: handedness restored, first corner top-left
    np.testing.assert_allclose(orient_grid(g[::-1, ::-1].reshape(-1, 2), board), truth)


def test_summary_ignores_nan_and_none():
    s = summary([1.0, np.nan, 3.0, None])
    assert s["n"] == 2 and s["mean"] == 2.0 and s["max"] == 3.0
    assert summary([])["mean"] is None


# ----------------------------------------------------------------------------------------------
# scenes, methods, solvers
# ----------------------------------------------------------------------------------------------


def test_render_scenes_seeded_and_quantised():
    cfg = BenchConfig.tiny()
    a = render_scenes(cfg, "clean", 1, 2, "corners")
    b = render_scenes(cfg, "clean", 1, 2, "corners")
    assert a.images.shape == (1, 2, 1, 240, 320) and a.corners.shape == (1, 2, 24, 2)
    assert torch.equal(a.images, b.images)
    assert torch.allclose(a.images * 255, torch.round(a.images * 255), atol=1e-4)
    other = render_scenes(cfg, "clean", 1, 2, "calibration")  # another section: other scenes
    assert not torch.equal(a.images, other.images)
    with pytest.raises(ValueError):
        render_scenes(cfg, "fog", 1, 1, "corners")


def test_optics_conditions_finish_the_renders_and_keep_the_other_seeds():
    """The realistic-optics conditions are the clean / blur+noise sets through the wild renders' camera chain (point
    spread, noise, a tone curve: brighter mid-tones, softer edges); adding them moved no other condition's scenes."""
    from ccs_kornia.bench.config import CALIB_CONDITIONS, OPTICS_CONDITIONS

    cfg = BenchConfig.tiny()
    assert set(OPTICS_CONDITIONS) <= set(CALIB_CONDITIONS)
    optics = render_scenes(cfg, "optics", 1, 2, "calibration")
    assert torch.equal(optics.images, render_scenes(cfg, "optics", 1, 2, "calibration").images)
    assert torch.allclose(optics.images * 255, torch.round(optics.images * 255), atol=1e-4)
    clean = render_scenes(cfg, "clean", 1, 2, "calibration")
    assert not torch.equal(optics.K, clean.K)  # seeds of its own
    assert float(optics.images.mean()) > float(clean.images.mean())  # gamma > 1 lifts the mid-tones
    # the older conditions' seed index: their sorted order without the optics conditions (seed base + 1000 x index)
    severe = render_scenes(cfg, "severe", 1, 1, "calibration")
    gen = torch.Generator().manual_seed(9_000_000 + 100_000 + 1000 * 8)
    from ccs_kornia.bench.scenes.scenes import random_cameras

    assert torch.equal(severe.K, random_cameras(1, cfg.image_size, gen))


def test_methods_detect_rendered_boards_precisely():
    cfg = BenchConfig.tiny()
    scenes = render_scenes(cfg, "clean", 1, 2, "corners")
    methods = make_methods(FAST_METHODS)
    for m in methods.values():
        corners, found = m.detect(scenes.flat_images, cfg.board)
        assert corners.shape == (2, 24, 2) and found.all()
        for b in range(2):
            assert corner_errors(corners[b], scenes.flat_corners[b].numpy(), cfg.board).max() < 0.5
    with pytest.raises(ValueError):
        make_methods(("nope",))


def test_learned_method_reports_missing_weights_or_is_available():
    from ccs_kornia.modules.detection.learned.learned_detector import (
        DEFAULT_DETECTOR_WEIGHTS,
    )

    m = make_methods(("learned",))["learned"]
    if DEFAULT_DETECTOR_WEIGHTS.is_file():
        assert m.available and m.reason == ""
    else:
        assert not m.available and "weights not available" in m.reason
        with pytest.raises(RuntimeError):
            m.detect(torch.zeros(1, 1, 32, 32), (4, 3))


def test_learned_method_runs_at_the_batch_it_is_given():
    # the speed section times the learned detector at batch 1 and 16: its calls must be of that size, not the
    # bench's usual batches of cfg.learned_batch
    m = make_methods(("learned",), learned_batch=2)["learned"]
    if not m.available:
        pytest.skip(m.reason)
    det, sizes = m._fn.detector, []
    hook = det.register_forward_pre_hook(lambda mod, args: sizes.append(args[0].shape[0]))
    try:
        images = torch.zeros(4, 1, 48, 64)
        m.detect(images, (4, 3))
        m.detect(images, (4, 3), batch=4)
        m.detect(images[:3], (4, 3), batch=1)
    finally:
        hook.remove()
    assert sizes == [2, 2, 4, 1, 1, 1]


def test_solvers_recover_exact_intrinsics():
    board, square, size = (6, 5), 0.03, (640, 480)
    obj = board_object_points(*board, square, dtype=torch.float64)
    K = torch.tensor([[600.0, 0, 322], [0, 590, 236], [0, 0, 1]], dtype=torch.float64)
    g = torch.Generator().manual_seed(0)
    V = 6
    rvec = 0.5 * (torch.rand(V, 3, generator=g, dtype=torch.float64) - 0.5)
    tvec = torch.tensor([-0.07, -0.06, 0.5], dtype=torch.float64).expand(V, 3)
    uv = project_points(obj.expand(V, -1, -1), K.expand(V, 3, 3), None, rvec, tvec).numpy()
    found = np.ones(V, dtype=bool)
    cv = cv2_calibrate(uv, found, board, square, size, K1K2)
    assert cv["success"] and np.allclose(cv["K"], K.numpy(), atol=1e-3) and cv["rms"] < 1e-3
    ours = ccs_calibrate(uv[None], found[None], board, square, size, K1K2)
    assert bool(ours["success"][0]) and np.allclose(ours["K"][0], K.numpy(), atol=1e-3)
    # fewer than three found views: a failure, not an exception
    assert not cv2_calibrate(uv, np.array([1, 1, 0, 0, 0, 0], bool), board, square, size)["success"]
    # partial boards: both solvers leave the hidden (NaN) corners out
    partial = uv.copy()
    partial[1, [0, 7, 12]] = np.nan
    partial[4, 20] = np.nan
    cv = cv2_calibrate(partial, found, board, square, size, K1K2)
    assert cv["success"] and np.allclose(cv["K"], K.numpy(), atol=1e-3) and cv["rms"] < 1e-3
    ours = ccs_calibrate(partial[None], found[None], board, square, size, K1K2)
    assert bool(ours["success"][0]) and np.allclose(ours["K"][0], K.numpy(), atol=1e-3)


def test_corner_section_has_the_collinearity_rows():
    from ccs_kornia.bench.sections.corners import run_corners

    methods = make_methods(("learned",))
    if not methods["learned"].available:
        pytest.skip(methods["learned"].reason)
    cfg = BenchConfig.tiny(corner_conditions=("clean",), corner_images=1, corner_views_per_camera=1)
    res = run_corners(cfg, methods, log=lambda *_: None)["conditions"]["clean"]
    assert set(res) == {"learned", "learned_collinearity", "learned_collinearity_last"}
    for key in ("learned_collinearity", "learned_collinearity_last"):
        assert res[key]["ablation_of"] == "learned" and res[key]["detected"] == 1 and res[key]["mean_px"] < 0.1
        assert res[key]["common_images"] == res["learned"]["common_images"] == 1
    assert "ablation_of" not in res["learned"]


# ----------------------------------------------------------------------------------------------
# the whole run
# ----------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("bench")
    md = out / "benchmarks.md"
    argv = ["--tiny", "--out", str(out), "--markdown", str(md), "--no-cuda", "--methods", *FAST_METHODS,
            "--sections", "corners", "calibration", "distortion", "speed"]
    rc = main(argv)
    return rc, out, md, argv


def test_tiny_run_writes_json_and_markdown(tiny_run):
    rc, out, md, argv = tiny_run
    assert rc == 0
    results = json.loads((out / "results.json").read_text())
    meta, sections = results["meta"], results["sections"]
    assert meta["config"]["preset"] == "tiny" and meta["machine"]["cores"] >= 1
    assert set(sections) == {"corners", "calibration", "distortion", "speed"}
    # corners: every condition and method, rates in [0, 1], sub-pixel errors on clean renders
    corners = sections["corners"]["conditions"]
    assert set(corners) == {"clean", "severe"}
    for cond in corners.values():
        assert set(cond) == set(FAST_METHODS)
        for r in cond.values():
            assert 0.0 <= r["detection_rate"] <= 1.0 and r["images"] == 2
    assert corners["clean"]["opencv_subpix"]["detection_rate"] == 1.0
    assert corners["clean"]["opencv_subpix"]["mean_px"] < 0.3
    # calibration: both solvers for every detector, exact corners give (almost) exact intrinsics
    calib = sections["calibration"]["conditions"]["blur_noise"]
    assert set(calib) == {"truth", *FAST_METHODS}
    assert calib["truth"]["ccs"]["e_ip"] < 1e-3 and calib["truth"]["opencv"]["e_ip"] < 1e-3
    for r in calib.values():
        assert {"e_fl", "e_pp", "e_ip", "e_ip_var", "rms", "failures"} <= set(r["ccs"])
        assert len(r["opencv"]["e_ip_per_trial"]) == 2
    # distortion: skipped with a reason unless weights are shipped
    dist = sections["distortion"]
    assert "skipped" in dist or {"network", "severe", "wide"} <= set(dist)
    # speed: images/s at both batch sizes, solver timings against OpenCV
    cpu = sections["speed"]["devices"]["cpu"]
    for r in cpu["detection"].values():
        assert set(r["images_per_s"]) == {"1", "2"} and all(v > 0 for v in r["images_per_s"].values())
    assert cpu["solver"]["2"]["ccs_calibrations_per_s"] > 0 and cpu["solver"]["2"]["opencv_calibrations_per_s"] > 0
    assert cpu["peak_memory_mb"] > 0
    # markdown: command, machine, tables straight from the JSON, the honest-reading placeholder
    for text in ((out / "report.md").read_text(), md.read_text()):
        assert " ".join(argv[:2]) in text and meta["machine"]["cpu"] in text
        assert meta["machine"]["cpu_vector"] in text and "bfloat16" in meta["machine"]["cpu_vector"]
        assert "## 1. Corner accuracy" in text and "## 2. Calibration" in text and "## 5. Speed" in text
        assert HONEST_START in text and HONEST_END in text and "Placeholder" in text
        mean = corners["clean"]["opencv_subpix"]["mean_px"]
        assert f"{mean:.4f}" in text


def test_markdown_keeps_hand_written_reading(tiny_run, tmp_path):
    _, out, md, _ = tiny_run
    results = json.loads((out / "results.json").read_text())
    target = tmp_path / "b.md"
    write_markdown(results, target)
    text = target.read_text()
    target.write_text(text.replace("_Placeholder", "Our corners beat OpenCV's.\n_Placeholder", 1))
    write_markdown(results, target)
    again = target.read_text()
    assert "Our corners beat OpenCV's." in again and again.count(HONEST_START) == 1


def test_distortion_section_with_an_untrained_network(tmp_path):
    from ccs_kornia.bench.sections.distortion import run_distortion
    from ccs_kornia.modules.correction.distortion_net import DistortionNet

    net = DistortionNet(base_channels=4, input_size=64)
    weights = tmp_path / "dnet.pt"
    torch.save({"kind": "DistortionNet", "config": net.config, "state_dict": net.state_dict()}, weights)
    cfg = BenchConfig.tiny(dc_views=4, wide_views=4, distortion_weights=str(weights))
    res = run_distortion(cfg, make_methods(("opencv_subpix",)), log=lambda *_: None)
    # an untrained network predicts (nearly) the identity correction: no straightening, no correction applied
    net_part = res["network"]
    assert net_part["views"] == 4
    assert net_part["grid_loss"]["network"] == pytest.approx(net_part["grid_loss"]["identity"], rel=0.05)
    assert net_part["grid_loss"]["oracle"] < net_part["grid_loss"]["identity"]
    assert net_part["straightness_after_oracle"] < net_part["straightness_before"]
    for part in ("severe", "wide"):
        rows = res[part]["methods"]
        assert set(rows) == {"ccs_on", "ccs_off", "opencv", "opencv_ccs_corrected"}
        assert all(r["trials"] == 1 for r in rows.values())
        assert res[part]["correction_applied"] == 0
    from ccs_kornia.bench.report.report import _distortion_md

    md = "\n".join(_distortion_md(res))
    assert "Straightness" in md and "wide camera" in md
    missing = run_distortion(BenchConfig.tiny(distortion_weights=str(tmp_path / "none.pt")), {}, log=lambda *_: None)
    assert "not available" in missing["skipped"]


@pytest.mark.skipif(not REAL.is_dir(), reason="shared/data/real is not present next to the repository")
def test_real_section_and_boxplot(tmp_path):
    from ccs_kornia.bench.sections.real import run_real

    cfg = BenchConfig.tiny(real_dir=str(REAL), real_max_images=5, real_subsets=3)
    res = run_real(cfg, make_methods(("opencv_subpix",)), log=lambda *_: None)
    s = res["sets"]["boofcv_bumblebee2_left"]
    assert s["images"] == 5 and s["reference"] is not None and s["model"] == "k1k2"
    r = s["methods"]["opencv_subpix"]
    assert r["found"] == 5
    # all-image calibration near BoofCV's published one (few views: a loose bound)
    assert abs(r["all"]["opencv"]["diff_reference"]["fx"]) < 15
    assert len(r["subsets"]["ccs"]["rms_values"]) == 3
    png = draw_boxplot(res, tmp_path / "box.png")
    import cv2

    img = cv2.imread(str(png))
    assert img is not None and img.shape[0] > 100 and img.shape[1] > 300
    # the fisheye sets are section 7's (a fisheye model on both sides), named so in the skip reason
    skipped = run_real(BenchConfig.tiny(real_dir=str(REAL), real_sets=("ros_fisheye_mono", "nope")), {},
                       log=lambda *_: None)["skipped"]
    assert "section 7" in skipped["ros_fisheye_mono"] and "unknown set" in skipped["nope"]


def test_bad_arguments_exit_2(tmp_path, capsys):
    assert main(["--tiny", "--calib-trials", "0", "--out", str(tmp_path)]) == 2
    assert "must be >= 1" in capsys.readouterr().err
    assert main(["--sections", "nope"]) == 2
    assert main(["--quick", "--tiny"]) == 2
    assert main(["--tiny", "--sections", "calibration", "--calib-conditions", "fog", "--out", str(tmp_path)]) == 2
    assert "unknown calibration condition" in capsys.readouterr().err
    assert main(["--tiny", "--calib-views", "8", "--calib-pool-views", "5", "--out", str(tmp_path)]) == 2
    with pytest.raises(ValueError):
        run_bench(BenchConfig.tiny(sections=("nope",)), tmp_path)


def test_load_reference_reads_one_camera_of_a_stereo_file(tmp_path):
    from ccs_kornia.bench.sections.real import load_reference

    path = tmp_path / "stereo.yaml"
    path.write_text("left:\n  pinhole:\n    fx: 1.5\n    fy: 2.5\n    cx: 3.5\n    cy: 4.5\nmodel: stereo_camera\n"
                    "right:\n  pinhole:\n    fx: 10.0\n    fy: 20.0\n    cx: 30.0\n    cy: 40.0\n")
    assert load_reference(path, "right") == {"fx": 10.0, "fy": 20.0, "cx": 30.0, "cy": 40.0}
    assert load_reference(path, "left") == {"fx": 1.5, "fy": 2.5, "cx": 3.5, "cy": 4.5}
    assert load_reference(path) == {"fx": 1.5, "fy": 2.5, "cx": 3.5, "cy": 4.5}  # the first camera
    assert load_reference(path, "middle") is None and load_reference(tmp_path / "none.yaml") is None
