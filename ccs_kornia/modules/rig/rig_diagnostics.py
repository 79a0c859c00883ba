"""How good a rig calibration is: epipolar RMS (fit and held-out frames), uncertainties and the verdict.

The thresholds of the verdict scale with the image size: they are given per 1000 px of image diagonal
(``sqrt(W^2 + H^2)``), so a 640x480 camera (diagonal 800 px) is held to 0.8 times and a 1920x1080 one (2203 px) to
2.2 times the figures below. The single-camera verdict's 1 px / 2 px reprojection limits
(:class:`~ccs_kornia.modules.calibration.quality.diagnostics.VerdictThresholds`) are the values at a diagonal of 1000 px.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import torch

from ccs_kornia.geometry.camera import Camera
from ccs_kornia.geometry.poses import pair_pose
from ccs_kornia.modules.calibration.quality.verdict import Findings
from ccs_kornia.modules.rig.stereo import epipolar_distances

__all__ = ["RigVerdictThresholds", "epipolar_sums", "rig_verdict"]


@dataclass
class RigVerdictThresholds:
    """Limits of the rig verdict (pixel figures per 1000 px of image diagonal; see the module doc).

    Attributes:
        good_rms / usable_rms: reprojection RMS of a camera.
        good_epipolar / usable_epipolar: held-out epipolar RMS of a pair (the fit's when no frame could be held out).
        good_baseline_rel / usable_baseline_rel: 1-sigma of ``|T|`` over ``|T|``.
        good_rotation_deg / usable_rotation_deg: 1-sigma of the relative rotation (degrees).
        moved_sigma: an intrinsic the joint fit moved by more than this many single-camera sigmas is a weakness.
    """

    good_rms: float = 1.0
    usable_rms: float = 2.0
    good_epipolar: float = 1.0
    usable_epipolar: float = 2.0
    good_baseline_rel: float = 0.005
    usable_baseline_rel: float = 0.02
    good_rotation_deg: float = 0.1
    usable_rotation_deg: float = 0.5
    moved_sigma: float = 3.0


def epipolar_sums(
    cameras: Camera, R: torch.Tensor, T: torch.Tensor, corners: torch.Tensor, valid: torch.Tensor,
    frames: torch.Tensor,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Sum of squared symmetric epipolar distances and their count per camera pair, :math:`(C, C)` each (symmetric),
    over the corners both cameras see in the same frame, on the frames where ``frames`` :math:`(C, F)` is True for
    both (corners :math:`(C, F, N, 2)`, valid :math:`(C, F, N)`)."""
    C = len(cameras)
    sums = torch.zeros(C, C, dtype=R.dtype, device=R.device)
    counts = torch.zeros(C, C, dtype=torch.long, device=R.device)
    for i in range(C):
        for j in range(i + 1, C):
            m = valid[i] & valid[j] & (frames[i] & frames[j])[:, None]
            if not bool(m.any()):
                continue
            Rij, Tij = pair_pose(R, T, i, j)
            d = epipolar_distances(cameras[i], cameras[j], Rij, Tij, corners[i][m], corners[j][m])
            d = d[d.isfinite()]
            sums[i, j] = sums[j, i] = float((d * d).sum())
            counts[i, j] = counts[j, i] = int(d.numel())
    return sums, counts


def rig_verdict(
    names: Sequence[str],
    image_sizes: Sequence[tuple[int, int]],
    camera_rms: torch.Tensor,
    epipolar_rms: torch.Tensor,
    heldout_epipolar_rms: torch.Tensor,
    baseline: torch.Tensor,
    baseline_std: torch.Tensor,
    rotation_std_deg: torch.Tensor,
    thresholds: RigVerdictThresholds | None = None,
    converged: bool = True,
    iterations: int = 0,
    moved_sigma: Sequence[float] | None = None,
) -> tuple[str, list[str]]:
    """``("good" | "usable" | "not reliable: <advice>", reasons)`` of one rig.

    Args:
        names, image_sizes: per camera.
        camera_rms: :math:`(C,)` px; epipolar_rms, heldout_epipolar_rms: :math:`(C, C)` px.
        baseline: :math:`(C,)` ``|T_c|``; baseline_std, rotation_std_deg: :math:`(C,)` (camera 0: 0).
        thresholds: :class:`RigVerdictThresholds`.
        converged: the joint fit met its tolerance; one that stopped at its iteration limit (``iterations``) is not
            usable, whatever its figures (they are those of where it stopped).
        moved_sigma: per camera the largest move of an intrinsic in the joint fit, in units of its single-camera
            1-sigma: beyond ``thresholds.moved_sigma`` the rig's frames disagree with the camera's own views (a
            weakness: the verdict is at best usable).

    Example:
        >>> z = torch.zeros(2, 2)
        >>> rig_verdict(["a", "b"], [(640, 480)] * 2, torch.tensor([0.2, 0.3]), z, z + 0.2,
        ...             torch.tensor([0.0, 0.1]), torch.tensor([0.0, 1e-4]), torch.tensor([0.0, 0.01]))
        ('good', [])
        >>> rig_verdict(["a", "b"], [(640, 480)] * 2, torch.tensor([0.2, 3.0]), z, z + 0.2,
        ...             torch.tensor([0.0, 0.1]), torch.tensor([0.0, 1e-4]), torch.tensor([0.0, 0.01]))[0][:73]
        "not reliable: b's reprojection RMS 3.00 px is over 1.60 px: check the cor"
    """
    t = thresholds or RigVerdictThresholds()
    C = len(names)
    scale = [math.hypot(*image_sizes[c]) / 1000.0 for c in range(C)]
    found = Findings()
    # every piece of advice starts with the figure that failed and its limit, so that the verdict line says what is
    # wrong before what to do about it
    for c in range(C):
        r, limit = float(camera_rms[c]), t.usable_rms * scale[c]
        if not math.isfinite(r):
            found.fail(f"{names[c]}: no reprojection error (not calibrated)",
                       f"{names[c]} has no reprojection error (not calibrated): add frames where {names[c]} sees the "
                       "board")
        else:
            found.grade(r, t.good_rms * scale[c], limit, f"{names[c]}: reprojection RMS {r:.2f} px",
                        f"{names[c]}'s reprojection RMS {r:.2f} px is over {limit:.2f} px: check the corner detections "
                        f"of {names[c]}, or choose a distortion model that fits its lens",
                        f"{names[c]}: reprojection RMS {r:.2f} px is high")
    for c in range(1, C):
        b, sb, sr = float(baseline[c]), float(baseline_std[c]), float(rotation_std_deg[c])
        rel = sb / b if b > 0 else float("inf")
        text = f"{names[c]}: baseline 1-sigma {100 * rel:.2f} %, rotation 1-sigma {sr:.3f} deg"
        if not (math.isfinite(rel) and math.isfinite(sr)) or rel > t.usable_baseline_rel or sr > t.usable_rotation_deg:
            failed = []
            if not math.isfinite(sr) or sr > t.usable_rotation_deg:
                failed.append(f"rotation 1-sigma {sr:.2f} deg is over {t.usable_rotation_deg:g} deg")
            if not math.isfinite(rel) or rel > t.usable_baseline_rel:
                failed.append(f"baseline 1-sigma {100 * rel:.2f} % is over {100 * t.usable_baseline_rel:g} %")
            found.fail(text, f"{names[c]}'s {' and its '.join(failed)}: add frames that {names[0]} (or a camera "
                             f"linked to it) and {names[c]} both see, nearer and at varied distances and tilts")
        elif rel > t.good_baseline_rel or sr > t.good_rotation_deg:
            found.warn(text)
    for i in range(C):
        for j in range(i + 1, C):
            held, fit = float(heldout_epipolar_rms[i, j]), float(epipolar_rms[i, j])
            s = 0.5 * (scale[i] + scale[j])
            pair = f"{names[i]}-{names[j]}"
            if not math.isfinite(held):
                if math.isfinite(fit):
                    found.warn(f"{pair}: too few shared frames to hold some out (fit epipolar RMS {fit:.2f} px)")
                    held = fit
                else:
                    continue
            label = "held-out epipolar RMS" if held != fit else "epipolar RMS"
            found.grade(held, t.good_epipolar * s, t.usable_epipolar * s, f"{pair}: {label} {held:.2f} px",
                        f"{pair}'s {label} {held:.2f} px is over {t.usable_epipolar * s:.2f} px: add frames both "
                        f"{names[i]} and {names[j]} see, spread over the image and in depth (and check that the "
                        "cameras did not move during the capture)")
    for c, m in enumerate(moved_sigma or []):
        if m > t.moved_sigma:
            found.warn(f"{names[c]}: the joint fit moved its intrinsics up to {m:.1f} sigma from its own calibration")
    if not converged:
        found.fail(f"the joint fit stopped unconverged after {iterations} iterations",
                   f"the joint fit stopped unconverged after {iterations} iterations (its figures are those of where "
                   "it stopped): check the frames named as disagreeing, or hold each camera's own intrinsics fixed")
    return found.outcome()
