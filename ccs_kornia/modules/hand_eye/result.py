r"""The hand-eye result and its verdict.

:class:`HandEyeResult` holds ``B`` solved problems (batch first). Standard deviations are 1-sigma: the rotation's about
each axis of the robot frame (a left perturbation, ``R <- exp(w) R``) in degrees, the translation's in the robot
poses' unit. They come from the spread of the leave-one-pose-out refits (a jackknife: it holds the robot poses' own
errors, which move all corners of a view together) wherever enough poses were held out, else from the fit's covariance
(scaled by the fit's residuals, ``sigma^2 = cost / dof``), which sees the corners' noise only.

The verdict (:func:`hand_eye_verdict`) reads the figures a user acts on: the held-out prediction error (pixel
figures per 1000 px of image diagonal, as the rig verdict's) and the 1-sigma of ``X``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import torch

from ccs_kornia.geometry.camera import Camera
from ccs_kornia.modules.hand_eye.setup import HandEyeSetup

__all__ = ["HandEyeResult", "HandEyeVerdictThresholds", "camera_misfits", "hand_eye_verdict"]


@dataclass
class HandEyeVerdictThresholds:
    """Limits of the verdict: held-out RMS (px per 1000 px of diagonal), ``X``'s 1-sigma (degrees; metres), and how
    much more each view's own board pose leaves with the given camera than with one calibrated from the views (the
    medians over the views: a ratio, and a difference in px) for the camera not to fit the images."""

    good_heldout: float = 1.5
    usable_heldout: float = 4.0
    good_rotation_deg: float = 0.2
    usable_rotation_deg: float = 1.0
    good_translation: float = 0.002
    usable_translation: float = 0.01
    camera_misfit_ratio: float = 1.3
    camera_misfit_px: float = 0.15


def camera_misfits(camera_fit_px: float, calibrated_fit_px: float,
                   thresholds: HandEyeVerdictThresholds | None = None) -> bool:
    """Whether the given camera does not fit the images: each view's own board pose leaves clearly more with it
    (``camera_fit_px``, the median over the views) than with a camera calibrated from them (``calibrated_fit_px``);
    ``False`` where either is not measured.

    Example:
        >>> camera_misfits(2.5, 0.3), camera_misfits(0.35, 0.3), camera_misfits(float("nan"), 0.3)
        (True, False, False)
    """
    t = thresholds or HandEyeVerdictThresholds()
    return math.isfinite(camera_fit_px) and math.isfinite(calibrated_fit_px) and \
        camera_fit_px > t.camera_misfit_ratio * calibrated_fit_px and \
        camera_fit_px - calibrated_fit_px > t.camera_misfit_px


def hand_eye_verdict(heldout_rms_px: float, rotation_std_deg: float, translation_std: float,
                     image_size: tuple[int, int], metres_per_unit: float = 1.0,
                     thresholds: HandEyeVerdictThresholds | None = None, camera_fit_px: float = float("nan"),
                     calibrated_fit_px: float = float("nan"), fit_rms_px: float = float("nan")
                     ) -> tuple[str, list[str]]:
    """``("good" | "usable" | "not reliable: <advice>", reasons)`` of one calibration; each advice names the figure
    that failed. Three causes are told apart: a camera that does not fit its images (each view's own pose leaves
    clearly more with it than with a camera calibrated from the views: the robot is then not blamed for the
    held-out error, which the camera explains), robot
    poses that disagree with the images (held-out poses predicted far off while the camera fits), too little motion
    (``X``'s 1-sigma).

    Args:
        heldout_rms_px: leave-one-pose-out RMS (px; NaN when no pose could be held out).
        rotation_std_deg, translation_std: ``X``'s 1-sigma (the norms over the axes; translation in the poses' unit).
        image_size: ``(W, H)``.
        metres_per_unit: the poses' unit in metres.
        camera_fit_px: the median over the views of the RMS px each view's own board pose leaves with the camera (NaN:
            not measured); calibrated_fit_px: the same with a camera calibrated from the views
            (:func:`~ccs_kornia.modules.hand_eye.camera_fit.calibrated_view_rms`).
        fit_rms_px: the joint fit's RMS px (for the robot's advice).

    Example:
        >>> hand_eye_verdict(0.6, 0.05, 0.0008, (640, 480))
        ('good', [])
        >>> hand_eye_verdict(9.0, 0.05, 0.0008, (640, 480))[0][:14]
        'not reliable: '
        >>> hand_eye_verdict(9.0, 0.05, 0.0008, (640, 480), camera_fit_px=3.0, calibrated_fit_px=0.2)[0][:57]
        'not reliable: the given camera does not fit these images '
    """
    t = thresholds or HandEyeVerdictThresholds()
    scale = math.hypot(*image_size) / 1000.0
    trans = translation_std * metres_per_unit
    bad, weak, advice = [], [], []
    misfit = camera_misfits(camera_fit_px, calibrated_fit_px, t)
    if misfit:
        bad.append(f"each view's own board pose leaves {camera_fit_px:.2f} px RMS with the camera, "
                   f"{calibrated_fit_px:.2f} px with one calibrated from the views")
        advice.append(f"the given camera does not fit these images (each view's own board pose leaves "
                      f"{camera_fit_px:.2f} px RMS with it, {calibrated_fit_px:.2f} px with a camera calibrated from "
                      "them): calibrate it from them or give its distortion")
    if not math.isfinite(heldout_rms_px):
        weak.append("too few poses to hold one out: the prediction error is not measured")
    elif heldout_rms_px > t.usable_heldout * scale:
        bad.append(f"poses held out are predicted {heldout_rms_px:.2f} px off")
        if not misfit:
            fit = f", while the fit of every pose is {fit_rms_px:.2f} px" if math.isfinite(fit_rms_px) else ""
            advice.append(f"check the robot's pose of each image (held-out poses predicted {heldout_rms_px:.2f} px "
                          f"off from the robot alone{fit}: pose file order, units, convention) and that the board "
                          "and camera did not move on their mounts")
    elif heldout_rms_px > t.good_heldout * scale:
        weak.append(f"poses held out are predicted {heldout_rms_px:.2f} px off")
    if not (math.isfinite(rotation_std_deg) and math.isfinite(trans)) or rotation_std_deg > t.usable_rotation_deg \
            or trans > t.usable_translation:
        bad.append(f"X 1-sigma {rotation_std_deg:.3f} deg, {1000 * trans:.2f} mm")
        advice.append(f"add poses rotated by 15-30 degrees about different axes, the board filling more of the image "
                      f"(X 1-sigma {rotation_std_deg:.2f} deg, {1000 * trans:.1f} mm: too little motion)")
    elif rotation_std_deg > t.good_rotation_deg or trans > t.good_translation:
        weak.append(f"X 1-sigma {rotation_std_deg:.3f} deg, {1000 * trans:.2f} mm")
    if bad:
        return "not reliable: " + "; ".join(dict.fromkeys(advice)), bad + weak
    return ("usable" if weak else "good"), weak


@dataclass
class HandEyeResult:
    """Hand-eye calibration of ``B`` problems of ``V`` views (``N`` board corners, ``P`` camera parameters).

    ``X`` is the camera's pose in its robot frame (eye-in-hand: ``x_flange = X x_camera``; eye-to-hand:
    ``x_base = X x_camera``), ``Z`` the board's in the other one (:mod:`~ccs_kornia.modules.hand_eye.setup`).
    """

    setup: HandEyeSetup
    success: torch.Tensor  #: (B,) bool
    reasons: list[str]  #: per problem, "" on success, else the refusal in one line
    issues: list[list[dict]]  #: per problem, every check's finding (severity, check, message, poses)
    X: torch.Tensor  #: (B, 4, 4)
    Z: torch.Tensor  #: (B, 4, 4)
    camera: Camera  #: the B problems' cameras (their parameters fitted where free)
    covariance: torch.Tensor  #: (B, G, G) the fit's, over (w_X, t_X, w_Z, t_Z, free intrinsics)
    x_covariance: torch.Tensor  #: (B, 6, 6) the reported covariance of X (rotation vector, translation)
    z_covariance: torch.Tensor  #: (B, 6, 6) ... of Z
    std_source: list[str]  #: per problem, "leave-one-pose-out" (jackknife of the refits) or "fit"
    x_rotation_std_deg: torch.Tensor  #: (B, 3) about the robot frame's axes
    x_translation_std: torch.Tensor  #: (B, 3) the poses' unit
    z_rotation_std_deg: torch.Tensor  #: (B, 3)
    z_translation_std: torch.Tensor  #: (B, 3)
    intrinsics_std: torch.Tensor  #: (B, P), 0 where held
    rms: torch.Tensor  #: (B,) px over the used corners
    view_rms: torch.Tensor  #: (B, V) px, NaN where unused
    residuals: torch.Tensor  #: (B, V, N, 2) projection minus observation, px
    used: torch.Tensor  #: (B, V) bool, the views the fit used
    board_poses: torch.Tensor  #: (B, V, 4, 4) the board's pose in the camera from each view alone (NaN where none)
    start: list[str]  #: per problem, the closed form the fit started from
    start_rms: torch.Tensor  #: (B, K) px, every closed form's RMS before the fit
    start_names: list[str]  #: the closed forms, in that order
    heldout_rms_px: torch.Tensor  #: (B, V) leave-one-pose-out prediction RMS, px (NaN where not held out)
    heldout_rms_distance: torch.Tensor  #: (B, V) ... as a distance to the lines of sight, the poses' unit
    heldout_predicted: torch.Tensor  #: (B, V, N, 2) the held-out views' corners predicted from their robot poses
    verdict: list[str]  #: per problem
    verdict_reasons: list[list[str]] = field(default_factory=list)
    iterations: torch.Tensor | None = None  #: (B,)
    #: (B,) int64 :class:`~ccs_kornia.modules.calibration.schur_lm.LMStatus`: how the fit ended
    lm_status: torch.Tensor | None = None
    robot_noise: torch.Tensor | None = None  #: (B, 2) the robot poses' sigma of the fit: radians, the poses' unit
    pixel_sigma: torch.Tensor | None = None  #: (B,) the corners' sigma estimated with it (px, for unit weights)
    corrections: tuple[torch.Tensor, torch.Tensor] | None = None  #: the noise term's pose corrections (R (B, V, 3, 3), t)
    #: (B, V) int64: 0 where a view's corners were used as numbered, k > 0 where renumbered by the board's k-th symmetry
    #: (1: the 180-degree turn) to agree with the other views (``residuals`` are in the board's numbering)
    board_order: torch.Tensor | None = None
    corners: torch.Tensor | None = None  #: (B, V, N, 2) the corners fitted, in the board's numbering (NaN: not seen)
    #: per problem, the model of the robot's error kept instead of the estimated noise term (the poses taken as exact,
    #: or fixed sigmas: ``robot_noise``) and why ("" where the term was kept)
    noise_choice: list[str] | None = None
    #: (B, 2) the board's sag (mrcal's ``calobject_warp``, the poses' unit) where the fit estimated it (0 where a
    #: problem kept the board flat), else None
    board_warp: torch.Tensor | None = None
    board_warp_std: torch.Tensor | None = None  #: (B, 2) its 1-sigma (NaN where the board was kept flat)
    #: per problem, the sag and whether held-out poses kept it
    #: (:func:`~ccs_kornia.modules.calibration.board_flatness.board_warp_record`; None where not judged)
    board_flatness: list[dict | None] | None = None

    @property
    def X_rotation_std_deg(self) -> torch.Tensor:
        """(B,) the norm of ``X``'s rotation 1-sigma over the axes (degrees): the expected size of the error."""
        return self.x_rotation_std_deg.norm(dim=-1)

    @property
    def X_translation_std(self) -> torch.Tensor:
        """(B,) the norm of ``X``'s translation 1-sigma over the axes (the poses' unit)."""
        return self.x_translation_std.norm(dim=-1)

    @property
    def heldout_rms(self) -> torch.Tensor:
        """(B,) leave-one-pose-out RMS over every held-out corner, px (NaN where none)."""
        return _pooled(self.heldout_rms_px, self.used)

    @property
    def heldout_distance(self) -> torch.Tensor:
        """(B,) the same as a distance to the lines of sight, the poses' unit."""
        return _pooled(self.heldout_rms_distance, self.used)


def _pooled(per_view: torch.Tensor, used: torch.Tensor) -> torch.Tensor:
    ok = used & per_view.isfinite()
    s = torch.where(ok, per_view ** 2, 0.0).sum(-1)
    n = ok.sum(-1)
    return (s / n.clamp_min(1)).sqrt().masked_fill(n == 0, float("nan"))
