"""Detectors by name (``"opencv"``, ``"learned"``), for the command line and the pipeline."""

from __future__ import annotations

from ccs_kornia.modules.detection.base import ChessboardDetector

__all__ = ["DETECTORS", "make_detector"]

#: detector names accepted by :func:`make_detector`
DETECTORS: tuple[str, ...] = ("opencv", "learned")


def make_detector(name: str = "learned", **kwargs) -> ChessboardDetector:
    """Build a detector by name.

    Args:
        name: ``"opencv"`` (classic + SB fallback) or ``"learned"`` (heatmap network; needs its
            module and shipped weights).
        kwargs: passed to the detector's constructor.

    Raises:
        ValueError: unknown name, or the learned detector is not available.

    Example:
        >>> type(make_detector("opencv")).__name__
        'OpenCVChessboardDetector'
    """
    if name == "opencv":
        from ccs_kornia.modules.detection.opencv_detector import (
            OpenCVChessboardDetector,
        )

        return OpenCVChessboardDetector(**kwargs)
    if name == "learned":
        try:
            from ccs_kornia.modules.detection.learned.learned_detector import (
                LearnedChessboardDetector,
            )
        except ImportError as err:
            raise ValueError(f"learned detector not available yet ({err}); use --detector opencv") from err
        try:
            return LearnedChessboardDetector(**kwargs)
        except FileNotFoundError as err:
            raise ValueError(f"learned detector weights not available ({err}); use --detector opencv") from err
    raise ValueError(f"unknown detector {name!r}; expected one of {', '.join(DETECTORS)}")
