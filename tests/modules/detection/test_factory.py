"""Tests of make_detector."""

from __future__ import annotations

import sys

import pytest

from ccs_kornia.modules.detection.factory import make_detector
from ccs_kornia.modules.detection.opencv_detector import OpenCVChessboardDetector


def test_make_detector(monkeypatch):
    assert isinstance(make_detector("opencv"), OpenCVChessboardDetector)
    with pytest.raises(ValueError, match="unknown detector"):
        make_detector("magic")
    monkeypatch.setitem(sys.modules, "ccs_kornia.modules.detection.learned.learned_detector", None)  # import fails
    with pytest.raises(ValueError, match="use --detector opencv"):
        make_detector("learned")
