"""Calibrate many cameras at once through Lightning's ``Trainer.predict`` (``calibrate-many``).

One *image set* (a directory of chessboard images of one camera) is one dataset item:

* :class:`ImageSetDataset` loads a set (in DataLoader workers, in parallel with the model) and
  keeps the images of its most common size;
* :class:`CalibrationLitModule` wraps :class:`~ccs_kornia.pipeline.CalibrationPipeline`: its
  ``predict_step`` detects the boards of every set of the batch, then calibrates all sets of one
  image size in **one batched solver call** (cameras padded to the same number of views, with masks);
* :class:`JsonlPredictionWriter` appends one JSON line per set as soon as its batch is done, so
  results stream to disk (nothing is accumulated in memory) and an interrupted run keeps what it
  finished.

Every line has the keys of ``calibrate``'s JSON (DESIGN section 4) plus ``set`` (the directory),
``success`` and, for a set that could not be calibrated, ``error`` (with ``K`` null).

The pipeline itself imports no Lightning; this module is the only inference code that does.
"""

from __future__ import annotations

import glob
import logging
import os
import time
import warnings
from collections.abc import Iterable, Sequence
from typing import Any

import lightning.pytorch as pl
import numpy as np
import torch
from lightning.pytorch.callbacks import BasePredictionWriter
from torch.utils.data import DataLoader, Dataset

from ccs_kornia.io import IMAGE_EXTENSIONS, json_line, load_image_gray
from ccs_kornia.modules.calibration.result import CalibrationResult
from ccs_kornia.pipeline import CalibrationPipeline
from ccs_kornia.records import calibration_record, plan_views

__all__ = [
    "find_image_sets",
    "ImageSetDataset",
    "ImageSetDataModule",
    "CalibrationLitModule",
    "JsonlPredictionWriter",
    "calibrate_many",
]

_PER_VIEW = ("rvec", "tvec", "view_rms", "used", "view_reason", "candidate_rms")


def _images_in(directory: str) -> list[str]:
    return sorted(
        os.path.join(directory, name)
        for name in os.listdir(directory)
        if name.lower().endswith(IMAGE_EXTENSIONS) and os.path.isfile(os.path.join(directory, name))
    )


def find_image_sets(items: Iterable[str]) -> tuple[list[tuple[str, list[str]]], list[tuple[str, str]]]:
    """Turn command-line items into image sets (one camera each).

    A directory holding image files is one set. A directory holding no image file but
    sub-directories that do (``cameras/cam_000/*.png``, ...) gives one set per such sub-directory.
    A glob gives every directory it matches, by the same rules.

    Args:
        items: directories or globs.

    Returns:
        ``(sets, problems)``: ``(name, files)`` per set in a stable order, and ``(item, reason)`` for
        items that gave no set.

    Example:
        >>> find_image_sets(["/nonexistent"])
        ([], [('/nonexistent', 'no such directory')])
    """
    sets: list[tuple[str, list[str]]] = []
    problems: list[tuple[str, str]] = []
    seen: set[str] = set()

    def add_directory(directory: str, item: str) -> bool:
        files = _images_in(directory)
        if files:
            key = os.path.normpath(os.path.abspath(directory))
            if key not in seen:
                seen.add(key)
                sets.append((directory, files))
            return True
        found = False
        for name in sorted(os.listdir(directory)):
            sub = os.path.join(directory, name)
            if os.path.isdir(sub) and _images_in(sub):
                found = add_directory(sub, item) or found
        return found

    for item in items:
        if os.path.isdir(item):
            if not add_directory(item, item):
                problems.append((item, "no image files in it or in its sub-directories"))
        elif os.path.isfile(item):
            problems.append((item, "is a file; an image set is a directory of images (use calibrate for one set)"))
        elif set("*?[") & set(item):
            dirs = sorted(p for p in glob.glob(item, recursive=True) if os.path.isdir(p))
            if not dirs:
                problems.append((item, "glob matched no directory"))
            elif not any([add_directory(d, item) for d in dirs]):
                problems.append((item, "the directories it matched hold no image files"))
        else:
            problems.append((item, "no such directory"))
    return sets, problems


class ImageSetDataset(Dataset):
    """One item per image set: its grey images stacked, of the set's most common size.

    Args:
        sets: ``(name, files)`` pairs (see :func:`find_image_sets`).

    Item:
        dict with ``name``, ``files`` (all inputs, in order), ``paths`` (the files in ``images``),
        ``images`` :math:`(V, 1, H, W)` float in ``[0, 1]`` or ``None`` when no file could be read,
        and ``skipped``: ``{path: reason}`` for unreadable files and files of another size.
    """

    def __init__(self, sets: Sequence[tuple[str, list[str]]]) -> None:
        self.sets = list(sets)

    def __len__(self) -> int:
        return len(self.sets)

    def __getitem__(self, index: int) -> dict[str, Any]:
        name, files = self.sets[index]
        loaded: list[tuple[str, Any]] = []
        skipped: dict[str, str] = {}
        counts: dict[tuple[int, int], int] = {}
        for path in files:
            image, reason = load_image_gray(path)
            if image is None:
                skipped[path] = reason
                continue
            key = (image.shape[1], image.shape[0])
            counts[key] = counts.get(key, 0) + 1
            loaded.append((path, image))
        images, paths = None, []
        if counts:
            size = max(counts, key=lambda k: counts[k])
            keep = []
            for path, image in loaded:
                if (image.shape[1], image.shape[0]) == size:
                    keep.append(image)
                    paths.append(path)
                else:
                    skipped[path] = (f"image size {image.shape[1]}x{image.shape[0]} differs from the set's "
                                     f"{size[0]}x{size[1]}")
            images = torch.from_numpy(np.stack(keep))[:, None]
        return {"name": name, "files": list(files), "paths": paths, "images": images, "skipped": skipped}


def _collate_sets(items: list[dict[str, Any]]) -> list[dict[str, Any]]:
    # sets differ in view count and image size: keep them as a list, the module pads what it batches
    return items


class ImageSetDataModule(pl.LightningDataModule):
    """Predict-only data module over image sets.

    Args:
        sets: ``(name, files)`` pairs.
        sets_per_batch: sets handed to one ``predict_step`` (those of one image size are calibrated in
            one batched solver call).
        num_workers: DataLoader worker processes loading sets ahead of the model.
    """

    def __init__(self, sets: Sequence[tuple[str, list[str]]], sets_per_batch: int = 4, num_workers: int = 0) -> None:
        super().__init__()
        if sets_per_batch < 1:
            raise ValueError(f"sets_per_batch must be >= 1, got {sets_per_batch}.")
        self.dataset = ImageSetDataset(sets)
        self.sets_per_batch = sets_per_batch
        self.num_workers = num_workers

    def predict_dataloader(self) -> DataLoader:
        return DataLoader(
            self.dataset, batch_size=self.sets_per_batch, shuffle=False, num_workers=self.num_workers,
            collate_fn=_collate_sets, persistent_workers=False,
        )


def _camera(result: CalibrationResult, c: int, views: int) -> CalibrationResult:
    """Camera ``c`` of a batched result, its first ``views`` views (the rest is padding)."""
    fields = {}
    for key, value in result.__dict__.items():
        if not isinstance(value, torch.Tensor):
            fields[key] = value
        elif key in _PER_VIEW:
            fields[key] = value[c, :views]
        else:
            fields[key] = value[c]
    return CalibrationResult(**fields)


class CalibrationLitModule(pl.LightningModule):
    """:class:`~ccs_kornia.pipeline.CalibrationPipeline` as a LightningModule for ``Trainer.predict``.

    Args:
        pipeline: the pipeline (detector, model, RANSAC settings).
        board_size: ``(cols, rows)`` inner corners.
        square: square side in world units.
        detector_name: recorded in the output.

    ``predict_step`` takes a list of image-set items (:class:`ImageSetDataset`) and returns one
    JSON-ready dict per set.
    """

    def __init__(self, pipeline: CalibrationPipeline, board_size: tuple[int, int], square: float = 1.0,
                 detector_name: str = "learned") -> None:
        super().__init__()
        self.pipeline = pipeline
        self.board_size = (int(board_size[0]), int(board_size[1]))
        self.square = float(square)
        self.detector_name = detector_name

    def _failed(self, item: dict[str, Any], message: str, views: list[dict[str, Any]] | None = None) -> dict[str, Any]:
        if views is None:
            views = [{"path": p, "used": False, "rms": None, "found": False, "reason": f"unreadable: {r}"}
                     for p, r in item["skipped"].items()]
        return {
            "set": item["name"], "success": False, "error": message, "image_size": None, "K": None,
            "distortion": None, "rms": None, "views": views, "board": list(self.board_size), "square": self.square,
            "detector": self.detector_name, "model": self.pipeline.model,
            "num_views": {"files": len(item["files"]), "found": sum(1 for v in views if v.get("found")),
                          "usable": 0, "used": 0},
            "skipped": [{"path": v["path"], "reason": v["reason"]} for v in views if "reason" in v],
        }

    def predict_step(self, batch: list[dict[str, Any]], batch_idx: int = 0) -> list[dict[str, Any]]:
        board = self.board_size
        out: list[dict[str, Any] | None] = [None] * len(batch)
        plans: dict[tuple[int, int], list[tuple[int, list[dict], list[str], dict]]] = {}
        for k, item in enumerate(batch):
            if item["images"] is None:
                out[k] = self._failed(item, "no readable image in the set")
                continue
            start = time.perf_counter()
            images = item["images"].to(self.device)
            correction = None
            if self.pipeline.distortion_net is not None:
                size_wh = (int(images.shape[-1]), int(images.shape[-2]))
                corr, apply = self.pipeline.pool_corrections(self.pipeline.view_corrections(images)[None], size_wh)
                correction = {"coeffs": corr[0], "apply": bool(apply[0])}
            if correction is not None and correction["apply"]:
                det = self.pipeline.detect_corrected(images, correction["coeffs"], board)
            else:
                det = self.pipeline.detect(images, board)
            detect_s = time.perf_counter() - start
            corners, found = det.corners.detach().double().cpu().tolist(), det.found.cpu().tolist()
            reasons = det.reasons or [""] * len(found)
            size = [int(item["images"].shape[-1]), int(item["images"].shape[-2])]
            records: dict[str, dict[str, Any]] = {}
            for path, reason in item["skipped"].items():
                records[path] = {"found": False, "corners": None, "image_size": None, "error": reason}
            for j, path in enumerate(item["paths"]):
                records[path] = {"found": bool(found[j]), "corners": corners[j] if found[j] else None,
                                 "image_size": size}
                if not found[j]:
                    records[path]["reason"] = reasons[j] or "board not found"
            views, usable, image_size = plan_views(item["files"], records)
            if len(usable) < 3:
                n_found = sum(1 for v in views if v["found"])
                out[k] = self._failed(item, f"only {len(usable)} usable view(s) (board found in {n_found} of "
                                            f"{len(item['files'])} files); at least 3 are needed", views)
                continue
            plans.setdefault(tuple(image_size), []).append(
                (k, views, usable, {"detect_s": detect_s, "records": records, "correction": correction}))

        # one batched solver call per image size: cameras padded to the same number of views
        for image_size, group in plans.items():
            v_max = max(len(usable) for _, _, usable, _ in group)
            n = board[0] * board[1]
            corners = torch.zeros(len(group), v_max, n, 2, dtype=torch.float64)
            valid = torch.zeros(len(group), v_max, n, dtype=torch.bool)
            for c, (_, _, usable, extra) in enumerate(group):
                corners[c, : len(usable)] = torch.tensor([extra["records"][p]["corners"] for p in usable], dtype=torch.float64)
                valid[c, : len(usable)] = True
            start = time.perf_counter()
            corrections = [extra["correction"] for _, _, _, extra in group]
            applied = torch.zeros(len(group), dtype=torch.bool)
            if all(c is not None for c in corrections) and any(c["apply"] for c in corrections):
                coeffs = torch.stack([c["coeffs"].to(self.device) for c in corrections])
                apply = torch.tensor([c["apply"] for c in corrections], device=self.device)
                result, _, applied = self.pipeline.solve_with_correction(
                    corners.to(self.device), valid[..., 0].to(self.device), coeffs, apply, board, self.square, image_size)
                applied = applied.cpu()
            else:
                result = self.pipeline.calibrate(corners.to(self.device), valid.to(self.device), board, self.square,
                                                 image_size)
            solve_s = (time.perf_counter() - start) / len(group)
            for c, (k, views, usable, extra) in enumerate(group):
                one = _camera(result, c, len(usable))
                if not bool(one.success):
                    out[k] = self._failed(batch[k], f"calibration failed on {len(usable)} views (degenerate or "
                                                    "inconsistent views)", views)
                    continue
                record = calibration_record(views, usable, image_size, one, board=board, square=self.square,
                                            detector=self.detector_name, model=self.pipeline.model)
                corr = extra["correction"]
                record["distortion_correction"] = (
                    {"enabled": False} if corr is None else
                    {"enabled": True, "applied": bool(applied[c]),
                     "network_correction": [float(x) for x in corr["coeffs"].tolist()]})
                out[k] = {"set": batch[k]["name"], "success": True, **record,
                          "timings": {"detect_s": extra["detect_s"], "solve_s": solve_s}}
        return [o for o in out if o is not None]


class JsonlPredictionWriter(BasePredictionWriter):
    """Append one JSON line per image set to ``path`` after every predict batch (flushed at once).

    Attributes:
        succeeded / failed: counts of sets written so far.
    """

    def __init__(self, path: str) -> None:
        super().__init__(write_interval="batch")
        self.path = path
        self.succeeded = 0
        self.failed = 0
        self._handle = None

    def on_predict_start(self, trainer: pl.Trainer, pl_module: pl.LightningModule) -> None:
        self._handle = open(self.path, "w", encoding="utf-8")  # noqa: SIM115 (closed in on_predict_end)

    def write_on_batch_end(self, trainer, pl_module, prediction, batch_indices, batch, batch_idx, dataloader_idx) -> None:
        assert self._handle is not None
        for record in prediction:
            self._handle.write(json_line(record) + "\n")
            if record.get("success"):
                self.succeeded += 1
            else:
                self.failed += 1
        self._handle.flush()

    def on_predict_end(self, trainer: pl.Trainer, pl_module: pl.LightningModule) -> None:
        if self._handle is not None:
            self._handle.close()
            self._handle = None


def _accelerator(device: str) -> tuple[str, Any]:
    if device.startswith("cuda"):
        return "gpu", [int(device[5:]) if ":" in device else 0]
    return "cpu", 1


def calibrate_many(
    sets: Sequence[tuple[str, list[str]]],
    board_size: tuple[int, int],
    output: str,
    square: float = 1.0,
    pipeline: CalibrationPipeline | None = None,
    detector_name: str = "learned",
    device: str = "cpu",
    sets_per_batch: int = 4,
    num_workers: int = 0,
    progress: bool = True,
) -> dict[str, Any]:
    """Calibrate every image set with ``Trainer.predict``; write one JSON line per set to ``output``.

    Args:
        sets: ``(name, files)`` pairs (see :func:`find_image_sets`).
        board_size: ``(cols, rows)`` inner corners.
        output: the JSON Lines file to write (its directory must exist).
        square: square side in world units.
        pipeline: the pipeline (default: ``CalibrationPipeline(detector_name)``).
        detector_name: detector name, used when ``pipeline`` is None and recorded in the output.
        device: ``cpu``, ``cuda`` or ``cuda:N``.
        sets_per_batch: sets per ``predict_step``.
        num_workers: DataLoader workers loading sets ahead.
        progress: show Lightning's progress bar.

    Returns:
        ``{"sets": int, "succeeded": int, "failed": int, "seconds": float}``.

    Example:
        >>> sets, _ = find_image_sets(["cameras/"])  # doctest: +SKIP
        >>> calibrate_many(sets, (9, 6), "results.jsonl", square=0.025)  # doctest: +SKIP
        {'sets': 300, 'succeeded': 298, 'failed': 2, 'seconds': 412.3}
    """
    pipeline = pipeline if pipeline is not None else CalibrationPipeline(detector_name)
    module = CalibrationLitModule(pipeline, board_size, square, detector_name)
    data = ImageSetDataModule(sets, sets_per_batch=sets_per_batch, num_workers=num_workers)
    writer = JsonlPredictionWriter(output)
    accelerator, devices = _accelerator(device)
    start = time.perf_counter()
    quiet = [logging.getLogger(name) for name in ("lightning.pytorch", "lightning.fabric", "lightning")]
    levels = [logger.level for logger in quiet]
    for logger in quiet:  # no "GPU available: ..." banners around a command-line tool
        logger.setLevel(logging.WARNING)
    try:
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", message=".*does not have many workers.*")
            warnings.filterwarnings("ignore", message=".*predict_dataloader.*num_workers.*")
            warnings.filterwarnings("ignore", message=".*LeafSpec.*")  # Lightning 2.6 vs torch 2.13 pytree notice
            trainer = pl.Trainer(
                accelerator=accelerator, devices=devices, logger=False, enable_checkpointing=False,
                enable_model_summary=False, enable_progress_bar=progress, callbacks=[writer], inference_mode=True,
            )
            trainer.predict(module, datamodule=data, return_predictions=False)
    finally:
        for logger, level in zip(quiet, levels):
            logger.setLevel(level)
        writer.on_predict_end(None, None)  # type: ignore[arg-type]  # closes the file after an interruption too
    return {"sets": len(sets), "succeeded": writer.succeeded, "failed": writer.failed,
            "seconds": time.perf_counter() - start}
