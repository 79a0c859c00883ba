"""Self-labelled pairs of real photographs: degraded crops of real board views with the corners found on their clean
originals as targets, for fine-tuning the heatmap network on real pixels.

The labels come from :mod:`ccs_kornia.training.self_labels` (a JSON file: per view, the real image and the corners this
package and OpenCV agree on). Each training view is made from one labelled photograph by

1. the degradations of the benchmark's real poor images (:mod:`~ccs_kornia.data.render.poor_images`), with their
   strength drawn around the benchmark's values, one or a random mix of them (:data:`DEGRADATIONS`): blur and motion
   blur on the photograph's pixels, then the ``small`` scale (area), then the light (dark with Gaussian or
   Poisson-Gaussian noise) and JPEG on the small image, as a camera would;
2. an area rescale to the level the detector works on (squares of ``square_px`` px, the scale-selecting detector's
   target and its fallback levels), and a ``crop`` x ``crop`` window around the board.

Only the crop's neighbourhood is degraded and rescaled (a margin of the blur's reach), so a view costs about the same
whatever the photograph's size; the corners move with every resampling (``p' = (p + 0.5) s - 0.5``), so the targets
stay on the corners. A share of each batch (``rendered_prob``) are the rendered views of
:class:`~ccs_kornia.data.datamodules.datamodule.DetectorDataModule`'s distribution, so the renders' skills are kept.

The split by set (:data:`SELF_TRAINING_SETS` are trained on; :data:`HELD_OUT_SETS` are the benchmark's, never seen in
training) is recorded in ``docs/training.md``.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import cv2
import lightning as L
import numpy as np
import torch

from ccs_kornia.data.datamodules.datamodule import BatchStreams, DetectorDataModule
from ccs_kornia.data.render.poor_images import (
    BLUR_SIGMA,
    DARK,
    GAIN,
    JPEG_QUALITY,
    MOTION_PX,
    READ_NOISE,
    SMALL,
    motion_kernel,
)
from ccs_kornia.data.scenes.targets import gaussian_heatmaps

__all__ = ["DEGRADATIONS", "HELD_OUT_SETS", "SELF_TRAINING_SETS", "RealPairsDataModule", "degrade_crop"]

#: the real sets self-training learns from: name -> (kind, board, file patterns); chessboard boards are (cols, rows)
#: inner corners, ChArUco boards ``CharucoBoard``'s arguments (squares x, squares y, square, marker, dictionary).
#: The two Bumblebee2 sets are one stereo rig at the same instants, so they stay on the same side of the split.
SELF_TRAINING_SETS: dict[str, tuple[str, tuple, tuple[str, ...]]] = {
    "opencv_left": ("chessboard", (9, 6), ()),
    "boofcv_sony_hx5v": ("chessboard", (4, 6), ()),
    "boofcv_bumblebee2_left": ("chessboard", (4, 6), ()),
    "boofcv_bumblebee2_right": ("chessboard", (4, 6), ()),
    "udacity_camera_cal": ("chessboard", (9, 6), ()),
    "caliscope_4cam_charuco": ("charuco", (4, 5, 0.054, 0.0405, "DICT_4X4_1000"), ("cam_*/*.jpg",)),
}
#: the real sets kept out of self-training: the benchmark's held-out sets (another camera and board each; the two
#: fisheye sets and the GoPro's strongly curved views among them)
HELD_OUT_SETS: tuple[str, ...] = ("charuco_opencv_tutorial", "ric_charuco_eye_to_hand", "udacity_gopro_wide",
                                  "ros_fisheye_mono", "boofcv_fisheye_chessboard")
#: the degradations a view draws from (one, or a mix of two or three)
DEGRADATIONS: tuple[str, ...] = ("dark", "dark sensor", "blur", "motion", "small", "jpeg")


def _draw(rng: np.random.Generator, conditions: tuple[str, ...]) -> dict:
    """The strength of each of ``conditions``, drawn around the benchmark's (:mod:`~ccs_kornia.data.render.poor_images`)."""
    p: dict = {}
    for c in conditions:
        if c in ("dark", "dark sensor"):
            p["light"] = float(np.exp(rng.uniform(np.log(DARK * 0.6), np.log(0.5))))
            p["sensor"] = c == "dark sensor"
        elif c == "blur":
            p["blur"] = float(rng.uniform(0.5, 1.4) * BLUR_SIGMA)
        elif c == "motion":
            p["motion"] = (int(rng.integers(5, MOTION_PX + 6)), float(rng.uniform(0.0, np.pi)))
        elif c == "small":
            p["small"] = float(rng.uniform(0.6, 1.5) * SMALL)
        elif c == "jpeg":
            p["jpeg"] = int(rng.integers(JPEG_QUALITY - 15, JPEG_QUALITY + 31))
        elif c != "clean":
            raise ValueError(f"Unknown degradation {c!r}; expected 'clean' or one of {DEGRADATIONS}.")
    return p


def _resize(image: np.ndarray, points: np.ndarray, scale: float) -> tuple[np.ndarray, np.ndarray]:
    """``image`` resized by about ``scale`` (area when shrinking, linear when growing) and ``points`` moved with it."""
    h, w = image.shape
    nw, nh = max(1, round(w * scale)), max(1, round(h * scale))
    if (nw, nh) == (w, h):
        return image, points
    out = cv2.resize(image, (nw, nh), interpolation=cv2.INTER_AREA if scale < 1 else cv2.INTER_LINEAR)
    return out, (points + 0.5) * np.array([nw / w, nh / h]) - 0.5


def degrade_crop(
    gray8: np.ndarray,
    corners: np.ndarray,
    centre: np.ndarray,
    square_px: float,
    level_square: float,
    crop: int,
    params: dict,
    rng: np.random.Generator,
) -> tuple[np.ndarray, np.ndarray]:
    """One training view: the ``crop`` x ``crop`` window around ``centre`` of the photograph degraded by ``params``
    (from the module's degradations) and rescaled so its squares have ``level_square`` px.

    Args:
        gray8: ``(H, W)`` ``uint8`` photograph.
        corners: ``(N, 2)`` its labelled corners (px, pixel centres at integers).
        centre: ``(2,)`` the window's centre in the photograph's pixels.
        square_px: the board's square side in the photograph (px).
        level_square: the square side the view is rescaled to (px).
        crop: the view's side (px).
        params: degradation strengths (``light``, ``sensor``, ``blur``, ``motion``, ``small``, ``jpeg``; absent: not
            applied).
        rng: the noise.

    Returns:
        ``(view, corners)``: ``(crop, crop)`` float32 in ``[0, 1]`` and the corners ``(N, 2)`` in its pixels (those
        outside included).

    Example:
        >>> img = np.full((100, 120), 128, np.uint8)
        >>> v, c = degrade_crop(img, np.array([[60.0, 50.0]]), np.array([60.0, 50.0]), 20.0, 10.0, 32, {"small": 0.5},
        ...                     np.random.default_rng(0))
        >>> v.shape, c.round(2).tolist()
        ((32, 32), [[16.5, 16.5]])
    """
    if gray8.ndim != 2 or gray8.dtype != np.uint8:
        raise ValueError(f"Expected a (H, W) uint8 image, got {gray8.shape} {gray8.dtype}.")
    total = level_square / square_px  # output px per photograph px
    small = params.get("small", 1.0)
    reach = 3.0 * params.get("blur", 0.0) + params.get("motion", (0, 0.0))[0] + 4.0
    half = 0.5 * crop / total + reach / min(1.0, small) + 2.0
    h, w = gray8.shape
    # the window stays inside the photograph where it fits (a padded border must not hold a mirrored board)
    inner = 0.5 * crop / total
    centre = np.array([np.clip(centre[i], inner, n - 1 - inner) if n - 1 > 2 * inner else (n - 1) / 2.0
                       for i, n in enumerate((w, h))])
    x0, y0 = math.floor(centre[0] - half), math.floor(centre[1] - half)
    x1, y1 = math.ceil(centre[0] + half) + 1, math.ceil(centre[1] + half) + 1
    pad = (max(0, -y0), max(0, y1 - h), max(0, -x0), max(0, x1 - w))
    region = gray8[max(0, y0):min(h, y1), max(0, x0):min(w, x1)]
    if any(pad):
        region = cv2.copyMakeBorder(region, *pad, cv2.BORDER_REPLICATE)  # streaks, never a corner
    pts = corners - np.array([x0, y0], np.float64)
    c = np.asarray(centre, np.float64) - np.array([x0, y0])
    x = region.astype(np.float32)
    if "blur" in params:
        x = cv2.GaussianBlur(x, (0, 0), params["blur"], borderType=cv2.BORDER_REFLECT)
    if "motion" in params:
        x = cv2.filter2D(x, -1, motion_kernel(*params["motion"]), borderType=cv2.BORDER_REFLECT)
    if "small" in params:
        x8 = np.clip(np.rint(x), 0, 255).astype(np.uint8)
        x8, moved = _resize(x8, np.vstack([pts, c[None]]), small)
        pts, c, x = moved[:-1], moved[-1], x8.astype(np.float32)
        total /= small
    if "light" in params:
        if params.get("sensor"):
            x = rng.poisson(np.clip(x, 0.0, None) * params["light"] / GAIN).astype(np.float32) * GAIN  # no FFT ripple below 0
        else:
            x = x * params["light"]
        x = x + rng.normal(0.0, READ_NOISE, x.shape).astype(np.float32)
    x8 = np.clip(np.rint(x), 0, 255).astype(np.uint8)
    if "jpeg" in params:
        ok, buf = cv2.imencode(".jpg", x8, [cv2.IMWRITE_JPEG_QUALITY, int(params["jpeg"])])
        if ok:
            x8 = cv2.imdecode(buf, cv2.IMREAD_GRAYSCALE)
    x8, moved = _resize(x8, np.vstack([pts, c[None]]), total)
    pts, c = moved[:-1], moved[-1]
    ox, oy = round(c[0] - crop / 2), round(c[1] - crop / 2)
    ox = min(max(ox, 0), x8.shape[1] - crop)
    oy = min(max(oy, 0), x8.shape[0] - crop)
    view = x8[oy:oy + crop, ox:ox + crop]
    if view.shape != (crop, crop):  # a region smaller than the crop (rounding at the photograph's edge)
        view = cv2.copyMakeBorder(view, 0, crop - view.shape[0], 0, crop - view.shape[1], cv2.BORDER_REPLICATE)
    return view.astype(np.float32) / 255.0, pts - np.array([ox, oy], np.float64)


class RealPairsDataModule(BatchStreams, L.LightningDataModule):
    """Degraded crops of self-labelled real photographs with Gaussian target heatmaps (module doc), in the batch format
    of :class:`~ccs_kornia.data.datamodules.datamodule.DetectorDataModule` (``image``, ``heatmap``, ``corners``,
    ``valid``) for :class:`~ccs_kornia.training.detector.DetectorLitModule`.

    Args:
        labels: the labels file of :mod:`ccs_kornia.training.self_labels`.
        real_dir: the folder of the real sets (``None``: the one recorded in the labels file).
        crop: side of the training views (px).
        batch_size: views per step.
        sigma: target Gaussian sigma in px.
        level_square: range of the square side (px) the views are rescaled to, drawn log-uniformly.
        clean_prob: share of views left clean (rescaled and cropped only).
        mix_prob: share of the degraded views with two or three degradations instead of one.
        degradations: the degradations drawn from (:data:`DEGRADATIONS`).
        rendered_prob: share of each batch rendered by :class:`DetectorDataModule` (the renders' distribution).
        rendered: keyword arguments of that :class:`DetectorDataModule` (its ``image_size`` is ``(crop, crop)``).
        seed: offset into the training / validation seed ranges.
        val_batches: fixed number of validation batches.
        num_workers: DataLoader workers (0: made in the training process).
    """

    def __init__(
        self,
        labels: str,
        real_dir: str | None = None,
        crop: int = 128,
        batch_size: int = 16,
        sigma: float = 1.5,
        level_square: tuple[float, float] = (6.0, 18.0),
        clean_prob: float = 0.1,
        mix_prob: float = 0.4,
        degradations: tuple[str, ...] = DEGRADATIONS,
        rendered_prob: float = 0.25,
        rendered: dict | None = None,
        seed: int = 0,
        val_batches: int = 8,
        num_workers: int = 0,
    ) -> None:
        super().__init__()
        self.save_hyperparameters()
        if not (0.0 <= clean_prob <= 1.0 and 0.0 <= mix_prob <= 1.0 and 0.0 <= rendered_prob < 1.0):
            raise ValueError("clean_prob and mix_prob must be in [0, 1], rendered_prob in [0, 1).")
        if not 0 < level_square[0] <= level_square[1]:
            raise ValueError(f"level_square must be a positive range, got {level_square}.")
        _draw(np.random.default_rng(0), tuple(degradations))  # unknown names fail here, not in a worker
        self.views: list[dict] | None = None
        self.images: dict[str, np.ndarray] = {}
        self._rendered: DetectorDataModule | None = None

    @property
    def rendered(self) -> DetectorDataModule | None:
        """The data module of the rendered share (made on first use, outside the command line's instantiation, which
        would hand it this module's hyperparameters)."""
        hp = self.hparams
        if self._rendered is None and hp.rendered_prob > 0:
            self._rendered = DetectorDataModule(image_size=(hp.crop, hp.crop), batch_size=hp.batch_size, sigma=hp.sigma,
                                                **(hp.rendered or {}))
        return self._rendered

    def _load(self) -> list[dict]:
        if self.views is None:
            payload = json.loads(Path(self.hparams.labels).read_text())
            root = Path(self.hparams.real_dir or payload["real_dir"])
            views = [dict(v, path=str(root / v["file"])) for v in payload["views"]]
            if not views:
                raise ValueError(f"{self.hparams.labels} holds no labelled view.")
            self.views = views
        return self.views

    def _image(self, path: str) -> np.ndarray:
        if path not in self.images:  # the training sets are small (tens of MB): read each photograph once
            image = cv2.imread(path, cv2.IMREAD_GRAYSCALE)
            if image is None:
                raise FileNotFoundError(f"cannot read {path}")
            self.images[path] = image
        return self.images[path]

    def real_views(self, n: int, rng: np.random.Generator) -> tuple[torch.Tensor, list[np.ndarray]]:
        """``n`` degraded views ``(n, 1, crop, crop)`` and their corners (each ``(N_i, 2)``), the sets drawn evenly."""
        hp = self.hparams
        views = self._load()
        sets = sorted({v["set"] for v in views})
        images, corners = [], []
        for _ in range(n):
            name = sets[int(rng.integers(len(sets)))]
            pool = [v for v in views if v["set"] == name]
            v = pool[int(rng.integers(len(pool)))]
            c = np.asarray(v["corners"], np.float64)
            level = float(np.exp(rng.uniform(*np.log(hp.level_square))))
            # the window's centre: near a random labelled corner, so most views hold part of the board
            reach = 0.35 * hp.crop * v["square_px"] / level
            centre = c[int(rng.integers(len(c)))] + rng.uniform(-reach, reach, 2)
            if rng.random() < hp.clean_prob:
                chosen: tuple[str, ...] = ()
            else:
                k = 1 if rng.random() >= hp.mix_prob else int(rng.integers(2, 4))
                chosen = tuple(rng.choice(np.array(hp.degradations), size=k, replace=False).tolist())
            view, pts = degrade_crop(self._image(v["path"]), c, centre, v["square_px"], level, hp.crop,
                                     _draw(rng, chosen), rng)
            images.append(torch.from_numpy(view))
            corners.append(pts)
        return torch.stack(images)[:, None], corners

    def make_batch(self, generator: torch.Generator) -> dict[str, torch.Tensor]:
        hp = self.hparams
        n_rendered = round(hp.batch_size * hp.rendered_prob) if self.rendered is not None else 0
        rng = np.random.default_rng(int(torch.randint(0, 2**62, (1,), generator=generator)))
        images, corners = self.real_views(hp.batch_size - n_rendered, rng)
        n = max(len(c) for c in corners)
        pts = torch.zeros(len(corners), n, 2)
        present = torch.zeros(len(corners), n, dtype=torch.bool)
        for i, c in enumerate(corners):
            pts[i, : len(c)] = torch.from_numpy(c).float()
            present[i, : len(c)] = True
        inside = (pts >= -0.5).all(-1) & (pts[..., 0] < hp.crop - 0.5) & (pts[..., 1] < hp.crop - 0.5) & present
        heatmap = gaussian_heatmaps(pts, inside, (hp.crop, hp.crop), hp.sigma)
        # a corner counts for the validation figures when it lies a fit window inside the view
        m = 2.0 * hp.sigma + 1.0
        valid = present & (pts >= m).all(-1) & (pts[..., 0] <= hp.crop - 1 - m) & (pts[..., 1] <= hp.crop - 1 - m)
        out = {"image": images, "heatmap": heatmap, "corners": pts, "valid": valid}
        if n_rendered:
            r = self.rendered.make_batch(generator)
            r = {k: t[:n_rendered] for k, t in r.items()}
            width = max(out["corners"].shape[1], r["corners"].shape[1])

            def pad(t: torch.Tensor) -> torch.Tensor:
                return torch.nn.functional.pad(t, (0, 0, 0, width - t.shape[1])) if t.dim() == 3 else \
                    torch.nn.functional.pad(t, (0, width - t.shape[1]))

            out = {"image": torch.cat([out["image"], r["image"]]), "heatmap": torch.cat([out["heatmap"], r["heatmap"]]),
                   "corners": torch.cat([pad(out["corners"]), pad(r["corners"])]),
                   "valid": torch.cat([pad(out["valid"]), pad(r["valid"])])}
        return out
