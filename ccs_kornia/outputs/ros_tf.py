r"""Calibrated transforms as ROS loads them: a launch file of ``tf2_ros static_transform_publisher`` nodes.

Each transform is published in the quaternion form of the publisher's arguments (``x y z qx qy qz qw parent child``:
the child frame's pose in the parent frame, metres and a unit quaternion), with the ROS 2 command line of the same
transform in a comment. Hand-eye publishes the camera in its robot frame, camera-IMU each camera in the IMU's frame.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import torch

__all__ = ["StaticTransform", "pose_tq", "static_transform_launch"]


def pose_tq(T: torch.Tensor) -> dict[str, list[float]]:
    """``{"t": [x, y, z], "q": [qx, qy, qz, qw]}`` of a 4x4 rigid transform (``qw >= 0``).

    Example:
        >>> pose_tq(torch.eye(4, dtype=torch.float64))
        {'t': [0.0, 0.0, 0.0], 'q': [0.0, 0.0, 0.0, 1.0]}
    """
    from kornia.geometry.conversions import rotation_matrix_to_quaternion

    T = T.double()
    wxyz = rotation_matrix_to_quaternion(T[:3, :3].contiguous()[None], eps=1e-12)[0]
    wxyz = wxyz / wxyz.norm()
    if float(wxyz[0]) < 0:
        wxyz = -wxyz
    return {"t": [float(v) for v in T[:3, 3]], "q": [float(wxyz[1]), float(wxyz[2]), float(wxyz[3]), float(wxyz[0])]}


@dataclass
class StaticTransform:
    """One published transform: the child frame's pose in the parent frame (``t`` metres, ``q`` = qx, qy, qz, qw)
    and the publishing node's name."""

    t: Sequence[float]
    q: Sequence[float]
    parent: str
    child: str
    node: str


def static_transform_launch(transforms: Sequence[StaticTransform], comment: str) -> str:
    """A ROS 1 launch file publishing ``transforms``, ``comment`` (one line) and each one's ROS 2 command above them.

    Example:
        >>> tf = StaticTransform([0.1, 0.0, 0.05], [0.0, 0.0, 0.0, 1.0], "tool0", "camera", "broadcaster")
        >>> 'args="0.1 0 0.05 0 0 0 1 tool0 camera"' in static_transform_launch([tf], "a camera on a flange")
        True
    """
    lines = ["<launch>", f"  <!-- {comment}, metres and a unit quaternion (x y z qx qy qz qw)."]
    for tf in transforms:
        t, q = tf.t, tf.q
        lines.append(f"       ROS 2: ros2 run tf2_ros static_transform_publisher --x {t[0]:.9g} --y {t[1]:.9g} "
                     f"--z {t[2]:.9g} --qx {q[0]:.9g} --qy {q[1]:.9g} --qz {q[2]:.9g} --qw {q[3]:.9g} "
                     f"--frame-id {tf.parent} --child-frame-id {tf.child}")
    lines[-1] += " -->"
    for tf in transforms:
        nums = " ".join(f"{v:.9g}" for v in (*tf.t, *tf.q))
        lines += [f"  <node pkg=\"tf2_ros\" type=\"static_transform_publisher\" name=\"{tf.node}\"",
                  f"        args=\"{nums} {tf.parent} {tf.child}\" />"]
    return "\n".join(lines + ["</launch>"]) + "\n"
