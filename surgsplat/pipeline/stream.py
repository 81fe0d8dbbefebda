"""`surgsplat stream`: reconstruct while the video plays.

The source (`data.stream_source`) is read on a thread of its own, which stamps each frame with
its arrival time and queues it; the training loop takes what has arrived before every step:
each frame is written into the run's scene folder (RUN/scene, an ordinary scene folder, with the
depth and tool masks the frame came with, or its automatic tool mask), integrated into the
model (`train.stream.StreamTrainer`) and trained on at the next step, and replay steps fill the
time until the next frame. The stream ends with the source, or on Ctrl-C; an optional polish
trains on for some seconds; then the time axis is fitted to the frames that came and the scene
folder and the run's files are finished, so that RUN is an ordinary run (`eval`, `render`,
`view`, `export`).

RUN/stream_log.jsonl gets one line per frame when it is first trained on (test frames: when they
arrive), and is rewritten at the end with every frame's final PSNR. RUN/stream.json sums the
stream up. A checkpoint is written after the first frame, every `checkpoint_seconds` and at the
end; until the end, RUN/live.json says what the latest was trained on (`stream_scene`).
"""

from __future__ import annotations

import importlib
import json
import queue
import statistics
import threading
import time
from collections import deque
from collections.abc import Callable, Iterator
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from surgsplat.atomic import write_text_atomic
from surgsplat.data.auto_tool_masks import AutoMaskConfig, auto_tool_masks
from surgsplat.data.stream_source import ArrivedFrame, BadFrame, StreamSource, open_source
from surgsplat.errors import DataError, SurgsplatError
from surgsplat.methods.config import MethodConfig
from surgsplat.pipeline.stream_scene import LIVE_FILE, SCENE_DIR, StreamScene
from surgsplat.pipeline.train import Note, quiet
from surgsplat.train.stream import DEFAULT_HORIZON, FrameRecord, StreamConfig, StreamTrainer
from surgsplat.train.trainer import (CHECKPOINT, LOG_EVERY, LOG_FILE, BUDGET_WINDOW, StepStats,
                                     stops_between_steps)

STREAM_LOG = "stream_log.jsonl"
STREAM_SUMMARY = "stream.json"
BAD_FRAME_ACTIONS = ("skip", "stop")
MASK_SOURCES = ("given", "auto", "none")
"""Tool masks of a stream: the source's own (a scene folder's masks/), the automatic
segmenter's, or none."""


@dataclass
class StreamOptions:
    """What `surgsplat stream` was asked for, beside the method."""

    source: str
    out: Path
    rate: float | None = None  # a video's playing rate, frames per second (None: its own)
    frames: int | None = None  # how many frames the source sends, when the source cannot say
    idle_timeout: float = 10.0  # a folder's end: seconds without a new frame
    on_bad_frame: str = "skip"
    tool_masks: str = "given"
    focal: float | None = None  # pixels; None: the source's, else an assumed field of view
    polish_seconds: float = 0.0
    checkpoint_seconds: float = 10.0  # a checkpoint (and RUN/live.json) this often
    settings: StreamConfig = field(default_factory=StreamConfig)


@dataclass
class StreamResult:
    """What a finished stream reports."""

    trainer: StreamTrainer
    records: list[FrameRecord]
    bad_frames: list[str]
    steps_streaming: int
    polish_steps: int
    stopped_by_user: bool
    streamed_until: float  # seconds from the stream's start to its end (before the polish)
    source_rate: float | None  # frames per second the source played at, when it said


END = object()
"""Queued after the source's last frame."""


def _read_source(source: StreamSource, items: queue.Queue, stop: threading.Event) -> None:
    """Queue every frame of `source` (an ArrivedFrame or a BadFrame) and the error that ends
    it, if one does, then END."""
    frames = source.frames(stop)
    try:
        while not stop.is_set():
            try:
                items.put(next(frames))
            except StopIteration:
                break
            except Exception as err:  # noqa: BLE001 - handed to the training thread to raise
                items.put(err)
                break
    finally:
        frames.close()
        items.put(END)


class AutoMasks:
    """The automatic tool segmenter run on the arriving frames: frame i's mask is ready once
    the segmenter's temporal window past it has arrived (or the stream has ended)."""

    def __init__(self) -> None:
        config = AutoMaskConfig()
        self.delay = config.temporal_radius
        """Frames that must arrive after a frame before its mask is decided."""
        self._images: queue.Queue = queue.Queue()
        self._masks = auto_tool_masks(self._arrived(), None, config)

    def _arrived(self) -> Iterator[np.ndarray]:
        while (image := self._images.get()) is not None:
            yield image

    def add(self, image: np.ndarray) -> None:
        self._images.put(image)

    def end(self) -> None:
        self._images.put(None)

    def next_mask(self) -> np.ndarray:
        return next(self._masks).mask


class _LiveLog:
    """RUN/stream_log.jsonl: a line per frame once it is trained on (test frames: at arrival)."""

    def __init__(self, path: Path):
        self.path = path
        self.handle = open(path, "w", buffering=1)
        self.known = 0  # records 0..known-1 have been seen
        self.pending: set[int] = set()  # seen, not yet written

    def update(self, records: dict[int, FrameRecord]) -> None:
        """Write the lines of the frames of `records` (indices 0..N-1) trained on since."""
        self.pending.update(range(self.known, len(records)))
        self.known = len(records)
        for index in sorted(self.pending):
            record = records[index]
            if record.is_test or record.trained_at is not None:
                self.handle.write(json.dumps(record_line(record)) + "\n")
                self.pending.discard(index)

    def rewrite(self, records: list[FrameRecord]) -> None:
        self.handle.close()
        write_text_atomic(self.path, "".join(json.dumps(record_line(r)) + "\n" for r in records))


def record_line(record: FrameRecord) -> dict:
    line = asdict(record)
    line["lag"] = record.lag
    return line


def stream_run(config: MethodConfig, options: StreamOptions, note: Note = quiet,
               on_step: Callable[[StepStats, int], None] | None = None) -> StreamResult:
    """Stream `options.source` into the run folder `options.out`, which the caller owns
    (`cli.train.new_run_folder`; see the module docstring); `on_step(stats, frames_so_far)`
    after every step."""
    for option, value, choices in (("--on-bad-frame", options.on_bad_frame, BAD_FRAME_ACTIONS),
                                   ("--tool-masks", options.tool_masks, MASK_SOURCES)):
        if value not in choices:
            raise SurgsplatError(f"{option} must be one of {', '.join(choices)}, got {value!r}")
    # PyTorch's optimisers import torch._dynamo when the first is built (about 2 s): import it
    # before the source starts, or the first frames wait for it
    importlib.import_module("torch._dynamo")
    source = open_source(options.source, options.rate, options.idle_timeout, options.frames)
    items: queue.Queue = queue.Queue()
    stop = threading.Event()
    reader = threading.Thread(target=_read_source, args=(source, items, stop), daemon=True,
                              name="stream-source")
    started = time.monotonic()
    reader.start()
    try:
        return _stream(config, options, source, items, started, note, on_step)
    finally:
        # the source's thread ends before this returns: it decodes frames with fd 2 (native
        # code's stderr) redirected, which would swallow the error this may be returning with
        stop.set()
        reader.join()


def _stream(config: MethodConfig, options: StreamOptions, source: StreamSource,
            items: queue.Queue, started: float, note: Note,
            on_step: Callable[[StepStats, int], None] | None) -> StreamResult:
    out = options.out
    bad_frames: list[str] = []
    masks = AutoMasks() if options.tool_masks == "auto" else None
    waiting: deque[ArrivedFrame] = deque()  # arrived, their automatic mask not yet ready
    scene_files: StreamScene | None = None
    trainer: StreamTrainer | None = None
    ended = stopped_by_user = False
    steps_streaming = 0
    log = None
    train_log = None
    recent: deque[float] = deque(maxlen=BUDGET_WINDOW)
    last_save = time.monotonic()

    def take(arrived: ArrivedFrame) -> None:
        nonlocal scene_files, trainer, log, train_log
        tool = arrived.tool if options.tool_masks == "given" else None
        if masks is not None:
            tool = masks.next_mask()
        if scene_files is None:
            out.mkdir(parents=True, exist_ok=True)
            scene_files = StreamScene(out / SCENE_DIR, arrived, source, options.focal,
                                      f"stream of {options.source}", tool)
            frame = scene_files.add(arrived, tool)
            horizon = options.frames or source.camera.expected_frames or DEFAULT_HORIZON
            trainer = StreamTrainer(config, scene_files.scene([frame]), out, horizon,
                                    options.settings, started)
            trainer.records[0].arrival = arrived.arrival - started
            trainer.write_run_files()
            save()
            log = _LiveLog(out / STREAM_LOG)
            train_log = open(out / LOG_FILE, "w", buffering=1)
            return
        trainer.integrate(scene_files.add(arrived, tool), arrived.arrival)

    def save() -> None:
        nonlocal last_save
        trainer.save()
        scene_files.write_live(out, len(trainer.scene.frames), trainer.horizon)
        last_save = time.monotonic()

    def bad(err: BadFrame) -> None:
        bad_frames.append(str(err))
        if options.on_bad_frame == "stop":
            raise err
        note(f"skipped a bad frame: {err}")

    def take_or_skip(arrived: ArrivedFrame) -> None:
        try:
            take(arrived)
        except BadFrame as err:
            bad(err)

    def receive(item) -> None:
        nonlocal ended
        if item is END:
            ended = True
            if masks is not None:
                masks.end()
                while waiting:
                    take_or_skip(waiting.popleft())
            return
        if isinstance(item, BadFrame):
            bad(item)
            return
        if isinstance(item, Exception):
            raise item
        if masks is None:
            take_or_skip(item)
            return
        masks.add(item.image)
        waiting.append(item)
        while len(waiting) > masks.delay:
            take_or_skip(waiting.popleft())

    try:
        with stops_between_steps() as stop_requested:
            while not ended or (trainer is not None and trainer.has_fresh_frames):
                block = trainer is None or not trainer.has_frames_to_train
                try:
                    while not stopped_by_user:
                        receive(items.get(timeout=0.05) if block else items.get_nowait())
                        block = False
                except queue.Empty:
                    pass
                if stop_requested() and not stopped_by_user:
                    # Ctrl-C: no frame is taken from here on; those taken get their step
                    stopped_by_user = ended = True
                if trainer is None:
                    if stopped_by_user:
                        break
                    continue
                if not trainer.has_frames_to_train:
                    continue
                before = trainer.elapsed
                stats = trainer.step()
                recent.append(trainer.elapsed - before)
                steps_streaming += 1
                _log_step(train_log, stats)
                log.update(trainer.records)
                if on_step:
                    on_step(stats, len(trainer.scene.frames))
                if time.monotonic() - last_save >= options.checkpoint_seconds:
                    save()
    except DataError as err:  # a bad frame (--on-bad-frame stop), or the source failed
        stopped_at = err
    else:
        stopped_at = None
    if trainer is None:
        raise stopped_at or SurgsplatError(f"{options.source}: the stream ended before its "
                                           "first frame")
    streamed_until = time.monotonic() - started
    polish_steps = 0 if stopped_by_user else _polish(trainer, options.polish_seconds, recent,
                                                     train_log, on_step)
    trainer.finish()
    trainer.scene = scene_files.finish()
    train_log.close()
    trainer.write_run_files()
    trainer.save()
    (out / LIVE_FILE).unlink()  # an ordinary run from here on
    records = [trainer.records[i] for i in sorted(trainer.records)]
    log.rewrite(records)
    result = StreamResult(trainer, records, bad_frames, steps_streaming, polish_steps,
                          stopped_by_user, streamed_until, source.camera.rate)
    write_text_atomic(out / STREAM_SUMMARY, json.dumps(stream_summary(result, options),
                                                       indent=2) + "\n")
    if stopped_at is not None:
        why = " (--on-bad-frame stop)" if isinstance(stopped_at, BadFrame) else ""
        raise SurgsplatError(f"{stopped_at}; the stream stopped there{why}, and {out} holds "
                             f"the run of the {len(records)} frames before it")
    return result


def _log_step(handle, stats: StepStats) -> None:
    if stats.iteration % LOG_EVERY == 0:
        handle.write(json.dumps(asdict(stats)) + "\n")


def _polish(trainer: StreamTrainer, seconds: float, recent: deque[float], train_log,
            on_step) -> int:
    """Train on for `seconds` after the last frame (rates decaying to their final values);
    the number of steps it took."""
    if seconds <= 0:
        return 0
    per_step = statistics.mean(recent) if recent else 0.1
    steps = max(int(seconds / per_step), 1)
    trainer.start_polish(steps)
    deadline = time.monotonic() + seconds
    done = 0
    with stops_between_steps() as stop_requested:
        while done < steps and time.monotonic() < deadline and not stop_requested():
            stats = trainer.step()
            _log_step(train_log, stats)
            done += 1
            if on_step:
                on_step(stats, len(trainer.scene.frames))
    return done


def stream_summary(result: StreamResult, options: StreamOptions) -> dict:
    """RUN/stream.json: the stream's settings and what it measured."""
    trained = [r for r in result.records if r.lag is not None]
    lags = [r.lag for r in trained]
    trainer = result.trainer
    return {
        "source": options.source, "method": trainer.config.name,
        "rate": options.rate or result.source_rate, "frames": len(result.records),
        "train_frames": sum(not r.is_test for r in result.records),
        "bad_frames": result.bad_frames, "stopped_by_user": result.stopped_by_user,
        "steps_streaming": result.steps_streaming, "polish_steps": result.polish_steps,
        "polish_seconds": options.polish_seconds,
        "lag_median_s": statistics.median(lags) if lags else None,
        "lag_max_s": max(lags) if lags else None,
        "untrained_frames": sum(not r.is_test and r.lag is None for r in result.records),
        "first_arrival_s": result.records[0].arrival,
        "last_arrival_s": result.records[-1].arrival,
        "streamed_until_s": result.streamed_until,
        "train_seconds": trainer.elapsed,
        "gaussians": trainer.model.gaussians.num_gaussians,
        "tool_masks": options.tool_masks,
        "settings": asdict(options.settings),
        "checkpoint": str(options.out / CHECKPOINT),
    }
