r"""The robot's poses of a hand-eye data set, as users write them: one CSV row per image.

Each row holds the image's file name, then the flange's pose in the robot's base frame (``x_base = T x_flange``) in
one of three forms (:data:`POSE_FORMATS`):

* ``quat``: ``x, y, z, qx, qy, qz, qw`` (a unit quaternion, scalar last: ROS's and SciPy's order);
* ``quat-wxyz``: ``x, y, z, qw, qx, qy, qz`` (scalar first: Eigen's coefficients as written, ABB's and kornia's order);
* ``rotvec``: ``x, y, z, rx, ry, rz`` (a rotation vector in radians: UR's and ViSP's form);
* ``matrix``: the 16 numbers of the 4x4 matrix, row by row.

Translations are in metres or millimetres (``units``); poses come back in metres. A first line whose second field is
not a number is a header; blank lines and lines starting with ``#`` are skipped; commas, semicolons, tabs or spaces
separate the fields. ``auto`` takes the form from the count of numbers (7: ``quat``, 6 or 16).

:func:`match_poses` pairs the rows with the images by file name (the whole path, the file name, or the name without
its extension), never by order: an image without a row, or a row without an image, is reported, not shifted onto
its neighbour.
"""

from __future__ import annotations

import math
import os
import re
from dataclasses import dataclass

import numpy as np

from ccs_kornia.runtime.errors import UserError

__all__ = ["POSE_FORMATS", "POSE_UNITS", "RobotPoses", "match_poses", "parse_robot_poses", "read_robot_poses"]

#: the pose forms and their count of numbers
POSE_FORMATS: dict[str, int] = {"quat": 7, "quat-wxyz": 7, "rotvec": 6, "matrix": 16}
#: the form ``auto`` reads for each count of numbers
_AUTO_FORMATS: dict[int, str] = {7: "quat", 6: "rotvec", 16: "matrix"}
#: translation units and their size in metres
POSE_UNITS: dict[str, float] = {"m": 1.0, "mm": 1e-3}

_SPLIT = re.compile(r"\s*[,;\t]\s*|\s+")


@dataclass
class RobotPoses:
    """Robot poses by image name."""

    names: list[str]  #: the first field of each row
    poses: np.ndarray  #: (K, 4, 4) flange in base, metres
    lines: list[int]  #: each row's line number in the file
    format: str  #: the form read


def _number(text: str) -> float | None:
    try:
        value = float(text)
    except ValueError:
        return None
    return value


def _rotation(kind: str, r: np.ndarray) -> np.ndarray:
    """A rotation matrix from a rotation vector or a unit quaternion ``x, y, z, w`` (``quat``) or ``w, x, y, z``
    (``quat-wxyz``) (kornia's conversions)."""
    import torch
    from kornia.geometry.conversions import (
        axis_angle_to_rotation_matrix,
        quaternion_to_rotation_matrix,
    )

    t = torch.from_numpy(np.asarray(r, dtype=np.float64))[None]
    if kind == "rotvec":
        return axis_angle_to_rotation_matrix(t)[0].numpy()
    if kind == "quat-wxyz":
        return quaternion_to_rotation_matrix(t)[0].numpy()
    return quaternion_to_rotation_matrix(t[:, [3, 0, 1, 2]])[0].numpy()  # kornia's quaternions are w, x, y, z


def parse_robot_poses(text: str, pose_format: str = "auto", units: str = "m", source: str = "poses") -> RobotPoses:
    """Robot poses from the text of a pose file (module doc).

    Args:
        text: the file's text.
        pose_format: ``quat``, ``quat-wxyz``, ``rotvec``, ``matrix`` or ``auto`` (by the count of numbers).
        units: ``m`` or ``mm``: the translations' unit.
        source: the file's name, for the messages.

    Raises:
        UserError: one line naming the file, the line and what is wrong.

    Example:
        >>> p = parse_robot_poses("image,x,y,z,rx,ry,rz\\na.png, 100, 0, 0, 0, 0, 3.14159265", "rotvec", "mm")
        >>> p.names, np.round(p.poses[0, :3, 3], 3).tolist(), round(float(p.poses[0, 0, 0]), 6)
        (['a.png'], [0.1, 0.0, 0.0], -1.0)
    """
    if pose_format not in (*POSE_FORMATS, "auto"):
        raise UserError(f"--pose-format {pose_format}: expected quat, quat-wxyz, rotvec, matrix or auto")
    if units not in POSE_UNITS:
        raise UserError(f"--pose-units {units}: expected m or mm")
    scale = POSE_UNITS[units]
    names, poses, lines = [], [], []
    fmt = None if pose_format == "auto" else pose_format
    first = True
    for number, raw in enumerate(text.splitlines(), 1):
        line = raw.strip()
        if not line or line.startswith("#"):
            continue
        fields = [f for f in _SPLIT.split(line) if f != ""]
        if first and (len(fields) < 2 or _number(fields[1]) is None):
            first = False
            continue  # a header
        first = False
        name, values = fields[0], [_number(f) for f in fields[1:]]
        where = f"{source} line {number}"
        if any(v is None for v in values):
            bad = fields[1 + [v is None for v in values].index(True)]
            raise UserError(f"{where}: {bad!r} is not a number (expected the image's name, then the pose's numbers)")
        kind = fmt
        if kind is None:
            kind = _AUTO_FORMATS.get(len(values))
            if kind is None:
                raise UserError(f"{where}: {len(values)} numbers after the name; a pose has 7 (x,y,z,qx,qy,qz,qw), "
                                "6 (x,y,z,rx,ry,rz) or 16 (a 4x4 matrix row by row)")
            fmt = kind
        if len(values) != POSE_FORMATS[kind]:
            raise UserError(f"{where}: {len(values)} numbers after the name, --pose-format {kind} has "
                            f"{POSE_FORMATS[kind]}")
        v = np.array(values, dtype=np.float64)
        if not np.isfinite(v).all():
            raise UserError(f"{where}: the pose holds a non-finite number")
        T = np.eye(4)
        if kind in ("quat", "quat-wxyz"):
            q = v[3:]
            n = float(np.linalg.norm(q))
            if abs(n - 1) > 1e-2:
                order = "qx,qy,qz,qw" if kind == "quat" else "qw,qx,qy,qz"
                raise UserError(f"{where}: the quaternion ({', '.join(f'{x:g}' for x in q)}) has norm {n:.4g}, not 1 "
                                f"({kind} is x,y,z,{order}: is this another form, e.g. Euler angles or rotvec?)")
            T[:3, :3], T[:3, 3] = _rotation(kind, q / n), v[:3]
        elif kind == "rotvec":
            T[:3, :3], T[:3, 3] = _rotation("rotvec", v[3:]), v[:3]
            if float(np.linalg.norm(v[3:])) > 2 * math.pi + 1e-6:
                raise UserError(f"{where}: the rotation vector's angle is {float(np.linalg.norm(v[3:])):.4g}, above "
                                "2 pi: rotvec is in radians (degrees given?)")
        else:
            M = v.reshape(4, 4)
            R = M[:3, :3]
            err = float(np.abs(R @ R.T - np.eye(3)).max())
            if err > 1e-3 or not np.allclose(M[3], [0, 0, 0, 1], atol=1e-6) or np.linalg.det(R) < 0:
                raise UserError(f"{where}: not a rigid transform (its rotation is off orthonormal by {err:.2g}, or its "
                                "last row is not 0 0 0 1)")
            U, _, Vt = np.linalg.svd(R)
            T[:3, :3], T[:3, 3] = U @ Vt, M[:3, 3]
        T[:3, 3] *= scale
        if name in names:
            raise UserError(f"{where}: {name} has a pose already (line {lines[names.index(name)]})")
        names.append(name)
        poses.append(T)
        lines.append(number)
    if not names:
        raise UserError(f"{source}: no pose found (one row per image: the file name, then the pose's numbers)")
    return RobotPoses(names, np.stack(poses), lines, fmt or pose_format)


def read_robot_poses(path: str, pose_format: str = "auto", units: str = "m") -> RobotPoses:
    """:func:`parse_robot_poses` of a file; a file that cannot be read is a :class:`UserError`."""
    try:
        with open(path, encoding="utf-8-sig") as handle:
            text = handle.read()
    except OSError as err:
        raise UserError(f"--robot-poses {path}: cannot read ({err.strerror or err})") from None
    except UnicodeDecodeError:
        raise UserError(f"--robot-poses {path}: not a text file") from None
    return parse_robot_poses(text, pose_format, units, os.path.basename(path))


def _keys(path: str) -> tuple[str, str, str]:
    base = os.path.basename(path)
    return os.path.normpath(path), base, os.path.splitext(base)[0]


def match_poses(images: list[str], poses: RobotPoses) -> tuple[np.ndarray, list[str], list[str]]:
    """Each image's pose by name (module doc).

    Returns:
        ``(poses (V, 4, 4) with NaN where an image has no row, images without a row, rows without an image)``.

    Example:
        >>> p = parse_robot_poses("a.png 0 0 0 0 0 0\\nc.png 0 0 0 0 0 0")
        >>> T, missing, unused = match_poses(["dir/a.png", "dir/b.png"], p)
        >>> bool(np.isnan(T[1]).all()), missing, unused
        (True, ['dir/b.png'], ['c.png'])
    """
    index: dict[str, int] = {}
    for k, name in enumerate(poses.names):
        for key in _keys(name):
            index.setdefault(key, k)
    out = np.full((len(images), 4, 4), np.nan)
    used: set[int] = set()
    missing = []
    for v, path in enumerate(images):
        hit = next((index[key] for key in _keys(path) if key in index), None)
        if hit is None:
            missing.append(path)
            continue
        out[v] = poses.poses[hit]
        used.add(hit)
    unused = [name for k, name in enumerate(poses.names) if k not in used]
    return out, missing, unused
