"""Calibrate many cameras at once through Lightning's ``Trainer.predict`` (``calibrate-many``).

One *image set* (a directory of chessboard images of one camera) is one dataset item:

* :class:`ImageSetDataset` loads a set (in DataLoader workers, in parallel with the model) and
  keeps the images of its most common size;
* :class:`ImageSetDataModule` leaves out the sets already written and hands each process (rank) of a distributed
  run its own disjoint share, whole batches strided over the ranks (no set twice: Lightning's distributed sampler,
  which pads the last ranks with repeated items, is not used), so a set meets the same batch on any number of ranks;
* :class:`CalibrationLitModule` wraps :class:`~ccs_kornia.pipeline.calibration_pipeline.CalibrationPipeline` (moved to the rank's device
  by Lightning): its ``predict_step`` detects the boards of every set of the batch, then calibrates all sets of one
  image size in **one batched solver call** (cameras padded to the same number of views, with masks);
* :class:`JsonlPredictionWriter` appends one JSON line per set as soon as its batch is done, so
  results stream to disk (nothing is accumulated in memory) and an interrupted run keeps what it
  finished; a distributed run writes one shard per rank, merged into the output by rank 0 at the end
  (:mod:`ccs_kornia.fleet.shards`).

:func:`calibrate_many` hands ``accelerator``, ``devices``, ``num_nodes`` and ``strategy`` to the Trainer: DDP over
processes, GPUs and nodes, launched by Lightning itself, by ``torchrun`` or by SLURM's ``srun`` (``docs/fleet.md``).

Every line has the keys of ``calibrate``'s JSON (DESIGN section 4) plus ``set`` (the directory),
``success`` and ``error`` (``None`` for a calibrated set, the reason for a set that could not be calibrated, with
``K`` null).

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
from datetime import timedelta
from typing import Any

import lightning.pytorch as pl
import torch
from lightning.pytorch.callbacks import BasePredictionWriter
from torch.utils.data import DataLoader, Dataset

from ccs_kornia.fleet.shards import (
    finished_sets,
    merge_shards,
    not_jsonl_reason,
    set_outcomes,
    shard_files,
    shard_path,
    trim_partial_line,
)
from ccs_kornia.io.files import json_line
from ccs_kornia.io.images import IMAGE_EXTENSIONS, load_image_gray
from ccs_kornia.io.video import is_video
from ccs_kornia.outputs.records import camera_record
from ccs_kornia.pipeline.calibration_pipeline import CalibrationPipeline
from ccs_kornia.pipeline.sources import ViewSource
from ccs_kornia.runtime.checks import check_board_size

__all__ = [
    "find_image_sets",
    "ImageSetDataset",
    "ImageSetDataModule",
    "CalibrationLitModule",
    "JsonlPredictionWriter",
    "calibrate_many",
    "finished_sets",
    "launched_as_rank_zero",
]

#: how long the ranks that are done wait for the slowest one before the merge (the process group's timeout)
FINISH_TIMEOUT = timedelta(hours=24)

def _images_in(directory: str) -> list[str]:
    return sorted(
        os.path.join(directory, name)
        for name in os.listdir(directory)
        if name.lower().endswith(IMAGE_EXTENSIONS) and os.path.isfile(os.path.join(directory, name))
    )


def _videos_in(directory: str) -> list[str]:
    return sorted(os.path.join(directory, name) for name in os.listdir(directory)
                  if is_video(name) and os.path.isfile(os.path.join(directory, name)))


def find_image_sets(items: Iterable[str]) -> tuple[list[tuple[str, list[str]]], list[tuple[str, str]]]:
    """Turn command-line items into image sets (one camera each).

    A directory holding image files is one set. A directory holding no image file but
    sub-directories that do (``cameras/cam_000/*.png``, ...) gives one set per such sub-directory.
    A glob gives every directory it matches, by the same rules. A video is one set (its files: the video alone; its
    frames are chosen when the set is loaded), and so is each video of a directory holding videos and no image.

    Args:
        items: directories, videos or globs.

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

    def add_video(path: str) -> None:
        key = os.path.normpath(os.path.abspath(path))
        if key not in seen:
            seen.add(key)
            sets.append((path, [path]))

    def add_directory(directory: str, item: str) -> bool:
        files = _images_in(directory)
        if files:
            key = os.path.normpath(os.path.abspath(directory))
            if key not in seen:
                seen.add(key)
                sets.append((directory, files))
            return True
        videos = _videos_in(directory)
        for path in videos:
            add_video(path)
        found = bool(videos)
        for name in sorted(os.listdir(directory)):
            sub = os.path.join(directory, name)
            if os.path.isdir(sub) and _images_in(sub):
                found = add_directory(sub, item) or found
        return found

    for item in items:
        if os.path.isdir(item):
            if not add_directory(item, item):
                problems.append((item, "no image files in it or in its sub-directories"))
        elif os.path.isfile(item) and is_video(item):
            add_video(item)
        elif os.path.isfile(item):
            problems.append((item, "is a file; an image set is a directory of images or a video (use calibrate for "
                                   "one set)"))
        elif set("*?[") & set(item):
            matches = sorted(glob.glob(item, recursive=True))
            videos = [p for p in matches if os.path.isfile(p) and is_video(p)]
            dirs = [p for p in matches if os.path.isdir(p)]
            for path in videos:
                add_video(path)
            if not dirs and not videos:
                problems.append((item, "glob matched no directory"))
            elif not any([add_directory(d, item) for d in dirs]) and not videos:
                problems.append((item, "the directories it matched hold no image files"))
        else:
            problems.append((item, "no such directory"))
    return sets, problems


class ImageSetDataset(Dataset):
    """One item per image set: its grey images, decoded (in DataLoader workers, ahead of the model).

    Args:
        sets: ``(name, files)`` pairs (see :func:`find_image_sets`).
        video: how a video set becomes views (:class:`~ccs_kornia.pipeline.video_input.VideoOptions`; ``None``:
            no video set is expected).

    Item:
        dict with ``name``, ``files`` (all inputs, in order) and ``images``: one :math:`(1, H, W)` float tensor in
        ``[0, 1]`` per file, or the reason string where the file could not be read (sizes may differ: the pipeline
        decides which views fit the camera). A video set's ``files`` are its chosen frames (``VIDEO#INDEX``), its
        images ``uint8``, with ``timestamps`` and ``video`` (what the screening saw).
    """

    def __init__(self, sets: Sequence[tuple[str, list[str]]], video: Any = None) -> None:
        self.sets = list(sets)
        self.video = video

    def __len__(self) -> int:
        return len(self.sets)

    def __getitem__(self, index: int) -> dict[str, Any]:
        name, files = self.sets[index]
        if len(files) == 1 and is_video(files[0]):
            from ccs_kornia.pipeline.video_input import VideoOptions, load_video_set

            if not isinstance(self.video, VideoOptions):
                raise ValueError(f"{files[0]} is a video: the dataset needs VideoOptions (the board's screen)")
            return {"name": name, **load_video_set(files[0], self.video)}
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
        if isinstance(image, str):
            return None, image
        return (image if image.is_floating_point() else image.float() / 255.0), ""


def _collate_sets(items: list[dict[str, Any]]) -> list[dict[str, Any]]:
    # sets differ in view count and image size: keep them as a list, the pipeline pads what it batches
    return items


class ImageSetDataModule(pl.LightningDataModule):
    """Predict-only data module over image sets: the sets not written yet, this rank's share of them.

    Args:
        sets: ``(name, files)`` pairs.
        sets_per_batch: sets handed to one ``predict_step`` (those of one image size are calibrated in
            one batched call).
        num_workers: DataLoader worker processes loading sets ahead of the model.
        output: the output file; the sets with a line in it or in one of its shards are left out (``None``: none).
        overwrite: leave nothing out (the output is started again).
        video: how video sets become views (:class:`~ccs_kornia.pipeline.video_input.VideoOptions`).

    The sets left to do are cut into batches of ``sets_per_batch`` in order, and rank ``r`` of ``W`` takes batches
    ``r, r + W, r + 2W, ...``: the shares are disjoint, together they hold every set once, and each batch is the one a
    single process would form. A rank may get no batch (fewer batches than ranks).
    """

    def __init__(self, sets: Sequence[tuple[str, list[str]]], sets_per_batch: int = 4, num_workers: int = 0,
                 output: str | None = None, overwrite: bool = False, video: Any = None) -> None:
        super().__init__()
        if sets_per_batch < 1:
            raise ValueError(f"sets_per_batch must be >= 1, got {sets_per_batch}.")
        # a rank may have no set left (fewer batches than ranks): its loop is empty, the others go on
        self.allow_zero_length_dataloader_with_multiple_devices = True
        self.sets = list(sets)
        self.todo = list(self.sets)
        self.sets_per_batch = sets_per_batch
        self.num_workers = num_workers
        self.output = output
        self.overwrite = overwrite
        self.video = video

    def setup(self, stage: str) -> None:
        # every rank reads the same files here: no rank writes before Lightning's barrier that follows the setup hooks
        if self.output is not None and not self.overwrite:
            done = finished_sets(self.output)
            self.todo = [s for s in self.sets if str(s[0]) not in done]

    def rank_share(self) -> list[tuple[str, list[str]]]:
        """This rank's sets: its batches of the sets left to do, in order."""
        rank, world = (self.trainer.global_rank, self.trainer.world_size) if self.trainer is not None else (0, 1)
        starts = range(rank * self.sets_per_batch, len(self.todo), world * self.sets_per_batch)
        return [s for start in starts for s in self.todo[start:start + self.sets_per_batch]]

    def transfer_batch_to_device(self, batch: Any, device: torch.device, dataloader_idx: int) -> Any:
        # the decoded images stay on the host: the pipeline moves each detection batch to its own device (the
        # rank's GPU), a bounded number of pixels at a time, as it does for ``calibrate --device cuda``
        return batch

    def predict_dataloader(self) -> DataLoader:
        # consecutive batches of the share are the rank's batches: all full but the last of all
        return DataLoader(
            ImageSetDataset(self.rank_share(), self.video), batch_size=self.sets_per_batch, shuffle=False,
            num_workers=self.num_workers, collate_fn=_collate_sets, persistent_workers=False,
        )


class CalibrationLitModule(pl.LightningModule):
    """:class:`~ccs_kornia.pipeline.calibration_pipeline.CalibrationPipeline` as a LightningModule for ``Trainer.predict``.

    Args:
        pipeline: the pipeline (detector, model, RANSAC settings).
        board_size: ``(cols, rows)`` inner corners.
        square: square side in world units.
        detector_name: recorded in the output.
        board_record: recorded in every line too, e.g. ``{"charuco": {...}}`` for a marker board (``None``: nothing).

    ``predict_step`` runs the pipeline's one composition (:meth:`~ccs_kornia.pipeline.calibration_pipeline.CalibrationPipeline.run`)
    on the sets of the batch (cameras of one image size are solved in one batched call) and returns one
    JSON-ready dict per set.
    """

    def __init__(self, pipeline: CalibrationPipeline, board_size: tuple[int, int], square: float = 1.0,
                 detector_name: str = "learned", board_record: dict[str, Any] | None = None) -> None:
        super().__init__()
        self.pipeline = pipeline
        self.board_record = dict(board_record or {})
        self.board_size = check_board_size(board_size)
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
                                   detector=self.detector_name, model=self.pipeline.settings.model)
            if "video" in item:  # a recording: each view's timestamp, and what the screening saw of every frame
                for view in record["views"]:
                    if view["path"] in item["timestamps"]:
                        view["timestamp"] = item["timestamps"][view["path"]]
                record["video"] = item["video"]
                if item.get("error"):
                    record["success"], record["error"] = False, item["error"]
            # every line has the same keys: ``error`` is None for a calibrated set
            records.append({"set": item["name"], "success": record["success"], "error": None, **record,
                            **self.board_record, "timings": {"seconds_per_set": seconds}})
        return records


class JsonlPredictionWriter(BasePredictionWriter):
    """Append one JSON line per image set after every predict batch (flushed and synced at once).

    One process appends to ``path`` itself; rank ``r`` of a distributed run appends to its shard ``<path>.rank<r>``,
    which :func:`calibrate_many`'s rank 0 merges into ``path`` once every rank is done
    (:func:`~ccs_kornia.fleet.shards.merge_shards`). Lines already there are kept (``calibrate_many`` skips their
    sets), and an interrupted run leaves every finished line intact in the output or a shard.

    Args:
        path: the output file.
        overwrite: start the output again (its shards too) instead of appending.

    Attributes:
        succeeded / failed: counts of sets this rank wrote.
    """

    def __init__(self, path: str, overwrite: bool = False) -> None:
        super().__init__(write_interval="batch")
        self.path = path
        self.overwrite = overwrite
        self.succeeded = 0
        self.failed = 0
        self._handle = None

    def setup(self, trainer: pl.Trainer, pl_module: pl.LightningModule, stage: str) -> None:
        # before Lightning's barrier that follows the setup hooks, so before any rank opens its shard
        if self.overwrite and trainer.is_global_zero:
            for shard in shard_files(self.path):
                os.remove(shard)
            open(self.path, "w", encoding="utf-8").close()  # noqa: SIM115

    def on_predict_start(self, trainer: pl.Trainer, pl_module: pl.LightningModule) -> None:
        shard = shard_path(self.path, trainer.global_rank, trainer.world_size)
        trim_partial_line(shard)
        self._handle = open(shard, "a", encoding="utf-8")  # noqa: SIM115 (closed in on_predict_end or close)

    def write_on_batch_end(self, trainer, pl_module, prediction, batch_indices, batch, batch_idx, dataloader_idx) -> None:
        assert self._handle is not None
        for record in prediction:
            self._handle.write(json_line(record) + "\n")
            if record.get("success"):
                self.succeeded += 1
            else:
                self.failed += 1
        self._handle.flush()
        os.fsync(self._handle.fileno())

    def on_predict_end(self, trainer: pl.Trainer, pl_module: pl.LightningModule) -> None:
        self.close()

    def close(self) -> None:
        """Close this rank's file (also after an interruption)."""
        if self._handle is not None:
            self._handle.close()
            self._handle = None


def launched_as_rank_zero() -> bool:
    """Whether this process is rank 0 as its launcher set it (``torchrun``: ``RANK``; SLURM: ``SLURM_PROCID``;
    Lightning's own launcher: ``NODE_RANK`` and ``LOCAL_RANK``); true for a process started alone. Known before the
    Trainer exists, so only rank 0 says what a run is about to do.

    Example:
        >>> isinstance(launched_as_rank_zero(), bool)
        True
    """
    return all(os.environ.get(key, "0") in ("", "0") for key in ("RANK", "SLURM_PROCID", "NODE_RANK", "LOCAL_RANK"))


def _launched_by_others() -> bool:
    # processes started by torchrun, srun or Lightning's launcher: each one has to meet the others in the Trainer
    return any(os.environ.get(key) for key in ("WORLD_SIZE", "LOCAL_RANK", "TORCHELASTIC_RUN_ID")) or \
        int(os.environ.get("SLURM_NTASKS", "1") or 1) > 1


def _trainer_devices(device: str, accelerator: str | None, devices: int | list[int] | None) -> tuple[str, Any]:
    if accelerator is None:
        accelerator = "gpu" if device.startswith("cuda") else "cpu"
    if devices is None:
        devices = [int(device[5:])] if device.startswith("cuda:") and accelerator == "gpu" else 1
    return accelerator, devices


def _strategy(strategy: str, devices: int | list[int], num_nodes: int) -> Any:
    many = (devices if isinstance(devices, int) else len(devices)) * num_nodes > 1
    if strategy == "ddp" or (strategy == "auto" and many):
        from lightning.pytorch.strategies import DDPStrategy

        return DDPStrategy(timeout=FINISH_TIMEOUT)
    if strategy != "auto":
        raise ValueError(f"strategy must be 'auto' or 'ddp', got {strategy!r}.")
    return "auto"


def _summary(output: str, sets: Sequence[tuple[str, list[str]]], todo: Sequence[tuple[str, list[str]]],
             seconds: float, rank: int, world: int) -> dict[str, Any]:
    names = [str(n) for n, _ in sets]
    ran = [str(n) for n, _ in todo]
    held = set_outcomes(output, names) if rank == 0 else {}
    succeeded = sum(1 for n in ran if held.get(n) is True)
    failed = sum(1 for n in ran if held.get(n) is False)
    return {"sets": len(names), "succeeded": succeeded, "failed": failed, "skipped": len(names) - len(ran),
            "missing": len(ran) - succeeded - failed if rank == 0 else 0, "seconds": seconds,
            "file_succeeded": sum(held.values()), "file_failed": len(held) - sum(held.values()),
            "rank": rank, "world_size": world}


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
    accelerator: str | None = None,
    devices: int | list[int] | None = None,
    num_nodes: int = 1,
    strategy: str = "auto",
    board_record: dict[str, Any] | None = None,
    video: Any = None,
) -> dict[str, Any]:
    """Calibrate every image set with ``Trainer.predict``; append one JSON line per set to ``output``.

    Sets that already have a line in ``output`` (or in a shard a stopped distributed run left beside it) are skipped
    (a run resumes where an interrupted one stopped); ``overwrite`` starts the file again. With several processes
    (``devices`` x ``num_nodes``), each takes a disjoint share of the sets and writes a shard, merged into ``output``
    by rank 0 at the end (:mod:`ccs_kornia.fleet.shards`); the lines are the ones one process writes.

    Args:
        sets: ``(name, files)`` pairs (see :func:`find_image_sets`).
        board_size: ``(cols, rows)`` inner corners.
        output: the JSON Lines file to write (its directory must exist; on a shared file system for several nodes).
        square: square side in world units.
        pipeline: the pipeline (default: ``CalibrationPipeline(detector_name)``).
        detector_name: detector name, used when ``pipeline`` is None and recorded in the output.
        device: ``cpu``, ``cuda`` or ``cuda:N`` (one device; ``accelerator``/``devices`` take precedence).
        sets_per_batch: sets per ``predict_step``.
        num_workers: DataLoader workers loading sets ahead (per rank).
        progress: show Lightning's progress bar (rank 0's share).
        overwrite: truncate ``output`` first instead of resuming.
        accelerator: the Trainer's ``cpu``, ``gpu`` or ``auto`` (default: from ``device``).
        devices: processes per node (one per GPU), or a list of GPU indices (default: from ``device``).
        num_nodes: nodes.
        strategy: ``auto`` (DDP when there are several processes) or ``ddp``.
        board_record: added to every line (a marker board's description, e.g. ``{"charuco": {...}}``).
        video: how video sets become views (:class:`~ccs_kornia.pipeline.video_input.VideoOptions`).

    Returns:
        On rank 0: ``{"sets", "succeeded", "failed", "skipped", "missing", "seconds", "file_succeeded",
        "file_failed", "rank", "world_size"}``: ``succeeded``/``failed`` count what this run wrote, ``skipped`` the
        sets already written, ``missing`` the sets of this run with no line (a rank that stopped early),
        ``file_succeeded``/``file_failed`` the given sets as the output now holds them. The other ranks return their
        ``rank`` and zero counts.

    Raises:
        ValueError: ``output`` is not calibrate-many's JSON Lines (and ``overwrite`` is not set).

    Example:
        >>> sets, _ = find_image_sets(["cameras/"])  # doctest: +SKIP
        >>> calibrate_many(sets, (9, 6), "results.jsonl", square=0.025)  # doctest: +SKIP
        {'sets': 300, 'succeeded': 298, 'failed': 2, 'skipped': 0, 'missing': 0, 'seconds': 412.3, ...}
    """
    if not overwrite and (reason := not_jsonl_reason(output)) is not None:
        raise ValueError(f"{output}: {reason}")
    pipeline = pipeline if pipeline is not None else CalibrationPipeline(detector_name)
    sets = list(sets)
    accelerator, devices = _trainer_devices(device, accelerator, devices)
    trainer_strategy = _strategy(strategy, devices, num_nodes)
    start = time.perf_counter()
    if not overwrite and not _launched_by_others() and trainer_strategy == "auto":
        # one process alone: nothing to do is known before any Trainer (a stopped run's shards are merged)
        done = finished_sets(output)
        if all(str(name) in done for name, _ in sets):
            merge_shards(output, [str(n) for n, _ in sets])
            return _summary(output, sets, [], 0.0, 0, 1)
    module = CalibrationLitModule(pipeline, board_size, square, detector_name, board_record)
    data = ImageSetDataModule(sets, sets_per_batch=sets_per_batch, num_workers=num_workers, output=output,
                              overwrite=overwrite, video=video)
    writer = JsonlPredictionWriter(output, overwrite=overwrite)
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
            warnings.filterwarnings("ignore", message=".*across ranks is zero.*")  # a rank with no set left
            trainer = pl.Trainer(
                accelerator=accelerator, devices=devices, num_nodes=num_nodes, strategy=trainer_strategy,
                use_distributed_sampler=False,  # the data module shares the sets out itself (no padded repeats)
                logger=False, enable_checkpointing=False, enable_model_summary=False, enable_progress_bar=progress,
                callbacks=[writer], inference_mode=True,
            )
            try:
                trainer.predict(module, datamodule=data, return_predictions=False)
                writer.close()
                # every rank done (a rank with no set left returns at once): rank 0 merges the shards
                trainer.strategy.barrier("calibrate-many: every rank done")
            except SystemExit:
                # Lightning turns Ctrl-C into a graceful shutdown and sys.exit(1); say what it was
                if trainer.interrupted:
                    raise KeyboardInterrupt from None
                raise
            except RuntimeError as err:
                if trainer.world_size == 1:
                    raise
                first = (str(err).strip().splitlines() or [""])[0]
                raise RuntimeError(f"a process of the run stopped ({first}); every finished line is kept and the same "
                                   "command again completes the rest") from err
            if trainer.is_global_zero:
                merge_shards(output, [str(n) for n, _ in sets])
    finally:
        signal.signal(signal.SIGINT, sigint)  # Lightning ignores SIGINT after an interruption
        for logger, level in zip(quiet, levels):
            logger.setLevel(level)
        writer.close()  # after an interruption too
    return _summary(output, sets, data.todo, time.perf_counter() - start, trainer.global_rank, trainer.world_size)
