"""Degenerate-input checks of a planar-board calibration, batched over cameras.

A calibration can converge, report a small RMS and still be wrong when the views cannot determine the
camera: copies of one photo, boards that are all parallel (fronto-parallel: the focal length trades off
against the distance), too few corners for the unknowns, boards that never reach the image borders (the
distortion is extrapolated there). Each check here returns, per camera, a measured value, a severity
(``OK``, ``WARNING``, ``ERROR``) and the views concerned; :class:`DegeneracyReport` turns them into
messages. The solver refuses (``success = False``) a camera with an ``ERROR`` and lists the warnings.

Every threshold of :class:`DegeneracyThresholds` is a measured choice; the measurements are in
``docs/diagnostics.md``.

Shapes: C cameras, V views, N corners per view (grid order), as the solver.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import torch
from torch import nn

from ccs_kornia.geometry.models.base import CameraModel
from ccs_kornia.geometry.models.factory import OPENCV5
from ccs_kornia.geometry.so3 import exp_so3
from ccs_kornia.modules.calibration.duplicates import (
    batch_view_corners,
    duplicate_views,
    view_differences,
)
from ccs_kornia.modules.calibration.quality.coverage import (
    covered_pixels,
    image_coverage,
)

__all__ = [
    "CHECKS",
    "WEAK_CHECKS",
    "OK",
    "WARNING",
    "ERROR",
    "DegeneracyThresholds",
    "DegeneracyReport",
    "num_camera_unknowns",
    "view_differences",
    "duplicate_views",
    "pose_spread",
    "corners_per_unknown",
    "covered_pixels",
    "image_coverage",
    "check_degeneracy",
    "DegeneracyChecks",
]

OK, WARNING, ERROR = 0, 1, 2
_SEVERITY = {OK: "ok", WARNING: "warning", ERROR: "error"}

#: the checks, in the order of the ``K`` dim of :class:`DegeneracyReport`
CHECKS: tuple[str, ...] = (
    "duplicate_views",  # copies of a view (dropped before the solve); error when < min_views distinct remain
    "near_identical_views",  # views whose corners nearly coincide: they add no pose diversity
    "pose_diversity",  # largest angle between two board planes (degrees)
    "tilt_direction",  # spread of the board normals across the main tilt direction (degrees)
    "corners_per_unknown",  # observations (2 per corner) per unknown (camera + 6 per view)
    "image_coverage",  # fraction of the image inside some board
    "focal_uncertainty",  # relative std of fx, fy from the covariance (or of cx, cy to the image size when > 1)
)


#: the checks that say the views determine the camera weakly, not that it cannot be computed: an error of theirs is
#: kept when ``DegeneracyThresholds.refuse_weak`` is off (a focal uncertainty that could not be computed never is)
WEAK_CHECKS: tuple[str, ...] = ("pose_diversity", "corners_per_unknown", "focal_uncertainty")


@dataclass
class DegeneracyThresholds:
    """Where a check turns into a warning or an error (measurements in ``docs/diagnostics.md``).

    Attributes:
        duplicate_px: RMS corner difference (px) below which a view is a copy of an earlier one.
        near_identical_px: RMS corner difference (px) below which two views are flagged as near-identical.
        min_views: distinct views needed (as the solver's ``min_views``).
        parallel_error_deg / parallel_warning_deg: largest angle between two board planes below which the
            set is refused / flagged (the focal length is not determined by parallel planes).
        tilt_direction_deg: spread of the board normals across their main direction below which the set is
            flagged as "tilted about one axis only" (only when ``pose_diversity`` passed).
        per_unknown_error / per_unknown_warning: observations per unknown below which the set is refused /
            flagged.
        coverage_warning: fraction of the image inside some board below which the set is flagged.
        focal_std_warning / focal_std_error: relative focal standard deviation above which the result is
            flagged / refused.
        refuse_weak: refuse a camera the views determine only weakly (:data:`WEAK_CHECKS` in error: nearly parallel
            boards, few observations per unknown, a large but computed uncertainty). ``False`` keeps it: the checks
            stay errors (the verdict says ``not reliable`` and why), the camera is calibrated anyway.
    """

    duplicate_px: float = 0.5
    near_identical_px: float = 5.0
    min_views: int = 3
    parallel_error_deg: float = 8.0
    parallel_warning_deg: float = 20.0
    tilt_direction_deg: float = 3.0
    per_unknown_error: float = 1.25
    per_unknown_warning: float = 2.0
    coverage_warning: float = 0.20
    focal_std_warning: float = 0.02
    focal_std_error: float = 0.05
    refuse_weak: bool = True


def num_camera_unknowns(model: CameraModel, fix_aspect_ratio: bool = False, fix_principal_point: bool = False) -> int:
    """Free camera parameters (intrinsics + the coefficients the model estimates) of the solver's model.

    Example:
        >>> from ccs_kornia.geometry.models import K1K2, OPENCV5
        >>> num_camera_unknowns(OPENCV5), num_camera_unknowns(K1K2, fix_principal_point=True)
        (9, 4)
    """
    return (1 if fix_aspect_ratio else 2) + (0 if fix_principal_point else 2) + sum(model.default_free()[4:])


def _normals(rvec: torch.Tensor) -> torch.Tensor:
    R = exp_so3(rvec.to(torch.float64))
    return R[..., :, 2]  # board z axis in the camera frame


def pose_spread(rvec: torch.Tensor, used: torch.Tensor) -> torch.Tensor:
    r"""Diversity of the board orientations, in degrees.

    Args:
        rvec: :math:`(C, V, 3)` world-to-camera rotations (board frame to camera frame).
        used: :math:`(C, V)` bool.

    Returns:
        :math:`(C, 3)`: the largest angle between two board planes, the spread (standard deviation) of the
        board normals across their main direction of variation (0 when every view is tilted about one
        axis), and the largest tilt of a board against the image plane. NaN for cameras without a used view.

    Example:
        >>> rv = torch.tensor([[[0.0, 0, 0], [0.3, 0, 0], [-0.3, 0, 0]]])  # tilted about the x axis only
        >>> [round(x, 1) for x in pose_spread(rv, torch.ones(1, 3, dtype=torch.bool))[0].tolist()]
        [34.4, 0.0, 17.2]
    """
    n = _normals(rvec)
    used = used.bool()
    cos = (n @ n.transpose(-1, -2)).clamp(-1, 1)
    pair = used[:, :, None] & used[:, None, :]
    cos = torch.where(pair, cos, torch.ones_like(cos))
    max_angle = torch.rad2deg(torch.acos(cos.amin((-1, -2))))
    tilt = torch.rad2deg(torch.acos(n[..., 2].abs().clamp(max=1)))
    max_tilt = torch.where(used, tilt, torch.zeros_like(tilt)).amax(-1)
    # spread of the normals in the tangent plane of their mean: eigenvalues of the 3x3 scatter about the mean
    w = used.to(n.dtype)[..., None]
    cnt = w.sum(1).clamp_min(1)
    mean = (n * w).sum(1) / cnt
    m = torch.nn.functional.normalize(mean, dim=-1)
    d = n * w
    d = d - (d * m[:, None]).sum(-1, keepdim=True) * m[:, None]  # tangent-plane components (radians)
    d = (d - d.sum(1, keepdim=True) / cnt[:, None]) * w
    scatter = d.transpose(-1, -2) @ d / cnt[..., None]
    ev = torch.linalg.eigvalsh(scatter)  # ascending; the smallest is 0 (along the mean normal)
    minor = torch.rad2deg(ev[:, 1].clamp_min(0).sqrt())
    out = torch.stack([max_angle, minor, max_tilt], -1)
    return torch.where(used.any(-1)[:, None], out, torch.full_like(out, float("nan")))


def corners_per_unknown(valid: torch.Tensor, used: torch.Tensor, camera_unknowns: int) -> torch.Tensor:
    r"""Observations (2 per valid corner of the used views) per unknown (camera + 6 per used view).

    Args:
        valid: :math:`(C, V, N)` bool.
        used: :math:`(C, V)` bool.
        camera_unknowns: see :func:`num_camera_unknowns`.

    Returns:
        :math:`(C,)` float.

    Example:
        >>> corners_per_unknown(torch.ones(1, 3, 4, dtype=torch.bool), torch.ones(1, 3, dtype=torch.bool), 9)
        tensor([0.8889], dtype=torch.float64)
    """
    obs = 2.0 * (valid.bool() & used.bool()[..., None]).sum((-1, -2)).to(torch.float64)
    unknowns = camera_unknowns + 6.0 * used.sum(-1).to(torch.float64)
    return obs / unknowns.clamp_min(1)


def _views_text(idx: list[int]) -> str:
    if len(idx) > 8:
        return ", ".join(str(i) for i in idx[:8]) + f" and {len(idx) - 8} more"
    return ", ".join(str(i) for i in idx)


@dataclass
class DegeneracyReport:
    """Result of :func:`check_degeneracy`: one row per camera, one column per entry of :data:`CHECKS`.

    Attributes:
        severity: :math:`(C, K)` int64, ``OK`` / ``WARNING`` / ``ERROR``.
        value: :math:`(C, K)` float64, the measured quantity of each check (see :data:`CHECKS`).
        views: :math:`(C, K, V)` bool, the views a message names.
        duplicate_of: :math:`(C, V)` int64, see :func:`duplicate_views`.
        min_views: distinct views needed.
    """

    severity: torch.Tensor
    value: torch.Tensor
    views: torch.Tensor
    duplicate_of: torch.Tensor
    min_views: int = 3
    thresholds: DegeneracyThresholds = field(default_factory=DegeneracyThresholds)

    @property
    def errors(self) -> torch.Tensor:
        """:math:`(C,)` bool: some check refuses the camera (not the weak ones where ``thresholds.refuse_weak`` is
        off, unless their value could not be computed)."""
        refusing = self.severity == ERROR
        if not self.thresholds.refuse_weak:
            weak = torch.tensor([name in WEAK_CHECKS for name in CHECKS], device=refusing.device)
            refusing = refusing & ~(weak & self.value.isfinite())
        return refusing.any(-1)

    def issues(self) -> list[list[dict]]:
        """Per camera, the failed checks as JSON-able dicts ``{"check", "severity", "message", "advice", "views",
        "value"}`` (``value``: the check's measure, ``None`` where it could not be computed)."""
        return issues_from_tensors(self.severity, self.value, self.views, self.duplicate_of, self.thresholds)


def issues_from_tensors(severity, value, views, duplicate_of=None, thresholds=None) -> list[list[dict]]:
    """Messages of the checks from their tensors (as stored on a ``CalibrationResult``); see :data:`CHECKS`.

    Accepts batched :math:`(C, K)` or single-camera :math:`(K,)` tensors; always returns one list per camera.
    """
    t = thresholds or DegeneracyThresholds()
    if severity.dim() == 1:
        severity, value, views = severity[None], value[None], views[None]
        duplicate_of = None if duplicate_of is None else duplicate_of[None]
    out = []
    for c in range(severity.shape[0]):
        items = []
        for k, name in enumerate(CHECKS):
            s = int(severity[c, k])
            if s == OK:
                continue
            v = float(value[c, k])
            idx = views[c, k].nonzero().flatten().tolist()
            problem, advice = _message(name, s, v, idx, c, duplicate_of, t)
            items.append({"check": name, "severity": _SEVERITY[s], "message": f"{problem}: {advice}", "advice": advice,
                          "views": idx, "value": v if math.isfinite(v) else None})
        out.append(items)
    return out


def _message(name, s, v, idx, c, duplicate_of, t: DegeneracyThresholds) -> tuple[str, str]:
    """(problem, advice) of a failed check."""
    views = _views_text(idx)
    if name == "duplicate_views":
        pairs = ""
        if duplicate_of is not None:
            pairs = " (" + ", ".join(f"{i}={int(duplicate_of[c, i])}" for i in idx[:8]) + ")"
        problem = f"views {views} are copies of earlier views{pairs} and were not used"
        advice = f"remove duplicate views {views}"
        if s == ERROR:
            problem += f"; only {int(v)} distinct view(s) remain, {t.min_views} needed"
            advice += " and add views of the board in other poses"
        return problem, advice
    if name == "near_identical_views":
        return f"views {views} nearly coincide with another view (no new pose)", "move the board between shots"
    if name == "pose_diversity":
        return (f"the board planes of all views are nearly parallel (largest angle between two views {v:.1f} deg), "
                "so the focal length is poorly determined",
                "tilt the board more (views are nearly fronto-parallel or all tilted the same way), by 20-45 deg in "
                "different directions")
    if name == "tilt_direction":
        return (f"all views are tilted about one axis (spread across it {v:.1f} deg)",
                "tilt the board about the other axis too (left/right as well as up/down)")
    if name == "corners_per_unknown":
        return (f"only {v:.1f} observations per unknown for this model",
                "add views, use a board with more corners or a distortion model with fewer coefficients")
    if name == "image_coverage":
        return (f"the boards cover {100 * v:.0f} % of the image, the distortion is extrapolated elsewhere",
                "add views with the board near the image corners and edges")
    if name == "focal_uncertainty" and not math.isfinite(v):
        return ("the uncertainty of the camera could not be computed (non-finite information matrix: the solution "
                "is numerically broken or some parameter is not determined by these views)",
                "add views with the board tilted in different directions, or try a model with fewer coefficients")
    if name == "focal_uncertainty":
        amount = f"{100 * v:.1f} %" if v < 1 else "over 100 %"
        return (f"the focal length or principal point is uncertain (standard deviation {amount} of the focal "
                "length or of the image size)",
                "add views with the board tilted in different directions and filling more of the image")
    return name, ""


def check_degeneracy(
    corners: torch.Tensor,
    valid: torch.Tensor,
    object_points: torch.Tensor,
    image_size: tuple[int, int],
    used: torch.Tensor,
    rvec: torch.Tensor,
    K: torch.Tensor | None = None,
    std_intrinsics: torch.Tensor | None = None,
    model: CameraModel = OPENCV5,
    fix_aspect_ratio: bool = False,
    fix_principal_point: bool = False,
    duplicate_of: torch.Tensor | None = None,
    thresholds: DegeneracyThresholds | None = None,
    differences: torch.Tensor | None = None,
    homographies: torch.Tensor | None = None,
) -> DegeneracyReport:
    r"""Run every check of :data:`CHECKS` on a (solved) calibration.

    Args:
        corners: :math:`(C, V, N, 2)` px.
        valid: :math:`(C, V, N)` bool.
        object_points: :math:`(N, 3)` or :math:`(C, N, 3)`.
        image_size: ``(W, H)``.
        used: :math:`(C, V)` views the solution uses (copies already removed).
        rvec: :math:`(C, V, 3)` their poses.
        K, std_intrinsics: :math:`(C, 3, 3)`, :math:`(C, 4)` for the focal-uncertainty check (skipped if None).
        model, fix_aspect_ratio, fix_principal_point: the solver's model (for the unknowns count).
        duplicate_of: :math:`(C, V)` from :func:`duplicate_views` (computed here when None).
        thresholds: :class:`DegeneracyThresholds`.
        differences: :math:`(C, V, V)` from :func:`view_differences` when already computed.
        homographies: :math:`(C, V, 3, 3)` of the views when already computed (for the coverage).

    Returns:
        :class:`DegeneracyReport`.
    """
    t = thresholds or DegeneracyThresholds()
    corners, valid, unbatched = batch_view_corners(corners, valid)
    if unbatched:
        used, rvec = used[None], rvec[None]
        K = None if K is None else K[None]
        std_intrinsics = None if std_intrinsics is None else std_intrinsics[None]
        duplicate_of = None if duplicate_of is None else duplicate_of[None]
        differences = None if differences is None else differences[None]
        homographies = None if homographies is None else homographies[None]
    C, V, _ = valid.shape
    dev, f64 = corners.device, torch.float64
    used = used.bool()
    cand = valid.sum(-1) >= 4
    d = view_differences(corners, valid) if differences is None else differences
    if duplicate_of is None:
        duplicate_of = duplicate_views(corners, valid, cand, t.duplicate_px, d)
    # every check gives a value, an error flag and a warning flag per camera (columns stacked once at the end)
    any_used, no = used.any(-1), torch.zeros(C, dtype=torch.bool, device=dev)

    # duplicates: value = distinct candidate views
    dup = duplicate_of >= 0
    distinct = (cand & ~dup).sum(-1)
    has_dup = dup.any(-1)

    # near-identical used views (not copies): value = smallest RMS difference between two used views
    d = d.masked_fill(~(used[:, :, None] & used[:, None, :]), float("inf"))
    near = (d <= t.near_identical_px).any(-1)

    # pose diversity and tilt direction
    spread = pose_spread(rvec, used)
    enough = used.sum(-1) >= 2
    par_err = enough & (spread[:, 0] < t.parallel_error_deg)
    par_warn = par_err | (enough & (spread[:, 0] < t.parallel_warning_deg))
    one_axis = enough & ~par_warn & (spread[:, 1] < t.tilt_direction_deg)

    # observations per unknown
    ratio = corners_per_unknown(valid, used, num_camera_unknowns(model, fix_aspect_ratio, fix_principal_point))

    # image coverage
    cov = image_coverage(corners, valid, object_points, used, image_size, homographies=homographies)[:, 0]

    # focal uncertainty from the covariance; a principal point not determined at all (std beyond the image size)
    # counts too: a singular information matrix can put its huge variance there while the focal's comes out tiny
    rel, rel_err, rel_warn = torch.full((C,), float("nan"), dtype=f64, device=dev), no, no
    if K is not None and std_intrinsics is not None:
        rel = torch.maximum(std_intrinsics[:, 0] / K[:, 0, 0].abs(), std_intrinsics[:, 1] / K[:, 1, 1].abs()).to(f64)
        rel_pp = torch.maximum(std_intrinsics[:, 2] / image_size[0], std_intrinsics[:, 3] / image_size[1]).to(f64)
        rel = torch.where((rel_pp > 1.0) & (rel_pp > rel), rel_pp, rel)
        # not computable (a non-finite information matrix: the solution overflowed somewhere) is refused too
        rel_err = (~rel.isfinite() & any_used) | (rel > t.focal_std_error)
        rel_warn = rel > t.focal_std_warning

    val = torch.stack([distinct.to(f64), d.amin((-1, -2)), spread[:, 0], spread[:, 1], ratio, cov, rel], -1)
    err = torch.stack([has_dup & (distinct < t.min_views), no, par_err, no, ratio < t.per_unknown_error, no, rel_err], -1)
    warn = torch.stack([has_dup, near.any(-1), par_warn, one_axis, ratio < t.per_unknown_warning,
                        any_used & (cov < t.coverage_warning), rel_warn], -1)
    sev = torch.maximum(err.long() * ERROR, warn.long() * WARNING)
    none_v = torch.zeros_like(used)
    views = torch.stack([dup, near, used & par_warn[:, None], used & one_axis[:, None], none_v, none_v, none_v], 1)
    rep = DegeneracyReport(sev, val, views, duplicate_of, t.min_views, t)
    if unbatched:
        rep = DegeneracyReport(sev[0], val[0], views[0], duplicate_of[0], t.min_views, t)
    return rep


class DegeneracyChecks(nn.Module):
    r"""Module form of :func:`check_degeneracy` with fixed thresholds and model.

    Args:
        model, fix_aspect_ratio, fix_principal_point: the solver's model.
        thresholds: :class:`DegeneracyThresholds`.

    Example:
        >>> from ccs_kornia.geometry.board_points import board_object_points
        >>> from ccs_kornia.geometry.camera import project_points
        >>> obj = board_object_points(6, 5, 0.1, dtype=torch.float64)
        >>> K = torch.tensor([[600., 0, 320], [0, 600, 240], [0, 0, 1]], dtype=torch.float64)
        >>> rv = torch.zeros(4, 3, dtype=torch.float64)  # four fronto-parallel views
        >>> tv = torch.tensor([[-0.3, -0.2, 1.5], [-0.1, -0.2, 1.5], [-0.3, 0.0, 1.6], [-0.2, -0.1, 1.4]],
        ...                   dtype=torch.float64)
        >>> uv = project_points(obj.expand(4, -1, -1), K.expand(4, 3, 3), None, rv, tv)
        >>> from ccs_kornia.geometry.models import K1K2
        >>> rep = DegeneracyChecks(model=K1K2)(uv, None, obj, (640, 480), torch.ones(4, dtype=torch.bool), rv)
        >>> [i["check"] for i in rep.issues()[0] if i["severity"] == "error"]
        ['pose_diversity']
    """

    def __init__(
        self,
        model: CameraModel = OPENCV5,
        fix_aspect_ratio: bool = False,
        fix_principal_point: bool = False,
        thresholds: DegeneracyThresholds | None = None,
    ) -> None:
        super().__init__()
        self.model = model
        self.fix_aspect_ratio = fix_aspect_ratio
        self.fix_principal_point = fix_principal_point
        self.thresholds = thresholds or DegeneracyThresholds()

    def forward(self, corners, valid, object_points, image_size, used, rvec, K=None, std_intrinsics=None,
                duplicate_of=None) -> DegeneracyReport:
        return check_degeneracy(
            corners, valid, object_points, image_size, used, rvec, K, std_intrinsics, self.model,
            self.fix_aspect_ratio, self.fix_principal_point, duplicate_of, self.thresholds,
        )
