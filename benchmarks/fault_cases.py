"""The fault cases of issue 53, beyond the files themselves: data derived from valid files,
checkpoint contents, folders of the user's that commands write into, `batch`'s resources and
signals, and option values. Each runs against the CLI as a user runs it (fault_probe.cli) in a
workspace holding the small phantom (`phantom`) and a short run of it (`run`); bench_faults
runs them.

Classes, as the issue's table counts them: scene input, import, train, outputs, batch, numeric
options.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
import warnings
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np
from fault_probe import CASE_SECONDS, FAST, cli, outcome, surgsplat_command

from surgsplat.train.checkpoint import previous_path
from surgsplat.train.trainer import CHECKPOINT

BATCH_SECONDS = 90
"""A batch still starting after this long is a hang (Ray starts in seconds)."""
USER_FILE = b"the user's own file\n"


# ---- scene input ----
def copied_scene(w: Path, name: str) -> Path:
    return Path(shutil.copytree(w / "phantom", w / f"scene-{name}", symlinks=True))


def info_refuses(scene: Path, names: Path) -> dict:
    return outcome(cli("info", str(scene)), 2, str(names))


def case_dangling_symlink(w: Path) -> dict:
    """scene input: a dangling symlink among the frames is named, not skipped."""
    scene = copied_scene(w, "dangling")
    frame = sorted((scene / "images").iterdir())[5]
    frame.unlink()
    frame.symlink_to(scene / "gone.png")
    return info_refuses(scene, frame)


def case_looping_symlink(w: Path) -> dict:
    """scene input: a symlink to itself among the frames is named, not skipped."""
    scene = copied_scene(w, "looping")
    frame = sorted((scene / "images").iterdir())[5]
    frame.unlink()
    frame.symlink_to(frame)
    return info_refuses(scene, frame)


def tool_line(result: subprocess.CompletedProcess | None) -> str:
    return next((line for line in (result.stdout if result else "").splitlines()
                 if "tool" in line), "")


def case_red_masks(w: Path) -> dict:
    """scene input: masks stored red on black read as the grey ones (info's tool coverage)."""
    scene = copied_scene(w, "red-masks")
    for path in (scene / "masks").iterdir():
        grey = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
        cv2.imwrite(str(path), np.stack([np.zeros_like(grey)] * 2 + [grey], -1))  # BGR: red
    result = cli("info", str(scene))
    wrong = result is not None and result.returncode == 0 and (
        tool_line(result) != tool_line(cli("info", str(w / "phantom"))))
    return outcome(result, 0, "", wrong=wrong)


def case_depth_is_a_file(w: Path) -> dict:
    """scene input: a regular file named depth where the folder belongs is named."""
    scene = copied_scene(w, "depth-file")
    shutil.rmtree(scene / "depth")
    (scene / "depth").write_bytes(b"depth")
    return info_refuses(scene, scene / "depth")


def case_depth_absurdly_far(w: Path) -> dict:
    """scene input: a depth frame of 1e30 mm is named by info."""
    scene = copied_scene(w, "far-depth")
    png = sorted((scene / "depth").iterdir())[3]
    png.unlink()
    np.save(png.with_suffix(".npy"), np.full((128, 160), 1e30, np.float32))
    return info_refuses(scene, png.with_suffix(".npy"))


def case_lzw_tiff(w: Path) -> dict:
    """scene input: frames as LZW-compressed TIFF (OpenCV's default) are read."""
    scene = copied_scene(w, "tiff")
    for path in (scene / "images").iterdir():
        cv2.imwrite(str(path.with_suffix(".tif")), cv2.imread(str(path)))
        path.unlink()
    return outcome(cli("info", str(scene)), 0, "")


# ---- import ----
def frames_and_labels(w: Path, name: str) -> tuple[Path, Path]:
    """A folder of the phantom's frames and one of CholecSeg8k-style class-ID masks (50
    tissue, 31 tool) for them."""
    frames, labels = w / f"frames-{name}", w / f"labels-{name}"
    shutil.copytree(w / "phantom" / "images", frames)
    labels.mkdir()
    for path in (w / "phantom" / "masks").iterdir():
        tool = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE) > 127
        cv2.imwrite(str(labels / path.name), np.where(tool, 31, 50).astype(np.uint8))
    return frames, labels


def imported(w: Path, name: str, *args: str, status: int, names: str,
             source: Path | None = None) -> dict:
    """`import SOURCE --out OUT *args`: ended with `status` naming `names`; a refusal leaves no
    OUT."""
    out = w / f"imported-{name}"
    source = source or w / "phantom" / "images"
    result = cli("import", str(source), "--out", str(out), *args)
    left = status != 0 and out.exists() and any(out.iterdir())
    return outcome(result, status, names, wrong=left)


def case_scale_nan(w: Path) -> dict:
    """import: --scale nan is refused naming the option."""
    return imported(w, "scale-nan", "--scale", "nan", status=2, names="--scale")


def case_scale_huge(w: Path) -> dict:
    """import: --scale 1000 is refused before allocating the frames."""
    return imported(w, "scale-huge", "--scale", "1000", status=2, names="--scale")


def case_label_masks(w: Path) -> dict:
    """import: class-ID masks without --tool-labels: refused before writing, the masks named,
    --tool-labels suggested."""
    frames, labels = frames_and_labels(w, "labels")
    out = w / "imported-labels"
    result = cli("import", str(frames), "--out", str(out), "--masks", str(labels))
    said = result.stderr if result else ""
    return outcome(result, 2, str(labels), wrong="--tool-labels" not in said or out.exists())


def case_special_source(kind: str) -> Callable[[Path], dict]:
    """import: a source that is not a regular file is said to be what it is."""
    def case(w: Path) -> dict:
        source = Path("/dev/null")
        if kind == "fifo":
            source = w / "stream.mp4"
            os.mkfifo(source)
        result = cli("import", str(source), "--out", str(w / f"imported-{kind}"), seconds=60)
        said = result.stderr if result else ""
        return outcome(result, 2, str(source), wrong="does not exist" in said)
    case.__doc__ = f"import: {kind} as the source is not called missing"
    return case


def onnx_model(path: Path, output: Callable) -> Path:
    """A one-op ONNX network at `path`: `output(x)` of its NCHW input."""
    import torch

    class Net(torch.nn.Module):
        def forward(self, x):
            return output(x)

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        torch.onnx.export(Net().eval(), (torch.zeros(1, 3, 128, 160),), str(path), dynamo=False,
                          input_names=["x"], output_names=["y"], dynamic_axes={"x": {0: "n"}})
    return path


def case_model_output(option: str, values: str) -> Callable[[Path], dict]:
    """import: a model (`option`) whose every output is `values` stops import naming it."""
    outputs = {"nan": lambda x: x[:, :1] * float("nan"), "negative": lambda x: -1 - x[:, :1] ** 2}

    def case(w: Path) -> dict:
        model = onnx_model(w / f"{option.strip('-')}-{values}.onnx", outputs[values])
        return imported(w, f"{option}-{values}", option, str(model), status=2, names=str(model))
    case.__doc__ = f"import: {option} model that outputs {values} is named"
    return case


def case_stereo_same_images(w: Path) -> dict:
    """import: a stereo pair whose right frames are its left ones yields no depth: stopped."""
    right = shutil.copytree(w / "phantom" / "images", w / "right-same")
    return imported(w, "stereo-same", "--right", str(right), "--baseline", "5", "--focal", "140",
                    status=2, names=str(right))


# ---- train ----
def copied_run(w: Path, name: str) -> Path:
    return Path(shutil.copytree(w / "run", w / f"run-{name}"))


def rewritten_checkpoint(path: Path, change: Callable[[dict], None]) -> None:
    import torch

    state = torch.load(path, weights_only=False)
    change(state)
    torch.save(state, path)


def drop_a_row(state: dict) -> None:
    state["gaussians"]["opacity_logits"] = state["gaussians"]["opacity_logits"][:-1]


def nan_means(state: dict) -> None:
    state["gaussians"]["means"][:5] = float("nan")


def case_resume_rows_disagree(w: Path) -> dict:
    """train: --resume where latest.pt's tensors disagree in length falls back to previous.pt."""
    run = copied_run(w, "rows")
    shutil.copy(run / CHECKPOINT, previous_path(run / CHECKPOINT))
    rewritten_checkpoint(run / CHECKPOINT, drop_a_row)
    return outcome(cli("train", "--out", str(run), "--resume", "--iters", "8"), 0, "")


def case_resume_latest_deleted(w: Path) -> dict:
    """train: --resume with latest.pt deleted and previous.pt intact falls back."""
    run = copied_run(w, "no-latest")
    (run / CHECKPOINT).rename(previous_path(run / CHECKPOINT))
    return outcome(cli("train", "--out", str(run), "--resume", "--iters", "8"), 0, "")


def case_resume_nan(w: Path) -> dict:
    """train: --resume of a checkpoint holding NaN Gaussians names the checkpoint."""
    run = copied_run(w, "nan-resume")
    rewritten_checkpoint(run / CHECKPOINT, nan_means)
    return outcome(cli("train", "--out", str(run), "--resume", "--iters", "8"), 2,
                   str(run / CHECKPOINT))


def trained(w: Path, name: str, *args: str, status: int, names: str) -> dict:
    return outcome(cli("train", "--data", str(w / "phantom"), "--out", str(w / f"run-{name}"),
                       *args), status, names)


def case_densify_window(w: Path) -> dict:
    """train: a densification window that ends before it starts is refused."""
    return trained(w, "window", *FAST, "--set", "densify.start=0.9", "--set", "densify.stop=0.1",
                   status=2, names="densify.stop")


def case_iters_and_set(w: Path) -> dict:
    """train: --iters and --set train.iterations together are refused, not one dropped."""
    return trained(w, "iters-set", "--iters", "20", "--set", "train.iterations=30",
                   status=2, names="train.iterations")


def case_two_trains_at_once(w: Path) -> dict:
    """train: two `train --out X` started at the same instant: the loser names the holder."""
    out = w / "run-race"
    command = surgsplat_command("train", "--data", str(w / "phantom"), "--out", str(out), *FAST)
    first, second = (subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                      text=True) for _ in range(2))
    results = [subprocess.CompletedProcess(p.args, p.wait(CASE_SECONDS), *p.communicate())
               for p in (first, second)]
    failed = [result for result in results if result.returncode != 0]
    return outcome(failed[0] if failed else results[1], 2, "in use")


def case_alexnet_text(w: Path) -> dict:
    """train: eval --alexnet-weights of a text file is one line naming it."""
    weights = w / "alexnet.pth"
    weights.write_text("not weights\n")
    run = copied_run(w, "alexnet")
    return outcome(cli("eval", str(run), "--no-geometry", "--alexnet-weights", str(weights)), 2,
                   str(weights))


# ---- outputs ----
def case_eval_nan_checkpoint(w: Path) -> dict:
    """outputs: eval of a checkpoint with NaN Gaussians names the checkpoint."""
    run = copied_run(w, "nan-eval")
    rewritten_checkpoint(run / CHECKPOINT, nan_means)
    return outcome(cli("eval", str(run), "--no-geometry"), 2, str(run / CHECKPOINT))


def case_eval_other_scene(w: Path) -> dict:
    """outputs: eval --data OTHER of a run whose scene.json is gone does not score OTHER."""
    run = copied_run(w, "other-scene")
    (run / "scene.json").unlink()
    other = w / "phantom-other"
    if not other.is_dir():
        cli("phantom", "--out", str(other), "--preset", "small", "--seed", "7")
    result = cli("eval", str(run), "--no-geometry", "--data", str(other))
    return outcome(result, 2, "scene")


def user_folder(w: Path, name: str, file: str) -> Path:
    folder = w / name
    folder.mkdir()
    (folder / file).write_bytes(USER_FILE)
    return folder


def case_render_into_user_folder(w: Path) -> dict:
    """outputs: render --out a folder of the user's holding rgb.mp4 leaves it alone."""
    folder = user_folder(w, "myvids", "rgb.mp4")
    result = cli("render", str(w / "run"), "--out", str(folder), "--channels", "rgb")
    return outcome(result, 2, str(folder), overwrote=(folder / "rgb.mp4").read_bytes() != USER_FILE)


def case_export_sim_into_user_folder(w: Path) -> dict:
    """outputs: export --sim a folder of the user's holding scene.xml leaves it alone (a run of
    a method with a tool field, which --sim needs)."""
    run = w / "run-physiosplat"
    trained = cli("train", "--method", "physiosplat", "--data", str(w / "phantom"), "--out",
                  str(run), *FAST)
    if trained is None or trained.returncode != 0:
        return outcome(trained, 0, "")
    folder = user_folder(w, "mysim", "scene.xml")
    result = cli("export", str(run), "--sim", str(folder))
    return outcome(result, 2, str(folder),
                   overwrote=(folder / "scene.xml").read_bytes() != USER_FILE)


def case_export_time_and_frames(w: Path) -> dict:
    """outputs: export --ply --time 0.5 --frames 3 is refused, not --frames ignored."""
    return outcome(cli("export", str(w / "run"), "--ply", "--time", "0.5", "--frames", "3",
                       "--out", str(w / "ply-time-frames")), 2, "--frames")


def case_export_repeated_frames(w: Path) -> dict:
    """outputs: export --ply --frames 1,1,1 writes what it reports (or refuses)."""
    out = w / "ply-repeated"
    result = cli("export", str(w / "run"), "--ply", "--frames", "1,1,1", "--out", str(out))
    if result is None or result.returncode != 0:
        return outcome(result, 2, "--frames")
    written = len(list(out.glob("*.ply")))
    return outcome(result, 0, "", wrong=written != 1 or "3 " in result.stdout)


def case_report_negative_frames(w: Path) -> dict:
    """outputs: report --frames -3 is refused."""
    return outcome(cli("report", str(w / "run"), "--frames", "-3", "--out",
                       str(w / "report-negative.html")), 2, "--frames")


def case_report_out_folder(w: Path) -> dict:
    """outputs: report --out an existing folder names it, not a hidden temporary."""
    folder = w / "a-folder"
    folder.mkdir()
    result = cli("report", str(w / "run"), "--out", str(folder))
    said = result.stderr if result else ""
    return outcome(result, 2, str(folder), wrong=f"{os.sep}." in said)


def case_mesh_resolution(w: Path) -> dict:
    """outputs: export --mesh --mesh-resolution 100000 is refused before allocating."""
    return outcome(cli("export", str(w / "run"), "--mesh", "--mesh-resolution", "100000",
                       "--out", str(w / "mesh-huge")), 2, "--mesh-resolution")


def case_view_ipv6(w: Path) -> dict:
    """outputs: view --host ::1 prints its URL with the address in brackets."""
    with socket.socket(socket.AF_INET6) as probe:
        probe.bind(("::1", 0))
        port = probe.getsockname()[1]
    process = subprocess.Popen(surgsplat_command("view", str(w / "run"), "--host", "::1",
                                                 "--port", str(port)),
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 60
    said = ""
    while time.monotonic() < deadline and "viewer at" not in said and process.poll() is None:
        said += process.stdout.readline()  # viser's own banner first, then surgsplat's line
    process.send_signal(signal.SIGINT)
    stdout, stderr = process.communicate(timeout=30)
    result = subprocess.CompletedProcess(process.args, 0, said + stdout, stderr)
    return outcome(result, 0, "http://[::1]:")


READ_ONLY = """
import builtins, io
RUN = {run!r}
real_open, real_os_open = builtins.open, os.open
def refuse(name):
    if os.fsdecode(name).startswith(RUN):
        raise OSError(errno.EROFS, os.strerror(errno.EROFS), os.fsdecode(name))
def ro_open(file, mode="r", *args, **kwargs):
    if isinstance(file, (str, bytes, os.PathLike)) and set(mode) & set("wax+"):
        refuse(file)
    return real_open(file, mode, *args, **kwargs)
def ro_os_open(path, flags, *args, **kwargs):
    if flags & (os.O_WRONLY | os.O_RDWR | os.O_CREAT):
        refuse(path)
    return real_os_open(path, flags, *args, **kwargs)
builtins.open = io.open = ro_open
os.open = ro_os_open
"""
"""The run folder {run} as on a read-only mount: opening anything under it to write fails."""


def case_read_only_run(w: Path) -> dict:
    """outputs: a run on a read-only mount renders into a folder elsewhere."""
    run = copied_run(w, "read-only")
    out = w / "videos-of-read-only"
    result = cli("render", str(run), "--out", str(out), "--channels", "rgb",
                 patch=READ_ONLY.format(run=str(run)))
    return outcome(result, 0, "", wrong=not (out / "rgb.mp4").is_file())


# ---- batch ----
def batch(w: Path, name: str, *args: str) -> subprocess.CompletedProcess | None:
    return cli("batch", str(w / "phantom"), "--out", str(w / f"batch-{name}"), "--iters", "2",
               *args, seconds=BATCH_SECONDS)


def case_batch_resources(*args: str, names: str) -> Callable[[Path], dict]:
    """batch: resources the cluster can never grant are refused at start, no hang."""
    def case(w: Path) -> dict:
        return outcome(batch(w, names.strip("-"), *args), 2, names)
    case.__doc__ = f"batch: {' '.join(args)} refused at start"
    return case


def case_batch_ray_client(w: Path) -> dict:
    """batch: --ray-address ray://host:port (the README's form) without a cluster there is one
    line."""
    return outcome(batch(w, "ray-client", "--ray-address", "ray://127.0.0.1:1"), 2,
                   "--ray-address")


def case_batch_ray_auto(w: Path) -> dict:
    """batch: --ray-address auto with no cluster names --ray-address."""
    return outcome(batch(w, "ray-auto", "--ray-address", "auto"), 2, "--ray-address")


def case_batch_sigterm(w: Path) -> dict:
    """batch: SIGTERM stops it with one surgsplat line and no native crash dump."""
    out = w / "batch-sigterm"
    process = subprocess.Popen(surgsplat_command("batch", str(w / "phantom"), "--out", str(out),
                                                 "--iters", "200"),
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + BATCH_SECONDS
    while (time.monotonic() < deadline and process.poll() is None
           and not any(out.rglob("train_log.jsonl"))):  # training has started
        time.sleep(0.2)
    process.send_signal(signal.SIGTERM)
    try:
        stdout, stderr = process.communicate(timeout=BATCH_SECONDS)
    except subprocess.TimeoutExpired:
        process.kill()
        return outcome(None, 2, "")
    result = subprocess.CompletedProcess(process.args, process.returncode, stdout, stderr)
    return outcome(result, 2, "error:", wrong="*** SIG" in stderr or "Fatal Python" in stderr)


def case_second_batch_keeps_finished_clip(w: Path) -> dict:
    """batch: a second batch into a folder with a finished clip keeps it in summary.csv."""
    out = w / "batch-twice"
    first = cli("batch", str(w / "phantom"), "--out", str(out), "--iters", "2", "--no-geometry",
                seconds=CASE_SECONDS)
    if first is None or first.returncode != 0:
        return outcome(first, 0, "")
    other = w / "phantom-second-clip"
    if not other.is_dir():
        cli("phantom", "--out", str(other), "--preset", "small", "--seed", "3")
    second = cli("batch", str(other), "--out", str(out), "--iters", "2", "--no-geometry",
                 seconds=CASE_SECONDS)
    summary = out / "summary.csv"
    kept = summary.is_file() and "phantom," in summary.read_text().replace("\n", ",")
    if second is not None and second.returncode == 2:
        return outcome(second, 2, str(out), wrong=not kept)
    return outcome(second, 0, "", wrong=not kept)


# ---- numeric options ----
def case_phantom_seed(w: Path) -> dict:
    """numeric options: phantom --seed -1 is refused naming the option."""
    return outcome(cli("phantom", "--out", str(w / "phantom-seed"), "--seed", "-1"), 2,
                   "--seed")


CASES: list[tuple[str, Callable[[Path], dict]]] = [
    *[("scene input", case) for case in (case_dangling_symlink, case_looping_symlink,
                                         case_red_masks, case_depth_is_a_file,
                                         case_depth_absurdly_far, case_lzw_tiff)],
    *[("import", case) for case in (
        case_scale_nan, case_scale_huge, case_label_masks, case_special_source("/dev/null"),
        case_special_source("fifo"), case_model_output("--tool-segmenter", "nan"),
        case_model_output("--depth", "nan"), case_model_output("--depth", "negative"),
        case_stereo_same_images)],
    *[("train", case) for case in (case_resume_rows_disagree, case_resume_latest_deleted,
                                   case_resume_nan, case_densify_window, case_iters_and_set,
                                   case_two_trains_at_once, case_alexnet_text)],
    *[("outputs", case) for case in (
        case_eval_nan_checkpoint, case_eval_other_scene, case_render_into_user_folder,
        case_export_sim_into_user_folder, case_export_time_and_frames,
        case_export_repeated_frames, case_report_negative_frames, case_report_out_folder,
        case_mesh_resolution, case_view_ipv6, case_read_only_run)],
    *[("batch", case) for case in (
        case_batch_resources("--memory-gb", "1000", names="--memory-gb"),
        case_batch_resources("--cpus-per-clip", "64", names="--cpus-per-clip"),
        case_batch_resources("--cpus-per-clip", "2", "--num-cpus", "1", names="--cpus-per-clip"),
        case_batch_ray_client, case_batch_ray_auto, case_batch_sigterm,
        case_second_batch_keeps_finished_clip)],
    ("numeric options", case_phantom_seed),
]
"""(class, case) in the order run."""


if __name__ == "__main__":  # one case by name, for development: fault_cases.py WORK CASE
    work, name = Path(sys.argv[1]), sys.argv[2]
    print(json.dumps(next(case for _, case in CASES if case.__name__ == name
                          or name in (case.__doc__ or ""))(work)))
