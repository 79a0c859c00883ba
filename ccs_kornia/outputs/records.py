"""The JSON records of ``detect``, ``calibrate`` and ``calibrate-many`` (DESIGN section 4), made from one camera
of a :class:`~ccs_kornia.pipeline.result.PipelineResult`: which views entered the calibration, why the others did
not, the camera, its uncertainty and what the distortion correction did.

Above :mod:`ccs_kornia.io` (files) and :mod:`ccs_kornia.pipeline`: ``io/`` stays free of the solver.
"""

from __future__ import annotations

import math
from typing import Any

from ccs_kornia.geometry.camera import Camera
from ccs_kornia.modules.calibration.result import VIEW_REASONS
from ccs_kornia.modules.calibration.splined import nearest_opencv
from ccs_kornia.modules.detection.markers.corner_merge import corners_by_path
from ccs_kornia.outputs.calibration_file import camera_record_fields
from ccs_kornia.pipeline.result import PipelineResult
from ccs_kornia.pipeline.sources import SIZE_TOLERANCE_PX

__all__ = ["camera_record", "correction_record", "opencv_equivalent", "selection_reasons", "view_records"]


def _num(x: float) -> float | None:
    x = float(x)
    return x if math.isfinite(x) else None


def view_records(result: PipelineResult, paths: list[str]) -> list[dict[str, Any]]:
    """One dict per view of one camera: ``path``, ``found``, ``corners`` (when found; ``[None, None]`` at the corners of a
    partial board that the image does not show), ``hidden_corners`` (their count, where any), ``method`` (how it was
    found) and, for a marker board, ``corners_by_path`` (the corners its marker path and its lattice path each named,
    :func:`~ccs_kornia.modules.detection.markers.corner_merge.corners_by_path`), ``image_size``, and
    ``reason`` where the view cannot be used (unreadable, board not found, another image size).

    Args:
        result: one camera of a pipeline run (``result.select(c)``).
        paths: the view names in order (file paths).
    """
    det = result.detections
    main = tuple(int(x) for x in result.image_size)
    out = []
    for v, path in enumerate(paths):
        found = bool(det.found[v])
        view: dict[str, Any] = {"path": path, "used": False, "rms": None, "found": found}
        size = tuple(int(x) for x in result.view_sizes[v].tolist()) if result.view_sizes is not None else main
        if bool(result.present[v]):
            view["image_size"] = list(size)
        if found:
            view["corners"] = det.corners[v].double().cpu().tolist()  # null at the hidden corners of a partial board
            hidden = int((~det.corners[v].isfinite().all(-1)).sum())
            if hidden:
                view["hidden_corners"] = hidden
            how = det.reasons[v] if det.reasons else ""
            if how:
                view["method"] = how
            by_path = corners_by_path(how)
            if by_path is not None:  # a marker board: the corners each of its paths named, before the merge
                view["corners_by_path"] = by_path
        if not bool(result.present[v]):
            view["reason"] = (det.reasons[v] if det.reasons else "") or "unreadable"
        elif not found:
            view["reason"] = (det.reasons[v] if det.reasons else "") or "board not found"
        elif size != main:
            if max(abs(size[0] - main[0]), abs(size[1] - main[1])) > SIZE_TOLERANCE_PX:
                view["reason"] = f"image size {size[0]}x{size[1]} differs from the camera's {main[0]}x{main[1]}"
            else:
                view["note"] = (f"image size {size[0]}x{size[1]} used as {main[0]}x{main[1]} (within "
                                f"{SIZE_TOLERANCE_PX} px: same pixel grid from the top-left corner)")
        out.append(view)
    return out


def selection_reasons(views: list[dict[str, Any]], reasons: list[str]) -> None:
    """The views the frame selection left out (``reasons[v]`` not empty), in their records: not used, and why
    (``adds nothing``, ``near copy of frame 412``, ...); the first solve's pose and error of them dropped."""
    for view, why in zip(views, reasons):
        if not why:
            continue
        view.update(used=False, rms=None, reason=f"left out by the frame selection: {why}")
        for key in ("rvec", "tvec", "rms_if_used"):
            view.pop(key, None)


def correction_record(result: PipelineResult) -> dict[str, Any]:
    """What the distortion correction did for one camera (``{"enabled": False}`` when it is off)."""
    if result.correction is None:
        return {"enabled": False}
    det = result.detections
    on_corrected = sum(1 for r in (det.reasons or []) if r.startswith("corrected image"))
    before, after = (None, None) if result.straightness is None else (_num(result.straightness[0]),
                                                                      _num(result.straightness[1]))
    from ccs_kornia.modules.correction.pooling import correction_displacement

    size = (max(1, int(result.image_size[0])), max(1, int(result.image_size[1])))
    displacement = float(correction_displacement(result.correction[None].double(), size)[0])
    tried, applied = bool(result.correction_tried), bool(result.corrected)
    if applied:
        decision = "calibrated in the corrected frame (radial model about a free centre), kept: it fits clearly better"
    elif tried:
        decision = "corrected-frame calibration tried, not kept: it did not fit the corners clearly better"
    else:
        decision = "not tried: the lens is close enough to a pinhole for the usual calibration"
    return {
        "enabled": True,
        "tried": tried,
        "applied": applied,
        "views_detected_on_corrected_images": on_corrected,
        "network_displacement_px": displacement,
        "straightness_before_px": before,
        "straightness_after_px": after,
        "correction": [float(x) for x in result.correction.tolist()],
        "decision": decision,
        "note": "paper radial correction r_c = r_d (k0' + k1' r_d + ... + k4' r_d^4), radii from the image centre "
                "in units of max(W, H); straightness = median RMS distance of the detected corners from lines fitted "
                "to each board row and column, before and after the correction",
    }


def opencv_equivalent(camera: Camera) -> dict[str, Any]:
    """For a camera no OpenCV model holds (a splined one): the closest OpenCV camera
    (:func:`~ccs_kornia.modules.calibration.splined.nearest_opencv`, the rational model) as the JSON writes a camera, and
    how far it departs from the camera over the image (px: RMS, largest, and per cell of a 16 x 12 grid, rows top to
    bottom; null beyond 80 degrees). What ``--opencv-yaml`` and ``--ros-yaml`` write."""
    opencv, departure = nearest_opencv(camera)
    d = departure[departure.isfinite()]
    fields = camera_record_fields(opencv)
    return {"K": fields["K"], "distortion": fields["distortion"],
            "departure_rms_px": float(d.square().mean().sqrt()) if d.numel() else None,
            "departure_max_px": float(d.max()) if d.numel() else None,
            "departure_grid_px": [[_num(v) for v in row] for row in departure.tolist()]}


def camera_record(
    result: PipelineResult, paths: list[str], *, board: tuple[int, int], square: float, detector: str, model: Any
) -> dict[str, Any]:
    """The calibration JSON of one camera (DESIGN section 4) plus what helps users judge it.

    Args:
        result: one camera of a calibrated pipeline run (``result.select(c)``).
        paths: the view names in order.
        board, square, detector, model: recorded as given.

    Returns:
        JSON-ready dict: ``success``, ``error`` (failed cameras), ``image_size``, ``K``, ``distortion``, ``rms``,
        ``views``, ``std``, ``num_views``, ``skipped``, ``distortion_correction``, ``diagnostics``,
        ``model_selection`` (``model="auto"``).
    """
    views = view_records(result, paths)
    cal = result.calibration
    success = cal is not None and bool(cal.success)
    n_found = sum(1 for v in views if v["found"])
    usable = [v for v in views if v["found"] and "reason" not in v]
    data: dict[str, Any] = {
        "success": success,
        "image_size": [int(result.image_size[0]), int(result.image_size[1])],
        "K": None, "distortion": None, "rms": None,
        "rms_kind": "RMS reprojection error over all corners of the used views, px",
        "views": views,
        "board": list(board), "square": square, "detector": detector, "model": str(model),
        # the fit weights each corner by the precision measured on its image (plain least squares with --unweighted)
        "corner_weights": result.detections.sigma is not None,
    }
    if cal is not None:
        codes = cal.view_reason.cpu().tolist()
        cand = cal.candidate_rms.double().cpu().tolist() if getattr(cal, "candidate_rms", None) is not None else None
        rms = cal.view_rms.double().cpu().tolist()
        for v, view in enumerate(views):
            if "reason" in view or not view["found"]:
                continue
            view["used"] = bool(cal.used[v])
            view["rms"] = _num(rms[v]) if view["used"] else None
            view["rvec"], view["tvec"] = cal.rvec[v].double().tolist(), cal.tvec[v].double().tolist()
            if not view["used"]:
                code = int(codes[v])
                view["reason"] = VIEW_REASONS.get(code, "not used by the solver") if success or code else \
                    "in the failed calibration (no consistent camera)"
                if cand is not None and _num(cand[v]) is not None:
                    view["rms_if_used"] = float(cand[v])
    choice = getattr(result, "frame_choice", None)
    if choice is not None:
        selection_reasons(views, choice.view_reasons[0])
        data["selection"] = choice.record(paths)
    if success:
        std_i = cal.std_intrinsics.double().cpu().tolist()
        fields = camera_record_fields(cal.camera)
        data.update({
            "K": fields["K"],
            "distortion": fields["distortion"],
            "rms": float(cal.rms),
            "std": {"fx": std_i[0], "fy": std_i[1], "cx": std_i[2], "cy": std_i[3],
                    "distortion": cal.std_dist.double().cpu().tolist()},
        })
        if cal.camera.model.opencv_family == "splined":
            data["opencv_equivalent"] = opencv_equivalent(cal.camera)
    else:
        data["error"] = result.camera_reasons or "calibration failed"
    if cal is not None and hasattr(cal, "issues"):
        issues = cal.issues()[0] if cal.K.dim() == 2 else []
        for issue in issues:  # the views a check names, as the user's files
            issue["files"] = [paths[v] for v in issue.get("views", []) if 0 <= v < len(paths)]
        data["warnings"] = [i for i in issues if i.get("severity") == "warning"]
        data["errors"] = [i for i in issues if i.get("severity") == "error"]
    data["num_views"] = {"files": len(views), "found": n_found, "usable": len(usable),
                         "used": sum(1 for v in views if v["used"]),
                         "partial": sum(1 for v in views if v["used"] and v.get("hidden_corners"))}
    data["skipped"] = [{"path": v["path"], "reason": v["reason"]} for v in views if not v["used"] and "reason" in v]
    data["distortion_correction"] = correction_record(result)
    if result.diagnostics is not None:
        data["diagnostics"] = result.diagnostics
    if getattr(result, "model_selection", None) is not None:
        data["model_selection"] = result.model_selection  # --model auto: the choice, the runner-up, the figures
    structure = cal.residual_structure() if bool(cal.success) else None
    if structure is not None:  # the residuals' structure over the image and whether the model fits
        data["residual_structure"] = structure
    if getattr(result, "board_flatness", None) is not None:
        data["board_flatness"] = result.board_flatness  # the board's sag, and whether held-out views kept it
    return data
