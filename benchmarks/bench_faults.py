"""Fault benchmark: work lost when `surgsplat train` is killed with SIGKILL (kill -9) at random
moments, whether every kill leaves a run that resumes, and the bad inputs and faults of every
class of issues 30 and 53 run against the CLI.

    python benchmarks/bench_faults.py [--trials 20] [--checkpoint-seconds 60] [--out FILE]
                                      [--no-cases] [--no-kills]

Cases: per class of issue 30 a few concrete bad inputs or faults (here), and every case of
issue 53 (fault_cases.py), each run as a user runs
`surgsplat` (a subprocess, a time limit), on the small phantom and a run of a few iterations.
A case is handled when it ends as it should: one line `error: ...` naming the path, key or
option at fault (or success, where the fault must be survived), no traceback, no hang, and the
user's files byte-for-byte as they were. The report counts the cases handled and, over all of
them, silent wrong results, overwritten user files, tracebacks and hangs. Run by an interpreter
that imports an older checkout of surgsplat (the editable install's import hook removed and the
checkout put first on sys.path, e.g. by a sitecustomize.py on PYTHONPATH), the cases run that
code, and the report records its commit: what the cases caught before their fixes.

One run of deform3dgs on the small phantom is killed `--trials` times, each time at a random
moment in the two checkpoint intervals after training (re)started, and resumed with
`surgsplat train --resume` after each kill. Per kill: the wall seconds of training since the last
complete checkpoint (what the kill lost), the iterations past it that the log had reached, and
whether the checkpoint loaded. At the end the run is resumed to completion and its log must hold
strictly increasing iterations. Results go to benchmarks/results/bench_faults-<cpu>-<best ISA>.json.
"""

from __future__ import annotations

import argparse
import json
import os
import random
import shutil
import signal
import socket
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from datetime import datetime, timezone
from pathlib import Path

import fault_cases
from bench_render import results_path
from fault_probe import FAST, FULL_DISK_ON, cli, contents, outcome, summarise, surgsplat_command

from surgsplat.render import native
from surgsplat.train.checkpoint import load_checkpoint
from surgsplat.train.trainer import CHECKPOINT, LOG_FILE

ENDLESS = 1_000_000
"""Iterations asked of the killed run: it never ends on its own."""
FAILING_FFMPEG = """#!/bin/sh
for output; do :; done
head -c 1000 > "$output"
echo "Error writing trailer: No space left on device" >&2
exit 228
"""


def logged(run: Path) -> list[int]:
    """Iterations in RUN/train_log.jsonl (a line cut by the kill is skipped)."""
    path = run / LOG_FILE
    found = []
    for line in path.read_text().splitlines() if path.is_file() else []:
        try:
            found.append(json.loads(line)["iteration"])
        except (json.JSONDecodeError, KeyError):
            pass
    return found


def one_kill(phantom: Path, run: Path, checkpoint_seconds: float, rng: random.Random) -> dict:
    """Start (or resume) training, SIGKILL it at a random moment, measure what was lost."""
    if (run / CHECKPOINT).is_file():
        command = surgsplat_command("train", "--out", str(run), "--resume")
    else:
        command = surgsplat_command("train", "--data", str(phantom), "--out", str(run), "--iters",
                                    str(ENDLESS), "--set",
                                    f"train.checkpoint_seconds={checkpoint_seconds}")
    before = logged(run)
    process = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    while logged(run) == before or len(logged(run)) < 1:  # training has (re)started
        if process.poll() is not None:
            raise RuntimeError(f"training ended early: {process.stderr.read().decode()}")
        time.sleep(0.02)
    started = time.time()
    time.sleep(rng.uniform(0.0, 2.0 * checkpoint_seconds))
    process.send_signal(signal.SIGKILL)
    killed = time.time()
    process.wait()
    reached = max(logged(run), default=0)
    state = load_checkpoint(run / CHECKPOINT)  # raises if the kill left it damaged
    saved = (run / CHECKPOINT).stat().st_mtime
    return {"seconds_after_start": killed - started,
            "lost_wall_s": killed - max(saved, started),
            "checkpoint_iteration": int(state["iteration"]),
            "logged_iteration": reached,
            "lost_iterations_logged": max(reached - int(state["iteration"]), 0)}


def case_frame_order(w: Path) -> dict:
    """Class 1: files named 0.png ... 15.png load in numeric order (the run's fingerprint equals
    that of the zero-padded original)."""
    renamed = shutil.copytree(w / "phantom", w / "renamed")
    for sub in ("images", "depth", "masks"):
        for path in (renamed / sub).iterdir():
            path.rename(path.with_name(f"{int(path.stem)}{path.suffix}"))
    result = cli("train", "--data", str(renamed), "--out", str(w / "run-renamed"), *FAST)
    fingerprint = lambda run: json.loads((run / "scene.json").read_text())["fingerprint"]
    wrong = result is not None and result.returncode == 0 and (
        fingerprint(w / "run-renamed") != fingerprint(w / "run"))
    return outcome(result, 0, "", wrong=wrong)


def refused_out(w: Path, out: Path, status: int = 2) -> dict:
    """`train --out out`: refused with out named, its files unchanged."""
    before = contents(out)
    result = cli("train", "--data", str(w / "phantom"), "--out", str(out), *FAST)
    return outcome(result, status, str(out), overwrote=contents(out) != before)


def case_out_is_the_scene(w: Path) -> dict:
    """Class 2: `train --out` the scene folder."""
    return refused_out(w, shutil.copytree(w / "phantom", w / "scene-as-out"))


def case_out_holds_user_files(w: Path) -> dict:
    """Class 2: `train --out` a folder holding the user's own config.json."""
    folder = w / "mine"
    folder.mkdir()
    (folder / "config.json").write_text('{"mine": true}\n')
    return refused_out(w, folder)


def case_render_full_disk(w: Path) -> dict:
    """Class 3: ffmpeg fails with a full disk: one line, the existing rgb.mp4 kept."""
    run = shutil.copytree(w / "run", w / "run-render")
    videos = run / "videos"
    videos.mkdir(exist_ok=True)
    (videos / "rgb.mp4").write_bytes(b"the user's good video")
    ffmpeg = w / "ffmpeg"
    ffmpeg.write_text(FAILING_FFMPEG)
    ffmpeg.chmod(0o755)
    before = contents(videos)
    result = cli("render", str(run), "--channels", "rgb", env={"IMAGEIO_FFMPEG_EXE": str(ffmpeg)})
    return outcome(result, 2, "No space left", overwrote=contents(videos) != before)


def case_set_name(w: Path) -> dict:
    """Class 4: a run trained with --set name=mine evaluates, and metrics.json says which
    method it scored."""
    run = w / "run-named"
    trained = cli("train", "--data", str(w / "phantom"), "--out", str(run), *FAST,
                  "--set", "name=mine")
    if trained is None or trained.returncode != 0:
        return outcome(trained, 2, "name")  # refused with one line is handled too
    result = cli("eval", str(run), "--no-geometry")
    metrics = run / "metrics.json"
    wrong = metrics.is_file() and "deform3dgs" not in metrics.read_text() \
        and "mine" not in metrics.read_text()
    return outcome(result, 0, "", wrong=wrong)


def config_value(key_value: str) -> Callable[[Path], dict]:
    """Class 5: `train --set key_value` refused with one line naming the key."""
    def case(w: Path) -> dict:
        out = w / f"run-{key_value.replace('=', '-')}"
        result = cli("train", "--data", str(w / "phantom"), "--out", str(out), *FAST,
                     "--set", key_value)
        return outcome(result, 2, key_value.split("=")[0])
    case.__doc__ = f"Class 5: --set {key_value}"
    return case


def case_nan_in_config_file(w: Path) -> dict:
    """Class 5: NaN in a --config JSON file, refused naming the key."""
    config = w / "nan.json"
    config.write_text('{"losses": {"depth": {"weight": NaN}}}\n')
    result = cli("train", "--data", str(w / "phantom"), "--out", str(w / "run-nan"), *FAST,
                 "--config", str(config))
    return outcome(result, 2, "losses.depth.weight")


def case_resume(method: str) -> Callable[[Path], dict]:
    """Class 6: a `method` run resumes from its checkpoint."""
    def case(w: Path) -> dict:
        run = w / f"run-resume-{method}"
        first = cli("train", "--method", method, "--data", str(w / "phantom"), "--out",
                    str(run), *FAST)
        if first is None or first.returncode != 0:
            return outcome(first, 0, "")
        return outcome(cli("train", "--out", str(run), "--resume", "--iters", "8"), 0, "")
    case.__doc__ = f"Class 6: {method} resumes"
    return case


def case_damaged_log(damage: bytes) -> Callable[[Path], dict]:
    """Class 7: `report` on a run whose train_log.jsonl ends with `damage`."""
    def case(w: Path) -> dict:
        run = shutil.copytree(w / "run", w / f"run-log-{len(list(w.iterdir()))}")
        with open(run / "train_log.jsonl", "ab") as log:
            log.write(damage)
        return outcome(cli("report", str(run), "--out", str(w / "report.html")), 0, "")
    case.__doc__ = f"Class 7: report with a log ending in {damage!r}"
    return case


def case_view_port_in_use(w: Path) -> dict:
    """Class 8: `view --port` of a port in use: refused with the port named, no hang."""
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = str(taken.getsockname()[1])
        return outcome(cli("view", str(w / "run"), "--port", port), 2, port)


def case_view_option(*args: str, names: str) -> Callable[[Path], dict]:
    """Class 8: `view RUN *args` refused with one line naming `names`, no hang."""
    def case(w: Path) -> dict:
        return outcome(cli("view", str(w / "run"), *args), 2, names)
    case.__doc__ = f"Class 8: view {' '.join(args)}"
    return case


def case_eval_records_coverage(w: Path) -> dict:
    """Class 9: eval records how many frames each metric family covered."""
    run = shutil.copytree(w / "run", w / "run-eval")
    result = cli("eval", str(run))
    metrics = run / "metrics.json"
    wrong = result is not None and result.returncode == 0 and (
        not metrics.is_file() or "frames" not in metrics.read_text())
    return outcome(result, 0, "", wrong=wrong)


def case_batch_out_is_a_file(w: Path) -> dict:
    """Class 10: `batch --out` a file: one line, no Ray traceback, the file intact."""
    out = w / "a-file"
    out.write_text("the user's file\n")
    result = cli("batch", str(w / "phantom"), "--out", str(out), "--iters", "2")
    return outcome(result, 2, str(out), overwrote=out.read_text() != "the user's file\n")


def case_checkpoint_full_disk(w: Path) -> dict:
    """Class 11: the disk fills during a checkpoint write: one line naming the checkpoint."""
    result = cli("train", "--data", str(w / "phantom"), "--out", str(w / "run-full"), *FAST,
                 patch=FULL_DISK_ON.format(suffix=".pt"))
    return outcome(result, 2, "No space left on device")


def case_phantom_full_disk(w: Path) -> dict:
    """Class 12: `phantom` on a full disk: one line naming a path."""
    out = w / "phantom-full"
    result = cli("phantom", "--out", str(out), "--preset", "small",
                 patch=FULL_DISK_ON.format(suffix=".png"))
    return outcome(result, 2, str(out))


def case_stale_temporary(w: Path) -> dict:
    """Class 12: a report re-run removes the temporary a killed writer left."""
    folder = w / "reports"
    folder.mkdir()
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    from surgsplat.atomic import temporary_path
    stale = temporary_path(folder / "report.html")
    stale = stale.with_name(stale.name.replace(f"-{os.getpid()}-", f"-{dead.pid}-"))
    stale.write_text("left by kill -9")
    result = cli("report", str(w / "run"), "--out", str(folder / "report.html"))
    return outcome(result, 0, "", wrong=stale.exists())


def case_info_depth_scale_nan(w: Path) -> dict:
    """Class 12: `info --depth-scale nan` names the option."""
    return outcome(cli("info", str(w / "phantom"), "--depth-scale", "nan"), 2, "--depth-scale")


def damaged_frame(damage: Callable[[Path], None], folder: str) -> Callable[[Path], dict]:
    """Class 13: the last frame's file in `folder` damaged by `damage`: `train` stops with the
    file named before any training (no run is left with a checkpoint)."""
    def case(w: Path) -> dict:
        scene = shutil.copytree(w / "phantom", w / f"scene-{damage.__name__}-{folder}")
        last = sorted((scene / folder).iterdir())[-1]
        damage(last)
        run = w / f"run-{damage.__name__}-{folder}"
        result = cli("train", "--data", str(scene), "--out", str(run), *FAST)
        trained = (run / "checkpoints").is_dir()
        return outcome(result, 2, str(last), wrong=trained)
    case.__doc__ = f"Class 13: last {folder} file {damage.__name__}"
    return case


def truncated(path: Path) -> None:
    path.write_bytes(path.read_bytes()[:-20])


def resized(path: Path) -> None:
    from PIL import Image
    Image.new("L", (20, 20)).save(path)


CASES: list[tuple[int, Callable[[Path], dict]]] = [
    (1, case_frame_order),
    (2, case_out_is_the_scene), (2, case_out_holds_user_files),
    (3, case_render_full_disk),
    (4, case_set_name),
    *[(5, config_value(kv)) for kv in ("densify.every=0", "train.checkpoint_every=0",
                                       "init.pixel_stride=0", "gaussians.sh_degree=99",
                                       "gaussians.init_opacity=2", "init.max_points=0",
                                       "train.tool_mask_offset_px=100000",
                                       "losses.depth.weight=-1", "train.iterations=0",
                                       "losses.photometric.weight=1e999")],
    (5, case_nan_in_config_file),
    (6, case_resume("endogsg")), (6, case_resume("drawer")),
    *[(7, case_damaged_log(d)) for d in (b'{"iteration": 7, "lo', b"\xff\xfe\n", b"[1, 2]\n",
                                          b'{"loss": 1}\n')],
    (8, case_view_port_in_use), (8, case_view_option("--height", "0", names="--height")),
    (8, case_view_option("--height", "-5", names="--height")),
    (8, case_view_option("--host", "203.0.113.1", names="203.0.113.1")),
    (9, case_eval_records_coverage),
    (10, case_batch_out_is_a_file),
    (11, case_checkpoint_full_disk),
    (12, case_phantom_full_disk), (12, case_stale_temporary), (12, case_info_depth_scale_nan),
    (13, damaged_frame(truncated, "images")), (13, damaged_frame(truncated, "depth")),
    (13, damaged_frame(resized, "masks")),
]
"""(class of issue 30, case) in the order run."""


def prepare_workspace(workspace: Path) -> None:
    """The small phantom (`phantom`) and a short run of it (`run`) that the cases start from."""
    phantom, run = workspace / "phantom", workspace / "run"
    subprocess.run(surgsplat_command("phantom", "--out", str(phantom), "--preset", "small"),
                   check=True, capture_output=True)
    subprocess.run(surgsplat_command("train", "--data", str(phantom), "--out", str(run), *FAST),
                   check=True, capture_output=True)


def run_cases(cases: list[tuple[int | str, Callable[[Path], dict]]], workspace: Path) -> dict:
    """Every case of `cases` ((class, case) pairs) in the prepared `workspace`: per case its
    outcome, and the totals."""
    rows = []
    for issue_class, case in cases:
        started = time.perf_counter()
        row = {"class": issue_class, "case": case.__doc__.split(": ", 1)[1].split("\n")[0],
               **case(workspace), "seconds": round(time.perf_counter() - started, 1)}
        rows.append(row)
        print(json.dumps(row), file=sys.stderr, flush=True)
    return summarise(rows)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=20)
    parser.add_argument("--checkpoint-seconds", type=float, default=60.0,
                        help="train.checkpoint_seconds of the run (the bound on lost work)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path)
    parser.add_argument("--no-cases", action="store_true", help="skip the cases")
    parser.add_argument("--no-kills", action="store_true", help="skip the kill -9 trials")
    args = parser.parse_args()
    groups = {}
    if not args.no_cases:
        with tempfile.TemporaryDirectory() as tmp:
            prepare_workspace(Path(tmp))
            for name, cases in (("issue_30", CASES), ("issue_53", fault_cases.CASES)):
                groups[name] = run_cases(cases, Path(tmp))
                totals = groups[name]
                print(f"{name}: {totals['handled']} of {totals['cases']} cases handled; silent "
                      f"wrong results {totals['silent_wrong']}, overwritten user files "
                      f"{totals['overwrote']}, tracebacks {totals['traceback']}, hangs "
                      f"{totals['hang']}")
    info = native.system_info()
    report = {"benchmark": "bench_faults", "cpu": info["cpu"], "system": info,
              "date": datetime.now(timezone.utc).isoformat(timespec="seconds"),
              "commit": source_commit(), **groups}
    if not args.no_kills:
        report.update(kill_trials(args.trials, args.checkpoint_seconds, random.Random(args.seed)))
    out = args.out or results_path("bench_faults", info)
    out.write_text(json.dumps(report, indent=1) + "\n")
    print(f"written to {out}")
    if not report.get("final_resume_ok", True):
        sys.exit(1)


def source_commit() -> str:
    """The commit of the surgsplat source these cases ran (a fault benchmark may run an older
    checkout, to count the cases it fails)."""
    import surgsplat

    found = subprocess.run(["git", "-C", str(Path(surgsplat.__file__).parent), "rev-parse",
                            "--short", "HEAD"], capture_output=True, text=True)
    return found.stdout.strip() or "unknown"


def kill_trials(trials: int, checkpoint_seconds: float, rng: random.Random) -> dict:
    """`trials` kill -9 of one training run, each resumed, then a final resume to the end: the
    work each kill lost, and whether every checkpoint loaded and the log stayed in order."""
    with tempfile.TemporaryDirectory() as tmp:
        phantom, run = Path(tmp) / "phantom", Path(tmp) / "run"
        subprocess.run(surgsplat_command("phantom", "--out", str(phantom), "--preset", "small"),
                       check=True, capture_output=True)
        rows = []
        for trial in range(trials):
            rows.append(one_kill(phantom, run, checkpoint_seconds, rng))
            print(json.dumps({"trial": trial, **rows[-1]}), file=sys.stderr)
        end = load_checkpoint(run / CHECKPOINT)["iteration"] + 10
        finished = subprocess.run(surgsplat_command("train", "--out", str(run), "--resume",
                                                    "--iters", str(end)),
                                  capture_output=True, text=True)
        iterations = logged(run)
        resumed_ok = (finished.returncode == 0 and iterations[-1] == end
                      and all(a < b for a, b in zip(iterations, iterations[1:])))
    lost = [row["lost_wall_s"] for row in rows]
    print(f"{trials} kills, checkpoint every {checkpoint_seconds:g} s: work lost median "
          f"{statistics.median(lost):.1f} s, max {max(lost):.1f} s; every checkpoint loaded; "
          f"final resume {'ok' if resumed_ok else 'FAILED'}")
    return {"command": "surgsplat train --method deform3dgs (small phantom), kill -9, --resume",
            "checkpoint_seconds": checkpoint_seconds, "trials": trials,
            "lost_wall_s_median": statistics.median(lost), "lost_wall_s_max": max(lost),
            "lost_iterations_logged_max": max(row["lost_iterations_logged"] for row in rows),
            "checkpoints_damaged": 0, "final_resume_ok": resumed_ok,
            "final_log_strictly_increasing": resumed_ok, "rows": rows}


if __name__ == "__main__":
    main()
