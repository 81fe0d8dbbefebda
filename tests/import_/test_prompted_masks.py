"""Tool masks from clicks (`surgsplat import --tool-prompts`): the prompt file's errors, one
click carried through a drawn clip whose instrument and camera move, a tool that leaves the view
and comes back found again without a new click, a second prompt re-anchoring the clip, and the
import writing the masks and recording the prompts."""

import json
from pathlib import Path

import cv2
import imageio.v3 as iio
import numpy as np
import pytest

from surgsplat.data.importer import ImportConfig, import_scene
from surgsplat.data.prompted_masks import (PromptConfig, ToolPrompt, farthest_inside,
                                           prompted_tool_masks, read_prompts, seed_mask)
from surgsplat.data.scene import load_scene
from surgsplat.errors import DataError, SurgsplatError
from surgsplat.export.mask_preview import STRIP_PX, write_mask_preview

HEIGHT, WIDTH = 240, 427


def tissue(seed: int, size=(HEIGHT + 40, WIDTH + 40)) -> np.ndarray:
    """float32 RGB: pink tissue with shading, vessels and fine texture, larger than a frame."""
    rng = np.random.default_rng(seed)
    height, width = size
    ys, xs = np.mgrid[0:height, 0:width]
    light = 0.65 + 0.3 * np.cos((xs - width / 2) / width * 2.5) * np.cos((ys - height / 2) / height)
    canvas = np.stack([c * light for c in (205, 95, 80)], axis=-1).astype(np.float32)
    for _ in range(10):
        row = int(rng.integers(0, height))
        cv2.line(canvas, (0, row), (width - 1, row + int(rng.integers(-80, 80))),
                 (120, 40, 40), 2)
    return canvas + cv2.GaussianBlur(rng.normal(0, 5, canvas.shape).astype(np.float32), (0, 0), 1)


def instrument(frame: np.ndarray, tip: tuple[int, int], colour=(120, 118, 122),
               from_left: bool = False) -> np.ndarray:
    """Draw a shaft of `colour` entering from the right border (or the left) to `tip`, with
    darker edges and a highlight; bool [H, W] its mask."""
    mask = np.zeros(frame.shape[:2], np.uint8)
    entry = (-40 if from_left else WIDTH + 40, tip[1] - 60)
    cv2.line(mask, entry, tip, 1, 22)
    frame[mask > 0] = colour
    edges = np.zeros_like(mask)
    cv2.line(edges, entry, tip, 1, 22)
    cv2.line(edges, entry, tip, 0, 16)
    frame[edges > 0] = tuple(0.5 * c for c in colour)
    streak = np.zeros_like(mask)
    cv2.line(streak, (entry[0], entry[1] - 3), (tip[0], tip[1] - 3), 1, 2)
    frame[(streak > 0) & (mask > 0)] = (245, 245, 245)
    return mask > 0


def clip(tips: list[tuple[int, int]]) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Frames (uint8 RGB [H, W, 3]) of a camera drifting over tissue while the instrument's tip
    follows `tips`, and the instrument's true masks."""
    canvas = tissue(0)
    frames, truths = [], []
    for step, tip in enumerate(tips):
        frame = canvas[20 - step // 2:20 - step // 2 + HEIGHT,
                       20 + step // 2:20 + step // 2 + WIDTH].copy()
        truths.append(instrument(frame, tip))
        frames.append(np.clip(frame, 0, 255).astype(np.uint8))
    return frames, truths


def masks(frames, prompts) -> list[np.ndarray]:
    """The prompted masks of `frames` (already at the working size) and their confidences."""
    results = prompted_tool_masks(frames, None, [seeds(prompt) for prompt in prompts])
    assert all(0.0 <= result.confidence <= 1.0 for result in results)
    return [result.at_frame_size(frame, None, PromptConfig())
            for result, frame in zip(results, frames)]


def iou(mask: np.ndarray, truth: np.ndarray) -> float:
    union = (mask | truth).sum()
    return 1.0 if union == 0 else float((mask & truth).sum() / union)


def seeds(prompt: ToolPrompt) -> tuple[int, np.ndarray, np.ndarray]:
    """(frame, tool seeds, tissue seeds) of `prompt` at the frame size."""
    radius = PromptConfig().click_radius
    return (prompt.frame, seed_mask(prompt, "tool", (HEIGHT, WIDTH), radius),
            seed_mask(prompt, "tissue", (HEIGHT, WIDTH), radius))


def test_one_click_follows_a_moving_tool_through_the_clip():
    """One click on the shaft of frame 6 (the middle); the instrument moves 5 px a frame and
    the camera drifts: every frame's mask matches the truth (IoU >= 0.85), before and after
    the clicked frame."""
    frames, truths = clip([(230 - 5 * step, 120 + 3 * step) for step in range(12)])
    click = ToolPrompt(6, (farthest_inside(truths[6]),))
    scores = [iou(mask, truth) for mask, truth in zip(masks(frames, [click]), truths)]
    assert min(scores) >= 0.85, scores


def test_a_tool_that_leaves_and_returns_is_found_again():
    """The instrument withdraws out of the view in frames 5-8 and comes back in 9-13: no mask
    while it is gone (at most 0.5 % of the frame), and IoU >= 0.8 once it is back, from the one
    click on frame 0."""
    tips = ([(200 + 40 * step, 120) for step in range(5)] + [(WIDTH + 80, 120)] * 4
            + [(WIDTH - 40 * step, 120) for step in range(1, 6)])
    frames, truths = clip(tips)
    click = ToolPrompt(0, (farthest_inside(truths[0]),), ((100.0, 120.0),))
    assert not truths[0][120, 100] and not any(truth.any() for truth in truths[5:9])
    found = masks(frames, [click])
    for mask in found[5:9]:
        assert mask.mean() <= 0.005
    scores = [iou(mask, truth) for mask, truth in zip(found[10:], truths[10:])]
    assert min(scores) >= 0.8, scores


def test_a_second_prompt_reanchors_the_frames_nearest_it():
    """A dark blue object enters from the left in frame 5. From the first prompt (frame 0) alone it
    is largely found as a tool coming into view. A second prompt on frame 9 clicks it as tissue (a
    dark retractor, say) and the grey instrument as tool: the frames nearest that prompt (5-9)
    leave the object out and keep the instrument (all but its dark rim, which is like the
    object's); frames 0-4 are unchanged."""
    frames, instruments = clip([(230 - 5 * step, 120 + 3 * step) for step in range(10)])
    objects = {}
    for index in range(5, 10):
        frame = frames[index].astype(np.float32)
        objects[index] = instrument(frame, (90 + 4 * index, 200), colour=(40, 70, 110),
                                    from_left=True) & ~instruments[index]
        frames[index] = np.clip(frame, 0, 255).astype(np.uint8)
    first = ToolPrompt(0, (farthest_inside(instruments[0]),))
    second = ToolPrompt(9, (farthest_inside(instruments[9]),), (farthest_inside(objects[9]),))
    only_first, both = masks(frames, [first]), masks(frames, [first, second])
    for index in range(5, 10):
        assert only_first[index][objects[index]].mean() > 0.3, index
        assert both[index][objects[index]].mean() < 0.05, index
        # the instrument's near-black rim is as dark as the object's and goes with it
        assert both[index][instruments[index]].mean() >= 0.7, index
        assert (both[index] & ~instruments[index]).mean() < 0.002, index  # false alarms
    for index in range(5):
        assert np.array_equal(both[index], only_first[index]), index


@pytest.mark.parametrize("entries, message", [
    ("{}", "expected a non-empty JSON list"),
    ('[{"frame": 12, "tool": [[10, 10]]}]', "entry 0: frame 12 is out of range: the import has "
                                             "10 frames (0..9)"),
    ('[{"frame": 1, "tool": [[10, 10]]}, {"frame": -1, "tool": [[5, 5]]}]',
     "entry 1: frame -1 is out of range"),
    ('[{"frame": 0, "tool": [[100, 10]]}]', "entry 0: tool point [100, 10] lies outside the "
                                             "96x64 (WxH) source frame"),
    ('[{"frame": 0, "tool": [[10, 10]], "tissue": [[5, 70]]}]',
     "entry 0: tissue point [5, 70] lies outside"),
    ('[{"frame": 0, "tool": []}]', "entry 0: needs at least one tool point"),
    ('[{"frame": 0, "tool": [[1, 2, 3]]}]', "entry 0: tool point [1, 2, 3] is not [x, y]"),
    ('[{"frame": "a", "tool": [[1, 2]]}]', "entry 0: frame must be an integer index"),
    ('[{"frame": 0, "tools": [[1, 2]]}]', "entry 0: expected"),
    ('[{"frame": 0, "tool": [[1, 2]], "other": 1}]', "entry 0: unknown key 'other'"),
    ('[{"frame": 0, "tool": [[1, 2]]}, {"frame": 0, "tool": [[3, 4]]}]',
     "entry 1: frame 0 is prompted twice"),
    ("[{", "is not a JSON prompt file"),
])
def test_bad_prompt_files_are_named_with_their_entry(tmp_path: Path, entries: str,
                                                      message: str):
    path = tmp_path / "prompts.json"
    path.write_text(entries)
    with pytest.raises(DataError, match=r"prompts\.json") as err:
        read_prompts(path, 10, (64, 96))
    assert message in str(err.value)


def test_prompts_are_read_sorted_by_frame(tmp_path: Path):
    path = tmp_path / "prompts.json"
    path.write_text(json.dumps([{"frame": 7, "tool": [[1, 2]]},
                                {"frame": 2, "tool": [[3.5, 4]], "tissue": [[5, 6]]}]))
    prompts = read_prompts(path, 10, (64, 96))
    assert [prompt.frame for prompt in prompts] == [2, 7]
    assert prompts[0] == ToolPrompt(2, ((3.5, 4.0),), ((5.0, 6.0),))


def write_clip(folder: Path, frames: list[np.ndarray], round_view: bool = False) -> Path:
    """The frames as PNG files frame_000.png ... (`round_view`: black outside a disk, as an
    endoscope's circular view)."""
    folder.mkdir()
    ys, xs = np.mgrid[0:HEIGHT, 0:WIDTH]
    disk = (xs - WIDTH / 2) ** 2 + (ys - HEIGHT / 2) ** 2 <= (0.42 * WIDTH) ** 2
    for index, frame in enumerate(frames):
        if round_view:
            frame = np.where(disk[..., None], frame, 0).astype(np.uint8)
        cv2.imwrite(str(folder / f"frame_{index:03d}.png"), frame[..., ::-1])
    return folder


def test_import_writes_the_prompted_masks_and_records_the_prompts(tmp_path: Path):
    """`import --tool-prompts` on a folder of frames, clicks on frame 2 at the source size
    while the scene is written at half size: every written mask matches the truth (IoU >=
    0.8), scene.json records the prompts and one confidence per frame, and the masks preview
    shows the mask tinted over its frame (IoU >= 0.7 through the video's compression)."""
    frames, truths = clip([(230 - 5 * step, 120 + 3 * step) for step in range(8)])
    big = [cv2.resize(frame, (2 * WIDTH, 2 * HEIGHT), interpolation=cv2.INTER_LINEAR)
           for frame in frames]
    source = tmp_path / "frames"
    source.mkdir()
    for index, frame in enumerate(big):
        cv2.imwrite(str(source / f"frame_{index:03d}.png"), frame[..., ::-1])
    x, y = farthest_inside(truths[2])
    prompts = tmp_path / "prompts.json"
    prompts.write_text(json.dumps([{"frame": 2, "tool": [[2 * x, 2 * y]]}]))
    out = import_scene(source, tmp_path / "scene",
                       ImportConfig(tool_prompts=prompts, scale=0.5, fov_mask=False))
    scene = load_scene(out)
    for frame, truth in zip(scene.frames, truths):
        assert iou(frame.tool.numpy(), truth) >= 0.8
    masks_meta = json.loads((out / "scene.json").read_text())["extra"]["masks"]
    assert masks_meta["prompts"] == [{"frame": 2, "tool": [[2 * x, 2 * y]], "tissue": []}]
    assert len(masks_meta["confidence"]) == len(truths)
    preview = iio.imread(write_mask_preview(scene))  # [frames, H + strip, W, 3]
    assert preview.shape == (len(truths), HEIGHT + STRIP_PX, WIDTH - 1, 3)
    tinted = preview[5, :HEIGHT, :WIDTH - 1].astype(int)
    green = (tinted[..., 1] - tinted[..., 0]) > 60  # the tool tint; tissue is red
    assert iou(green, truths[5][:, :WIDTH - 1]) >= 0.7


def test_import_names_a_click_outside_the_field_of_view(tmp_path: Path):
    frames, _ = clip([(230, 120)] * 4)
    source = write_clip(tmp_path / "frames", frames, round_view=True)
    prompts = tmp_path / "prompts.json"
    prompts.write_text(json.dumps([{"frame": 1, "tool": [[300, 100]], "tissue": [[2, 2]]}]))
    with pytest.raises(DataError, match=r"prompts\.json: entry for frame 1: tissue point "
                                        r"\[2, 2\] lies outside the field of view"):
        import_scene(source, tmp_path / "scene", ImportConfig(tool_prompts=prompts))


def test_one_source_of_tool_masks(tmp_path: Path):
    with pytest.raises(SurgsplatError, match="give one source of tool masks, not "
                                             "--auto-tool-masks and --tool-prompts"):
        ImportConfig(auto_tool_masks=True, tool_prompts=tmp_path / "p.json").validate()
