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
import signal
import time
import warnings
from collections.abc import Iterable, Sequence
from typing import Any

import lightning.pytorch as pl
import torch
from lightning.pytorch.callbacks import BasePredictionWriter
from torch.utils.data import DataLoader, Dataset

from ccs_kornia.io import IMAGE_EXTENSIONS, json_line, load_image_gray
from ccs_kornia.pipeline import CalibrationPipeline
from ccs_kornia.records import camera_record
from ccs_kornia.sources import ViewSource

__all__ = [
    "find_image_sets",
    "ImageSetDataset",
    "ImageSetDataModule",
    "CalibrationLitModule",
    "JsonlPredictionWriter",
    "calibrate_many",
    "finished_sets",
]

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
    """One item per image set: its grey images, decoded (in DataLoader workers, ahead of the model).

    Args:
        sets: ``(name, files)`` pairs (see :func:`find_image_sets`).

    Item:
        dict with ``name``, ``files`` (all inputs, in order) and ``images``: one :math:`(1, H, W)` float tensor in
        ``[0, 1]`` per file, or the reason string where the file could not be read (sizes may differ: the pipeline
        decides which views fit the camera).
    """

    def __init__(self, sets: Sequence[tuple[str, list[str]]]) -> None:
        self.sets = list(sets)

    def __len__(self) -> int:
        return len(self.sets)

    def __getitem__(self, index: int) -> dict[str, Any]:
        name, files = self.sets[index]
        images: list[Any] = []
        for path in files:
            image, reason = load_image_gray(path)
            images.append(reason if image is None else torch.from_numpy(image)[None])
        return {"name": name, "files": list(files), "images": images}


class _DecodedSource(ViewSource):
    """The views of a predict batch, decoded by the dataset (unreadable files keep their reason)."""

    def __init__(self, items: list[dict[str, Any]]) -> None:
        self.items = items
        super().__init__([len(item["files"]) for item in items], [item["name"] for item in items])

    def describe(self, camera: int, view: int) -> str:
        return self.items[camera]["files"][view]

    def _load(self, camera: int, view: int) -> tuple[torch.Tensor | None, str]:
        image = self.items[camera]["images"][view]
        return (None, image) if isinstance(image, str) else (image, "")


def _collate_sets(items: list[dict[str, Any]]) -> list[dict[str, Any]]:
    # sets differ in view count and image size: keep them as a list, the pipeline pads what it batches
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


class CalibrationLitModule(pl.LightningModule):
    """:class:`~ccs_kornia.pipeline.CalibrationPipeline` as a LightningModule for ``Trainer.predict``.

    Args:
        pipeline: the pipeline (detector, model, RANSAC settings).
        board_size: ``(cols, rows)`` inner corners.
        square: square side in world units.
        detector_name: recorded in the output.

    ``predict_step`` runs the pipeline's one composition (:meth:`~ccs_kornia.pipeline.CalibrationPipeline.run`)
    on the sets of the batch (cameras of one image size are solved in one batched call) and returns one
    JSON-ready dict per set.
    """

    def __init__(self, pipeline: CalibrationPipeline, board_size: tuple[int, int], square: float = 1.0,
                 detector_name: str = "learned") -> None:
        super().__init__()
        self.pipeline = pipeline
        self.board_size = (int(board_size[0]), int(board_size[1]))
        self.square = float(square)
        self.detector_name = detector_name

    def predict_step(self, batch: list[dict[str, Any]], batch_idx: int = 0) -> list[dict[str, Any]]:
        start = time.perf_counter()
        out = self.pipeline.run(_DecodedSource(batch), self.board_size, self.square)
        seconds = (time.perf_counter() - start) / max(1, len(batch))
        records = []
        for c, item in enumerate(batch):
            one = out.select(c)
            record = camera_record(one, item["files"], board=self.board_size, square=self.square,
                                   detector=self.detector_name, model=self.pipeline.model)
            records.append({"set": item["name"], **record, "timings": {"seconds_per_set": seconds}})
        return records


class JsonlPredictionWriter(BasePredictionWriter):
    """Append one JSON line per image set to ``path`` after every predict batch (flushed at once).

    The file is opened for appending: lines already there are kept (``calibrate_many`` skips their sets), and an
    interrupted run leaves every finished line intact.

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
        self._handle = open(self.path, "a", encoding="utf-8")  # noqa: SIM115 (closed in on_predict_end)

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


def finished_sets(path: str) -> set[str]:
    """Names of the sets that already have a complete line in a ``calibrate-many`` output file.

    A last line cut short by an interruption is ignored (and will be written again).

    Example:
        >>> finished_sets("/nonexistent.jsonl")
        set()
    """
    import json

    done: set[str] = set()
    if not os.path.isfile(path):
        return done
    with open(path, encoding="utf-8") as handle:
        for line in handle:
            try:
                record = json.loads(line)
            except ValueError:
                continue
            if isinstance(record, dict) and "set" in record:
                done.add(str(record["set"]))
    return done


def _trim_partial_line(path: str) -> None:
    """Cut a last line without its newline (an interrupted write), so appended lines start clean."""
    if not os.path.isfile(path) or os.path.getsize(path) == 0:
        return
    with open(path, "rb+") as handle:
        data = handle.read()
        if data.endswith(b"\n"):
            return
        cut = data.rfind(b"\n") + 1
        handle.seek(cut)
        handle.truncate()


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
    overwrite: bool = False,
) -> dict[str, Any]:
    """Calibrate every image set with ``Trainer.predict``; append one JSON line per set to ``output``.

    Sets that already have a line in ``output`` are skipped (a run resumes where an interrupted one stopped);
    ``overwrite`` starts the file again.

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
        overwrite: truncate ``output`` first instead of resuming.

    Returns:
        ``{"sets": int, "succeeded": int, "failed": int, "skipped": int, "seconds": float}`` (``skipped``: sets
        already in ``output``).

    Example:
        >>> sets, _ = find_image_sets(["cameras/"])  # doctest: +SKIP
        >>> calibrate_many(sets, (9, 6), "results.jsonl", square=0.025)  # doctest: +SKIP
        {'sets': 300, 'succeeded': 298, 'failed': 2, 'seconds': 412.3}
    """
    pipeline = pipeline if pipeline is not None else CalibrationPipeline(detector_name)
    if overwrite and os.path.exists(output):
        open(output, "w", encoding="utf-8").close()  # noqa: SIM115
    _trim_partial_line(output)
    done = finished_sets(output)
    todo = [s for s in sets if str(s[0]) not in done]
    skipped = len(sets) - len(todo)
    if not todo:
        return {"sets": len(sets), "succeeded": 0, "failed": 0, "skipped": skipped, "seconds": 0.0}
    sets = todo
    module = CalibrationLitModule(pipeline, board_size, square, detector_name)
    data = ImageSetDataModule(sets, sets_per_batch=sets_per_batch, num_workers=num_workers)
    writer = JsonlPredictionWriter(output)
    accelerator, devices = _accelerator(device)
    start = time.perf_counter()
    sigint = signal.getsignal(signal.SIGINT)
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
            try:
                trainer.predict(module, datamodule=data, return_predictions=False)
            except SystemExit:
                # Lightning turns Ctrl-C into a graceful shutdown and sys.exit(1); say what it was
                if trainer.interrupted:
                    raise KeyboardInterrupt from None
                raise
    finally:
        signal.signal(signal.SIGINT, sigint)  # Lightning ignores SIGINT after an interruption
        for logger, level in zip(quiet, levels):
            logger.setLevel(level)
        writer.on_predict_end(None, None)  # type: ignore[arg-type]  # closes the file after an interruption too
    return {"sets": len(sets) + skipped, "succeeded": writer.succeeded, "failed": writer.failed,
            "skipped": skipped, "seconds": time.perf_counter() - start}
