"""Recordings (section ``video``): the frame selection against every frame, uniformly spaced frames and a
coverage-greedy choice as caliscope makes it; screening speed, end-to-end time and memory.

**Rendered recordings** (:func:`~ccs_kornia.data.recordings.recordings.handheld_recording`: a 9x6 chessboard waved by hand in
front of a webcam with OpenCV distortion, a rolling shutter reading the frame in 50-90 % of its period, motion blur,
sensor noise; 30 fps, written as MPEG-4 part 2) with seeds from :data:`SEED` (the selection's settings were chosen on
other seeds). Each is screened as ``calibrate`` screens it, then the full detector runs on every frame the screen saw
the board in ("all"). The frame choices, each solved by the same solver (:data:`MODEL`, RANSAC, corner weights):

* ``selected``: the command's own choice: the screening's still candidates, then the frame selection
  (:mod:`~ccs_kornia.pipeline.frame_selection`) on their detections;
* ``all``: every frame with a board;
* ``uniform``: as many frames as ``selected`` kept, evenly spaced over those with a board;
* ``coverage``: as many, chosen by :func:`~ccs_kornia.bench.methods.frame_baselines.coverage_greedy` (caliscope's scheme);
* ``unselected`` (rendered recordings only): what ``calibrate VIDEO`` uses without ``--select``: the frames its
  screening chose for the full detector (:data:`MAX_FRAMES`, stiller and spread over the poses), every one counted;
* ``still`` (rendered recordings only): every frame with a board that the screening measured still (its board moved
  at most :data:`~ccs_kornia.pipeline.frame_candidates.MAX_MOTION` of the image diagonal a frame), however many: the
  still gate alone, without the choice of poses or the cap.

Figures: the error against the true camera (E_FL, E_PP and the RMS over the image of the distance between where the
two cameras project the same ray, the rotation between them fitted out); the held-out error on a second recording of
the same camera (another trajectory): every frame with a board posed anew with the camera fixed
(:func:`~ccs_kornia.bench.sections.heldout.heldout_errors`), over all of them and over the still ones (the board slower than
:data:`STILL_SPEED` of the image diagonal per second, where a rolling shutter bends it least). And ``calibrate
VIDEO`` as a user runs it (learned detector, ``--model auto``, diagnostics): wall time, peak memory (PSS of its
processes), screening frames/s.

**The shared real recording** (``caliscope_4cam_charuco/video``: four 1280x720 webcams, 48 frames each at 6 fps, a
hand-held ChArUco board): per camera, two folds (alternate blocks of :data:`FOLD_BLOCK` frames): each frame choice
made on one fold, its held-out error on the other fold's frames; and on the whole recording E_FL and E_PP against
caliscope's published calibration (``reference/camera_array.toml``). The rig (the four cameras with their
``timestamps.csv``): per fold, each choice of instants calibrates the rig (each camera on its views of those
instants, then :class:`~ccs_kornia.modules.rig.rig_solver.RigSolver`), its held-out error is the board posed in one
camera and projected into every other (:func:`~ccs_kornia.bench.sections.heldout.transfer_errors`) on the other fold's
instants.
"""

from __future__ import annotations

import math
import os
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

from ccs_kornia.bench.methods.frame_baselines import coverage_greedy, uniform_frames
from ccs_kornia.bench.sections.heldout import heldout_errors, rms, transfer_errors
from ccs_kornia.geometry.camera import Camera
from ccs_kornia.geometry.models.factory import OPENCV5

__all__ = ["MODEL", "RENDERED_METHODS", "SEED", "STILL_SPEED", "run_video", "video_md"]

#: first seed of the rendered recordings (the tests use seeds below 1000; the selection was tuned on others)
SEED = 600_000
#: the one camera model of every frame choice's calibration (the comparison is of frames, not of models)
MODEL = OPENCV5
#: a held-out frame is still when its board moves slower than this fraction of the image diagonal per second
STILL_SPEED = 0.02
BOARD = (9, 6)
SQUARE = 0.03
#: frames the command's frame selection keeps at most (its default)
MAX_FRAMES = 60
METHODS = ("selected", "all", "uniform", "coverage")
#: the rendered recordings' frame choices: :data:`METHODS`, the command's frames without the selection and every still
#: frame
RENDERED_METHODS = (*METHODS, "unselected", "still")
REAL = "caliscope_4cam_charuco"


def _real_dir(cfg) -> Path:
    if cfg.real_dir:
        return Path(cfg.real_dir)
    from ccs_kornia.bench.sections.real import default_real_dir

    return Path(default_real_dir())


def _pipeline(detector, workers: int, frame_selection=None):
    from ccs_kornia.modules.calibration.quality.degeneracy import DegeneracyThresholds
    from ccs_kornia.pipeline.calibration_pipeline import CalibrationPipeline

    return CalibrationPipeline(detector, model=MODEL, workers=workers, distortion_correction=False,
                               frame_selection=frame_selection, thresholds=DegeneracyThresholds(refuse_weak=False))


def _detect(pipeline, refs, board, names=None):
    """Every frame of ``refs`` (per camera) through the full detector: a batched result without calibration."""
    from ccs_kornia.pipeline.sources import VideoSource

    source = VideoSource(refs, names)
    try:
        return pipeline.run(source, board, SQUARE, calibrate=False)
    finally:
        source.close()


def _solve(pipeline, detected, board: tuple[int, int], camera: int, views: list[int], source=None):
    """One camera calibrated on some of its detected views (``source``: where a frame selection reads the views'
    speeds and names); returns the one-camera result (``None``: no view)."""
    if not views:
        return None
    sub = detected.take_views(torch.tensor([camera]), torch.tensor([views]))
    return pipeline.finish(sub, board, SQUARE, source=source).select(0)


def _camera(result) -> Camera | None:
    """The camera (float64) of a solved one-camera result (``None`` when it failed)."""
    if result is None or result.calibration is None or not bool(result.calibration.success):
        return None
    return result.calibration.camera.to(dtype=torch.float64)


def _truth_figures(camera: Camera, truth: Camera, size: tuple[int, int]) -> dict:
    """E_FL, E_PP and the RMS projection difference over the image (rotation fitted out) against a known camera
    (one camera each, any models)."""
    from ccs_kornia.modules.calibration.quality.uncertainty import (
        image_points,
        projection_difference,
    )

    px = image_points(size, (16, 12))
    diff = projection_difference(truth.to(dtype=torch.float64), camera.to(dtype=torch.float64), px,
                                 compensate_rotation=torch.ones(px.shape[0], dtype=torch.bool))
    K, K_true = camera.K[0].double().numpy(), truth.K[0].double().numpy()
    return {"efl": float(abs(K[0, 0] - K_true[0, 0]) + abs(K[1, 1] - K_true[1, 1])),
            "epp": float(abs(K[0, 2] - K_true[0, 2]) + abs(K[1, 2] - K_true[1, 2])),
            "proj_rms": float(diff.pow(2).nanmean().sqrt())}


def _corners(detected, camera: int, views: list[int]) -> list[np.ndarray]:
    det = detected.detections
    return [np.where(bool(det.found[camera, v]), det.corners[camera, v].double().numpy(), np.nan) for v in views]


def _choices(pipeline, detected, board: tuple[int, int], found: list[int], candidates: list[int], candidate_source,
             obj: np.ndarray, size: tuple[int, int], camera: int = 0) -> dict:
    """The four frame choices on one camera's detections: ``{method: (views, one-camera result)}``."""
    selecting = _pipeline(pipeline.detector, pipeline.settings.workers, _selection())
    selected = _solve(selecting, detected, board, camera, candidates, candidate_source)
    kept = [] if selected is None or selected.frame_choice is None else \
        [candidates[v] for v, keep in enumerate(selected.frame_choice.view_kept(0)[:len(candidates)]) if keep]
    count = max(1, len(kept))
    uniform = uniform_frames(found, count)
    coverage = [found[k] for k in coverage_greedy([_corners(detected, camera, found)], obj, [size], count)]
    out = {"selected": (kept, selected), "all": (found, _solve(pipeline, detected, board, camera, found))}
    out["uniform"] = (uniform, _solve(pipeline, detected, board, camera, uniform))
    out["coverage"] = (coverage, _solve(pipeline, detected, board, camera, coverage))
    return out


def _still_frames(screened, indices: list[int], size: tuple[int, int]) -> list[int]:
    """Of the video frames ``indices``, those whose board the screening measured still: moving at most
    :data:`~ccs_kornia.pipeline.frame_candidates.MAX_MOTION` of the image diagonal a frame (the gate of the command's
    frame choice, :func:`~ccs_kornia.pipeline.frame_candidates.choose_frames`; an unknown motion counts as still)."""
    from ccs_kornia.pipeline.frame_candidates import MAX_MOTION, board_motion

    motion = board_motion([f.index for f in screened.frames], [f.sighting for f in screened.frames])
    limit = MAX_MOTION * math.hypot(*size)
    moves = {f.index: m for f, m in zip(screened.frames, motion)}
    return [i for i in indices if moves.get(i) is None or moves[i] <= limit]


def _selection():
    from ccs_kornia.pipeline.frame_selection import FrameSelection

    return FrameSelection(max_frames=MAX_FRAMES)


# ----------------------------------------------------------------------------------------------
# rendered recordings
# ----------------------------------------------------------------------------------------------


def _rendered(cfg, seed: int, folder: Path, log) -> dict:
    from ccs_kornia.bench.micro.video import run_command
    from ccs_kornia.data.recordings.patterns import ChessPattern
    from ccs_kornia.data.recordings.recording_files import write_recording
    from ccs_kornia.data.recordings.recordings import handheld_recording, webcam
    from ccs_kornia.modules.detection.factory import make_detector
    from ccs_kornia.modules.detection.screening import BoardScreen
    from ccs_kornia.pipeline.frame_candidates import detector_frames
    from ccs_kornia.pipeline.screening import screen_video
    from ccs_kornia.pipeline.sources import TensorSource, VideoFrameRef, VideoSource
    from ccs_kornia.pipeline.video_input import camera_frames

    size = tuple(cfg.video_size)
    camera = webcam(size, seed=seed)
    pattern = ChessPattern(BOARD[0], BOARD[1], SQUARE)
    rec = handheld_recording(camera, pattern, cfg.video_seconds, seed=seed)
    path = folder / f"handheld_{seed}.mp4"
    t = time.perf_counter()
    write_recording(rec, path)
    log(f"[video] rendered {path.name}: {len(rec)} frames {size[0]}x{size[1]} in {time.perf_counter() - t:.0f} s")
    workers = cfg.video_jobs
    t = time.perf_counter()
    screened = screen_video(str(path), BoardScreen(BOARD), workers=workers)
    screen_s = time.perf_counter() - t
    found_at = [k for k, f in enumerate(screened.frames) if f.found]
    frames = camera_frames([screened], detector_frames(MAX_FRAMES, True))
    speed = {r.index: r.speed for r in frames.refs[0]}
    refs = [VideoFrameRef(str(path), screened.frames[k].index, screened.frames[k].timestamp) for k in found_at]
    pipeline = _pipeline(make_detector("learned"), workers)
    t = time.perf_counter()
    detected = _detect(pipeline, [refs], BOARD)
    detect_s = time.perf_counter() - t
    position = {r.index: k for k, r in enumerate(refs)}
    found = [k for k in range(len(refs)) if bool(detected.detections.found[0, k])]
    candidates = [position[r.index] for r in frames.refs[0] if r.index in position]
    plain = camera_frames([screened], detector_frames(MAX_FRAMES, False))
    unselected = [position[r.index] for r in plain.refs[0] if r.index in position]
    cand_source = VideoSource([[VideoFrameRef(str(path), refs[k].index, refs[k].timestamp, speed.get(refs[k].index))
                                for k in candidates]])
    obj = np.asarray(pattern.object_points(), dtype=np.float64).reshape(-1, 3)
    choices = _choices(pipeline, detected, BOARD, found, candidates, cand_source, obj, size)
    unselected = [k for k in unselected if bool(detected.detections.found[0, k])]
    choices["unselected"] = (unselected, _solve(pipeline, detected, BOARD, 0, unselected))
    still_found = _still_frames(screened, [refs[k].index for k in found], size)
    still_views = [position[i] for i in still_found]
    choices["still"] = (still_views, _solve(pipeline, detected, BOARD, 0, still_views))
    cand_source.close()
    # the held-out recording: the same camera, another trajectory; still frames and all of them
    held = handheld_recording(camera, pattern, cfg.video_heldout_seconds, seed=seed + 1)
    step = max(1, len(held) // cfg.video_heldout_frames)
    idx = list(range(0, len(held), step))[:cfg.video_heldout_frames]
    images = torch.stack([held.image(i) for i in idx])[:, None]
    hdet = pipeline.run(TensorSource(images), BOARD, SQUARE, calibrate=False).detections
    allc = held.truth.corners
    diag = math.hypot(*size)
    still, moving = [], []
    for k, i in enumerate(idx):
        if not bool(hdet.found[0, k]):
            continue
        nb = [j for j in (i - 1, i + 1) if 0 <= j < len(held)]
        sp = max(float((allc[j] - allc[i]).norm(dim=-1).nanmean()) for j in nb) * held.camera.fps
        (still if sp < STILL_SPEED * diag else moving).append(hdet.corners[0, k].double().numpy())
    truth = camera.camera
    methods = {}
    for name, (views, result) in choices.items():
        cam = _camera(result)
        entry = {"frames": len(views)}
        if cam is None:
            entry["failed"] = True
        else:
            entry.update(_truth_figures(cam, truth, size))
            entry["heldout_rms"] = rms(heldout_errors(cam, obj, still + moving))
            entry["heldout_still_rms"] = rms(heldout_errors(cam, obj, still))
        methods[name] = entry
    out = {"seed": seed, "size": list(size), "frames": len(screened.frames), "board_seen": len(found_at),
           "screening_fps": len(screened.frames) / max(screen_s, 1e-9), "detected": len(refs),
           "detect_fps": len(refs) / max(detect_s, 1e-9), "candidates": len(candidates),
           "heldout_frames": {"still": len(still), "moving": len(moving)}, "methods": methods,
           "truth": {"K": truth.K[0].tolist(), "dist": truth.dist[0].tolist()}}
    if cfg.video_command:
        output = folder / f"calib_{seed}.json"
        code, wall, pss, text = run_command(["calibrate", str(path), "--board", f"{BOARD[0]}x{BOARD[1]}", "--square",
                                             str(SQUARE), "--jobs", str(workers), "--select", "--output",
                                             str(output)])
        command = {"exit": code, "wall_s": wall, "peak_mb": pss}
        if code == 0:
            import json

            from ccs_kornia.outputs.calibration_file import camera_from_record

            data = json.loads(Path(output).read_text())
            screened_n = sum(len(v["frames"]) for v in data["video"])
            screening_s = sum(v["screening_s"] for v in data["video"])
            cam = camera_from_record(data)
            command.update({"screening_fps": screened_n / max(screening_s, 1e-9), "model": data["distortion"]["model"],
                            "kept": data["selection"]["kept"], "candidates": data["selection"]["candidates"],
                            "total_s": data["timings"]["total_s"]})
            command.update(_truth_figures(cam, truth, size))
            command["heldout_still_rms"] = rms(heldout_errors(cam, obj, still))
        else:
            command["output"] = text[-2000:]
        out["command"] = command
    log(f"[video] {path.name}: " + ", ".join(f"{m} {e.get('frames')} frames proj {e.get('proj_rms', float('nan')):.3f}"
                                               f" held-out still {e.get('heldout_still_rms') or float('nan'):.4f}"
                                               for m, e in methods.items()))
    return out


# ----------------------------------------------------------------------------------------------
# the shared real recording
# ----------------------------------------------------------------------------------------------


#: the real recording's folds: alternate blocks of this many frames (a second and a third at 6 fps)
FOLD_BLOCK = 8


def _folds(n: int) -> list[list[int]]:
    """Two folds of ``n`` frames in time: alternate blocks of :data:`FOLD_BLOCK` (neighbouring frames, nearly copies of
    one another, fall in one fold).

    Example:
        >>> [len(f) for f in _folds(48)], _folds(20)[1][:3]
        ([24, 24], [8, 9, 10])
    """
    return [[k for k in range(n) if (k // FOLD_BLOCK) % 2 == h] for h in range(2)]


def _reference(folder: Path) -> list[Camera]:
    """caliscope's published cameras (OpenCV's five coefficients), float64."""
    import tomllib

    data = tomllib.loads((folder / "reference" / "camera_array.toml").read_text())
    f64 = torch.float64
    return [Camera.from_opencv(OPENCV5, torch.tensor(cam["matrix"], dtype=f64), torch.tensor(cam["distortions"], dtype=f64))
            for cam in (data["cameras"][str(c)] for c in range(4))]


def _real(cfg, folder: Path, log) -> dict:
    from ccs_kornia.modules.detection.boards import CharucoBoard, grid_object_points
    from ccs_kornia.modules.detection.markers.charuco import CharucoDetector
    from ccs_kornia.modules.detection.screening import BoardScreen
    from ccs_kornia.pipeline.screening import screen_video
    from ccs_kornia.pipeline.sources import VideoSource
    from ccs_kornia.pipeline.video_input import camera_frames

    video = folder / "video"
    board = CharucoBoard(4, 5, 0.054, 0.0405, "DICT_4X4_1000")
    inner = (3, 4)
    obj = grid_object_points(board, inner, SQUARE, dtype=torch.float64).numpy()
    reference = _reference(folder)
    cams = list(cfg.video_real_cameras)
    pipeline = _pipeline(CharucoDetector(board), cfg.video_jobs)
    screened, refs, detected, speeds = {}, {}, {}, {}
    for c in range(4):
        if c not in cams and not cfg.video_real_rig:
            continue
        t = time.perf_counter()
        screened[c] = screen_video(str(video / f"cam_{c}.mp4"), BoardScreen(inner, board), workers=cfg.video_jobs)
        screen_s = time.perf_counter() - t
        frames = camera_frames([screened[c]], len(screened[c].frames))  # every frame, with its speed
        refs[c] = frames.refs[0]
        speeds[c] = {"screening_fps": len(screened[c].frames) / max(screen_s, 1e-9)}
        detected[c] = _detect(pipeline, [refs[c]], inner)
    out: dict = {"cameras": [], "rig": None}
    for c in cams:
        n = len(refs[c])
        det = detected[c]
        found = [k for k in range(n) if bool(det.detections.found[0, k])]
        size = tuple(int(x) for x in det.image_size[0])
        halves = _folds(n)
        folds = {m: [] for m in METHODS}
        for h in range(2):
            pool = [k for k in halves[h] if k in found]
            other = [k for k in halves[1 - h] if k in found]
            source = VideoSource([[refs[c][k] for k in pool]])
            choices = _choices(pipeline, det, inner, pool, pool, source, obj, size)
            source.close()
            held = _corners(det, 0, other)
            for m, (views, result) in choices.items():
                cam = _camera(result)
                folds[m].append({"frames": len(views),
                                 "heldout_rms": None if cam is None else rms(heldout_errors(cam, obj, held))})
        source = VideoSource([[refs[c][k] for k in found]])
        whole = _choices(pipeline, det, inner, found, found, source, obj, size)
        source.close()
        ref = reference[c]
        methods = {}
        for m in METHODS:
            values = [f["heldout_rms"] for f in folds[m] if f["heldout_rms"] is not None]
            cam = _camera(whole[m][1])
            methods[m] = {"frames": [f["frames"] for f in folds[m]], "heldout_rms": values,
                          "heldout_rms_mean": float(np.mean(values)) if len(values) == 2 else None,
                          "whole_frames": len(whole[m][0]),
                          "vs_reference": None if cam is None else _truth_figures(cam, ref, size)}
        out["cameras"].append({"camera": c, "frames": n, "found": len(found), **speeds[c], "methods": methods})
        log(f"[video] caliscope cam_{c}: " + ", ".join(f"{m} {methods[m]['heldout_rms_mean']}" for m in METHODS))
    if cfg.video_real_rig:
        out["rig"] = _real_rig(folder, pipeline, screened, refs, detected, obj, inner, log)
    return out


def _real_rig(folder: Path, pipeline, screened, refs, detected, obj, inner, log) -> dict:
    """The rig of the four cameras by instants of ``timestamps.csv``: per fold, each choice of instants."""
    from ccs_kornia.io.timestamps import read_timestamps
    from ccs_kornia.modules.rig import RigSolver
    from ccs_kornia.pipeline.frame_matching import FrameTable
    from ccs_kornia.pipeline.frame_selection import camera_views, choose_frames
    from ccs_kornia.pipeline.rig_pipeline import rig_observations
    from ccs_kornia.pipeline.video_input import pair_videos

    video = folder / "video"
    table = pair_videos([screened[c] for c in range(4)], table=read_timestamps(str(video / "timestamps.csv")))
    # positions in the screened frames = positions in refs (every frame was a candidate)
    F = table.num_frames
    halves = _folds(F)
    sizes = [tuple(int(x) for x in detected[c].image_size[0]) for c in range(4)]
    objt = torch.tensor(obj)

    def cameras_on(instants: list[int]):
        out = []
        for c in range(4):
            views = sorted({table.index[c][f] for f in instants if table.index[c][f] is not None})
            res = _solve(pipeline, detected[c], inner, 0, views)
            out.append((views, res))
        return out

    def rig_on(instants: list[int]):
        cams = cameras_on(instants)
        if any(r is None or r.calibration is None or not bool(r.calibration.success) for _, r in cams):
            return None
        idx = [[None if table.index[c][f] is None or table.index[c][f] not in cams[c][0]
                else cams[c][0].index(table.index[c][f]) for f in instants] for c in range(4)]
        sub = FrameTable([table.labels[f] for f in instants], idx, table.by)
        results = [r for _, r in cams]
        corners, valid, weights = rig_observations(results, sub)
        initial = [r.calibration.camera.to(dtype=torch.float64) for r in results]
        try:
            rig = RigSolver(models=[c.model for c in initial])(corners, valid, objt, sizes, initial=initial,
                                                                weights=weights)
        except ValueError:
            return None
        return rig if bool(rig.success) else None

    def selected(instants: list[int]) -> list[int]:
        cams = cameras_on(instants)
        views = []
        for c, (vs, r) in enumerate(cams):
            speeds = [refs[c][v].speed for v in vs]
            views.append(None if r is None else camera_views(r, objt, pipeline.settings.weigh_corners, speeds))
        idx = [[None if table.index[c][f] is None or table.index[c][f] not in cams[c][0]
                else cams[c][0].index(table.index[c][f]) for f in instants] for c in range(4)]
        times = None if table.times is None else [[row[f] for f in instants] for row in table.times]
        spread = FrameTable([table.labels[f] for f in instants], idx, table.by, times).spread()
        choice = choose_frames(views, idx, _selection(), spread, [f"frame {table.labels[f]}" for f in instants])
        return [instants[k] for k, keep in enumerate(choice.kept) if keep]

    def instant_corners(instants: list[int]):
        out = []
        for f in instants:
            row = []
            for c in range(4):
                k = table.index[c][f]
                row.append(None if k is None or not bool(detected[c].detections.found[0, k]) else
                           detected[c].detections.corners[0, k].double().numpy())
            out.append(row)
        return out

    results = {m: [] for m in METHODS}
    for h in range(2):
        pool = [f for f in halves[h] if any(x is not None for x in instant_corners([f])[0])]
        held = instant_corners([f for f in halves[1 - h]])
        kept = selected(pool)
        count = max(1, len(kept))
        corners = [[row[c] for row in instant_corners(pool)] for c in range(4)]
        coverage = [pool[k] for k in coverage_greedy(corners, obj, sizes, count)]
        for m, instants in (("selected", kept), ("all", pool), ("uniform", uniform_frames(pool, count)),
                            ("coverage", coverage)):
            rig = rig_on(instants)
            entry = {"instants": len(instants), "transfer_rms": None}
            if rig is not None:
                entry["transfer_rms"] = rms(transfer_errors(rig.cameras, [r.double().numpy() for r in rig.R],
                                                            [t.double().numpy() for t in rig.T], obj, held))
                entry["rig_rms"] = float(rig.rms)
            results[m].append(entry)
    log("[video] caliscope rig: " + ", ".join(f"{m} {[e['transfer_rms'] for e in v]}" for m, v in results.items()))
    return {"instants": F, "methods": results}


# ----------------------------------------------------------------------------------------------
# the section
# ----------------------------------------------------------------------------------------------


def run_video(cfg, log=print) -> dict:
    """The ``video`` section's figures (see the module docstring)."""
    folder = Path(tempfile.mkdtemp(prefix="ccs_bench_video_"))
    out: dict = {"rendered": [], "real": None, "skipped": {}, "model": str(MODEL), "max_frames": MAX_FRAMES,
                 "seconds_per_recording": cfg.video_seconds, "jobs": cfg.video_jobs,
                 "load_average": os.getloadavg()[0] if hasattr(os, "getloadavg") else None}
    try:
        for k in range(cfg.video_recordings):
            out["rendered"].append(_rendered(cfg, SEED + 10 * k, folder, log))
        real = _real_dir(cfg) / REAL
        if not (real / "video").is_dir():
            out["skipped"][REAL] = f"{real / 'video'} not found"
        elif cfg.video_real_cameras or cfg.video_real_rig:
            out["real"] = _real(cfg, real, log)
    finally:
        shutil.rmtree(folder, ignore_errors=True)
    return out


def _f(x, digits: int = 3) -> str:
    return "n/a" if x is None or (isinstance(x, float) and not math.isfinite(x)) else f"{x:.{digits}f}"


def video_md(sec: dict) -> list[str]:
    """The section's markdown."""
    lines = [(f"Frame choices solved with one model (`{sec['model']}`); the command's selection keeps at most "
             f"{sec['max_frames']} frames. Load average at the start of the section: {_f(sec.get('load_average'), 1)} "
             "(timings on a loaded machine are upper bounds)."), ""]
    for r in sec.get("rendered", []):
        lines += [(f"**Rendered recording, seed {r['seed']}** ({r['size'][0]}x{r['size'][1]}, {r['frames']} frames at "
                  f"30 fps, board seen by the screen in {r['board_seen']}; the full detector on every one of those at "
                  f"{_f(r['detect_fps'], 1)} frames/s; screening {_f(r['screening_fps'], 0)} frames/s, "
                  f"{sec['jobs']} processes; held-out frames: {r['heldout_frames']['still']} still, "
                  f"{r['heldout_frames']['moving']} moving):"), ""]
        lines += [("| frames | count | E_FL px | E_PP px | projection vs truth, RMS px | held-out RMS px "
                   "| held-out (still) "
                  "RMS px |"), "|---|---|---|---|---|---|---|"]
        for m, e in r["methods"].items():
            lines.append(f"| {m} | {e['frames']} | {_f(e.get('efl'))} | {_f(e.get('epp'))} | {_f(e.get('proj_rms'))} | "
                         f"{_f(e.get('heldout_rms'), 4)} | {_f(e.get('heldout_still_rms'), 4)} |")
        cmd = r.get("command")
        if cmd:
            if cmd.get("exit") == 0:
                lines += ["", (f"`calibrate VIDEO` end to end ({cmd['model']}, {cmd['kept']} of {cmd['candidates']} "
                          f"candidate frames kept): {_f(cmd['wall_s'], 1)} s wall, "
                          f"peak memory {_f(cmd['peak_mb'], 0)} MB "
                          f"(PSS of its processes), screening {_f(cmd['screening_fps'], 0)} frames/s; E_FL "
                          f"{_f(cmd['efl'])} px, E_PP {_f(cmd['epp'])} px, "
                          f"projection vs truth {_f(cmd['proj_rms'])} px, "
                          f"held-out (still) {_f(cmd.get('heldout_still_rms'), 4)} px.")]
            else:
                lines += ["", f"`calibrate VIDEO` failed (exit {cmd.get('exit')})."]
        lines.append("")
    real = sec.get("real")
    if real:
        lines += [("**The shared real recording** (caliscope, four webcams, 48 frames each at 6 fps): "
                   "held-out RMS px of "
                  "each fold (a choice made on alternate blocks of 8 frames, judged on the other blocks' frames; n/a: "
                  "a fold without frames), frames chosen per fold:"), "",
                  "| camera | board in | " + " | ".join(METHODS) + " |", "|---|---|" + "---|" * len(METHODS)]
        for cam in real["cameras"]:
            cells = []
            for m in METHODS:
                e = cam["methods"][m]
                ho = " / ".join(_f(v, 3) for v in e["heldout_rms"]) or "n/a"
                cells.append(f"{ho} ({' + '.join(str(n) for n in e['frames'])})")
            lines.append(f"| cam_{cam['camera']} | {cam['found']} of {cam['frames']} | " + " | ".join(cells) + " |")
        lines += ["", ("On the whole recording, against caliscope's published calibration (E_FL / E_PP / projection "
                  "over the whole image, RMS, px; that calibration is no ground truth: the boards cover 3-7 % of "
                  "these images, so the projection compares two extrapolations towards the image's edges):"), "",
                  "| camera | " + " | ".join(METHODS) + " |", "|---|" + "---|" * len(METHODS)]
        for cam in real["cameras"]:
            cells = []
            for m in METHODS:
                ref = cam["methods"][m]["vs_reference"]
                cells.append("failed" if ref is None else f"{_f(ref['efl'], 1)} / {_f(ref['epp'], 1)} / "
                                                          f"{_f(ref.get('proj_rms'), 1)} "
                                                          f"({cam['methods'][m]['whole_frames']})")
            lines.append(f"| cam_{cam['camera']} | " + " | ".join(cells) + " |")
        rig = real.get("rig")
        if rig:
            lines += ["", ("Rig of the four cameras (`timestamps.csv`, frames chosen as instants), "
                           "held-out transfer RMS "
                      "px of each fold (the board posed in one camera, projected into the others, on the other "
                      "blocks' instants):"), "", "| instants | fold 1 | fold 2 |", "|---|---|---|"]
            for m, folds in rig["methods"].items():
                lines.append(f"| {m} | " + " | ".join(f"{_f(e['transfer_rms'])} ({e['instants']} instants)"
                                                     for e in folds) + " |")
        lines.append("")
    for item, why in (sec.get("skipped") or {}).items():
        lines.append(f"- skipped {item}: {why}")
    return lines
