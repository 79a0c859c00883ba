r"""``handeye.json`` (DESIGN section 4): the record of one hand-eye calibration.

``X`` is the camera's pose in its robot frame as a 4x4 matrix (eye-in-hand: flange -> camera, ``x_flange = X
x_camera``; eye-to-hand: base -> camera, ``x_base = X x_camera``) and as ``X_tq`` (translation, unit quaternion
``x, y, z, w``); ``board_in_robot`` the board's pose in the robot's other frame; their 1-sigma (rotation about each
axis of the robot frame, degrees; translation, millimetres); the camera used (``calibrate``'s JSON); the held-out
figures; per pose, its robot pose, the fit's residuals and the held-out prediction; the verdict.
"""

from __future__ import annotations

import math
from typing import Any

import torch

from ccs_kornia.modules.hand_eye.result import HandEyeResult
from ccs_kornia.outputs.ros_tf import pose_tq

__all__ = ["hand_eye_record"]


def _num(x: Any) -> float | None:
    x = float(x)
    return x if math.isfinite(x) else None


def _std(rot_deg: torch.Tensor, trans: torch.Tensor, source: str) -> dict[str, Any]:
    return {"rotation_deg": [_num(v) for v in rot_deg], "translation_mm": [_num(1000 * v) for v in trans],
            "rotation_deg_norm": _num(rot_deg.norm()), "translation_mm_norm": _num(1000 * trans.norm()),
            "source": source}


def hand_eye_record(result: HandEyeResult, paths: list[str], b: int = 0, *, camera: dict[str, Any],
                    robot_poses: torch.Tensor, corners: torch.Tensor, skipped: dict[str, str] | None = None,
                    board: dict[str, Any] | None = None) -> dict[str, Any]:
    """The JSON of problem ``b`` of a result (module doc).

    Args:
        result: the solver's result.
        paths: the views' image paths, in the result's order.
        b: the problem.
        camera: the camera's record (``calibrate``'s JSON, or what ``--calibration`` gave).
        robot_poses: :math:`(V, 4, 4)` the poses as read (metres; NaN where an image had none).
        corners: :math:`(V, N, 2)` the observed corners (NaN where not seen; the result's, in the board's numbering,
            where it has them).
        skipped: images left out before the solve and why (no pose, no board, unreadable).
        board: the target's description.
    """
    setup = result.setup
    ok = bool(result.success[b])
    used = result.used[b]
    views = []
    for v, path in enumerate(paths):
        T = robot_poses[v]
        view: dict[str, Any] = {"path": path, "used": bool(used[v]),
                                "robot_pose": T.tolist() if bool(T.isfinite().all()) else None}
        if bool(used[v]):
            seen = corners[v] if result.corners is None else result.corners[b, v]
            view["corners"] = [[_num(x), _num(y)] for x, y in seen.tolist()]
            if result.board_order is not None and int(result.board_order[b, v]):
                view["corner_order"] = int(result.board_order[b, v])
            view["rms_px"] = _num(result.view_rms[b, v])
            view["residuals_px"] = result.residuals[b, v].tolist()
            view["heldout_px"] = _num(result.heldout_rms_px[b, v])
            view["heldout_mm"] = _num(1000 * result.heldout_rms_distance[b, v])
            pred = result.heldout_predicted[b, v]
            view["heldout_predicted"] = pred.tolist() if bool(pred.isfinite().all()) else None
            board_pose = result.board_poses[b, v]
            view["board_in_camera"] = board_pose.tolist() if bool(board_pose.isfinite().all()) else None
        elif skipped and path in skipped:
            view["reason"] = skipped[path]
        else:
            view["reason"] = "too few corners for the board's pose"
        views.append(view)
    noise = None
    chosen = result.noise_choice[b] if result.noise_choice else ""
    if chosen:
        rn = result.robot_noise[b]
        noise = {"rotation_deg": _num(math.degrees(float(rn[0]))), "translation_mm": _num(1000 * float(rn[1])),
                 "corner_px": None, "exact": not bool(rn.any()), "note": chosen}
    elif result.robot_noise is not None:
        rn = result.robot_noise[b]
        noise = {"rotation_deg": _num(math.degrees(float(rn[0]))), "translation_mm": _num(1000 * float(rn[1])),
                 "corner_px": _num(result.pixel_sigma[b]) if result.pixel_sigma is not None else None,
                 "note": "the robot poses' and the corners' 1-sigma the fit estimated from the data (its "
                         "robot-pose noise term)"}
    data: dict[str, Any] = {
        "success": ok,
        "setup": setup.label,
        "convention": {"robot_poses": "the flange in the base frame: x_base = T x_flange",
                       "X": ("flange -> camera: x_flange = X x_camera" if setup.camera_frame == "flange"
                             else "base -> camera: x_base = X x_camera"),
                       "board_in_robot": f"the board in the {setup.board_frame} frame: x_{setup.board_frame} = "
                                         "board_in_robot x_board",
                       "camera_frame": "the optical frame: z along the optical axis, x right, y down",
                       "units": "metres; q = (x, y, z, w)"},
        "X": result.X[b].tolist(),
        "X_tq": pose_tq(result.X[b]),
        "X_std": _std(result.x_rotation_std_deg[b], result.x_translation_std[b], result.std_source[b]),
        "board_in_robot": result.Z[b].tolist(),
        "board_in_robot_tq": pose_tq(result.Z[b]),
        "board_in_robot_std": _std(result.z_rotation_std_deg[b], result.z_translation_std[b], result.std_source[b]),
        "board": board or {},
        "camera": camera,
        "rms_px": _num(result.rms[b]),
        "heldout": {"rms_px": _num(result.heldout_rms[b]), "rms_mm": _num(1000 * result.heldout_distance[b]),
                    "poses": int(result.heldout_rms_px[b].isfinite().sum()),
                    "kind": "leave-one-pose-out: each pose's board corners predicted from its robot pose alone by the "
                            "calibration of the other poses; px: RMS over the corners; mm: RMS distance of the "
                            "predicted corners to the lines of sight through the observed ones"},
        "robot_noise": noise,
        "start": {"method": result.start[b],
                  "closed_forms_rms_px": {n: _num(r) for n, r in zip(result.start_names, result.start_rms[b])}},
        "num_poses": {"images": len(paths), "used": int(used.sum())},
        "poses": views,
        "verdict": result.verdict[b],
        "verdict_reasons": result.verdict_reasons[b] if result.verdict_reasons else [],
        "warnings": [i for i in result.issues[b] if i.get("severity") == "warning"],
        "errors": [i for i in result.issues[b] if i.get("severity") == "error"],
    }
    if result.board_flatness is not None and result.board_flatness[b] is not None:
        data["board_flatness"] = result.board_flatness[b]  # the board's sag, and whether held-out poses kept it
    for issue in data["warnings"] + data["errors"]:
        issue["files"] = [paths[v] for v in issue.get("poses", []) if 0 <= v < len(paths)]
    if not ok:
        data["error"] = result.reasons[b]
    return data
