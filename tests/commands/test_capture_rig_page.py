"""A rig's capture page: every camera's frame annotated as one camera's page is, its next best pose's outline drawn,
and the cameras that still need views in common named on their frames."""

from __future__ import annotations

import math

import numpy as np
import torch

from ccs_kornia.commands._capture_rig import rig_view
from ccs_kornia.geometry.board_points import board_object_points
from ccs_kornia.geometry.models import K1K2
from ccs_kornia.modules.detection.screening import Sighting
from ccs_kornia.pipeline.guided_capture import CaptureDecision, GuidedCapture, KeptFrame
from ccs_kornia.pipeline.rig_capture import KeptInstant, RigCapture

ORANGE = (0, 165, 255)  # the suggested pose's outline (BGR), as on one camera's page


def _rig() -> RigCapture:
    """Two 320x240 cameras, each with one kept view, one of them in common."""
    obj = board_object_points(6, 4, 0.025, dtype=torch.float64)
    cams = [GuidedCapture((6, 4), obj, (320, 240), detect=lambda gray: None, live_model=K1K2) for _ in range(2)]
    quad = np.array([[100.0, 80.0], [220.0, 80.0], [220.0, 160.0], [100.0, 160.0]])
    for cam in cams:
        cam.kept.append(KeptFrame(0, 0.0, np.zeros((24, 2)), quad, "the first view"))
    rig = RigCapture(cams)
    rig.kept.append(KeptInstant(0, 0.0, (0, 1), "camera 0: the first view"))
    return rig


def test_the_rig_page_draws_every_cameras_next_pose_and_names_the_pair():
    rig = _rig()
    assert rig.common_needed(0) == "views in common with camera 1 (1 of 5)"
    assert rig.common_needed(1) == "views in common with camera 0 (1 of 5)"
    fills = [0.4, 0.4]
    suggestions = rig.suggestions(fills)
    assert all(s is not None and len(s.poses) for s in suggestions)
    assert rig.instruction(fills, suggestions).startswith("cameras 0 and 1 need views in common (1 of 5)")
    nothing = CaptureDecision(False, "no board", Sighting(False), math.inf, False)
    decision = type("Decision", (), {"decisions": [nothing, nothing]})()
    frames = [np.full((240, 320), 90, np.uint8)] * 2
    image = rig_view(frames, rig, decision, {"suggestions": suggestions, "maps": [None, None]}, 0.1)
    assert image.shape == (240, 640, 3)
    for c, best in enumerate(suggestions):  # each camera's outline on its own half of the page's image
        for x, y in np.round(best.poses.outline[0].numpy()).astype(int):
            assert tuple(int(v) for v in image[y, 320 * c + x]) == ORANGE
    bare = rig_view(frames, rig, decision, {}, 0.1)  # nothing suggested: no outline
    assert not (bare == np.array(ORANGE, np.uint8)).all(-1).any()


def test_a_camera_at_its_target_or_without_a_view_gets_no_suggestion():
    rig = _rig()
    rig.cameras[1].worst_px = 0.05  # at its target (0.1)
    rig.cameras[0].kept.clear()
    assert rig.waiting() == [] and rig.suggestions() == [None, None]
