r"""Markers read on a rectified patch: the bits of a marker whose square the corner lattice gives, compared with the
board's own codes.

OpenCV's marker detector finds a marker from its outline in the whole image (thresholding, contours, a quad fit);
blur, low light and small markers break that outline long before the bits themselves are lost. Where the corner
lattice already gives the marker's square (its four corners, refined), the square's homography rectifies the marker
exactly and only the bits remain to be read (:func:`sample_cells`, :func:`read_bits`): each bit cell's mean, split
by the mean of the marker's black border and the white ring around it.

The read bits are compared with the board's markers only (:class:`MarkerCodes`): a read names a marker where at most
:attr:`MarkerCodes.errors` bits differ from its code, in one of the eight orientations of the square (four turns,
mirrored or not). ``errors`` is below half the smallest distance between two of the board's codes turned any way, so
one read within it cannot name two markers of the board in the same handedness.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

__all__ = ["CLEAR", "CLEAR_MARGIN", "MARGIN", "MATCH", "ORIENTATIONS", "TEMPLATE_BLUR", "BitsRead", "CodeTemplates",
           "MarkerCodes", "read_bits", "sample_cells"]

#: the eight orientations of a square (signed permutations acting on centred ``(x, y)``): four turns, then mirrored
ORIENTATIONS = np.array([
    [[1, 0], [0, 1]], [[0, -1], [1, 0]], [[-1, 0], [0, -1]], [[0, 1], [-1, 0]],
    [[-1, 0], [0, 1]], [[0, 1], [1, 0]], [[1, 0], [0, -1]], [[0, -1], [-1, 0]],
], dtype=np.int64)
#: bit cells sampled per cell side (a ``k x k`` grid in the cell's central half)
SAMPLES = 3


def _oriented(bits: np.ndarray, placed: bool = False) -> np.ndarray:
    """``bits`` :math:`(..., n, n)` in every orientation :math:`(8, ..., n, n)`, cells as ``(x, y) = (column, row)``
    about the centre. ``placed=False``: ``out[o]`` at ``p`` is ``bits`` at ``T p`` (a read turned back into a code's
    frame, ``T`` = :data:`ORIENTATIONS` ``[o]``); ``placed=True``: ``out[o]`` at ``T p`` is ``bits`` at ``p`` (a code
    drawn as a read in orientation ``o`` shows it)."""
    n = bits.shape[-1]
    jj, ii = np.meshgrid(np.arange(n), np.arange(n))
    centred = np.stack([jj, ii], -1) - (n - 1) / 2.0
    out = []
    for t in ORIENTATIONS:
        t = t.T if placed else t  # the inverse of a signed permutation is its transpose
        src = np.rint(centred @ t.T + (n - 1) / 2.0).astype(np.int64)
        out.append(bits[..., src[..., 1], src[..., 0]])
    return np.stack(out)


@dataclass(frozen=True)
class MarkerCodes:
    """The codes of a board's markers: ``codes`` :math:`(K, n, n)` (1 white, OpenCV's bit order: row 0 at the marker's
    top), their ``ids`` :math:`(K,)`, the black ``border`` (bits) around them, and the bits a read may differ from a
    code (``errors``).

    Example:
        >>> codes = MarkerCodes.of("DICT_6X6_250", range(24), 1)
        >>> codes.codes.shape, codes.errors >= 3
        ((24, 6, 6), True)
    """

    codes: np.ndarray
    ids: np.ndarray
    border: int
    errors: int

    @staticmethod
    def of(dictionary: str, ids, border: int) -> "MarkerCodes":
        """The codes of the markers ``ids`` of OpenCV's predefined ``dictionary``, with ``errors`` below half the
        smallest distance between two of them turned any way (a code against itself turned included). Mirrored
        codes can be closer (a mirrored 4x4 code can be another one): a naming mirrors every marker of the lattice
        at once, so many squares tell mirrored and plain apart where one cannot."""
        from ccs_kornia.modules.detection.boards import aruco_dictionary

        d = aruco_dictionary(dictionary)
        ids = np.asarray(list(ids), dtype=np.int64)
        n = int(d.markerSize)
        codes = np.stack([d.getBitsFromByteList(d.bytesList[int(i):int(i) + 1], n) for i in ids]).astype(np.uint8)
        turned = _oriented(codes)[:4].reshape(4 * len(ids), n * n).astype(np.int64)  # (4K, n*n)
        dist = (turned[:, None, :] != codes.reshape(len(ids), n * n)[None]).sum(-1)  # (4K, K)
        same = np.zeros_like(dist, dtype=bool)
        same[np.arange(len(ids)), np.arange(len(ids))] = True  # code k unturned against itself
        smallest = int(dist[~same].min()) if (~same).any() else n * n
        errors = max(0, (smallest - 1) // 2)
        return MarkerCodes(codes, ids, int(border), errors)

    def distances(self, bits: np.ndarray) -> np.ndarray:
        """Bits that differ between ``bits`` :math:`(n, n)` (read in a square's own frame) turned into each
        orientation and each code: :math:`(8, K)`."""
        turned = _oriented(bits.astype(np.uint8))  # (8, n, n)
        return (turned[:, None] != self.codes[None]).sum((-1, -2))

    def corners_in_frame(self, orientation: int) -> np.ndarray:
        """Where the marker's corners (OpenCV's order: top left, top right, bottom right, bottom left of its code)
        lie in the square's unit frame, for a read in ``orientation``: :math:`(4, 2)`."""
        unit = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
        t = ORIENTATIONS[orientation]
        # cell (i, j) of the code is the read's cell t (j, i): the frame's points move the same way
        return (unit - 0.5) @ t.T + 0.5


#: blur of the code templates (Gaussian sigma in bit cells): from sharp to a blur wider than a bit
TEMPLATE_BLUR = (0.0, 0.3, 0.6, 0.9, 1.2, 1.6)
#: template samples per bit cell side
TEMPLATE_SAMPLES = 4
#: a read names a code where their correlation reaches this ...
MATCH = 0.8
#: ... and beats every other code (any orientation) by this much
MARGIN = 0.05
#: a read disputes a code it does not match where another code correlates this well, ...
CLEAR = 0.85
#: ... and by this much more than the code
CLEAR_MARGIN = 0.1


class CodeTemplates:
    """The board's codes as blurred images, matched to a rectified marker patch by normalised correlation.

    A read's hard bits fail once the blur is wider than a bit; the pattern itself survives much longer, so each code
    (in each orientation) is drawn with its black border and the light ring around it, blurred by each of
    :data:`TEMPLATE_BLUR`, and correlated with the patch over the marker's bits (:meth:`scores`; the best blur per
    code). A code is named where it correlates best, by :data:`MARGIN`, with at least :data:`MATCH`
    (:meth:`best`, :meth:`agrees`).

    Example:
        >>> codes = MarkerCodes.of("DICT_6X6_250", range(4), 1)
        >>> t = CodeTemplates(codes)
        >>> patch = t.draw(codes.codes[2], 0.5)  # marker 2, blurred by half a bit
        >>> t.best(t.scores(patch))
        (0, 2)
    """

    def __init__(self, codes: MarkerCodes, samples: int = TEMPLATE_SAMPLES, blur=TEMPLATE_BLUR) -> None:
        self.codes = codes
        self.samples = int(samples)
        n = codes.codes.shape[-1]
        self.cells = n + 2 * codes.border
        m = (self.cells + 2) * self.samples
        self.mask = np.zeros((m, m), dtype=bool)
        lo = (1 + codes.border) * self.samples - self.samples // 2
        self.mask[lo:m - lo, lo:m - lo] = True  # the bits and half a cell of the border around them
        oriented = _oriented(codes.codes, placed=True)  # (8, K, n, n): as a read in each orientation shows them
        drawn = np.stack([[[self.draw(oriented[o, k], b) for k in range(len(codes.ids))] for o in range(8)]
                          for b in blur])
        t = drawn[..., self.mask]
        t = t - t.mean(-1, keepdims=True)
        self.templates = t / (np.linalg.norm(t, axis=-1, keepdims=True) + 1e-12)  # (S, 8, K, P)
        flat = oriented.reshape(8 * len(codes.ids), -1)
        # codes that draw one image (a mirrored code can be another code): never evidence against each other
        self.identical = (flat[:, None, :] == flat[None, :, :]).all(-1).reshape(8, len(codes.ids), 8, len(codes.ids))

    def draw(self, bits: np.ndarray, blur: float) -> np.ndarray:
        """A code ``bits`` :math:`(n, n)` drawn with its border and the light ring, blurred by ``blur`` bit cells."""
        n, b, s = bits.shape[-1], self.codes.border, self.samples
        grid = np.ones((self.cells + 2, self.cells + 2))
        grid[1:-1, 1:-1] = 0.0
        grid[1 + b:1 + b + n, 1 + b:1 + b + n] = bits
        big = np.kron(grid, np.ones((s, s)))
        return cv2.GaussianBlur(big, (0, 0), blur * s) if blur > 0 else big

    def sample(self, image: np.ndarray, to_image: np.ndarray) -> np.ndarray:
        """The patch of the ``float32`` ``image`` over the marker whose unit square ``to_image`` maps to the image,
        with its ring, on the templates' grid (bilinear)."""
        m = (self.cells + 2) * self.samples
        u = ((np.arange(m) + 0.5) / self.samples - 1.0) / self.cells
        gx, gy = np.meshgrid(u, u)
        pts = np.stack([gx, gy, np.ones_like(gx)], -1) @ np.asarray(to_image, dtype=np.float64).T
        xy = (pts[..., :2] / pts[..., 2:3]).astype(np.float32)
        return cv2.remap(image, xy[..., 0], xy[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)

    def scores(self, patch: np.ndarray) -> np.ndarray:
        """Correlation of ``patch`` (:meth:`sample`; negate it for a white-on-black print) with every code in every
        orientation, at its best blur: :math:`(8, K)`."""
        p = patch[self.mask].astype(np.float64)
        p = p - p.mean()
        p = p / (np.linalg.norm(p) + 1e-12)
        return (self.templates @ p).max(0)

    def _others(self, scores: np.ndarray, o: int, k: int) -> float:
        """The best score of the codes that draw another image than code ``k`` in orientation ``o``."""
        other = np.where(self.identical[o, k], -np.inf, scores)
        return float(other.max())

    def best(self, scores: np.ndarray) -> tuple[int, int] | None:
        """The orientation and code index that ``scores`` name (:data:`MATCH`, :data:`MARGIN`), else ``None``."""
        o, k = np.unravel_index(int(np.argmax(scores)), scores.shape)
        top = float(scores[o, k])
        if top < MATCH or top - self._others(scores, int(o), int(k)) < MARGIN:
            return None
        return int(o), int(k)

    def agrees(self, scores: np.ndarray, o: int, k: int) -> bool:
        """The read is code ``k`` in orientation ``o``."""
        top = float(scores[o, k])
        return top >= MATCH and top - self._others(scores, o, k) >= MARGIN

    def disputes(self, scores: np.ndarray, o: int, k: int) -> bool:
        """The read is clearly another code, or this code turned otherwise."""
        other = self._others(scores, o, k)
        return other >= CLEAR and other - float(scores[o, k]) >= CLEAR_MARGIN


@dataclass
class BitsRead:
    """One marker read: ``bits`` :math:`(n, n)` bool (True: light), the fraction of its border cells that read
    dark, and the ``contrast`` between the border's and the surrounding ring's grey levels over the cells' noise."""

    bits: np.ndarray
    border_dark: float
    contrast: float

    @property
    def readable(self) -> bool:
        """A black border on a light ring, clearly above the noise."""
        return self.border_dark >= 0.6 and self.contrast >= 3.0


def sample_cells(image: np.ndarray, to_image: np.ndarray, cells: int, samples: int = SAMPLES) -> np.ndarray:
    """Mean grey level of each cell of a ``cells x cells`` grid over the unit square, plus a ring of cells around
    it: :math:`(cells + 2, cells + 2)`; ``to_image`` maps the unit square (``x`` right, ``y`` down) to the ``float32``
    ``image``'s pixels. Each cell is sampled on a ``samples x samples`` grid in its central half (bilinear).

    Example:
        >>> img = np.zeros((40, 40), np.float32)
        >>> img[10:30, 10:30] = 1.0
        >>> m = sample_cells(img, np.array([[20.0, 0, 9.5], [0, 20.0, 9.5], [0, 0, 1]]), 2)
        >>> m.round(2).tolist()
        [[0.0, 0.0, 0.0, 0.0], [0.0, 1.0, 1.0, 0.0], [0.0, 1.0, 1.0, 0.0], [0.0, 0.0, 0.0, 0.0]]
    """
    k = int(samples)
    offs = (np.arange(k) + 0.5) / k * 0.5 + 0.25  # the central half of a cell
    idx = np.arange(-1, cells + 1)
    u = ((idx[:, None] + offs[None]) / cells).reshape(-1)  # (cells + 2) * k
    gx, gy = np.meshgrid(u, u)
    pts = np.stack([gx, gy, np.ones_like(gx)], -1) @ np.asarray(to_image, dtype=np.float64).T
    xy = (pts[..., :2] / pts[..., 2:3]).astype(np.float32)
    vals = cv2.remap(image, xy[..., 0], xy[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                     borderValue=np.nan)
    n = cells + 2
    return vals.reshape(n, k, n, k).mean((1, 3))


def read_bits(means: np.ndarray, border: int) -> BitsRead:
    """The bits of a marker from its cell means (:func:`sample_cells`: the marker's cells plus the ring around it):
    each inner cell is light where it is above the middle between the black border's median and the ring's.

    Example:
        >>> means = np.zeros((6, 6))
        >>> means[0], means[-1], means[:, 0], means[:, -1] = 1.0, 1.0, 1.0, 1.0  # the light ring
        >>> means[2, 2] = means[3, 3] = 0.9
        >>> r = read_bits(means + 0.01 * np.random.default_rng(0).normal(size=(6, 6)), 1)
        >>> r.bits.astype(int).tolist(), r.readable
        ([[1, 0], [0, 1]], True)
    """
    n = means.shape[0] - 2
    inner = means[1:-1, 1:-1]
    ring = np.concatenate([means[0, 2:-2], means[-1, 2:-2], means[2:-2, 0], means[2:-2, -1]])
    edge = np.ones((n, n), dtype=bool)
    edge[border:n - border, border:n - border] = False
    dark_cells = inner[edge]
    if not (np.isfinite(inner).all() and np.isfinite(ring).all()):
        return BitsRead(np.zeros((n - 2 * border,) * 2, dtype=bool), 0.0, 0.0)
    dark, light = float(np.median(dark_cells)), float(np.median(ring))
    spread = 1.4826 * float(np.median(np.abs(np.concatenate([dark_cells - dark, ring - light]))))
    threshold = 0.5 * (dark + light)
    bits = inner[border:n - border, border:n - border] > threshold
    contrast = (light - dark) / max(spread, 1e-3 * max(abs(light), abs(dark), 1e-6))
    return BitsRead(bits, float((dark_cells < threshold).mean()), float(contrast))
