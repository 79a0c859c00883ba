"""Views whose corners were detected before: the corners files ``detect`` writes as the pipeline's source.

A :class:`CornersSource` holds one :class:`~ccs_kornia.io.corners_file.CornersFile` per camera. It has no images to
give: it gives the first look's result instead (:meth:`CornersSource.given_detections`), the corners, which views had
a board, each view's size, the corners' measured precision and the network's lens correction as the file holds them.
:meth:`~ccs_kornia.pipeline.calibration_pipeline.CalibrationPipeline.run` starts from that result as from its own first
look: the correction judged, the cameras solved, the model chosen, the frame selection and the diagnostics, as on
images; only the looks at missed views, which need the images, have nothing to look at.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch

from ccs_kornia.io.corners_file import CornersFile
from ccs_kornia.modules.detection.base import DetectionResult
from ccs_kornia.pipeline.frame_matching import FrameTable, match_by_time, match_frames
from ccs_kornia.pipeline.result import PipelineResult
from ccs_kornia.pipeline.sources import ViewSource

__all__ = ["NO_IMAGE", "CornersSource", "match_given_views"]

#: why a view of a corners file cannot be loaded
NO_IMAGE = "no image: its corners were given"


class CornersSource(ViewSource):
    """The views of corners files, one file per camera (module docstring).

    Args:
        files: one :class:`~ccs_kornia.io.corners_file.CornersFile` per camera.
        names: a name per camera (default ``camera0``, ...).
        image_size: ``(W, H)`` of every camera's images where the files do not say it (``None``: the files' own).

    Raises:
        ValueError: a camera's image size is known neither from its file nor from ``image_size``.

    Example:
        >>> from ccs_kornia.io.corners_file import CornersView
        >>> corners = torch.rand(12, 2, dtype=torch.float64) * 50
        >>> views = [CornersView(f"v{k}.png", True, corners, timestamp=0.1 * k) for k in range(3)]
        >>> src = CornersSource([CornersFile("c.json", (4, 3), views)], image_size=(64, 48))
        >>> out = src.given_detections((4, 3))
        >>> out.detections.corners.shape, out.image_size, src.describe(0, 2), src.timestamp(0, 1)
        (torch.Size([1, 3, 12, 2]), [(64, 48)], 'v2.png', 0.1)
    """

    def __init__(self, files: Sequence[CornersFile], names: Sequence[str] | None = None,
                 image_size: tuple[int, int] | None = None) -> None:
        self.files = list(files)
        self.sizes = []
        for f in self.files:
            size = f.image_size if f.image_size is not None else image_size
            if size is None:
                raise ValueError(f"{f.path} does not say the images' size.")
            self.sizes.append((int(size[0]), int(size[1])))
        super().__init__([len(f.views) for f in self.files], names)

    def describe(self, camera: int, view: int) -> str:
        return self.files[camera].views[view].path

    def timestamp(self, camera: int, view: int) -> float | None:
        """The view's time (s) where the file gives one."""
        return self.files[camera].views[view].timestamp

    def _load(self, camera: int, view: int) -> tuple[torch.Tensor | None, str]:
        return None, NO_IMAGE

    def given_detections(self, board_size: tuple[int, int], device: torch.device | str = "cpu") -> PipelineResult:
        """The files' corners as the first look's batched result: corners :math:`(C, V, N, 2)` (NaN where not seen,
        zeros where no board), found, the views read and their sizes, each view's reason, the corners' precision
        (``sigma``, where every file gives one), and the network's lens correction per camera (where every file gives
        one; ``correction_tried`` left for the pipeline to judge).

        Raises:
            ValueError: a file's board is not ``board_size``.
        """
        cols, rows = board_size
        n = cols * rows
        c, v = self.num_cameras, self.max_views
        for f in self.files:
            if f.board[0] * f.board[1] != n:
                raise ValueError(f"{f.path} holds the corners of a {f.board[0]}x{f.board[1]} board, not {cols}x{rows}.")
        corners = torch.zeros(c, v, n, 2, dtype=torch.float64)
        found = torch.zeros(c, v, dtype=torch.bool)
        present = torch.zeros(c, v, dtype=torch.bool)
        sizes = torch.zeros(c, v, 2, dtype=torch.long)
        weighed = all(any(view.sigma is not None for view in f.views) for f in self.files)
        sigma = torch.full((c, v, n), float("nan"), dtype=torch.float32) if weighed else None
        reasons = [[""] * v for _ in range(c)]
        for ci, f in enumerate(self.files):
            for vi, view in enumerate(f.views):
                present[ci, vi] = view.readable
                reasons[ci][vi] = view.reason or ("" if view.found else "board not found")
                if not view.readable:
                    continue
                sizes[ci, vi] = torch.tensor(view.image_size or self.sizes[ci])
                if view.found:
                    corners[ci, vi], found[ci, vi] = view.corners, True
                    if sigma is not None and view.sigma is not None:
                        sigma[ci, vi] = view.sigma.to(torch.float32)
        correction = None
        if all(f.correction is not None for f in self.files):
            correction = torch.stack([f.correction for f in self.files])
        device = torch.device(device)
        return PipelineResult(
            DetectionResult(corners.to(device), found.to(device), [r for rs in reasons for r in rs],
                            None if sigma is None else sigma.to(device)),
            None, list(self.sizes), present.to(device), sizes.to(device),
            correction=None if correction is None else correction.to(device), camera_reasons=[""] * c)


def match_given_views(source: CornersSource, tolerance: float | None = None) -> FrameTable:
    """The views of a rig's corners files matched into frames as the rig matches its frames: by timestamp where every
    view has one (:func:`~ccs_kornia.pipeline.frame_matching.match_by_time`, within ``tolerance`` s, by default half
    the shortest median step between a camera's views), else by the last number in the views' names
    (:func:`~ccs_kornia.pipeline.frame_matching.match_frames`).

    Raises:
        ValueError: the views have timestamps but no two cameras have views within the tolerance (one line).

    Example:
        >>> from ccs_kornia.io.corners_file import CornersView
        >>> nan = torch.full((4, 2), float("nan"), dtype=torch.float64)
        >>> cams = [[CornersView(f"c{c}.mp4#{k}", False, nan, timestamp=0.1 * k + 0.004 * c) for k in range(3)]
        ...         for c in range(2)]
        >>> src = CornersSource([CornersFile(f"c{c}.json", (2, 2), v, (64, 48)) for c, v in enumerate(cams)])
        >>> match_given_views(src).index
        [[0, 1, 2], [0, 1, 2]]
    """
    times = [[v.timestamp for v in f.views] for f in source.files]
    if not all(t is not None for row in times for t in row):
        return match_frames([[v.path for v in f.views] for f in source.files])
    if tolerance is None:
        steps = []
        for row in times:
            gaps = sorted(b - a for a, b in zip(sorted(row), sorted(row)[1:]) if b > a)
            if gaps:
                steps.append(gaps[len(gaps) // 2])
        tolerance = 0.5 * min(steps) if steps else 1.0 / 60.0
    table = match_by_time(times, float(tolerance))
    if not any(sum(row[f] is not None for row in table.index) > 1 for f in range(table.num_frames)):
        spans = ", ".join(f"{f.path} {min(t):.2f}-{max(t):.2f} s" for f, t in zip(source.files, times) if t)
        raise ValueError(f"no two corners files have views within {tolerance:.4g} s of each other ({spans}): the "
                         "recordings do not overlap in time; a larger --sync-tolerance pairs views further apart")
    return table
