"""The GPU path proven in one call: ``ccs_kornia/bench/gpu_check.sh`` / ``python -m ccs_kornia.bench.gpu_check``.

On a machine with CUDA, in a few minutes:

1. the test suite's device-parametrised tests on CUDA (``pytest -k cuda`` over the tests that take the ``device``
   fixture of ``tests/conftest.py``);
2. parity: the learned detector (float32 network on both) gives the same corners on CPU and GPU (at most
   ``--corner-tol`` px apart, the same boards found) on a rendered set, and the solver gives the same calibration from
   the same corners (``K`` and distortion within ``--calib-tol`` relative);
3. host round-trips: the CUDA synchronisations of one detection call at two batch sizes and of one solver call
   (``torch.cuda.set_sync_debug_mode``): a count that grows with the batch would be a round-trip per image;
4. throughput: detection images/s at batch 1/16/64 and calibrations/s at 1/64/256 cameras;
5. with two GPUs or more: ``calibrate-many`` on two GPUs (Lightning DDP, one process per GPU) writes the lines it
   writes on one GPU (each set once, ``K`` within ``--calib-tol`` relative), with both wall times.

Without CUDA (or with ``--dry-run``) it says what it would check and runs the CPU half (the CPU side of the parity
checks, the CPU throughput at the smaller sizes), so the script itself is exercised by the test suite. The exit
status is 0 when every check that ran passed.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
import warnings
from pathlib import Path

import torch

__all__ = ["main", "run_checks", "would_check"]

REPO = Path(__file__).resolve().parents[2]
BOARD = (9, 6)
SQUARE = 0.025
SIZE = (640, 480)


def _say(msg: str) -> None:
    """Print one progress line at once (the script's output is read while it runs)."""
    print(msg, flush=True)


def _render(views: int, seed: int = 7) -> tuple[torch.Tensor, torch.Tensor]:
    """A rendered 640x480 set and its true corners.

    Args:
        views: number of views.
        seed: the scene generator's seed.

    Returns:
        ``(images, corners)``: ``(views, 1, 480, 640)`` images quantised to 8 bits, ``(views, 54, 2)`` true corners.
    """
    from ccs_kornia.data.scenes.scenes import make_calibration_set

    K = torch.tensor([[560.0, 0, 322], [0, 555, 236], [0, 0, 1]], dtype=torch.float64)
    s = make_calibration_set(K, BOARD, SQUARE, SIZE, num_views=views, seed=seed, supersample=2,
                             dist=torch.tensor([-0.12, 0.05, 0.0, 0.0, 0.0], dtype=torch.float64))
    return torch.round(s.images.clamp(0, 1) * 255) / 255, s.corners


def _sync(device: str) -> None:
    """Wait for the device's queued work (CUDA only; CPU work is synchronous)."""
    if device == "cuda":
        torch.cuda.synchronize()


def _best(fn, device: str, repeats: int = 2) -> float:
    """Best wall time of ``fn``.

    Args:
        fn: the call to time (no arguments).
        device: ``"cpu"`` or ``"cuda"`` (synchronised around each call).
        repeats: timed calls after one warm-up call.

    Returns:
        The fastest timed call, in seconds.
    """
    fn()
    _sync(device)
    best = float("inf")
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        _sync(device)
        best = min(best, time.perf_counter() - t)
    return best


def _tests(cuda: bool, time_limit: float) -> dict:
    """Run (CUDA) or list (dry run) the device-parametrised tests.

    The dry run collects the ``cpu`` variants of the tests that take the ``device`` fixture: the CUDA run has exactly
    as many ``cuda`` variants.

    Args:
        cuda: run the ``cuda`` variants (else only collect the ``cpu`` ones).
        time_limit: seconds before the pytest subprocess is stopped.

    Returns:
        ``ok``, the pytest summary line and the command; on the dry run ``would_run``, the number of tests;
        ``skipped`` where the tests folder is not there.
    """
    tests = REPO / "tests"
    if not tests.is_dir():
        return {"skipped": f"{tests} not found (installed package without its tests)"}
    env = dict(os.environ, PYTHONPATH=str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    key = "cuda" if cuda else "cpu"
    cmd = [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "-k", key, str(tests)]
    if not cuda:
        cmd.insert(4, "--collect-only")
    try:
        proc = subprocess.run(cmd, check=False, capture_output=True, text=True, timeout=time_limit, cwd=REPO, env=env)
    except subprocess.TimeoutExpired:
        return {"ok": False, "error": f"over {time_limit:.0f} s"}
    tail = proc.stdout.strip().splitlines()[-1] if proc.stdout.strip() else proc.stderr[-300:]
    if cuda:
        return {"ok": proc.returncode == 0, "summary": tail, "command": "pytest -q -k cuda tests"}
    n = sum(1 for line in proc.stdout.splitlines() if "::" in line and "[cpu" in line)
    return {"ok": proc.returncode == 0, "would_run": n, "summary": tail, "command": "pytest -q -k cuda tests"}


def _parity(images: torch.Tensor, cuda: bool, corner_tol: float, calib_tol: float) -> dict:
    """CPU-vs-GPU parity of the learned detector (float32 network) and of the solver on the same corners.

    Args:
        images: ``(B, 1, H, W)`` rendered views.
        cuda: also run on CUDA and compare (else the CPU half only).
        corner_tol: largest allowed corner difference, px.
        calib_tol: largest allowed relative difference of ``fx, fy, cx, cy`` and of the distortion.

    Returns:
        ``cpu_found``, ``cpu_calibrated``; with CUDA also the differences and ``corners_ok`` / ``calibration_ok``.
    """
    from ccs_kornia.modules.detection.learned.learned_detector import (
        LearnedChessboardDetector,
    )
    from ccs_kornia.pipeline.calibration_pipeline import CalibrationPipeline

    out: dict = {}
    det = LearnedChessboardDetector(precision="float32")
    with torch.inference_mode():
        ref = det(images, BOARD)
    out["cpu_found"] = int(ref.found.sum())
    pipe = CalibrationPipeline(det, distortion_correction=False)
    cal = pipe.calibrate(ref.corners.double(), ref.found, BOARD, SQUARE, SIZE)
    out["cpu_calibrated"] = bool(cal.success)
    if not cuda:
        return out
    det = det.to("cuda")
    with torch.inference_mode():
        got = det(images.cuda(), BOARD)
    same_found = bool(torch.equal(got.found.cpu(), ref.found))
    both = got.found.cpu() & ref.found
    diff = (got.corners.cpu().double() - ref.corners.double())[both].norm(dim=-1)
    out["corners_max_diff_px"] = float(diff.max()) if diff.numel() else float("nan")
    out["corners_ok"] = same_found and bool(diff.numel()) and out["corners_max_diff_px"] <= corner_tol
    pipe = pipe.to("cuda")
    cal_gpu = pipe.calibrate(ref.corners.double().cuda(), ref.found.cuda(), BOARD, SQUARE, SIZE)
    idx = (torch.tensor([0, 1, 0, 1]), torch.tensor([0, 1, 2, 2]))  # fx, fy, cx, cy
    k_cpu, k_gpu = cal.K[idx], cal_gpu.K.cpu()[idx]
    out["K_max_rel_diff"] = float(((k_gpu - k_cpu).abs() / k_cpu.abs()).max())
    dist_scale = cal.dist.abs().max().clamp_min(1e-12)
    out["dist_max_rel_diff"] = float((cal_gpu.dist.cpu() - cal.dist).abs().max() / dist_scale)
    out["calibration_ok"] = bool(cal_gpu.success) and max(out["K_max_rel_diff"], out["dist_max_rel_diff"]) <= calib_tol
    return out


def _round_trips(images: torch.Tensor, truth: torch.Tensor) -> dict:
    """CUDA synchronisations of one detection call at two batch sizes and of one solver call.

    Args:
        images: rendered views (the first one is repeated into the batches).
        truth: ``(V, N, 2)`` float64 true corners of the views (the solver's input, for 4 cameras).

    Returns:
        ``detect_batch4``, ``detect_batch16``, ``solver_4_cameras``: synchronisations counted in one call.
    """
    from ccs_kornia.bench.common import ccs_calibrate
    from ccs_kornia.geometry.models import OPENCV5
    from ccs_kornia.modules.detection.learned.learned_detector import (
        LearnedChessboardDetector,
    )

    det = LearnedChessboardDetector(precision="float32").to("cuda")

    def count(fn) -> int:
        fn()  # warm-up (lazy initialisation syncs once)
        torch.cuda.synchronize()
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            torch.cuda.set_sync_debug_mode("warn")
            try:
                fn()
            finally:
                torch.cuda.set_sync_debug_mode("default")
        return sum("synchroniz" in str(w.message) for w in caught)

    out = {}
    for b in (4, 16):
        x = images[:1].repeat(b, 1, 1, 1).cuda()
        with torch.inference_mode():
            out[f"detect_batch{b}"] = count(lambda x=x: det(x, BOARD))
    corners = truth.numpy()[None].repeat(4, 0)  # (4, V, N, 2)
    found = torch.ones(corners.shape[:2], dtype=torch.bool).numpy()
    out["solver_4_cameras"] = count(lambda: ccs_calibrate(corners, found, BOARD, SQUARE, SIZE, OPENCV5, "cuda"))
    return out


def _throughput(images: torch.Tensor, truth: torch.Tensor, device: str, batches: tuple[int, ...],
                cameras: tuple[int, ...]) -> dict:
    """Detection images/s and solver calibrations/s (best of the repeats after a warm-up).

    Args:
        images: rendered views (repeated up to the largest batch).
        truth: ``(V, N, 2)`` float64 true corners (plus 0.1 px noise per camera for the solver).
        device: ``"cpu"`` or ``"cuda"``.
        batches: detection batch sizes.
        cameras: cameras per solver call.

    Returns:
        ``detect_images_per_s`` and ``calibrations_per_s``, each keyed by the size as a string.
    """
    from ccs_kornia.bench.common import ccs_calibrate
    from ccs_kornia.geometry.models import OPENCV5
    from ccs_kornia.modules.detection.learned.learned_detector import (
        LearnedChessboardDetector,
    )

    det = LearnedChessboardDetector().to(device)
    n = max(batches)
    pool = images.repeat((n + images.shape[0] - 1) // images.shape[0], 1, 1, 1)[:n].to(device)
    out: dict = {"detect_images_per_s": {}, "calibrations_per_s": {}}
    with torch.inference_mode():
        for b in batches:
            sec = _best(lambda b=b: det(pool[:b], BOARD), device)
            out["detect_images_per_s"][str(b)] = b / sec
            _say(f"[gpu_check] {device} detection batch {b}: {b / sec:.1f} img/s")
    g = torch.Generator().manual_seed(0)
    for c in cameras:
        noisy = (truth[None] + 0.1 * torch.randn((c, *truth.shape), generator=g, dtype=torch.float64)).numpy()
        found = torch.ones(noisy.shape[:2], dtype=torch.bool).numpy()
        sec = _best(lambda noisy=noisy, found=found: ccs_calibrate(noisy, found, BOARD, SQUARE, SIZE, OPENCV5, device),
                    device, repeats=1)
        out["calibrations_per_s"][str(c)] = c / sec
        _say(f"[gpu_check] {device} solver {c} cameras: {c / sec:.1f} calibrations/s")
    return out


def _fleet(calib_tol: float, time_limit: float = 240.0, accelerator: str = "gpu") -> dict:
    """``calibrate-many`` on one GPU and on two (DDP, the command line as a subprocess) over the same rendered sets.

    Args:
        calib_tol: largest allowed relative difference of ``K`` between the two runs.
        time_limit: seconds for each run.
        accelerator: ``gpu``, or ``cpu`` for one process against two on the CPU (the same code path, slower).

    Returns:
        ``ok``, ``sets``, the wall times ``one_device_s`` / ``two_devices_s``, ``K_max_rel_diff``, ``same_sets``
        (each set once, in the same order); ``error`` with the tail of stderr where a run failed.
    """
    import tempfile

    from ccs_kornia.io.images import write_image
    images, _ = _render(8, seed=11)
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp) / "cameras"
        names = [f"cam_{k}" for k in range(4)]
        for k, name in enumerate(names):  # four cameras of six views each, drawn from the eight renders
            (root / name).mkdir(parents=True)
            for v in range(6):
                write_image(root / name / f"v{v}.png", images[(k + v) % 8, 0])
        env = dict(os.environ, PYTHONPATH=str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", ""))
        base = [sys.executable, "-m", "ccs_kornia", "calibrate-many", str(root), "--board", f"{BOARD[0]}x{BOARD[1]}",
                "--square", str(SQUARE), "--sets-per-batch", "1"]
        out: dict = {"sets": len(names)}
        runs = {"one_device": ["--device", "cuda" if accelerator == "gpu" else "cpu"],
                "two_devices": ["--devices", "2", "--accelerator", accelerator, "--strategy", "ddp"]}
        lines = {}
        for key, extra in runs.items():
            path = Path(tmp) / f"{key}.jsonl"
            t = time.perf_counter()
            try:
                proc = subprocess.run([*base, "--output", str(path), *extra], capture_output=True, text=True,
                                      timeout=time_limit, cwd=REPO, env=env, check=False)
            except subprocess.TimeoutExpired:
                return {**out, "ok": False, "error": f"{key}: over {time_limit:.0f} s"}
            out[f"{key}_s"] = time.perf_counter() - t
            _say(f"[gpu_check] calibrate-many on {key.replace('_', ' ')} ({accelerator}): {out[f'{key}_s']:.1f} s")
            if proc.returncode != 0:
                return {**out, "ok": False, "error": f"{key}: exit {proc.returncode}: {proc.stderr[-500:]}"}
            lines[key] = [json.loads(line) for line in path.read_text().splitlines()]
    one, two = lines["one_device"], lines["two_devices"]
    out["same_sets"] = [r["set"] for r in one] == [r["set"] for r in two] and len({r["set"] for r in two}) == len(names)
    diffs = [float((torch.tensor(b["K"]) - torch.tensor(a["K"])).abs().max() / torch.tensor(a["K"]).abs().max())
             for a, b in zip(one, two) if a["success"] and b["success"]]
    out["K_max_rel_diff"] = max(diffs) if diffs else float("nan")
    out["ok"] = out["same_sets"] and len(diffs) == len(names) and out["K_max_rel_diff"] <= calib_tol
    return out


def would_check(corner_tol: float = 1e-3, calib_tol: float = 1e-6) -> list[str]:
    """What the script checks on a GPU machine, one line per check (printed by the dry run).

    Args:
        corner_tol: px, CPU vs GPU corners.
        calib_tol: relative, CPU vs GPU calibration.

    Returns:
        Five lines: the CUDA tests, the parity, the synchronisations, the throughput, calibrate-many on two GPUs.
    """
    return ["run the device-parametrised tests on CUDA: pytest -q -k cuda tests",
            (f"check CPU and GPU give the same corners (<= {corner_tol:g} px, same boards found) and the same "
             f"calibration from the same corners (K, distortion <= {calib_tol:g} relative) on a rendered set"),
            "count the CUDA synchronisations of a detection call at batch 4 and 16 and of a solver call",
            "print detection images/s at batch 1/16/64 and calibrations/s at 1/64/256 cameras",
            (f"with two GPUs: calibrate-many on 2 GPUs (DDP) writes the lines of 1 GPU (each set once, K <= "
             f"{calib_tol:g} relative), with both wall times")]


def run_checks(dry_run: bool = False, corner_tol: float = 1e-3, calib_tol: float = 1e-6, test_time_limit: float = 240.0,
               run_tests: bool = True) -> dict:
    """Run every check (the CPU half only without CUDA or with ``dry_run``).

    Args:
        dry_run: the CPU half only, even where CUDA is present.
        corner_tol: px, CPU vs GPU corners.
        calib_tol: relative, CPU vs GPU calibration.
        test_time_limit: seconds for the device-parametrised tests.
        run_tests: run (CUDA) or list (dry run) the device-parametrised tests.

    Returns:
        The report: ``cuda``, ``device``, ``torch``, ``threads``, ``tests`` (if run), ``parity``, ``syncs`` (CUDA),
        ``throughput``, ``fleet`` (CUDA; run with two GPUs), ``ok`` (every check that ran passed), ``dry_run``,
        ``would_check`` (the dry run's list) and ``seconds``.
    """
    cuda = torch.cuda.is_available() and not dry_run
    t0 = time.perf_counter()
    report: dict = {"cuda": cuda, "device": torch.cuda.get_device_name(0) if cuda else None,
                    "torch": torch.__version__, "threads": torch.get_num_threads()}
    report["dry_run"] = not cuda
    if not cuda:
        report["would_check"] = would_check(corner_tol, calib_tol)
        _say("[gpu_check] no CUDA device (or --dry-run): DRY RUN. On a GPU machine this script would\n"
             + "\n".join(f"  {i}. {line}" for i, line in enumerate(report["would_check"], 1))
             + "\n  It now runs the CPU half of 2 and 4" + (" and lists the tests of 1." if run_tests else "."))
    if run_tests:
        report["tests"] = _tests(cuda, test_time_limit)
        _say(f"[gpu_check] device tests: {report['tests']}")
    images, truth = _render(8)
    report["parity"] = _parity(images, cuda, corner_tol, calib_tol)
    _say(f"[gpu_check] parity: {report['parity']}")
    if cuda:
        report["syncs"] = _round_trips(images, truth.double())
        _say(f"[gpu_check] CUDA synchronisations per call: {report['syncs']}")
        report["throughput"] = _throughput(images, truth.double(), "cuda", (1, 16, 64), (1, 64, 256))
        if torch.cuda.device_count() >= 2:
            report["fleet"] = _fleet(calib_tol)
        else:
            report["fleet"] = {"skipped": f"needs two GPUs, found {torch.cuda.device_count()}"}
        _say(f"[gpu_check] calibrate-many on two GPUs: {report['fleet']}")
    else:
        report["throughput"] = _throughput(images, truth.double(), "cpu", (1, 8), (1, 16))
    checks = [report.get("tests", {}).get("ok", True)]
    if cuda:
        checks += [report["parity"].get("corners_ok", False), report["parity"].get("calibration_ok", False),
                   report["fleet"].get("ok", True)]
        syncs = report["syncs"]
        report["syncs_grow_with_batch"] = syncs["detect_batch16"] > syncs["detect_batch4"]
    else:
        checks += [report["parity"]["cpu_found"] > 0, report["parity"]["cpu_calibrated"]]
    report["ok"] = all(bool(c) for c in checks)
    report["seconds"] = time.perf_counter() - t0
    _say(f"[gpu_check] {'PASS' if report['ok'] else 'FAIL'} in {report['seconds']:.0f} s"
         + ("" if cuda else " (dry run: CPU half only)"))
    return report


def main(argv: list[str] | None = None) -> int:
    """Command line: ``ccs_kornia/bench/gpu_check.sh [--dry-run] [--no-tests] [--out report.json]``.

    Args:
        argv: the arguments (``sys.argv[1:]`` when ``None``).

    Returns:
        The exit status: 0 when every check that ran passed.
    """
    p = argparse.ArgumentParser(prog="python -m ccs_kornia.bench.gpu_check", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--dry-run", action="store_true", help="the CPU half only, even where CUDA is present")
    p.add_argument("--no-tests", action="store_true", help="skip the device-parametrised tests")
    p.add_argument("--corner-tol", type=float, default=1e-3, help="px, CPU vs GPU corners")
    p.add_argument("--calib-tol", type=float, default=1e-6, help="relative, CPU vs GPU calibration")
    p.add_argument("--out", default=None, help="write the report as JSON here")
    args = p.parse_args(argv)
    report = run_checks(args.dry_run, args.corner_tol, args.calib_tol, run_tests=not args.no_tests)
    if args.out:
        Path(args.out).write_text(json.dumps(report, indent=1))
    return 0 if report["ok"] else 1


if __name__ == "__main__":
    raise SystemExit(main())
