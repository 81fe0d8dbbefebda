"""Issue 53, scene input and `import`: every option's range is declared (--scale, the phantom's
seed, every number import takes), every frame, mask and depth file is read or named (links that
lead nowhere, a file where a folder belongs, class-ID masks without --tool-labels, depth beyond
what an endoscope sees, OpenCV's LZW TIFF), tool masks are read by one reader whatever their
colour, a source that is a pipe or a device says so, and every product import derives (tool
masks, depth, disparity) is checked for content before the scene is called done."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch

from surgsplat.data.layout import MAX_DEPTH_MM, MAX_FRAME_PIXELS, frame_stem
from surgsplat.data.scene import load_scene

SCALE_CASES = {"nan": "positive finite", "inf": "positive finite", "-1": "positive finite",
               "1000": "160x128 frames 160000x128000", "0.01": "160x128 frames 2x1"}
"""--scale values out of range, and what the error says."""

NUMBER_OPTIONS = (
    (("--scale",), ()), (("--focal",), ()), (("--fx", "--fy"), ()), (("--cx", "--cy"), ()),
    (("--hfov",), ()), (("--shading-gamma",), ("--depth", "shading")),
    (("--shading-median-depth",), ("--depth", "shading")),
    (("--depth-model-median-depth",), ("--depth", "model.onnx")),
    (("--tool-segmenter-threshold",), ("--tool-segmenter", "model.onnx")),
    (("--sfm-median-depth",), ("--poses", "sfm")))
"""Every float option of `import`, as (the options given the value, the options that make them
count)."""


def importing(source: Path, out: Path, *options: str) -> tuple[str, ...]:
    """The arguments of `surgsplat import SOURCE --out OUT *options`."""
    return ("import", str(source), "--out", str(out), *options)


def scene_copy(small_phantom: Path, tmp_path: Path) -> Path:
    """A copy of the small phantom without its ground truth."""
    copy = tmp_path / "scene"
    shutil.copytree(small_phantom, copy, ignore=shutil.ignore_patterns("gt"))
    return copy


def frame_folder(small_phantom: Path, tmp_path: Path) -> Path:
    """A folder holding a copy of the small phantom's frames, 000000.png .. 000015.png."""
    folder = tmp_path / "frames"
    shutil.copytree(small_phantom / "images", folder)
    return folder


@pytest.mark.parametrize("scale", SCALE_CASES)
def test_scale_out_of_range_is_one_line_naming_the_size(small_phantom, tmp_path, cli,
                                                        one_error_line, scale):
    """Case 1: nan gave a traceback and 1000 allocated 61 GB; the scaled size is named."""
    out = tmp_path / "out"
    line = one_error_line(cli(*importing(small_phantom / "images", out, "--scale", scale)))
    assert "--scale" in line and SCALE_CASES[scale] in line
    if scale == "1000":
        assert f"{MAX_FRAME_PIXELS:,} pixels" in line
    assert not out.exists()


@pytest.mark.parametrize("value", ["nan", "inf"])
@pytest.mark.parametrize("names, context", NUMBER_OPTIONS,
                         ids=[names[0] for names, _ in NUMBER_OPTIONS])
def test_every_number_import_takes_refuses_nan_and_inf(small_phantom, tmp_path, cli,
                                                       one_error_line, names, context, value):
    """Every float option's range is declared: NaN and infinity are one line, nothing written."""
    given = [part for name in names for part in (name, value)]
    out = tmp_path / "out"
    line = one_error_line(cli(*importing(small_phantom / "images", out, *given, *context)))
    assert value in line or "finite" in line, line
    assert not out.exists()


def test_baseline_and_model_mean_refuse_nan(small_phantom, tmp_path, cli, one_error_line):
    """--baseline (with --right) and the R,G,B mean and std of a model must be finite."""
    images = small_phantom / "images"
    cases = (("--right", str(images), "--focal", "100", "--baseline", "nan"),
             ("--depth", "model.onnx", "--depth-model-mean", "nan,0,0"),
             ("--tool-segmenter", "model.onnx", "--tool-segmenter-std", "1,inf,1"))
    for options in cases:
        line = one_error_line(cli(*importing(images, tmp_path / "out", *options)))
        assert "finite" in line, line
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("seed", ["-1", str(2**32)])
def test_phantom_seed_out_of_range_is_one_line(tmp_path, cli, one_error_line, seed):
    """Case 2: `phantom --seed -1` gave numpy's traceback."""
    line = one_error_line(cli("phantom", "--out", str(tmp_path / "p"), "--seed", seed))
    assert f"--seed: the phantom seed must be an integer in 0..{2**32 - 1}, got {seed}" in line
    assert not (tmp_path / "p").exists()


def test_phantom_frames_out_of_range_is_one_line(tmp_path, cli, one_error_line):
    """A mistyped frame count would ray-cast for days."""
    line = one_error_line(cli("phantom", "--out", str(tmp_path / "p"), "--frames", "1000000"))
    assert line == "error: --frames: the number of frames must be in 1..10000, got 1000000"
    assert not (tmp_path / "p").exists()


@pytest.mark.parametrize("link", ["dangling", "looping"])
def test_a_link_among_the_frames_is_named_not_skipped(small_phantom, tmp_path, cli,
                                                      one_error_line, link):
    """Case 3: a symbolic link that leads nowhere, among a source's frames or a scene's, was
    passed over, shifting every later frame in time."""
    frames = frame_folder(small_phantom, tmp_path)
    scene = scene_copy(small_phantom, tmp_path)
    for folder in (frames, scene / "images"):
        broken = folder / "000005.png"
        broken.unlink()
        broken.symlink_to("nowhere.png" if link == "dangling" else broken.name)
    line = one_error_line(cli(*importing(frames, tmp_path / "out")))
    assert line.startswith(f"error: {frames / '000005.png'}: is a symbolic link")
    assert not (tmp_path / "out").exists()
    line = one_error_line(cli("info", str(scene)))
    assert line.startswith(f"error: {scene / 'images' / '000005.png'}: is a symbolic link")


def red_on_black(folder: Path) -> None:
    """Rewrite every binary mask of `folder` as a red-on-black RGB image."""
    for path in folder.iterdir():
        mask = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
        red = np.zeros((*mask.shape, 3), np.uint8)
        red[..., 2] = mask  # OpenCV's order is BGR
        cv2.imwrite(str(path), red)


def test_red_on_black_masks_read_alike_by_info_train_and_import(small_phantom, tmp_path, cli):
    """Case 4: `info` and `train` read an RGB mask's blue channel (0 % tool), `import` all of
    them; one reader now serves both."""
    scene = scene_copy(small_phantom, tmp_path)
    red_on_black(scene / "masks")
    truth = [frame.tool for frame in load_scene(small_phantom).frames]
    red = load_scene(scene)
    assert all(bool(frame.tool.equal(tool)) for frame, tool in zip(red.frames, truth))
    result = cli(*importing(scene / "images", tmp_path / "out", "--masks", str(scene / "masks")))
    assert result.returncode == 0, result.stderr
    imported = load_scene(tmp_path / "out")
    assert all(bool(frame.tool.equal(tool)) for frame, tool in zip(imported.frames, truth))


def test_a_scenes_lossy_masks_read_as_their_bright_half(small_phantom, tmp_path):
    """A scene's masks saved as JPEG or resized (values near 0 and near 255, and between at the
    edges) load as before: tool above half the brightest value. Only the label images given to
    `import` must be strictly binary, where more values mean class IDs."""
    scene = scene_copy(small_phantom, tmp_path)
    truth = [frame.tool for frame in load_scene(small_phantom).frames]
    for path in sorted((scene / "masks").iterdir()):
        tool = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE) > 0
        lossy = np.where(tool, 250, 3).astype(np.uint8)
        lossy[0, :4] = (100, 140, 255, 0)  # edge values between the two
        cv2.imwrite(str(path), lossy)
    for frame, tool in zip(load_scene(scene).frames, truth):
        expected = tool.clone()
        expected[0, :4] = torch.tensor([False, True, True, False])
        assert bool(frame.tool.equal(expected))


@pytest.mark.parametrize("entry, kind", [("depth", "is a file"), ("masks", "is a file"),
                                         ("fov_mask.png", "is a folder"),
                                         ("scene.json", "is a folder")])
def test_an_entry_of_the_wrong_kind_is_named_not_read_as_absent(small_phantom, tmp_path, cli,
                                                               one_error_line, entry, kind):
    """Case 5: a regular file named `depth` loaded as "no depth"; so would a file for masks/,
    or a folder for fov_mask.png or scene.json."""
    scene = scene_copy(small_phantom, tmp_path)
    path = scene / entry
    if path.is_dir():
        shutil.rmtree(path)
    else:
        path.unlink(missing_ok=True)
    if kind == "is a file":
        path.write_text("not a folder\n")
    else:
        path.mkdir()
    line = one_error_line(cli("info", str(scene)))
    assert line.startswith(f"error: {path}: {kind}: expected")


def constant_model(path: Path, value: float) -> Path:
    """An ONNX model of the import contract whose output [N, 1, h, w] is `value` everywhere:
    0 x the input's channel mean + value."""
    onnx = pytest.importorskip("onnx")
    pytest.importorskip("onnxruntime")
    helper = onnx.helper
    graph = helper.make_graph(
        [helper.make_node("ReduceMean", ["x"], ["mean"], axes=[1], keepdims=1),
         helper.make_node("Mul", ["mean", "zero"], ["nothing"]),
         helper.make_node("Add", ["nothing", "value"], ["y"])],
        "constant",
        [helper.make_tensor_value_info("x", onnx.TensorProto.FLOAT, ["n", 3, "h", "w"])],
        [helper.make_tensor_value_info("y", onnx.TensorProto.FLOAT, ["n", 1, "h", "w"])],
        [helper.make_tensor("zero", onnx.TensorProto.FLOAT, [], [0.0]),
         helper.make_tensor("value", onnx.TensorProto.FLOAT, [], [value])])
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 13)])
    model.ir_version = 8
    onnx.save(model, str(path))
    return path


@pytest.mark.parametrize("value, message", [
    (float("nan"), "gave NaN for 100% of the pixels of frame 0"),
    (-20.0, "found no tool pixel in any of the 16 frames"),
    (20.0, "marks every pixel as tool")])
def test_a_tool_segmenter_without_usable_output_stops_import(small_phantom, tmp_path, cli,
                                                            one_error_line, value, message):
    """Case 6: a segmenter giving NaN gave 0 % tool without a word; one finding no tool on any
    frame, or tool everywhere, is named as well."""
    model = constant_model(tmp_path / "segmenter.onnx", value)
    out = tmp_path / "out"
    line = one_error_line(cli(*importing(small_phantom / "images", out, "--tool-segmenter",
                                         str(model), "--no-fov-mask")))
    assert line.startswith(f"error: {model}: ") and message in line
    assert not out.exists()


@pytest.mark.parametrize("value", [float("nan"), -1.0])
def test_a_depth_network_without_valid_depth_stops_import(small_phantom, tmp_path, cli,
                                                          one_error_line, value):
    """Case 6: a depth network giving NaN or negative values wrote a depth/ without a valid
    pixel, and the scene loaded as monocular."""
    model = constant_model(tmp_path / "depth.onnx", value)
    out = tmp_path / "out"
    line = one_error_line(cli(*importing(small_phantom / "images", out, "--depth", str(model))))
    assert line.startswith(f"error: {model}: gave no valid depth") and "16 frames" in line
    assert not out.exists()


@pytest.mark.parametrize("product", ["depth", "disparity"])
def test_a_stereo_pair_of_identical_images_stops_import(small_phantom, tmp_path, cli,
                                                        one_error_line, product):
    """Case 6: a right camera equal to the left matches no pixel; its depth/ (or disparity/)
    would hold no valid pixel."""
    images = small_phantom / "images"
    output = ("--focal", "100", "--baseline", "5") if product == "depth" else (
        "--disparity-only",)
    out = tmp_path / "out"
    line = one_error_line(cli(*importing(images, out, "--right", str(images), *output)))
    assert line.startswith(f"error: {images}: matches no pixel of {images}")
    assert not out.exists()


def test_lzw_tiff_frames_are_read_and_a_damaged_one_named(small_phantom, tmp_path, cli,
                                                         one_error_line):
    """Case 7: OpenCV's TIFF (LZW-compressed, which tifffile decodes only with imagecodecs) was
    called truncated or corrupt; a damaged one still is."""
    scene = scene_copy(small_phantom, tmp_path)
    for path in sorted((scene / "images").iterdir()):
        cv2.imwrite(str(path.with_suffix(".tif")), cv2.imread(str(path)))
        path.unlink()
    result = cli("info", str(scene))
    assert result.returncode == 0, result.stderr
    assert load_scene(scene).fingerprint == load_scene(small_phantom).fingerprint
    damaged = scene / "images" / "000003.tif"
    data = bytearray(damaged.read_bytes())
    data[len(data) // 4: len(data) // 2] = bytes(len(data) // 2 - len(data) // 4)
    damaged.write_bytes(bytes(data))
    line = one_error_line(cli("info", str(scene)))
    assert line.startswith(f"error: {damaged}: cannot be read as an image")


@pytest.mark.parametrize("background", [50, 0])
def test_class_id_masks_without_tool_labels_stop_before_writing(small_phantom, tmp_path, cli,
                                                                one_error_line, background):
    """Case 8: class-ID masks (tool 31 on background 50) without --tool-labels: the scene was
    written, then its own masks/000000.png named. A binary mask's zero is tissue."""
    masks = tmp_path / "labels"
    masks.mkdir()
    for index in range(16):
        labels = np.full((128, 160), background, np.uint8)
        labels[40:60, 40:80] = 31
        cv2.imwrite(str(masks / f"{frame_stem(index)}.png"), labels)
    out = tmp_path / "out"
    result = cli(*importing(small_phantom / "images", out, "--masks", str(masks)))
    if background == 0:  # a binary mask: 31 = tool
        assert result.returncode == 0, result.stderr
        return
    line = one_error_line(result)
    assert line.startswith(f"error: {masks / '000000.png'}: holds the values 31, 50")
    assert "--tool-labels" in line
    assert not out.exists()


def test_single_class_masks_without_tool_labels_name_the_source_mask(small_phantom, tmp_path,
                                                                    cli, one_error_line):
    """Case 8: a class-ID mask holding one class everywhere reads as all tool; the source mask
    is named, not the scene's copy of it."""
    masks = tmp_path / "labels"
    masks.mkdir()
    for index in range(16):
        cv2.imwrite(str(masks / f"{frame_stem(index)}.png"), np.full((128, 160), 50, np.uint8))
    out = tmp_path / "out"
    line = one_error_line(cli(*importing(small_phantom / "images", out, "--masks", str(masks))))
    assert line.startswith(f"error: {masks / '000000.png'}: marks every pixel as tool: no tissue "
                           "is visible; class-ID masks are imported with their tool classes")
    assert not out.exists()


def test_a_device_or_pipe_source_says_what_it_is(tmp_path, cli, one_error_line):
    """Case 9: /dev/null, a FIFO and <(cat video.mp4) were reported as "does not exist"."""
    line = one_error_line(cli(*importing(Path("/dev/null"), tmp_path / "out")))
    assert line == ("error: /dev/null: is a device, not a regular file: expected a video file or "
                    "a folder of frames")
    fifo = tmp_path / "fifo.mp4"
    os.mkfifo(fifo)
    read_end, write_end = os.pipe()
    try:
        for pipe in (fifo, Path(f"/dev/fd/{read_end}")):
            line = one_error_line(cli(*importing(pipe, tmp_path / "out")))
            assert line.startswith(f"error: {pipe}: is a pipe") and "save the stream" in line
    finally:
        os.close(read_end)
        os.close(write_end)
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("suffix", [".npy", ".png"])
def test_depth_beyond_what_an_endoscope_sees_is_named(small_phantom, tmp_path, cli,
                                                      one_error_line, suffix):
    """Case 10: a depth frame of 1e30 mm passed `info`, and training then diverged; so would a
    16-bit PNG whose stored depth, at the scale given, lies beyond 10 m."""
    scene = scene_copy(small_phantom, tmp_path)
    bad = scene / "depth" / f"000004{suffix}"
    (scene / "depth" / "000004.png").unlink()
    if suffix == ".npy":
        np.save(bad, np.full((128, 160), 1e30, np.float32))
        options = ()
    else:
        cv2.imwrite(str(bad), np.full((128, 160), 65535, np.uint16))
        options = ("--depth-scale", "0.5")  # the other frames' stored depth stays under 10 m
    line = one_error_line(cli("info", str(scene), *options))
    assert line.startswith(f"error: {bad}: depth reaches") and f"{MAX_DEPTH_MM:g}" in line


def test_scene_metadata_that_is_not_text_is_one_line(small_phantom, tmp_path, cli,
                                                     one_error_line):
    """scene.json holding bytes that are not UTF-8 (found by tests/faults/test_fuzz.py)."""
    scene = scene_copy(small_phantom, tmp_path)
    (scene / "scene.json").write_bytes(b"v4\x8b\xd9")
    line = one_error_line(cli("info", str(scene)))
    assert line.startswith(f"error: {scene / 'scene.json'}: cannot read scene metadata as JSON")
