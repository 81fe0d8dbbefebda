"""Random scene folders and option combinations through the CLI.

Hypothesis draws a scene, a few frames of the small phantom with up to three kinds of damage
(a file deleted, cut short, replaced by noise or by an image of another size; masks stored as
RGB or grey levels; a dangling or looping symlink; a file where a folder belongs; poses or
scene.json damaged; depth NaN, negative or absurdly far), and `train` options (a preset,
--iters, and --set assignments of random settings to values in their range, out of it, NaN,
infinite or of the wrong type). Each case runs `info` and, when `info` accepts the scene,
`train` for at most two iterations. A third test draws the numeric and list options of the
other commands (info, phantom, import, export, report, render) at such values.

A case passes when every command either exits 0 with its product (`info`: the summary;
`train`: a run folder with a checkpoint and a finite loss and PSNR in its log), or exits 2
with one `error:` line, or, for a value the command line cannot parse (text for a number),
with the CLI parser's usage message. Never a traceback, never a hang (CASE_SECONDS).

The draws are derandomised, so CI runs the same cases each time: FUZZ_SCENES + FUZZ_OPTIONS +
FUZZ_COMMANDS of them. SURGSPLAT_FUZZ_SEED=<int> draws others, SURGSPLAT_FUZZ_SCALE=k k times
as many (a longer search).
"""

from __future__ import annotations

import json
import math
import os
import shutil
import tempfile
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np
import pytest
from hypothesis import HealthCheck, Phase, given, seed, settings
from hypothesis import strategies as st

from surgsplat.data.layout import DEPTH_DIR, IMAGES_DIR, MASKS_DIR, META_FILE, POSES_FILE
from surgsplat.methods.ranges import declared_range
from surgsplat.methods.registry import PRESETS
from surgsplat.train.trainer import CHECKPOINT, LOG_FILE

from .test_config_ranges import numeric_fields, outside, scalar_types, with_value

pytestmark = pytest.mark.slow

FRAMES = 8
"""Frames of the small phantom in a drawn scene (one test frame: i % 8 == 1)."""
SCALE = int(os.environ.get("SURGSPLAT_FUZZ_SCALE", "1"))
FUZZ_SCENES = 220 * SCALE
"""Scene folders drawn (each checked by `info`, and by `train` when `info` accepts it)."""
FUZZ_OPTIONS = 100 * SCALE
"""`train` option combinations drawn (each a `train` of the undamaged scene)."""
FUZZ_COMMANDS = 200 * SCALE
"""Option combinations of the other commands drawn (each reading the undamaged scene or a
short run of it)."""
CASE_SECONDS = 120
"""A command still running after this long is a hang."""
FAST = ("--set", "init.max_points=300")
"""Settings that keep a case's training to about a second."""


def fuzz_settings(cases: int) -> Callable:
    """Hypothesis' settings for `cases` draws: derandomised unless SURGSPLAT_FUZZ_SEED is set,
    no example database (nothing written into the repository), no deadline (a training case
    takes seconds; hangs are CASE_SECONDS' business), no shrinking (a failing case is reported
    as drawn: shrinking re-runs commands of seconds for minutes)."""
    chosen = os.environ.get("SURGSPLAT_FUZZ_SEED")
    configured = settings(max_examples=cases, deadline=None, database=None,
                          phases=(Phase.explicit, Phase.generate), derandomize=chosen is None,
                          suppress_health_check=[HealthCheck.too_slow,
                                                 HealthCheck.function_scoped_fixture])

    def apply(test: Callable) -> Callable:
        return configured(seed(int(chosen))(test) if chosen is not None else test)
    return apply


# ---- the outcome of one command ----
def usage_error(stderr: str) -> bool:
    """Whether `stderr` is the command-line parser's message about an argument it could not
    parse (a usage line and a boxed error)."""
    return stderr.lstrip().startswith("Usage:") and "Error" in stderr


def checked(result, what: str) -> bool:
    """Whether `result` (a CompletedProcess) succeeded; fails the test unless it is success or
    a clean refusal (exit 2, one `error:` line or a usage message, no traceback)."""
    assert "Traceback" not in result.stderr, f"{what}: traceback\n{result.stderr}"
    if result.returncode == 0:
        return True
    assert result.returncode == 2, f"{what}: exit {result.returncode}\n{result.stderr}"
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    one_line = len(lines) == 1 and lines[0].startswith("error:")
    assert one_line or usage_error(result.stderr), f"{what}: not one line\n{result.stderr}"
    return False


def assert_valid_run(run: Path) -> None:
    """A checkpoint, and a training log whose last record has a finite loss and PSNR."""
    assert (run / CHECKPOINT).is_file(), f"{run}: no checkpoint"
    last = json.loads((run / LOG_FILE).read_text().splitlines()[-1])
    assert math.isfinite(last["loss"]) and math.isfinite(last["psnr"]), last


# ---- scenes ----
@pytest.fixture(scope="module")
def base_scene(small_phantom, tmp_path_factory) -> Path:
    """The first FRAMES frames of the small phantom, without its ground truth."""
    scene = tmp_path_factory.mktemp("fuzz") / "scene"
    for folder in (IMAGES_DIR, DEPTH_DIR, MASKS_DIR):
        (scene / folder).mkdir(parents=True)
        for path in sorted((small_phantom / folder).iterdir())[:FRAMES]:
            shutil.copy(path, scene / folder / path.name)
    np.save(scene / POSES_FILE, np.load(small_phantom / POSES_FILE)[:FRAMES])
    shutil.copy(small_phantom / META_FILE, scene / META_FILE)
    return scene


def frame_files(scene: Path, folder: str) -> list[Path]:
    """The files of `folder`, in name order (none when an earlier damage replaced it)."""
    path = scene / folder
    return sorted(entry for entry in path.iterdir() if entry.is_file()) if path.is_dir() else []


def frame_file(scene: Path, draw, folders=(IMAGES_DIR, DEPTH_DIR, MASKS_DIR)) -> Path:
    """A drawn file of one of `folders`, or scene.json when an earlier damage left none."""
    files = frame_files(scene, draw(st.sampled_from(folders)))
    return draw(st.sampled_from(files)) if files else scene / META_FILE


def delete_file(scene: Path, draw) -> None:
    target = draw(st.sampled_from(("frame", POSES_FILE, META_FILE)))
    (frame_file(scene, draw) if target == "frame" else scene / target).unlink(missing_ok=True)


def cut_short(scene: Path, draw) -> None:
    path = frame_file(scene, draw) if draw(st.booleans()) else scene / POSES_FILE
    if path.is_file() and path.stat().st_size > 0:
        data = path.read_bytes()
        path.write_bytes(data[:draw(st.integers(0, len(data) - 1))])


def noise_bytes(scene: Path, draw) -> None:
    path = frame_file(scene, draw)
    path.write_bytes(draw(st.binary(min_size=1, max_size=256)))


def other_size(scene: Path, draw) -> None:
    path = frame_file(scene, draw)
    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED) if path.is_file() else None
    if image is None:  # an earlier damage left no image here
        return
    height, width = draw(st.sampled_from(((64, 80), (128, 161), (129, 160), (1, 1))))
    cv2.imwrite(str(path), cv2.resize(image, (width, height), interpolation=cv2.INTER_NEAREST))


def masks_as_colour(scene: Path, draw) -> None:
    """Every mask red-on-black (as some labelling tools save them) or in grey levels."""
    red = draw(st.booleans())
    for path in frame_files(scene, MASKS_DIR):
        mask = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
        if mask is None:  # an earlier damage left no image here
            continue
        if red:
            colour = np.zeros((*mask.shape, 3), np.uint8)
            colour[..., 2] = mask  # OpenCV writes BGR: channel 2 is red
            cv2.imwrite(str(path), colour)
        else:
            cv2.imwrite(str(path), (mask // 2 + 40).astype(np.uint8))


def bad_symlink(scene: Path, draw) -> None:
    path = frame_file(scene, draw, (IMAGES_DIR,))
    path.unlink(missing_ok=True)
    path.symlink_to(path if draw(st.booleans()) else scene / "nowhere.png")


def file_for_folder(scene: Path, draw) -> None:
    folder = scene / draw(st.sampled_from((IMAGES_DIR, DEPTH_DIR, MASKS_DIR)))
    if folder.is_dir():
        shutil.rmtree(folder)
    folder.write_bytes(b"not a folder")


def bad_poses(scene: Path, draw) -> None:
    try:
        poses = np.load(scene / POSES_FILE)
    except (OSError, ValueError, EOFError):  # an earlier damage deleted it or cut it short
        return
    kind = draw(st.sampled_from(("nan", "rows", "columns", "zero focal", "near beyond far")))
    if kind == "nan":
        poses[draw(st.integers(0, FRAMES - 1)), draw(st.integers(0, 16))] = np.nan
    elif kind == "rows":
        poses = poses[:draw(st.integers(0, FRAMES - 1))]
    elif kind == "columns":
        poses = poses[:, :draw(st.integers(1, 16))]
    elif kind == "zero focal":
        poses[:, 14] = 0.0
    else:
        poses[:, 15], poses[:, 16] = poses[:, 16] + 1.0, poses[:, 15]
    np.save(scene / POSES_FILE, poses)


def bad_meta(scene: Path, draw) -> None:
    try:
        meta = json.loads((scene / META_FILE).read_text())
    except (OSError, ValueError):  # an earlier damage deleted it or replaced its text
        meta = {}
    kind = draw(st.sampled_from(("not json", "depth_scale", "depth_unit", "intrinsics", "list")))
    if kind == "not json":
        (scene / META_FILE).write_text("{depth_unit: mm")
        return
    if kind == "depth_scale":
        meta["depth_scale"] = draw(st.sampled_from((0, -1, "x", None, 1e300)))
    elif kind == "depth_unit":
        meta["depth_unit"] = draw(st.sampled_from(("furlong", 3, "")))
    elif kind == "intrinsics":
        meta["intrinsics"] = draw(st.sampled_from(({"fx": -1, "fy": 1, "cx": 0, "cy": 0},
                                                   {"fx": 100}, [1, 2, 3, 4])))
    else:
        meta = [meta]
    (scene / META_FILE).write_text(json.dumps(meta))


def bad_depth_values(scene: Path, draw) -> None:
    """One depth frame, or every one, as float .npy holding NaN, negative or huge values."""
    value = draw(st.sampled_from((math.nan, math.inf, -5.0, 1e30)))
    paths = frame_files(scene, DEPTH_DIR)
    if not paths:
        return
    chosen = paths if draw(st.booleans()) else [draw(st.sampled_from(paths))]
    for path in chosen:
        stored = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        if stored is None:  # an earlier damage left no image here
            continue
        depth = stored.astype(np.float32) * 0.01
        rows = draw(st.integers(1, depth.shape[0]))
        depth[:rows] = value
        path.unlink()
        np.save(path.with_suffix(".npy"), depth)


def stray_files(scene: Path, draw) -> None:
    folder = scene / draw(st.sampled_from((IMAGES_DIR, DEPTH_DIR, MASKS_DIR)))
    if not folder.is_dir():
        return
    name = draw(st.sampled_from(("notes.txt", ".DS_Store", "zz_extra.png", "subfolder")))
    if name == "subfolder":
        (folder / name).mkdir()
    else:
        (folder / name).write_bytes(b"\x89PNG\r\n\x1a\n" if name.endswith(".png") else b"x")


DAMAGES = (delete_file, cut_short, noise_bytes, other_size, masks_as_colour, bad_symlink,
           file_for_folder, bad_poses, bad_meta, bad_depth_values, stray_files)


# ---- options ----
WRONG_TYPE = "many"
"""A value of no numeric setting."""


@st.composite
def assignments(draw, preset: str) -> str:
    """One `--set key=value` of a numeric setting of `preset`: in range (its default scaled),
    just outside it, NaN, infinite or text."""
    field = draw(st.sampled_from(numeric_fields(preset)))
    valid = declared_range(field.declaration)
    integer = float not in scalar_types(field.annotation)
    default = field.value[0] if isinstance(field.value, tuple) else field.value
    kind = draw(st.sampled_from(("scaled", "outside", "nan", "inf", "text")))
    if kind == "scaled":
        number = default * draw(st.sampled_from((0.5, 2.0)))
        number = int(number) if integer else number
        value = json.dumps(with_value(field, number))
    elif kind == "outside":
        value = json.dumps(with_value(field, outside(valid, integer)))
    elif kind == "nan":
        value = "NaN"
    elif kind == "inf":
        value = draw(st.sampled_from(("Infinity", "-Infinity", "1e999")))
    else:
        value = WRONG_TYPE
    return f"{field.key}={value}"


@st.composite
def train_options(draw) -> tuple[str, ...]:
    preset = draw(st.sampled_from(sorted(PRESETS)))
    iterations = draw(st.sampled_from(("--iters", "train.iterations")))
    count = str(draw(st.sampled_from((-1, 0, 1, 2))))
    options = ["--method", preset, *FAST]
    options += ["--iters", count] if iterations == "--iters" else [
        "--set", f"train.iterations={count}"]
    for assignment in draw(st.lists(assignments(preset), max_size=3)):
        options += ["--set", assignment]
    return tuple(options)


NUMBERS = ("nan", "inf", "-inf", "-1", "0", "0.5", "1", "3", "1e6", "-1e6", WRONG_TYPE)
"""Values drawn for a numeric command-line option."""
FRAME_LISTS = ("all", "0", "1,1,1", "-3", "0,100", "2,1", "", "a,b", "99999999999999999999")
"""Values drawn for an option holding a list of frames."""
COMMAND_OPTIONS = {
    "info": {"--depth-scale": NUMBERS},
    "phantom": {"--seed": NUMBERS, "--frames": NUMBERS},
    "import": {"--scale": NUMBERS, "--stride": NUMBERS, "--start": NUMBERS, "--end": NUMBERS,
               "--resize": ("160x128", "0x0", "-5x10", "99999x99999", "80", "x"),
               "--focal": NUMBERS, "--hfov": NUMBERS},
    "export": {"--frames": FRAME_LISTS, "--time": NUMBERS, "--frame": NUMBERS,
               "--mesh-resolution": NUMBERS},
    "report": {"--frames": NUMBERS},
    "render": {"--fps": NUMBERS, "--channels": ("rgb", "depth", "rgb,rgb", "nothing", "")},
}
"""Per command that reads a run or a scene, its options and the values drawn for them."""


@st.composite
def command_lines(draw, scene: Path, run: Path, work: Path) -> tuple[str, ...]:
    """A command of COMMAND_OPTIONS with one to three of its options at drawn values, reading
    `scene` or `run` and writing under `work`."""
    command = draw(st.sampled_from(sorted(COMMAND_OPTIONS)))
    options = COMMAND_OPTIONS[command]
    chosen = draw(st.lists(st.sampled_from(sorted(options)), min_size=1, max_size=3,
                           unique=True))
    arguments = [argument for option in chosen
                 for argument in (option, draw(st.sampled_from(options[option])))]
    places = {"info": [str(scene)], "phantom": ["--out", str(work / "phantom")],
              "import": [str(scene / IMAGES_DIR), "--out", str(work / "imported")],
              "export": [str(run), "--ply", "--out", str(work / "export")],
              "report": [str(run), "--out", str(work / "report.html")],
              "render": [str(run), "--out", str(work / "videos")]}
    if command == "export" and draw(st.booleans()):
        arguments.append("--mesh")
    return (command, *places[command], *arguments)


# ---- the tests ----
@fuzz_settings(FUZZ_SCENES)
@given(data=st.data())
def test_random_scene_folders(base_scene, cli, data):
    with tempfile.TemporaryDirectory() as work:
        scene = Path(shutil.copytree(base_scene, Path(work) / "scene", symlinks=True))
        damages = st.lists(st.sampled_from(DAMAGES), max_size=3, unique=True)
        for damage in data.draw(damages, "damages"):
            damage(scene, data.draw)
        if not checked(cli("info", str(scene), timeout=CASE_SECONDS), "info"):
            return
        if data.draw(st.integers(0, 3), "train this scene") != 0:
            return
        run = Path(work) / "run"
        result = cli("train", "--data", str(scene), "--out", str(run), "--iters", "1", *FAST,
                     timeout=CASE_SECONDS)
        if checked(result, "train"):
            assert_valid_run(run)


@pytest.fixture(scope="module")
def trained_run(base_scene, tmp_path_factory, cli) -> Path:
    """A run of two iterations of the undamaged scene."""
    run = tmp_path_factory.mktemp("fuzz-run") / "run"
    result = cli("train", "--data", str(base_scene), "--out", str(run), "--iters", "2", *FAST)
    assert result.returncode == 0, result.stderr
    return run


@fuzz_settings(FUZZ_COMMANDS)
@given(data=st.data())
def test_random_command_options(base_scene, trained_run, cli, data):
    with tempfile.TemporaryDirectory() as work:
        run = Path(shutil.copytree(trained_run, Path(work) / "run"))
        command = data.draw(command_lines(base_scene, run, Path(work)), "command")
        checked(cli(*command, timeout=CASE_SECONDS), " ".join(command))


@fuzz_settings(FUZZ_OPTIONS)
@given(options=train_options())
def test_random_train_options(base_scene, cli, options):
    with tempfile.TemporaryDirectory() as work:
        run = Path(work) / "run"
        result = cli("train", "--data", str(base_scene), "--out", str(run), *options,
                     timeout=CASE_SECONDS)
        if checked(result, f"train {' '.join(options)}"):
            assert_valid_run(run)
