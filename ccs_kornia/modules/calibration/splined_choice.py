r"""``--model auto``'s last step: the splined stereographic model, taken only where held-out views say it predicts
clearly better than the model the cross-validation chose.

Tried only for a camera whose chosen model leaves structure in its residuals (its ``model_fit`` is not ``fits``,
:mod:`~ccs_kornia.modules.calibration.quality.residual_structure`): where the residuals are the corners' noise no model
can predict better, and the spline's hundreds of parameters cost time for nothing. There the views are split in two
halves (alternate views); each half's camera, of the chosen model and splined
(:func:`~ccs_kornia.modules.calibration.splined.calibrate_splined`, the grid of
:func:`~ccs_kornia.modules.calibration.splined.splined_configuration`), predicts the other half's views (their poses
refitted, the camera held), and the spline is kept where its median held-out error is below ``1 - margin`` times the
chosen model's (as the board's sag is, :mod:`~ccs_kornia.modules.calibration.board_flatness`).

``--model splined`` asks for the spline outright: :func:`splined_cameras` fits it on every calibrated camera from the
model the cross-validation chose, without the held-out comparison.
"""

from __future__ import annotations

from dataclasses import replace

import torch

from ccs_kornia.modules.calibration.board_flatness import heldout_errors, split_halves
from ccs_kornia.modules.calibration.quality.residual_structure import ModelFit
from ccs_kornia.modules.calibration.result import CalibrationResult
from ccs_kornia.modules.calibration.solver import (
    CalibrationSolver,
    with_residual_structure,
)
from ccs_kornia.modules.calibration.splined import (
    calibrate_splined,
    splined_configuration,
)

__all__ = ["SPLINE_MARGIN", "choose_splined", "splined_cameras"]

#: the spline's median held-out error must be below ``1 - SPLINE_MARGIN`` times the chosen model's
SPLINE_MARGIN = 0.05


def choose_splined(solver: CalibrationSolver, chosen: CalibrationResult, corners: torch.Tensor, valid: torch.Tensor,
                   object_points: torch.Tensor, image_size: tuple[int, int], weights: torch.Tensor | None = None,
                   margin: float = SPLINE_MARGIN) -> tuple[list[CalibrationResult | None], list[dict | None]]:
    """The splined camera where held-out views prefer it (module docstring), per camera of ``chosen`` (batched, the
    result of ``solver``).

    Returns:
        per camera the splined result to keep (batched, one camera) or ``None``, and the figures (``None`` for a camera
        not tried: not calibrated, or its residuals are noise): ``{"model", "heldout_median_px": {chosen, splined},
        "kept", "rule"}``.
    """
    C = corners.shape[0]
    keep: list[CalibrationResult | None] = [None] * C
    records: list[dict | None] = [None] * C
    fit = chosen.model_fit
    if fit is None:
        return keep, records
    for c in range(C):
        if not bool(chosen.success[c]) or int(fit[c]) == ModelFit.FITS:
            continue
        one = chosen.map_tensors(lambda t, c=c: t[c : c + 1], lambda cam, c=c: cam[c])
        x, ok, w = corners[c : c + 1], valid[c : c + 1], None if weights is None else weights[c : c + 1]
        obj = object_points if object_points.dim() == 2 else object_points[c : c + 1]
        model = splined_configuration(one.camera, int((ok & one.used[..., None]).sum()), image_size)
        halves = split_halves(one.used)
        medians = {}
        for name in ("chosen", "splined"):
            cams = []
            for h in range(2):
                part = ok & halves[h][..., None]
                cam = solver(x, part, obj, image_size, weights=w, initial=one)
                if name == "splined":
                    cam = calibrate_splined(cam, x, part, obj, image_size, model, w)
                cams.append(cam)
            errors = [heldout_errors(cams[h], x, ok, halves[1 - h], obj, one, w) for h in range(2)]
            medians[name] = float(torch.cat([e.flatten() for e in errors]).nanmedian())
        kept = medians["splined"] < (1 - margin) * medians["chosen"]
        records[c] = {"model": model.name, "heldout_median_px": {str(one.camera.model): medians["chosen"],
                                                                 "splined": medians["splined"]},
                      "kept": bool(kept),
                      "rule": f"tried where the chosen model's residuals have structure; kept where its median held-out "
                              f"error (alternate halves) is below {1 - margin:g} times the chosen model's"}
        if kept:
            whole = calibrate_splined(one, x, ok, obj, image_size, model, w)
            keep[c] = with_residual_structure(replace(whole), x, ok, obj if obj.dim() == 3 else obj[None], image_size)
    return keep, records


def splined_cameras(chosen: CalibrationResult, corners: torch.Tensor, valid: torch.Tensor, object_points: torch.Tensor,
                    image_size: tuple[int, int], weights: torch.Tensor | None = None
                    ) -> tuple[list[CalibrationResult | None], list[dict | None]]:
    """Every calibrated camera of ``chosen`` (batched) splined
    (:func:`~ccs_kornia.modules.calibration.splined.calibrate_splined` from it, the grid of
    :func:`~ccs_kornia.modules.calibration.splined.splined_configuration`), as :func:`choose_splined` returns them:
    per camera the splined result (batched, one camera; ``None`` where ``chosen`` did not calibrate it) and its
    figures ``{"model", "kept", "rule"}``.

    Example:
        >>> import math
        >>> from ccs_kornia.geometry.board_points import board_object_points
        >>> from ccs_kornia.geometry.camera import Camera
        >>> from ccs_kornia.geometry.models import K1K2
        >>> from ccs_kornia.geometry.so3 import exp_so3
        >>> obj = board_object_points(6, 5, 0.04, dtype=torch.float64)
        >>> K = torch.tensor([[400.0, 0, 320], [0, 400, 240], [0, 0, 1]], dtype=torch.float64)
        >>> lens = Camera.from_opencv(K1K2, K, torch.tensor([-0.2, 0.05], dtype=torch.float64), (640, 480))
        >>> r = torch.tensor([[0.3 * math.cos(k), 0.3 * math.sin(k), 0.1 * k] for k in range(8)], dtype=torch.float64)
        >>> t = torch.tensor([[-0.1 + 0.03 * k, -0.1 + 0.02 * (k % 3), 0.4] for k in range(8)], dtype=torch.float64)
        >>> X = (obj[None] - obj.mean(0)) @ exp_so3(r).transpose(-1, -2) + t[:, None]
        >>> corners = lens.project(X.reshape(1, -1, 3)).reshape(1, 8, 30, 2)
        >>> valid = torch.ones(1, 8, 30, dtype=torch.bool)
        >>> chosen = CalibrationSolver(model=K1K2, use_ransac=False)(corners, valid, obj, (640, 480))
        >>> out, records = splined_cameras(chosen, corners, valid, obj, (640, 480))
        >>> out[0].camera.model.name.startswith("splined"), records[0]["kept"], bool(out[0].rms < 0.05)
        (True, True, True)
    """
    C = corners.shape[0]
    keep: list[CalibrationResult | None] = [None] * C
    records: list[dict | None] = [None] * C
    for c in range(C):
        if not bool(chosen.success[c]):
            continue
        one = chosen.map_tensors(lambda t, c=c: t[c : c + 1], lambda cam, c=c: cam[c])
        x, ok, w = corners[c : c + 1], valid[c : c + 1], None if weights is None else weights[c : c + 1]
        obj = object_points if object_points.dim() == 2 else object_points[c : c + 1]
        model = splined_configuration(one.camera, int((ok & one.used[..., None]).sum()), image_size)
        whole = calibrate_splined(one, x, ok, obj, image_size, model, w)
        keep[c] = with_residual_structure(whole, x, ok, obj if obj.dim() == 3 else obj[None], image_size)
        records[c] = {"model": model.name, "kept": bool(whole.success.all()),
                      "rule": f"asked for (--model splined), from the {one.camera.model} camera the cross-validation "
                              "chose"}
    return keep, records
