"""The calibration record of ``calibrate`` and ``calibrate-many`` (DESIGN section 4): which views enter a
calibration and why the others do not, and the JSON of one camera's solver result.

Above :mod:`ccs_kornia.io` (files) and beside :mod:`ccs_kornia.pipeline`: it reads the solver's result and its
reason codes, so ``io.py`` stays free of the solver.
"""

from __future__ import annotations

from typing import Any

from ccs_kornia.modules.calibration.result import VIEW_REASONS

__all__ = ["plan_views", "calibration_record"]


def plan_views(
    files: list[str], records: dict[str, dict[str, Any]]
) -> tuple[list[dict[str, Any]], list[str], tuple[int, int] | None]:
    """Decide which detected views enter a calibration, and say why the others do not.

    The image size of the calibration is the most common size among images where the board was
    found (ties: first seen); found views of another size are excluded with a reason.

    Args:
        files: the input files, in order.
        records: per path ``{"found": bool, "corners": list | None, "image_size": [w, h] | None}``
            plus ``"error"`` (unreadable file) or ``"reason"`` (board not found), as detection wrote them.

    Returns:
        ``(views, usable, image_size)``: one view dict per file (``path``, ``used`` False, ``rms``
        None, ``found``, ``corners`` when found, ``reason`` when it cannot be used), the paths usable
        for the calibration, and the chosen ``(W, H)`` (None when the board was found nowhere).
    """
    found_sizes: dict[tuple[int, int], int] = {}
    for path in files:
        r = records[path]
        if r.get("found"):
            key = (int(r["image_size"][0]), int(r["image_size"][1]))
            found_sizes[key] = found_sizes.get(key, 0) + 1
    image_size = max(found_sizes, key=lambda k: found_sizes[k]) if found_sizes else None  # first seen wins ties
    views: list[dict[str, Any]] = []
    usable: list[str] = []
    for path in files:
        r = records[path]
        view: dict[str, Any] = {"path": path, "used": False, "rms": None, "found": bool(r.get("found"))}
        if r.get("found"):
            view["corners"] = r["corners"]
        if "error" in r:
            view["reason"] = f"unreadable: {r['error']}"
        elif not r.get("found"):
            view["reason"] = r.get("reason") or "board not found"
        elif (int(r["image_size"][0]), int(r["image_size"][1])) != image_size:
            assert image_size is not None
            view["reason"] = (
                f"image size {r['image_size'][0]}x{r['image_size'][1]} differs from the set's "
                f"{image_size[0]}x{image_size[1]}"
            )
        else:
            usable.append(path)
        views.append(view)
    return views, usable, image_size


def calibration_record(
    views: list[dict[str, Any]],
    usable: list[str],
    image_size: tuple[int, int],
    result: Any,
    *,
    board: tuple[int, int],
    square: float,
    detector: str,
    model: str,
    reasons: dict[int, str] | None = None,
) -> dict[str, Any]:
    """The calibration JSON of ``calibrate`` (DESIGN section 4) from one camera's solver result.

    Args:
        views: from :func:`plan_views` (updated in place with ``used``, ``rms``, poses, reasons).
        usable: the paths given to the solver, in the order of the result's views.
        image_size: ``(W, H)``.
        result: an unbatched :class:`~ccs_kornia.modules.calibration.result.CalibrationResult` (views in the
            order of ``usable``).
        board, square, detector, model: recorded as given.
        reasons: view reason codes to text (default: the solver's
            :data:`~ccs_kornia.modules.calibration.result.VIEW_REASONS`).

    Returns:
        The JSON-ready dict (``image_size``, ``K``, ``distortion``, ``rms``, ``views``, ``std``,
        ``num_views``, ``skipped``, ...).
    """
    if reasons is None:
        reasons = VIEW_REASONS
    K = result.K.detach().double().cpu()
    dist = result.dist.detach().double().cpu()
    view_rms = result.view_rms.detach().double().cpu().tolist()
    used = result.used.detach().cpu().tolist()
    rvec = result.rvec.detach().double().cpu().tolist()
    tvec = result.tvec.detach().double().cpu().tolist()
    codes = result.view_reason.cpu().tolist() if getattr(result, "view_reason", None) is not None else None
    candidate_rms = getattr(result, "candidate_rms", None)
    candidate_rms = candidate_rms.detach().double().cpu().tolist() if candidate_rms is not None else None
    index = {path: k for k, path in enumerate(usable)}
    for view in views:
        k = index.get(view["path"])
        if k is None:
            continue
        view["used"] = bool(used[k])
        vr = view_rms[k]
        view["rms"] = float(vr) if vr == vr else None  # NaN -> None
        view["rvec"], view["tvec"] = rvec[k], tvec[k]
        if not view["used"]:
            code = int(codes[k]) if codes is not None else -1
            view["reason"] = reasons.get(code, "not used by the solver")
            if candidate_rms is not None and candidate_rms[k] == candidate_rms[k]:
                view["rms_if_used"] = float(candidate_rms[k])
    std_i = result.std_intrinsics.detach().double().cpu().tolist()
    std_d = result.std_dist.detach().double().cpu().tolist()
    n_used = int(sum(bool(u) for u in used))
    return {
        "image_size": [int(image_size[0]), int(image_size[1])],
        "K": K.tolist(),
        "distortion": {"model": result.model, "coeffs": dist.tolist()},
        "rms": float(result.rms),
        "rms_kind": "RMS reprojection error over all corners of the used views, px",
        "views": views,
        "std": {"fx": std_i[0], "fy": std_i[1], "cx": std_i[2], "cy": std_i[3], "distortion": std_d},
        "board": list(board),
        "square": square,
        "detector": detector,
        "model": model,
        "num_views": {
            "files": len(views), "found": sum(1 for v in views if v["found"]), "usable": len(usable), "used": n_used,
        },
        "skipped": [{"path": v["path"], "reason": v["reason"]} for v in views if not v["used"] and "reason" in v],
    }
