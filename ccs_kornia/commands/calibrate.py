"""``ccs_kornia calibrate``: one camera from chessboard images (JSON, optional OpenCV YAML and report)."""

from __future__ import annotations

import argparse

from ccs_kornia.commands._one_camera import calibrate_camera

__all__ = ["run"]


def run(args: argparse.Namespace) -> int:
    return calibrate_camera(args)
