"""Image files in and out at the boundary of the library: inputs expanded, images decoded, written, streamed.

Everything here turns user-supplied paths into the library's conventions (grey float images in
``[0, 1]``) and reports problems as *reasons* instead of raising, so
that one bad file among many is skipped, not fatal.

Decisions recorded here:

* images are decoded from bytes with ``cv2.imdecode`` (no console warnings for non-images, works
  with any path encoding); libjpeg's own lines on a damaged JPEG are caught, and the file is refused with them as its
  reason (the pixels libjpeg filled in are not the scene's);
* the EXIF orientation flag is **ignored**: a calibration describes the sensor's pixel grid, and a
  rotated view of the same sensor would otherwise look like a different image size;
* colour is converted with OpenCV's BGR->grey weights; an alpha channel is dropped;
* 16-bit files keep their precision (divided by 65535), 8-bit files are divided by 255.
"""

from __future__ import annotations

import glob
import os
import re
import sys
import tempfile
import threading
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np
import torch

from ccs_kornia.io.files import atomic_path

__all__ = [
    "IMAGE_EXTENSIONS",
    "natural_key",
    "expand_inputs",
    "read_image",
    "image_pixels",
    "load_image",
    "load_image_gray",
    "write_image",
    "ImageBatch",
    "iter_image_batches",
    "DEFAULT_MAX_BATCH_PIXELS",
]

#: pixels loaded at most in one streamed batch (64 Mpx = 256 MB of float32 grey images)
DEFAULT_MAX_BATCH_PIXELS = 1 << 26

#: file name endings treated as images when a directory is expanded
IMAGE_EXTENSIONS: tuple[str, ...] = (
    ".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".pgm", ".ppm", ".pbm", ".webp", ".jp2", ".exr", ".hdr",
)

_GLOB_CHARS = set("*?[")


def _is_image_name(path: str) -> bool:
    return path.lower().endswith(IMAGE_EXTENSIONS)


def natural_key(path: str) -> list[Any]:
    """Sort key ordering the numbers inside names by value: ``calibration2`` before ``calibration10``.

    Example:
        >>> sorted(["c10.jpg", "c2.jpg", "c1.jpg"], key=natural_key)
        ['c1.jpg', 'c2.jpg', 'c10.jpg']
    """
    parts = re.split(r"(\d+)", path)  # text at the even places, digits at the odd ones: like compares with like
    return [int(t) if i % 2 else t for i, t in enumerate(parts)] + [path]


def expand_inputs(items: Iterable[str]) -> tuple[list[str], list[tuple[str, str]]]:
    """Expand command-line inputs (files, directories, globs) into a list of image files.

    Directories contribute their image files (by extension, not recursive) and globs their matches (``**``
    allowed), in natural order (:func:`natural_key`: ``c2`` before ``c10``); plain files are kept as given, whatever
    their extension, so that the loader can say why a non-image is skipped. Duplicates are removed, first occurrence
    kept.

    Args:
        items: paths, directories or glob patterns, in the user's order.

    Returns:
        ``(files, problems)``: the files to read, and ``(item, reason)`` for every item that gave no
        file (missing path, empty directory, glob matching nothing).

    Example:
        >>> files, problems = expand_inputs(["/nonexistent/*.png"])
        >>> files, problems[0][1]
        ([], 'glob matched no file')
    """
    files: list[str] = []
    problems: list[tuple[str, str]] = []
    seen: set[str] = set()

    def add(path: str) -> None:
        key = os.path.normpath(os.path.abspath(path))
        if key not in seen:
            seen.add(key)
            files.append(path)

    for item in items:
        if os.path.isdir(item):
            found = sorted(
                (os.path.join(item, name) for name in os.listdir(item)
                 if _is_image_name(name) and os.path.isfile(os.path.join(item, name))),
                key=natural_key,
            )
            if not found:
                problems.append((item, f"directory contains no image files ({', '.join(IMAGE_EXTENSIONS[:4])}, ...)"))
            for path in found:
                add(path)
        elif os.path.isfile(item):
            add(item)
        elif _GLOB_CHARS & set(item):
            found = sorted((p for p in glob.glob(item, recursive=True) if os.path.isfile(p)), key=natural_key)
            if not found:
                problems.append((item, "glob matched no file"))
            for path in found:
                add(path)
        else:
            problems.append((item, "no such file or directory"))
    return files, problems


#: JPEG start-of-frame markers (baseline, progressive, lossless, arithmetic): their segment holds the image size
_JPEG_SOF = {0xC0, 0xC1, 0xC2, 0xC3, 0xC5, 0xC6, 0xC7, 0xC9, 0xCA, 0xCB, 0xCD, 0xCE, 0xCF}


def image_pixels(path: str | os.PathLike) -> int | None:
    """Pixels of a PNG or JPEG file from its header alone (``None`` for other formats or an unreadable header): the
    number of pixels, which a rotation by the file's EXIF orientation does not change.

    Example:
        >>> import tempfile, os
        >>> path = os.path.join(tempfile.mkdtemp(), "a.png")
        >>> write_image(path, np.zeros((30, 40), np.uint8))
        True
        >>> image_pixels(path)
        1200
    """
    try:
        with open(path, "rb") as f:
            head = f.read(24)
            if head[:8] == b"\x89PNG\r\n\x1a\n" and head[12:16] == b"IHDR":
                return int.from_bytes(head[16:20], "big") * int.from_bytes(head[20:24], "big")
            if head[:2] != b"\xff\xd8":
                return None
            f.seek(2)
            while True:  # JPEG segments: marker, big-endian length, payload; the size is in the start of frame
                marker = f.read(4)
                if len(marker) < 4 or marker[0] != 0xFF:
                    return None
                length = int.from_bytes(marker[2:4], "big")
                if marker[1] in _JPEG_SOF:
                    frame = f.read(5)
                    return int.from_bytes(frame[1:3], "big") * int.from_bytes(frame[3:5], "big") if len(frame) == 5 \
                        else None
                f.seek(length - 2, os.SEEK_CUR)
    except OSError:
        return None


#: one JPEG decoded at a time while libjpeg's messages are caught (they go to the process's standard error)
_STDERR_LOCK = threading.Lock()
#: the start of libjpeg's warnings on a damaged file ("Corrupt JPEG data: 252 extraneous bytes before marker 0xd9",
#: "Premature end of JPEG file", ...)
_LIBJPEG_WARNINGS = ("Corrupt JPEG data", "Premature end of JPEG file", "Invalid SOS parameters", "Warning: ")


def _imdecode(data: np.ndarray, flags: int) -> np.ndarray | None:
    try:
        return cv2.imdecode(data, flags)
    except cv2.error:
        return None


def _decode_jpeg(data: np.ndarray, flags: int) -> tuple[np.ndarray | None, str]:
    """``cv2.imdecode`` of a JPEG with libjpeg's warnings caught instead of printed (libjpeg writes them to file
    descriptor 2 itself): ``(image, warning)``. What else reached the standard error meanwhile is passed on."""
    with _STDERR_LOCK:
        try:
            sys.stderr.flush()
            saved = os.dup(2)
        except (OSError, ValueError, AttributeError):  # no standard error to catch: decoded as it is
            return _imdecode(data, flags), ""
        try:
            with tempfile.TemporaryFile() as caught:
                os.dup2(caught.fileno(), 2)
                try:
                    image = _imdecode(data, flags)
                finally:
                    os.dup2(saved, 2)
                caught.seek(0)
                text = caught.read().decode("utf-8", "replace")
        finally:
            os.close(saved)
    lines = text.splitlines()
    mine = [line for line in lines if line.startswith(_LIBJPEG_WARNINGS)]
    others = [line for line in lines if line not in mine]
    if others:
        os.write(2, ("\n".join(others) + "\n").encode())
    return image, "; ".join(mine)


def _decode(path: str, flags: int) -> tuple[np.ndarray | None, str]:
    try:
        data = np.fromfile(path, dtype=np.uint8)
    except OSError as err:  # permission denied, is a directory, ...
        return None, f"cannot read file: {err.strerror or err}"
    if data.size == 0:
        return None, "empty file"
    damage = ""
    if data[:2].tobytes() == b"\xff\xd8":
        image, damage = _decode_jpeg(data, flags)
    else:
        image = _imdecode(data, flags)
    if image is None or image.size == 0:
        return None, "not a readable image (unknown format or corrupt/truncated file)"
    if damage:  # libjpeg filled in what it could not decode: pixels a calibration must not trust
        return None, f"corrupt JPEG data, the decoded pixels cannot be trusted (libjpeg: {damage})"
    return image, ""


#: colour images of more pixels are converted to float by :func:`read_image` ``_STRIPE_ROWS`` rows at a time (smaller
#: ones at once: on megapixel photos the stripes' many mid-size buffers raised the peak memory, docs/measurements.md)
_STRIPED_PIXELS = 4_000_000
_STRIPE_ROWS = 256


def _to_float(image: np.ndarray) -> np.ndarray:
    if image.dtype == np.uint8:
        return image.astype(np.float32) / 255.0
    if image.dtype == np.uint16:
        return image.astype(np.float32) / 65535.0
    if image.dtype == np.int8 or image.dtype == np.int16:
        info = np.iinfo(image.dtype)
        return (image.astype(np.float32) - info.min) / float(info.max - info.min)
    # float images (EXR, HDR, 32-bit TIFF): assume [0, 1] and clip
    return np.clip(np.nan_to_num(image.astype(np.float32)), 0.0, 1.0)


def read_image(path: str | os.PathLike, gray: bool = True) -> tuple[np.ndarray | None, str, int]:
    """Read an image file without raising, also returning the bit depth of the file.

    Args:
        path: file to read.
        gray: convert to one grey channel (``H x W``); otherwise keep colour as ``H x W x 3`` RGB
            (grey files stay ``H x W``).

    Returns:
        ``(image, reason, bit_depth)``: ``image`` is ``float32`` in ``[0, 1]`` or ``None`` with
        ``reason`` saying why (``""`` on success); ``bit_depth`` is 8, 16 or 32 (0 on failure).
    """
    flags = cv2.IMREAD_UNCHANGED | cv2.IMREAD_IGNORE_ORIENTATION
    image, reason = _decode(os.fspath(path), flags)
    if image is None:
        return None, reason, 0
    depth = 8 * image.dtype.itemsize
    if image.ndim == 3:
        channels = image.shape[2]
        if channels == 4:
            image = image[..., :3]  # alpha does not carry the board
        elif channels != 3:  # grey + alpha, or exotic layouts: first channel
            image = image[..., 0]
    if min(image.shape[:2]) < 8:
        return None, f"image too small ({image.shape[1]}x{image.shape[0]})", 0
    code = cv2.COLOR_BGR2GRAY if gray else cv2.COLOR_BGR2RGB
    if image.ndim == 2 or image.shape[0] * image.shape[1] <= _STRIPED_PIXELS:
        image = _to_float(image)
        if image.ndim == 3:  # converted in float so that 16-bit data keep their precision
            image = cv2.cvtColor(image, code)
        return np.ascontiguousarray(image, dtype=np.float32), "", depth
    # a large colour photo: a stripe of rows at a time (per-pixel operations, so the same values); at once, a 24 Mpx
    # photo's float copy alone is 288 MB of peak memory
    out = np.empty(image.shape[:2] if gray else image.shape, dtype=np.float32)
    for top in range(0, image.shape[0], _STRIPE_ROWS):
        out[top:top + _STRIPE_ROWS] = cv2.cvtColor(_to_float(image[top:top + _STRIPE_ROWS]), code)
    return out, "", depth


def load_image(path: str | os.PathLike, gray: bool = True) -> tuple[np.ndarray | None, str]:
    """Read an image file without raising: ``(float32 image in [0, 1] | None, reason)``.

    See :func:`read_image`; this drops the bit depth.
    """
    image, reason, _ = read_image(path, gray)
    return image, reason


def load_image_gray(path: str | os.PathLike) -> tuple[np.ndarray | None, str]:
    """Read an image as grey ``float32`` ``H x W`` in ``[0, 1]``; ``(None, reason)`` on failure.

    Handles 8- and 16-bit files, colour (converted to grey), grey+alpha and RGBA (alpha dropped),
    and non-image, empty or truncated files (returned as a reason, never an exception).

    Example:
        >>> load_image_gray("/nonexistent.png")[1]
        'cannot read file: No such file or directory'
    """
    return load_image(path, gray=True)


def write_image(path: str | os.PathLike, image: np.ndarray | torch.Tensor, bit_depth: int = 8) -> bool:
    """Write a float image in ``[0, 1]`` (``H x W``, ``H x W x 3`` RGB, or ``(C, H, W)`` tensor).

    Args:
        path: destination; the format follows the extension (16-bit needs PNG or TIFF).
        image: the image.
        bit_depth: 8 or 16.

    Returns:
        True if OpenCV could encode the image in the extension's format; the file is then written atomically
        (:func:`~ccs_kornia.io.files.atomic_path`: through a symbolic link, never over a device or FIFO).
    """
    if isinstance(image, torch.Tensor):
        image = image.detach().cpu().float()
        if image.dim() == 3:
            image = image.permute(1, 2, 0).squeeze(-1) if image.shape[0] in (1, 3) else image
        image = image.numpy()
    scale, dtype = (65535.0, np.uint16) if bit_depth == 16 else (255.0, np.uint8)
    out = np.clip(np.rint(np.asarray(image, dtype=np.float32) * scale), 0, scale).astype(dtype)
    if out.ndim == 3 and out.shape[2] == 3:
        out = cv2.cvtColor(out, cv2.COLOR_RGB2BGR)
    ext = os.path.splitext(os.fspath(path))[1] or ".png"
    ok, buf = cv2.imencode(ext, out)
    if not ok:
        return False
    with atomic_path(path) as tmp:
        buf.tofile(tmp)
    return True


@dataclass
class ImageBatch:
    """Images of one size loaded together, plus the files of this chunk that failed to load.

    Attributes:
        paths: the files of ``images``, in input order.
        images: :math:`(b, 1, H, W)` float tensor in ``[0, 1]`` (``None`` when ``paths`` is empty).
        skipped: ``(path, reason)`` for files that could not be loaded.
    """

    paths: list[str] = field(default_factory=list)
    images: torch.Tensor | None = None
    skipped: list[tuple[str, str]] = field(default_factory=list)

    @property
    def image_size(self) -> tuple[int, int] | None:
        """``(W, H)`` of the images, or None."""
        if self.images is None:
            return None
        return int(self.images.shape[-1]), int(self.images.shape[-2])


def iter_image_batches(
    files: list[str], batch_size: int = 16, max_pixels: int | None = DEFAULT_MAX_BATCH_PIXELS
) -> Iterator[ImageBatch]:
    """Stream grey images from disk in batches, so large sets never sit in memory at once.

    Images are grouped by size: a batch holds only images of one size (at most ``batch_size``, and
    at most ``max_pixels`` pixels in all, but always at least one image) and is yielded as soon as it
    is full; the remainders are yielded at the end. Files that fail to load are reported in
    ``skipped`` of the next batch yielded (possibly a batch with no images).

    Args:
        files: image paths.
        batch_size: most images per batch (>= 1).
        max_pixels: most pixels per batch (``None``: no limit); bounds memory when images are large
            (a 24 Mpx photo takes 96 MB as float32).

    Yields:
        :class:`ImageBatch` items; every input file appears exactly once, in ``paths`` or ``skipped``.
    """
    if batch_size < 1:
        raise ValueError(f"batch_size must be >= 1, got {batch_size}.")
    pending: dict[tuple[int, int], list[tuple[str, np.ndarray]]] = {}
    skipped: list[tuple[str, str]] = []

    def make(items: list[tuple[str, np.ndarray]]) -> ImageBatch:
        nonlocal skipped
        images = torch.from_numpy(np.stack([im for _, im in items]))[:, None]
        batch = ImageBatch([p for p, _ in items], images, skipped)
        skipped = []
        return batch

    for path in files:
        image, reason = load_image_gray(path)
        if image is None:
            skipped.append((path, reason))
            continue
        key = (image.shape[1], image.shape[0])
        per_batch = batch_size if max_pixels is None else max(1, min(batch_size, max_pixels // (key[0] * key[1])))
        pending.setdefault(key, []).append((path, image))
        if len(pending[key]) >= per_batch:
            yield make(pending.pop(key))
    for key in list(pending):
        yield make(pending.pop(key))
    if skipped:
        yield ImageBatch([], None, skipped)
