r"""Does the given camera fit the images? Each view's own board pose with it, against a camera calibrated from the same
corners.

A camera whose distortion is missing or wrong leaves each view's corners off the board's pose that fits them best; a
detector's corners are within a few tenths of a pixel, but that noise differs from set to set, so the figure is judged
against the same views with a camera calibrated from them (the model ``k1, k2``, the solver of
:mod:`~ccs_kornia.modules.calibration.solver`): where the given camera leaves clearly more than that one (a third
more, and 0.15 px: :class:`~ccs_kornia.modules.hand_eye.result.HandEyeVerdictThresholds`), the
camera, not the robot, explains a poor hand-eye (:func:`~ccs_kornia.modules.hand_eye.result.hand_eye_verdict`).
"""

from __future__ import annotations

import torch

__all__ = ["calibrated_view_rms"]


def calibrated_view_rms(corners: torch.Tensor, valid: torch.Tensor, object_points: torch.Tensor,
                        image_size: tuple[int, int]) -> torch.Tensor:
    """The median over the views of each view's RMS px :math:`(B,)` under a camera (``k1, k2``) calibrated from the
    views' own corners (NaN where it could not be calibrated).

    Args:
        corners: :math:`(B, V, N, 2)`; valid: :math:`(B, V, N)`; object_points: :math:`(N, 3)`; image_size: ``(W, H)``.

    Example:
        >>> from ccs_kornia.data.scenes.robots import render_hand_eye
        >>> s = render_hand_eye("eye_in_hand", views=6, seed=1, noise_px=0.0)
        >>> float(calibrated_view_rms(s.corners[None], s.valid[None], s.object_points, s.image_size)[0]) < 1e-3
        True
    """
    from ccs_kornia.geometry.models.factory import K1K2
    from ccs_kornia.modules.calibration.solver import CalibrationSolver

    solver = CalibrationSolver(model=K1K2, use_ransac=False)
    with torch.inference_mode():
        res = solver(corners.double().nan_to_num(0.0), valid, object_points.double(), image_size)
    out = torch.full((corners.shape[0],), float("nan"), dtype=torch.float64)
    for b in range(corners.shape[0]):
        rms = res.view_rms[b][res.used[b] & res.view_rms[b].isfinite()]
        if bool(res.success[b]) and rms.numel():
            out[b] = rms.median()
    return out
