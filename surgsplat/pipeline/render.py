"""Render a run's videos: one mp4 per channel over every frame of its scene.

The default videos are rgb, depth, normal and side_by_side (input | colour | depth); any other
channel the model declares (`SplatModel.channel_descriptors`, e.g. a decomposing method's
reflectance and illumination) can be chosen too, and is shown as its descriptor says
(`export.channel_image`), with a range left to the data fixed once for the whole video. Renders
may be made under another illumination state (the model's `relighting`), into files named
NAME-relit-SOURCE.mp4, or tissue-only.
"""

from __future__ import annotations

from collections.abc import Callable
from contextlib import ExitStack
from pathlib import Path

import numpy as np
import torch

from surgsplat.data.scene import Frame
from surgsplat.errors import SurgsplatError
from surgsplat.export.channel_image import channel_image, display_range, percentile_range
from surgsplat.export.video import VideoWriter, even_size, to_uint8
from surgsplat.model.capabilities import Relighting, required
from surgsplat.model.channels import DEPTH, NORMAL, RGB, ChannelDescriptor, ChannelKind
from surgsplat.model.component import FrameTime
from surgsplat.model.dynamic import SplatModel, render_frame
from surgsplat.render.render import RenderOutput
from surgsplat.train.run import TrainedRun

SIDE_BY_SIDE = "side_by_side"
"""Video: the input frame | the rendered colour | the rendered depth."""
DEFAULT_CHANNELS = (RGB, DEPTH, NORMAL, SIDE_BY_SIDE)


def video_channels(model: SplatModel) -> tuple[str, ...]:
    """The videos `model` can be rendered into: every channel it declares, and SIDE_BY_SIDE."""
    return (*(channel.name for channel in model.channel_descriptors()), SIDE_BY_SIDE)


def check_channels(run: TrainedRun, channels: tuple[str, ...]) -> None:
    """SurgsplatError naming the run's videos unless `channels` is a non-empty choice of them."""
    valid = video_channels(run.model)
    if not channels or any(name not in valid for name in channels):
        raise SurgsplatError(f"--channels: method {run.config.name!r} renders "
                             f"{', '.join(valid)}; got {', '.join(channels) or 'none'}")


def video_ranges(run: TrainedRun,
                 channels: list[ChannelDescriptor]) -> dict[str, tuple[float, float]]:
    """The colour-map range of each scalar channel among `channels` whose descriptor leaves it to
    the data, fixed for the whole video: the depth's from the scene's valid depth (every 97th
    value of each frame) when it has depth; the others' from frame 0's render."""
    open_ranges = [c for c in channels if c.kind is ChannelKind.SCALAR and c.value_range is None]
    ranges = {}
    if run.scene.has_depth and any(channel.name == DEPTH for channel in open_ranges):
        ranges[DEPTH] = percentile_range(torch.cat([f.depth[f.depth > 0][::97]
                                                    for f in run.scene.frames]))
    rest = [channel for channel in open_ranges if channel.name not in ranges]
    if rest:
        out = render_frame(run.model, run.scene.frames[0].camera, FrameTime(0, 0.0))
        ranges.update({channel.name: display_range(out, channel) for channel in rest})
    return ranges


def relighting(run: TrainedRun) -> Relighting:
    """The run's relighting state; SurgsplatError when its method has none."""
    return required(run.model.find(Relighting), f"--relight: method {run.config.name!r} has no "
                    "illumination state to change (train with a method that has one; "
                    "`surgsplat methods` lists each method's components)")


def video_image(name: str, out: RenderOutput, frame: Frame,
                described: dict[str, ChannelDescriptor],
                ranges: dict[str, tuple[float, float]]) -> np.ndarray:
    """uint8 RGB [H, W', 3] of video `name` for `frame` rendered as `out`."""
    if name == SIDE_BY_SIDE:
        return np.concatenate([to_uint8(frame.image.numpy()),
                               *(video_image(shown, out, frame, described, ranges)
                                 for shown in (RGB, DEPTH))], axis=1)
    return channel_image(out, described[name], frame.camera.K, ranges.get(name))


def write_run_videos(run: TrainedRun, out_dir: Path, fps: float,
                     channels: tuple[str, ...] = DEFAULT_CHANNELS,
                     relight: str | int | None = None, tissue_only: bool = False,
                     progress: Callable[[int, int], None] | None = None) -> list[Path]:
    """Render every frame of the run's scene (under illumination `relight` when given, see
    `Relighting.relit`; with `tissue_only`, the tissue-only render, the tool left out); write
    one video per channel in `channels` (of `video_channels`), frame by frame (memory does not
    grow with the clip); `progress(done, total)` after each frame."""
    check_channels(run, channels)
    described = {channel.name: channel for channel in run.model.channel_descriptors()}
    shown = {*channels, *((RGB, DEPTH) if SIDE_BY_SIDE in channels else ())}
    ranges = video_ranges(run, [described[name] for name in shown if name in described])
    background = run.background
    frames = run.scene.frames
    suffix = "" if relight is None else f"-relit-{relight}"
    with ExitStack() as stack:
        if relight is not None:
            stack.enter_context(relighting(run).relit(relight))
        videos = {name: stack.enter_context(VideoWriter(out_dir / f"{name}{suffix}.mp4", fps))
                  for name in channels}
        for done, frame in enumerate(frames, start=1):
            when = FrameTime(frame.index, frame.time, tissue_only=tissue_only)
            out = render_frame(run.model, frame.camera, when, background)
            for name, video in videos.items():
                video.add(even_size(video_image(name, out, frame, described, ranges)))
            if progress:
                progress(done, len(frames))
    return [video.path for video in videos.values()]
