"""The JSON record of ``calibrate-rig`` (``rig.json``): every camera as ``calibrate`` writes one, the cameras' poses
(``x_i = R_i x_0 + T_i``), the error per camera and frame, and every pair's relative pose with its figures.

Made from a :class:`~ccs_kornia.pipeline.rig_pipeline.RigPipelineResult`; read back by :func:`rig_cameras` and
:func:`record_extrinsics` (the ``rectify`` command and the export formats).
"""

from __future__ import annotations

import math
from typing import Any

import torch

from ccs_kornia.geometry.camera import Camera
from ccs_kornia.outputs.calibration_file import camera_from_record, camera_record_fields
from ccs_kornia.outputs.records import camera_record, selection_reasons

__all__ = ["CONVENTION", "INCONSISTENT_WEIGHT", "frame_lines", "frame_records", "rig_record", "pair_record",
           "record_extrinsics", "rotation_angle_deg", "rig_cameras", "rectify_maps"]

#: how the extrinsics map points: camera 0's frame to camera ``i``'s (OpenCV's ``stereoCalibrate`` convention)
CONVENTION = "x_i = R x_0 + T"


#: frames that weighed less than this in the final fit are named as inconsistent
INCONSISTENT_WEIGHT = 0.5


def _num(x: Any) -> float | None:
    x = float(x)
    return x if math.isfinite(x) else None


def _matrix(t: torch.Tensor) -> list:
    return [[_num(v) for v in row] for row in t.double().cpu().tolist()]


def rotation_angle_deg(R: Any) -> float:
    """The angle of a rotation matrix in degrees.

    Example:
        >>> round(rotation_angle_deg([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]), 6)
        90.0
    """
    R = torch.as_tensor(R, dtype=torch.float64)
    cos = ((torch.diagonal(R).sum() - 1.0) / 2.0).clamp(-1.0, 1.0)
    return math.degrees(math.acos(float(cos)))


def record_extrinsics(extrinsics: list[dict[str, Any]]) -> tuple[torch.Tensor, torch.Tensor]:
    """The record's per-camera extrinsics as tensors ``R`` :math:`(C, 3, 3)`, ``T`` :math:`(C, 3)` (float64), e.g. for
    :func:`~ccs_kornia.geometry.poses.pair_pose`.

    Example:
        >>> from ccs_kornia.geometry.poses import pair_pose
        >>> ext = [{"R": torch.eye(3).tolist(), "T": [0.0, 0.0, 0.0]}, {"R": torch.eye(3).tolist(), "T": [-0.1, 0, 0]}]
        >>> pair_pose(*record_extrinsics(ext), 1, 0)[1].tolist()
        [0.1, 0.0, 0.0]
    """
    R = torch.tensor([e["R"] for e in extrinsics], dtype=torch.float64)
    return R, torch.tensor([e["T"] for e in extrinsics], dtype=torch.float64)


def pair_record(rig: Any, i: int, j: int, labels: list[str] | None = None) -> dict[str, Any]:
    """One pair of a solved ``RigResult``: its relative pose, essential and fundamental matrices, baseline with its
    1-sigma (known for pairs with camera 0, whose poses the fit estimates directly), epipolar errors, the frames that
    carried it (both cameras use them and they weigh at least :data:`INCONSISTENT_WEIGHT`; ``labels``: the frames'
    names, else their positions)."""
    pair = rig.pair(i, j)
    baseline = float(torch.linalg.vector_norm(pair.T.double()))
    with_first = i == 0 or j == 0
    other = j if i == 0 else i
    return {
        "cameras": [i, j],
        "names": [rig.names[i], rig.names[j]],
        "R": _matrix(pair.R), "T": [_num(v) for v in pair.T.double().tolist()],
        "E": _matrix(pair.E), "F": _matrix(pair.F),
        "baseline": baseline,
        "baseline_std": _num(rig.baseline_std[other]) if with_first else None,
        "rotation_deg": rotation_angle_deg(pair.R),
        "rotation_std_deg": _num(rig.rotation_std_deg[other]) if with_first else None,
        "epipolar_rms": _num(rig.epipolar_rms[i, j]),
        "heldout_epipolar_rms": _num(rig.heldout_epipolar_rms[i, j]),
        # frames both cameras use, each counted with its weight in the fit: how much of the session links the pair
        "shared_frames": None if getattr(rig, "shared_frames", None) is None else _num(rig.shared_frames[i, j]),
        "frames_carried": _carried(rig, i, j, labels),
    }


def _carried(rig: Any, i: int, j: int, labels: list[str] | None) -> list[str] | None:
    if getattr(rig, "frame_weight", None) is None:
        return None
    both = rig.used[i] & rig.used[j] & (rig.frame_weight.nan_to_num(0.0) >= INCONSISTENT_WEIGHT)
    frames = torch.nonzero(both).flatten().tolist()
    return [labels[f] if labels is not None else str(f) for f in frames]


def _per_param(values: torch.Tensor) -> dict[str, Any]:
    v = [_num(x) for x in values.double().tolist()]
    return {"fx": v[0], "fy": v[1], "cx": v[2], "cy": v[3], "distortion": v[4:]}


def frame_records(rig: Any, labels: list[str]) -> list[dict[str, Any]]:
    """Per frame of a solved ``RigResult``: its label, the cameras' disagreement (px: how much worse one board pose
    explains them than each camera's own pose; ``None`` for frames of one camera), its weight in the fit, the board's
    motion around it (px per frame period, ``None`` when unknown) and the likely cause of a disagreement."""
    from ccs_kornia.modules.rig.frame_consistency import disagreement_cause

    if getattr(rig, "frame_disagreement", None) is None:
        return []
    out = []
    for f, label in enumerate(labels):
        d, w, m = (float(rig.frame_disagreement[f]), float(rig.frame_weight[f]), float(rig.frame_motion[f]))
        out.append({"frame": label, "disagreement_px": _num(d), "weight": _num(w), "motion_px": _num(m),
                    "cause": disagreement_cause(d, m) if w < INCONSISTENT_WEIGHT else ""})
    return out


def frame_lines(frames: list[dict[str, Any]], most: int = 10) -> list[str]:
    """The inconsistent frames of :func:`frame_records` (weight below :data:`INCONSISTENT_WEIGHT`), the worst first,
    as the command prints them: ``frame 0412: cameras disagree by 6.3 px, board moving (weight 0.02)``.

    Example:
        >>> frame_lines([{"frame": "0412", "disagreement_px": 6.3, "weight": 0.02, "cause": "board moving"},
        ...              {"frame": "0413", "disagreement_px": 0.1, "weight": 1.0, "cause": ""}])
        ['frame 0412: cameras disagree by 6.3 px, board moving (weight 0.02)']
    """
    bad = [f for f in frames if f.get("weight") is not None and f["weight"] < INCONSISTENT_WEIGHT
           and f.get("disagreement_px") is not None]
    bad.sort(key=lambda f: -f["disagreement_px"])
    lines = [f"frame {f['frame']}: cameras disagree by {f['disagreement_px']:.1f} px"
             f"{', ' + f['cause'] if f.get('cause') else ''} (weight {f['weight']:.2g})" for f in bad[:most]]
    if len(bad) > most:
        lines.append(f"... and {len(bad) - most} more frames weighed below {INCONSISTENT_WEIGHT:g} (rig.json: "
                     "frame_consistency)")
    return lines


def rig_record(out: Any, paths: list[list[str]], *, board: tuple[int, int], square: float, detector: str,
               models: list[Any]) -> dict[str, Any]:
    """The ``rig.json`` of a solved rig.

    Args:
        out: a :class:`~ccs_kornia.pipeline.rig_pipeline.RigPipelineResult` whose ``rig`` succeeded.
        paths: per camera its image files in the camera's own order.
        board, square, detector: recorded as given; models: the model asked for per camera (a model choice
            included).

    Returns:
        JSON-ready dict: ``convention``, ``cameras`` (each as ``calibrate`` writes one, with ``name``, the joint fit's
        ``K``, ``distortion``, ``rms`` and ``std``, and the camera's own calibration under ``single_camera``),
        ``extrinsics``, ``rms``, ``rms_matrix`` (camera x frame, ``None`` where unused), ``frames``, ``pairs``,
        ``board_poses`` (board -> camera 0 per frame), ``verdict``, ``frame_consistency`` (per frame its
        disagreement, weight, motion and cause: :func:`frame_records`), ``session_advice`` (what to record next);
        per camera ``intrinsics_moved_sigma`` and ``single_camera.std``; per pair ``shared_frames``.
    """
    rig = out.rig
    cameras = []
    for c, (result, files) in enumerate(zip(out.cameras, paths)):
        record = camera_record(result, files, board=board, square=square, detector=detector, model=models[c])
        cam = rig.cameras[c]
        std = [float(v) for v in rig.intrinsics_std[c].double().tolist()]
        single = {k: record[k] for k in ("K", "distortion", "rms")}
        fields = camera_record_fields(cam)
        record.update({
            "K": fields["K"],
            "distortion": fields["distortion"],
            "rms": _num(rig.camera_rms[c]),
            "rms_kind": "RMS reprojection error over the camera's corners in the rig's joint fit, px",
            "std": {"fx": std[0], "fy": std[1], "cx": std[2], "cy": std[3], "distortion": std[4:]},
            "image_size": [int(v) for v in rig.image_sizes[c]],
            "fixed": bool(out.fixed[c]) if out.fixed else False,
            "single_camera": single,
        })
        if getattr(rig, "single_std", None) is not None:
            single["std"] = _per_param(rig.single_std[c])
            # how far the joint fit moved each intrinsic from the camera's own calibration, in its own 1-sigma
            record["intrinsics_moved_sigma"] = _per_param(rig.intrinsics_moved_sigma[c])
        cameras.append({"name": out.names[c], **record})
    choice = getattr(out, "frame_choice", None)
    if choice is not None:  # the frame selection's reasons for the views of the frames it left out
        for c, cam in enumerate(cameras):
            selection_reasons(cam["views"], choice.view_reasons[c])
    labels = list(out.frames.labels)
    pairs = [pair_record(rig, i, j, labels) for i in range(len(cameras)) for j in range(i + 1, len(cameras))]
    selection = {} if choice is None else {"selection": choice.record(list(out.candidates.labels))}
    return {
        "success": True,
        "convention": CONVENTION,
        "units": "translations in the board's unit (--square, or an AprilGrid's tagSize)",
        "board": list(board), "square": square, "detector": detector,
        "cameras": cameras,
        "extrinsics": [{"name": out.names[c], "R": _matrix(rig.R[c]), "T": [_num(v) for v in rig.T[c].double().tolist()]}
                       for c in range(len(cameras))],
        "rms": _num(rig.rms),
        "rms_matrix": [[_num(v) for v in row] for row in rig.rms_matrix.double().tolist()],
        "frames": out.frames.files(paths),
        "frame_labels": list(out.frames.labels),
        "frames_matched_by": out.frames.by,
        "pairs": pairs,
        "board_poses": [{"rvec": [_num(v) for v in r], "tvec": [_num(v) for v in t]}
                        for r, t in zip(rig.board_rvec.double().tolist(), rig.board_tvec.double().tolist())],
        "verdict": rig.verdict,
        "verdict_reasons": list(getattr(rig, "reasons", []) or []),
        "frame_consistency": {"kernel_scale_px": _num(getattr(rig, "frame_scale", float("nan"))),
                              "frames": frame_records(rig, list(out.frames.labels))},
        "session_advice": list(getattr(rig, "advice", []) or []),
        "fit": {"converged": bool(getattr(rig, "converged", True)), "status": rig.lm_status.message,
                "iterations": int(getattr(rig, "iterations", 0)),
                "frames_used": [[bool(u) for u in row] for row in rig.used.tolist()],
                # per camera and frame: 0 where the corners kept the detector's numbering, k > 0 where the solver
                # renumbered a symmetric board by its k-th symmetry (1: turned 180 degrees) to agree with the frame
                "corner_order": None if getattr(rig, "corner_order", None) is None else rig.corner_order.tolist()},
        **selection,
        **({"board_flatness": out.board_flatness} if getattr(out, "board_flatness", None) is not None else {}),
    }


def rig_cameras(data: dict[str, Any]) -> Camera:
    """The cameras of a ``rig.json`` (``cameras[c]``: camera c, float64, with its image size)."""
    return Camera.cat([camera_from_record(cam) for cam in data["cameras"]])


def _projection_maps(cam, R, P, size) -> tuple[Any, Any]:
    """``cv2.remap``'s maps (float32 x and y) of the rectified view ``R``, ``P`` (3x3, 3x4) through ``cam``'s own
    projection: each pixel's ray ``R^T P[:, :3]^-1 (u, v, 1)`` projected by the camera (as
    ``cv2.initUndistortRectifyMap`` does for OpenCV's models)."""
    import numpy as np

    w, h = size
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float64)
    pix = np.stack([xs, ys, np.ones_like(xs)], -1).reshape(-1, 3)
    rays = pix @ (R.T @ np.linalg.inv(P[:, :3])).T
    uv = cam.project(torch.from_numpy(rays)[None].to(cam.dtype))[0].numpy().reshape(h, w, 2)
    return uv[..., 0].astype(np.float32), uv[..., 1].astype(np.float32)


def rectify_maps(data: dict[str, Any], rect: dict[str, Any], i: int = 0, j: int = 1) -> list[tuple[Any, Any]]:
    """``cv2.remap`` maps of cameras ``i`` and ``j`` of a ``rig.json`` into the rectified pair ``rect`` (``R1``,
    ``P1``, ``R2``, ``P2``, ``image_size`` of a stereo rectification): ``cv2.initUndistortRectifyMap``,
    ``cv2.fisheye.initUndistortRectifyMap`` for a fisheye camera, the camera's own projection for one OpenCV has no
    model of (a splined one)."""
    import cv2
    import numpy as np

    size = tuple(int(v) for v in rect["image_size"])
    maps = []
    for c, R, P in ((i, rect["R1"], rect["P1"]), (j, rect["R2"], rect["P2"])):
        cam = camera_from_record(data["cameras"][c])
        K = cam.K[0].numpy()
        coeffs = cam.model.opencv_coeffs(cam.coeffs(0).numpy()) if cam.model.opencv_family in ("opencv", "fisheye") \
            else None
        R, P = np.asarray(R, dtype=np.float64), np.asarray(P, dtype=np.float64)
        if cam.model.opencv_family not in ("opencv", "fisheye"):  # no OpenCV model (splined): its own projection
            maps.append(_projection_maps(cam, R, P, size))
        elif cam.model.is_fisheye:  # OpenCV's two APIs: cv2.fisheye for Kannala-Brandt lenses
            maps.append(cv2.fisheye.initUndistortRectifyMap(K, coeffs.reshape(4, 1), R, P, size, cv2.CV_32FC1))
        else:
            maps.append(cv2.initUndistortRectifyMap(K, coeffs, R, P, size, cv2.CV_32FC1))
    return maps
