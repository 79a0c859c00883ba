r"""Guided capture of a rig: which instants to keep when several cameras look at one board, and which cameras still
need views in common.

:class:`RigCapture` holds one :class:`~ccs_kornia.pipeline.guided_capture.GuidedCapture` per camera and is shown the
cameras' frames of one instant together (:meth:`RigCapture.offer`). An instant is **kept** when

1. a camera keeps its frame (its own gates: board seen, still, new, lowering its predicted uncertainty, corners
   found), or
2. the rig is not yet linked and the instant gives a **view in common** to the pair of cameras that the guidance asks
   for (both see the board still, and the view is not a near copy of that pair's earlier ones).

A kept instant is kept for every camera (``calibrate-rig`` reads the cameras' frames of one instant by their common
name), and each camera that sees the board still at it takes its corners too. The rig is **linked** when the pairs
with at least ``min_common`` views in common connect every camera (the rig's extrinsics are chained through them), and
the capture is **done** when it is linked and every camera has reached its target (or at ``max_frames`` instants).
Nothing here reads a camera or writes a file: the ``capture`` command does.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import torch

from ccs_kornia.modules.calibration.quality.next_pose import PoseSuggestion
from ccs_kornia.pipeline.frame_selection import near_copies
from ccs_kornia.pipeline.guided_capture import CaptureDecision, GuidedCapture

__all__ = ["MIN_COMMON", "KeptInstant", "RigCapture", "RigDecision"]

#: views in common that link two cameras (a rig's pair)
MIN_COMMON = 5


@dataclass
class KeptInstant:
    """An instant kept: its index and time, the cameras whose corners were taken at it, and why it was kept."""

    index: int
    timestamp: float
    cameras: tuple[int, ...]
    why: str


@dataclass
class RigDecision:
    """What :meth:`RigCapture.offer` made of one instant: kept or not and why, each camera's decision, done."""

    kept: bool
    reason: str
    decisions: list[CaptureDecision]
    done: bool


def _still(decision: CaptureDecision) -> bool:
    """The camera sees the board, not moving (its other gates aside)."""
    return decision.sighting.found and not decision.reason.startswith(("moving", "no pose", "no board"))


@dataclass
class RigCapture:
    """The live capture of a rig (module docstring).

    Args:
        cameras: one :class:`GuidedCapture` per camera, in the rig's order.
        min_common: views in common that link a pair (:data:`MIN_COMMON`).
        max_frames: instants kept at most (done at that count).

    Example:
        >>> rig = RigCapture([], min_common=2)
        >>> rig.common_views().shape, rig.linked()
        ((0, 0), True)
    """

    cameras: list[GuidedCapture]
    min_common: int = MIN_COMMON
    max_frames: int = 40
    kept: list[KeptInstant] = field(default_factory=list)

    def common_views(self) -> np.ndarray:
        """:math:`(C, C)` int: per pair of cameras, the kept instants at which both took corners."""
        C = len(self.cameras)
        counts = np.zeros((C, C), np.int64)
        for instant in self.kept:
            for a in instant.cameras:
                for b in instant.cameras:
                    counts[a, b] += a != b
        return counts

    def _linked_from_zero(self) -> set[int]:
        """The cameras linked to camera 0 through pairs of at least ``min_common`` views in common."""
        if not self.cameras:
            return set()
        links = self.common_views() >= self.min_common
        reached, frontier = {0}, [0]
        while frontier:
            a = frontier.pop()
            for b in np.nonzero(links[a])[0].tolist():
                if b not in reached:
                    reached.add(b)
                    frontier.append(b)
        return reached

    def linked(self) -> bool:
        """Every camera is linked to camera 0 through pairs of at least ``min_common`` views in common."""
        return len(self._linked_from_zero()) == len(self.cameras)

    def needed_pair(self) -> tuple[int, int, int] | None:
        """``(a, b, views in common)``: the pair that would link a camera not yet linked (the one with the most views
        in common already), or ``None`` once the rig is linked."""
        reached = self._linked_from_zero()
        if len(reached) == len(self.cameras):
            return None
        counts = self.common_views()
        pairs = [(int(counts[a, b]), a, b) for a in sorted(reached) for b in range(len(self.cameras))
                 if b not in reached]
        count, a, b = max(pairs, key=lambda p: (p[0], -p[1], -p[2]))  # ties: the lower cameras
        return a, b, count

    @property
    def done(self) -> bool:
        return len(self.kept) >= self.max_frames or (
            self.linked() and all(c.done or c.worst_px <= c.target for c in self.cameras))

    def _new_for_pair(self, a: int, b: int, outline: np.ndarray) -> bool:
        """Camera ``a``'s view of the board is not a near copy of the pair's views in common so far."""
        together = {i.index for i in self.kept if a in i.cameras and b in i.cameras}
        before = [k.outline for k in self.cameras[a].kept if k.index in together]
        if not before:
            return True
        outlines = torch.as_tensor(np.stack(before + [outline]))
        copies = near_copies(outlines, torch.ones(outlines.shape[:2], dtype=torch.bool),
                             self.cameras[a].min_change)[-1]
        return not bool(copies.any())

    def offer(self, frames: list[np.ndarray], index: int, timestamp: float) -> RigDecision:
        """Look at the cameras' frames of one instant (grey ``uint8``, in the rig's order) and keep it or say why
        not."""
        if len(frames) != len(self.cameras):
            raise ValueError(f"{len(frames)} frames for {len(self.cameras)} cameras")
        need = self.needed_pair()
        decisions = [cam.offer(frame, index, timestamp) for cam, frame in zip(self.cameras, frames)]
        keepers = [c for c, d in enumerate(decisions) if d.kept]
        if keepers:
            why = "; ".join(f"camera {c}: {decisions[c].reason}" for c in keepers)
        elif need is not None and _still(decisions[need[0]]) and _still(decisions[need[1]]) and \
                self._new_for_pair(need[0], need[1], decisions[need[0]].sighting.outline):
            why = f"a view cameras {need[0]} and {need[1]} share ({need[2] + 1} of {self.min_common})"
        else:
            reason = "; ".join(f"camera {c}: {d.reason}" for c, d in enumerate(decisions))
            return RigDecision(False, reason, decisions, self.done)
        taken = list(keepers)
        for c, decision in enumerate(decisions):
            if c not in keepers and _still(decision):
                late = self.cameras[c].keep_now(frames[c], index, timestamp, why=f"seen at an instant kept ({why})")
                if late.kept:
                    decisions[c] = late
                    taken.append(c)
        self.kept.append(KeptInstant(index, timestamp, tuple(sorted(taken)), why))
        return RigDecision(True, why, decisions, self.done)

    def undo(self) -> KeptInstant | None:
        """Drop the last kept instant, from every camera that took it."""
        if not self.kept:
            return None
        instant = self.kept.pop()
        for c in instant.cameras:
            if self.cameras[c].kept and self.cameras[c].kept[-1].index == instant.index:
                self.cameras[c].undo()
        return instant

    def common_needed(self, camera: int) -> str:
        """What ``camera`` still needs of the rig, in words: the camera it needs views in common with and how many
        it has (``"views in common with camera 1 (2 of 5)"``) where it is one of the pair :meth:`needed_pair` asks
        for once a view is kept, else ``""``."""
        need = self.needed_pair()
        if need is None or not any(c.kept for c in self.cameras) or camera not in need[:2]:
            return ""
        other = need[1] if camera == need[0] else need[0]
        return f"views in common with camera {other} ({need[2]} of {self.min_common})"

    def waiting(self) -> list[int]:
        """The cameras with kept frames that have not yet reached their target."""
        return [c for c, cam in enumerate(self.cameras) if cam.kept and not (cam.done or cam.worst_px <= cam.target)]

    def suggestions(self, fills: list[float | None] | None = None) -> list[PoseSuggestion | None]:
        """Each camera's next best pose (:meth:`GuidedCapture.suggestion`, ``fills`` the boards' fill now), ``None``
        for a camera with no kept frame or at its target: what the page draws on every camera."""
        waiting = set(self.waiting())
        return [self.cameras[c].suggestion(None if fills is None else fills[c]) if c in waiting else None
                for c in range(len(self.cameras))]

    def instruction(self, fills: list[float | None] | None = None,
                    suggestions: list[PoseSuggestion | None] | None = None) -> str:
        """The next thing to do, in one line: the pair that needs views in common, else the camera furthest from its
        target and its next pose (``suggestions``: :meth:`suggestions` already ranked, else that camera's is)."""
        need = self.needed_pair()
        if need is not None and any(c.kept for c in self.cameras):
            a, b, count = need
            return (f"cameras {a} and {b} need views in common ({count} of {self.min_common}): hold the board where "
                    "both see it")
        waiting = self.waiting()
        if not waiting:
            return "" if self.done else "show the board to every camera"
        c = max(waiting, key=lambda k: self.cameras[k].worst_px)
        if suggestions is not None and suggestions[c] is not None:
            best = suggestions[c]
        else:
            best = self.cameras[c].suggestion(None if fills is None else fills[c])
        return f"camera {c}: {best.instruction}" if best.instruction else ""
