"""What one :class:`~ccs_kornia.pipeline.calibration_pipeline.CalibrationPipeline` run returns, and selecting cameras out of it."""

from __future__ import annotations

from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass, field, fields, replace
from typing import Any

import torch

from ccs_kornia.geometry.camera import Camera
from ccs_kornia.modules.calibration.result import VIEW_REASONS, CalibrationResult
from ccs_kornia.modules.detection.base import DetectionResult
from ccs_kornia.pipeline.sources import SIZE_TOLERANCE_PX
from ccs_kornia.runtime.checks import check_tensor

__all__ = [
    "PipelineResult",
    "module_device",
    "select_result",
    "concat_results",
    "scatter_cameras",
    "main_size",
    "positive_size",
    "camera_reason",
]


def _index(value: Any, idx: torch.Tensor | int) -> Any:
    if isinstance(value, Camera):
        return value[idx]
    if isinstance(value, torch.Tensor) and value.dim() > 0:
        return value[idx.to(value.device) if isinstance(idx, torch.Tensor) else idx]
    return value


def select_result(result: Any, idx: torch.Tensor | int) -> Any:
    """Cameras ``idx`` of a dataclass result whose tensor fields all have the camera dimension first.

    An ``int`` drops the camera dimension (a :class:`~ccs_kornia.geometry.camera.Camera` keeps it: one camera); a
    :math:`(K,)` long tensor keeps it. Works for
    :class:`~ccs_kornia.modules.calibration.result.CalibrationResult` whatever optional fields it carries; cameras of
    one model taken from a result of several get their coefficient fields back to that model's width.

    Example:
        >>> d = DetectionResult(torch.zeros(3, 5, 4, 2), torch.tensor([[True] * 5] * 3))
        >>> select_result(d, torch.tensor([0, 2])).corners.shape, select_result(d, 1).found.shape
        (torch.Size([2, 5, 4, 2]), torch.Size([5]))
    """
    values = {}
    for f in fields(result):
        v = getattr(result, f.name)
        values[f.name] = _index(v, idx) if f.name != "reasons" else v
    camera = values.get("camera")
    if isinstance(camera, Camera) and camera.uniform and len(camera):
        values = _trim(values, camera.model.num_coeffs)
    return type(result)(**values)


def _trim(values: dict[str, Any], width: int) -> dict[str, Any]:
    """Coefficient fields cut back to ``width`` coefficients (after NaN padding for mixed models)."""
    out = dict(values)
    if isinstance(out.get("std_dist"), torch.Tensor):
        out["std_dist"] = out["std_dist"][..., :width]
    if isinstance(out.get("cov_camera"), torch.Tensor):
        out["cov_camera"] = out["cov_camera"][..., : 4 + width, : 4 + width]
    return out


def _pad(result: Any, width: int) -> Any:
    """A calibration result with its coefficient fields NaN-padded to ``width`` coefficients."""
    values = {f.name: getattr(result, f.name) for f in fields(result)}
    v = values["std_dist"]
    values["std_dist"] = torch.cat([v, v.new_full((*v.shape[:-1], width - v.shape[-1]), float("nan"))], -1)
    cov = values.get("cov_camera")
    if isinstance(cov, torch.Tensor):
        n = 4 + width
        padded = cov.new_full((*cov.shape[:-2], n, n), float("nan"))
        padded[..., : cov.shape[-2], : cov.shape[-1]] = cov
        values["cov_camera"] = padded
    return type(result)(**values)


def concat_results(parts: Sequence[Any]) -> Any:
    """Concatenate dataclass results along the camera dimension (non-tensor fields taken from the first; cameras of
    several models: the coefficient fields NaN-padded to the widest).

    Example:
        >>> a = DetectionResult(torch.zeros(1, 2, 4, 2), torch.ones(1, 2, dtype=torch.bool))
        >>> concat_results([a, a]).corners.shape
        torch.Size([2, 2, 4, 2])
    """
    cameras = [getattr(p, "camera", None) for p in parts]
    if all(isinstance(c, Camera) for c in cameras) and len({m for c in cameras for m in c.models}) > 1:
        width = max(p.std_dist.shape[-1] for p in parts)
        parts = [_pad(p, width) if p.std_dist.shape[-1] < width else p for p in parts]
    first = parts[0]
    values = {}
    for f in fields(first):
        vs = [getattr(p, f.name) for p in parts]
        if all(isinstance(v, Camera) for v in vs):
            values[f.name] = Camera.cat(vs)
        elif all(isinstance(v, torch.Tensor) and v.dim() > 0 for v in vs):
            values[f.name] = torch.cat([v.to(vs[0].device) for v in vs])
        else:
            values[f.name] = vs[0]
    return type(first)(**values)


@dataclass
class PipelineResult:
    """Detections and calibration of ``C`` cameras (the camera dimension is absent for one camera's views: then
    the per-camera lists below hold that camera's entry).

    The pipeline's stages and looks do not change a result in place: each returns a new one with its fields set
    (``dataclasses.replace``), but for the boards a look finds, written into ``detections``
    (:meth:`~ccs_kornia.modules.detection.base.DetectionResult.fill`).

    Attributes:
        detections: corners :math:`(C, V, N, 2)` in the original images (zeros where not found), found
            :math:`(C, V)`; ``reasons`` per view, flattened camera-major.
        calibration: the solver's :class:`~ccs_kornia.modules.calibration.result.CalibrationResult` per camera
            (``None`` when the run stopped after detection).
        image_size: ``(W, H)`` per camera (the size most of its views with a board have).
        present: :math:`(C, V)` bool, the view exists and could be read (views are padded to the largest camera).
        view_sizes: :math:`(C, V, 2)` long, ``(W, H)`` of each view (0 where not read); views within
            :data:`~ccs_kornia.pipeline.calibration_pipeline.SIZE_TOLERANCE_PX` of ``image_size`` are used.
        correction: :math:`(C, 5)` the lens correction per camera (the network's pooled prediction, or the re-fitted
            one where the corrected-frame calibration was kept); ``None`` when distortion correction is off.
        correction_tried: :math:`(C,)` bool, the corrected-frame calibration competed (the pooled correction is
            large).
        corrected: :math:`(C,)` bool, the corrected-frame calibration was kept.
        straightness: :math:`(C, 2)` median row/column RMS (px) of the detected boards before and after the
            network's correction.
        view_corrections: :math:`(C, V, 5)` the network's correction of each view (``None`` when it is off).
        camera_reasons: per camera, why it was not calibrated (empty string where it was).
        diagnostics: per camera, the quality figures of the calibration (see ``docs/diagnostics.md``) or ``None``.
        model_selection: with ``model="auto"``, per camera the choice and its figures (see
            :class:`~ccs_kornia.modules.calibration.model_selection.ModelSelection`); else ``None``.
        board_flatness: where the pipeline judged the board's sag, per camera what it found
            (:meth:`~ccs_kornia.modules.calibration.board_flatness.BoardWarpChoice.record`; ``None`` for a camera not
            judged); else ``None``.
        centre_bias: for a circle grid, :math:`(C, V, N, 2)` the offset of each dot's image's centre from the image of
            its centre under the solved camera, already subtracted from ``detections.corners`` (the measured centres
            are their sum; :mod:`~ccs_kornia.modules.detection.circles.centre_bias`); else ``None``.
        frame_choice: with a frame selection, per camera which views it kept and why not the others
            (:class:`~ccs_kornia.pipeline.frame_selection.FrameChoice`; ``None`` for a camera it did not judge); else
            ``None``.
    """

    detections: DetectionResult
    calibration: CalibrationResult | None
    image_size: list[tuple[int, int]] | tuple[int, int]
    present: torch.Tensor
    view_sizes: torch.Tensor | None = None
    correction: torch.Tensor | None = None
    correction_tried: torch.Tensor | None = None
    corrected: torch.Tensor | None = None
    straightness: torch.Tensor | None = None
    view_corrections: torch.Tensor | None = None
    camera_reasons: list[str] | str = field(default_factory=list)
    diagnostics: list[dict | None] | dict | None = None
    model_selection: list[dict | None] | dict | None = None
    frame_choice: list[Any] | Any = None
    board_flatness: list[dict | None] | dict | None = None
    centre_bias: torch.Tensor | None = None

    @property
    def batched(self) -> bool:
        """Whether the camera dimension is present."""
        return self.present.dim() == 2

    @property
    def same_size_views(self) -> torch.Tensor:
        """:math:`(C, V)` / :math:`(V,)` bool: the view was read and its size is within
        :data:`~ccs_kornia.pipeline.sources.SIZE_TOLERANCE_PX` of its camera's ``image_size``.

        Example:
            >>> d = DetectionResult(torch.zeros(1, 3, 4, 2), torch.tensor([[True, True, False]]))
            >>> r = PipelineResult(d, None, [(64, 48)], torch.ones(1, 3, dtype=torch.bool),
            ...                    torch.tensor([[[64, 48], [32, 24], [64, 48]]]), camera_reasons=[""])
            >>> r.same_size_views.tolist(), r.usable_views.tolist(), r.select(0).usable_views.tolist()
            ([[True, False, True]], [[True, False, False]], [True, False, False])
        """
        main = torch.tensor(self.image_size, device=self.view_sizes.device)
        main = main.view(-1, 1, 2) if self.batched else main
        return self.present & ((self.view_sizes - main).abs() <= SIZE_TOLERANCE_PX).all(-1)

    @property
    def usable_views(self) -> torch.Tensor:
        """:math:`(C, V)` / :math:`(V,)` bool: the views a solve takes, a board found on an image of its camera's
        size (:attr:`same_size_views`)."""
        return self.detections.found & self.same_size_views

    def select(self, cameras: int | Sequence[int] | torch.Tensor) -> PipelineResult:
        """The result of some cameras: an ``int`` gives one camera without the camera dimension.

        Example:
            >>> d = DetectionResult(torch.zeros(2, 3, 4, 2), torch.zeros(2, 3, dtype=torch.bool), [""] * 6)
            >>> r = PipelineResult(d, None, [(64, 48), (32, 24)], torch.ones(2, 3, dtype=torch.bool),
            ...                    camera_reasons=["a", "b"])
            >>> one = r.select(1)
            >>> one.detections.corners.shape, one.image_size, one.camera_reasons, one.batched
            (torch.Size([3, 4, 2]), (32, 24), 'b', False)
        """
        if not self.batched:
            raise ValueError("select() needs a batched result (cameras first).")
        single = isinstance(cameras, int)
        idx = cameras if single else torch.as_tensor(list(cameras) if not isinstance(cameras, torch.Tensor)
                                                     else cameras, dtype=torch.long)
        picks = [idx] if single else idx.tolist()
        v = self.present.shape[1]
        reasons = self.detections.reasons
        if reasons is not None:
            per = [reasons[c * v:(c + 1) * v] for c in picks]
            reasons = [r for p in per for r in p]
        det = replace(select_result(self.detections, idx), reasons=reasons)
        pick = (lambda seq: seq[idx]) if single else (lambda seq: [seq[c] for c in picks])
        return PipelineResult(
            detections=det,
            calibration=None if self.calibration is None else select_result(self.calibration, idx),
            image_size=pick(self.image_size),
            present=_index(self.present, idx),
            view_sizes=_index(self.view_sizes, idx),
            correction=_index(self.correction, idx),
            correction_tried=_index(self.correction_tried, idx),
            corrected=_index(self.corrected, idx),
            straightness=_index(self.straightness, idx),
            view_corrections=_index(self.view_corrections, idx),
            camera_reasons=pick(self.camera_reasons),
            diagnostics=None if self.diagnostics is None else pick(self.diagnostics),
            model_selection=None if self.model_selection is None else pick(self.model_selection),
            frame_choice=None if self.frame_choice is None else pick(self.frame_choice),
            board_flatness=None if self.board_flatness is None else pick(self.board_flatness),
            centre_bias=_index(self.centre_bias, idx),
        )

    @classmethod
    def from_detections(
        cls,
        corners: torch.Tensor,
        found: torch.Tensor,
        image_size: tuple[int, int],
        view_corrections: torch.Tensor | None = None,
    ) -> PipelineResult:
        """A result holding corners detected elsewhere (another detector, a file), for the pipeline's remaining
        stages (:meth:`~ccs_kornia.pipeline.calibration_pipeline.CalibrationPipeline.finish`).

        Args:
            corners: :math:`(C, V, N, 2)`; found: :math:`(C, V)` bool; image_size: ``(W, H)`` of every view.
            view_corrections: optional :math:`(C, V, 5)` network corrections of the views.

        Example:
            >>> r = PipelineResult.from_detections(torch.zeros(2, 3, 12, 2), torch.ones(2, 3, dtype=torch.bool), (64, 48))
            >>> r.present.shape, r.image_size, r.view_sizes[0, 0].tolist()
            (torch.Size([2, 3]), [(64, 48), (64, 48)], [64, 48])
        """
        check_tensor(corners, "corners", ["C", "V", "N", "2"])
        check_tensor(found, "found", corners.shape[:2])
        c, v = found.shape
        size = (int(image_size[0]), int(image_size[1]))
        sizes = torch.tensor(size, device=corners.device).expand(c, v, 2).clone()
        det = DetectionResult(corners.double(), found.bool(), ["" if f else "board not found" for f in
                                                               found.reshape(-1).tolist()])
        return cls(det, None, [size] * c, torch.ones(c, v, dtype=torch.bool, device=corners.device), sizes,
                   view_corrections=view_corrections, camera_reasons=[""] * c)

    def take_views(self, cameras: torch.Tensor, views: torch.Tensor) -> PipelineResult:
        """New cameras made of views of these ones, before the correction and solver stages (e.g. benchmark trials
        drawing subsets of a camera's views): trial ``t`` holds views ``views[t]`` of camera ``cameras[t]``.

        Args:
            cameras: :math:`(T,)` long; views: :math:`(T, V')` long.

        Returns:
            A batched result of ``T`` cameras with detections, sizes and per-view corrections only.

        Example:
            >>> d = DetectionResult(torch.zeros(2, 4, 6, 2), torch.ones(2, 4, dtype=torch.bool), [""] * 8)
            >>> r = PipelineResult(d, None, [(64, 48), (64, 48)], torch.ones(2, 4, dtype=torch.bool),
            ...                    torch.full((2, 4, 2), 48), camera_reasons=["", ""])
            >>> t = r.take_views(torch.tensor([1, 1, 0]), torch.tensor([[0, 2], [1, 3], [0, 1]]))
            >>> t.detections.corners.shape, t.present.shape, t.image_size
            (torch.Size([3, 2, 6, 2]), torch.Size([3, 2]), [(64, 48), (64, 48), (64, 48)])
        """
        if not self.batched:
            raise ValueError("take_views() needs a batched result (cameras first).")
        cam = torch.as_tensor(cameras, dtype=torch.long)
        view = torch.as_tensor(views, dtype=torch.long)
        check_tensor(cam, "cameras", ["T"])
        check_tensor(view, "views", ["T", "V'"], T=cam.shape[0])
        v = self.present.shape[1]

        def per_view(x):
            return None if x is None else x[cam.to(x.device)[:, None], view.to(x.device)]

        reasons = self.detections.reasons
        if reasons is not None:
            reasons = [reasons[int(c) * v + int(k)] for c, row in zip(cam.tolist(), view.tolist()) for k in row]
        measured = self.detections.corners if self.centre_bias is None else self.detections.corners + self.centre_bias
        det = DetectionResult(per_view(measured), per_view(self.detections.found), reasons,
                              per_view(self.detections.sigma))
        return PipelineResult(det, None, [self.image_size[int(c)] for c in cam.tolist()], per_view(self.present),
                              per_view(self.view_sizes), view_corrections=per_view(self.view_corrections),
                              camera_reasons=[""] * cam.shape[0])

    # shortcuts to the values most callers want
    @property
    def camera(self) -> Camera:
        """The calibrated cameras (:class:`~ccs_kornia.geometry.camera.Camera`; one camera for an unbatched result)."""
        return self.calibration.camera

    @property
    def K(self) -> torch.Tensor:
        """Camera matrices :math:`(3, 3)` / :math:`(C, 3, 3)` (NaN where the calibration failed)."""
        return self.calibration.K

    @property
    def dist(self) -> torch.Tensor:
        """Distortion coefficients in OpenCV order :math:`(D,)` / :math:`(C, D)`."""
        return self.calibration.dist

    @property
    def rvec(self) -> torch.Tensor:
        """World-to-camera rotations (axis-angle) :math:`(V, 3)` / :math:`(C, V, 3)`."""
        return self.calibration.rvec

    @property
    def tvec(self) -> torch.Tensor:
        """World-to-camera translations :math:`(V, 3)` / :math:`(C, V, 3)` in units of ``square``."""
        return self.calibration.tvec

    @property
    def view_rms(self) -> torch.Tensor:
        """Per-view RMS reprojection error in px :math:`(V,)` / :math:`(C, V)`, NaN for unused views."""
        return self.calibration.view_rms

    @property
    def used(self) -> torch.Tensor:
        """Views used by the final refinement :math:`(V,)` / :math:`(C, V)` bool."""
        return self.calibration.used

    @property
    def found(self) -> torch.Tensor:
        """Views where the board was detected :math:`(V,)` / :math:`(C, V)` bool."""
        return self.detections.found

    @property
    def rms(self) -> torch.Tensor:
        """Overall RMS reprojection error in px, scalar / :math:`(C,)`."""
        return self.calibration.rms

    @property
    def success(self) -> torch.Tensor:
        """Whether each camera was calibrated, bool scalar / :math:`(C,)`."""
        return self.calibration.success

    @property
    def std(self) -> torch.Tensor:
        """Standard deviations of ``(fx, fy, cx, cy, *dist)`` :math:`(4 + D,)` / :math:`(C, 4 + D)`."""
        return torch.cat([self.calibration.std_intrinsics, self.calibration.std_dist], -1)

def main_size(sizes: torch.Tensor, found: torch.Tensor, present: torch.Tensor) -> tuple[int, int]:
    """The image size of a camera: the most common among views with a board (else among readable views)."""
    pick = found if bool(found.any()) else present
    counts = Counter(tuple(int(x) for x in s) for s in sizes[pick].tolist())
    return max(counts, key=lambda k: counts[k]) if counts else (0, 0)


def scatter_cameras(part: CalibrationResult, index: torch.Tensor, like: CalibrationResult) -> CalibrationResult:
    """``like`` with the cameras ``index`` replaced by ``part``'s (tensor fields of equal trailing shapes; the cameras
    of ``part`` have the models of ``like``'s at ``index``)."""
    values = {}
    for key, value in like.__dict__.items():
        new = getattr(part, key)
        if isinstance(value, Camera):
            params = value.params.clone()
            params[index.to(params.device), : new.params.shape[-1]] = new.params.to(params)
            value = value.with_params(params)
        elif isinstance(value, torch.Tensor) and isinstance(new, torch.Tensor) and value.shape[1:] == new.shape[1:]:
            value = value.clone()
            value[index.to(value.device)] = new.to(value)
        values[key] = value
    return type(like)(**values)


def positive_size(size: tuple[int, int]) -> tuple[int, int]:
    """A camera none of whose views could be read has size (0, 0); the stages need a positive one (its views are
    all masked)."""
    return max(1, int(size[0])), max(1, int(size[1]))


def camera_reason(calib: CalibrationResult, c: int, usable: int, present: int) -> str:
    """Why camera ``c`` was not calibrated ('' where it was)."""
    if bool(calib.success[c]):
        return ""
    if present == 0:
        return "no readable image"
    if usable < 3:
        return f"board found in {usable} of {present} readable views; at least 3 are needed"
    issues = calib.issues()[c] if hasattr(calib, "issues") else []
    errors = [i["message"] for i in issues if i.get("severity") == "error"]
    if errors:
        return "; ".join(errors)
    codes = Counter(VIEW_REASONS.get(int(k), "not used") for k in calib.view_reason[c].tolist())
    detail = ", ".join(f"{n} {why}" for why, n in codes.most_common())
    return f"calibration failed on {usable} views ({detail})"


def module_device(module: torch.nn.Module) -> torch.device:
    """The device of a module's first parameter (or buffer); CPU for a module without either."""
    for p in module.parameters():
        return p.device
    for b in module.buffers():
        return b.device
    return torch.device("cpu")
