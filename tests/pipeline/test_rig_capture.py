"""The rig's guided capture (``RigCapture``): instants kept for a camera's gain or for the view in common a pair needs,
every camera that sees the board still taking it, the pairs counted, the rig linked, undo; with scripted cameras."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import pytest

from ccs_kornia.modules.detection.screening import Sighting
from ccs_kornia.pipeline.guided_capture import CaptureDecision, KeptFrame
from ccs_kornia.pipeline.rig_capture import RigCapture


@dataclass
class ScriptedCamera:
    """A camera whose frames are scripts: ``"keep"`` (its gates pass), ``"still"`` (seen, adds little), ``"moving"``,
    ``"none"`` (no board); the outline moves with the instant so that instants are never near copies."""

    target: float = 0.1
    worst_px: float = math.inf
    min_change: float = 0.05
    done: bool = False
    kept: list = field(default_factory=list)

    def _sighting(self, script: str, index: int) -> Sighting:
        if script == "none":
            return Sighting(False)
        s = 40.0 * index
        return Sighting(True, np.array([[s, 0.0], [s + 30, 0.0], [s + 30, 20.0], [s, 20.0]]), 24)

    def offer(self, script: str, index: int, timestamp: float) -> CaptureDecision:
        seen = self._sighting(script, index)
        reason = {"keep": "gain", "still": "adds little (1 %)", "moving": "moving (900 px/s)", "none": "no board"}
        if script == "keep":
            self.kept.append(KeptFrame(index, timestamp, np.zeros((24, 2)), seen.outline, "gain"))
        return CaptureDecision(script == "keep", reason[script], seen, self.worst_px, self.done)

    def keep_now(self, script: str, index: int, timestamp: float, why: str = "") -> CaptureDecision:
        seen = self._sighting(script, index)
        self.kept.append(KeptFrame(index, timestamp, np.zeros((24, 2)), seen.outline, why))
        return CaptureDecision(True, why, seen, self.worst_px, self.done)

    def undo(self):
        return self.kept.pop()


def test_an_instant_a_camera_keeps_is_taken_by_every_camera_that_sees_the_board_still():
    rig = RigCapture([ScriptedCamera(), ScriptedCamera(), ScriptedCamera()], min_common=2)
    decision = rig.offer(["keep", "still", "moving"], 0, 0.0)
    assert decision.kept and decision.reason == "camera 0: gain"
    assert rig.kept[0].cameras == (0, 1)  # the moving camera's frame is saved, its corners not taken
    assert rig.common_views()[0, 1] == 1 and rig.common_views()[0, 2] == 0
    # no gain anywhere, but the pair the guidance asks for (0 and 1, one view so far) both see the board still
    assert rig.offer(["still", "still", "none"], 1, 0.1).reason == "a view cameras 0 and 1 share (2 of 2)"
    assert rig.needed_pair() == (0, 2, 0)  # camera 2 is the one left to link


def test_the_pair_that_links_the_rig_is_asked_for_and_kept():
    rig = RigCapture([ScriptedCamera(), ScriptedCamera()], min_common=2)
    assert rig.offer(["keep", "none"], 0, 0.0).kept
    assert rig.needed_pair() == (0, 1, 0) and "cameras 0 and 1 need views in common (0 of 2)" in rig.instruction()
    # neither camera gains, but both see the board still: a view the pair shares
    decision = rig.offer(["still", "still"], 1, 0.1)
    assert decision.kept and decision.reason == "a view cameras 0 and 1 share (1 of 2)"
    assert not rig.offer(["still", "moving"], 2, 0.2).kept  # one of them moving: nothing shared
    assert rig.offer(["still", "still"], 3, 0.3).kept and rig.linked() and rig.needed_pair() is None
    assert not rig.offer(["still", "still"], 4, 0.4).kept  # linked: no more views for the pair alone
    assert not rig.done
    for cam in rig.cameras:
        cam.done = True
    assert rig.done and rig.instruction() == ""


def test_undo_drops_the_instant_from_every_camera():
    rig = RigCapture([ScriptedCamera(), ScriptedCamera()], min_common=2)
    rig.offer(["keep", "none"], 0, 0.0)
    rig.offer(["keep", "still"], 1, 0.1)
    assert [len(c.kept) for c in rig.cameras] == [2, 1]
    gone = rig.undo()
    assert gone.index == 1 and [len(c.kept) for c in rig.cameras] == [1, 0] and len(rig.kept) == 1


def test_frames_of_another_count_are_refused():
    with pytest.raises(ValueError, match="1 frames for 2 cameras"):
        RigCapture([ScriptedCamera(), ScriptedCamera()]).offer(["keep"], 0, 0.0)
