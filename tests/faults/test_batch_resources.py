"""`surgsplat batch` refuses what could never run, in one line: tasks that no node could hold
(checked before Ray starts when this machine is too small, once connected otherwise) and a Ray
cluster that cannot be joined; a SIGTERM stops it in one line; its summary covers every clip
finished in its folder. And the method benchmark's jobs racing to prepare one scene share it."""

from __future__ import annotations

import csv
import importlib.util
import os
import shutil
import signal
import subprocess
import sys
import threading
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest
import ray

from surgsplat.pipeline.batch import REPORT_FILE, SUMMARY_FILE, clip_jobs
from surgsplat.pipeline.batch_cluster import GIB, Node, check_nodes_hold
from surgsplat.pipeline.batch_stages import DONE, STATUS_FILE, record_status
from surgsplat.errors import SurgsplatError

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
import bench_methods  # noqa: E402

MACHINE_MEMORY_GIB = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") / GIB
CPUS = os.cpu_count()
NEVER = "no task of a clip could ever start"


@pytest.fixture
def ray_never_starts(monkeypatch):
    """ray.init fails the test: what is checked must be checked before Ray starts."""

    def started(*args, **kwargs):
        raise AssertionError("Ray was started")

    monkeypatch.setattr(ray, "init", started)


@pytest.mark.parametrize("options, refusal", [
    (("--memory-gb", f"{round(2 * MACHINE_MEMORY_GIB)}"),
     f"--memory-gb {round(2 * MACHINE_MEMORY_GIB)} is more than this machine's memory "
     f"({MACHINE_MEMORY_GIB:.1f} GiB)"),
    (("--cpus-per-clip", f"{2 * CPUS}"),
     f"--cpus-per-clip {2 * CPUS} is more than this machine's CPUs ({CPUS})"),
    (("--cpus-per-clip", "2", "--num-cpus", "1"), "--cpus-per-clip 2 is more than --num-cpus (1)"),
], ids=["memory", "cpus", "num-cpus"])
def test_a_batch_this_machine_cannot_hold_is_refused_before_ray_starts(
        cli, small_phantom, tmp_path, one_error_line, ray_never_starts, options, refusal):
    out = tmp_path / "batch"
    line = one_error_line(cli("batch", str(small_phantom), "--out", str(out), "--iters", "2",
                              *options, timeout=60))
    assert line == f"error: {refusal}; {NEVER}"
    assert not out.exists()


def test_the_tasks_must_fit_on_one_node_of_a_cluster():
    nodes = [Node(cpus=8, memory=16 * GIB), Node(cpus=2, memory=64 * GIB)]
    check_nodes_hold(nodes, 8, 16, "the Ray cluster at head:6379")
    check_nodes_hold(nodes, 2, 64, "the Ray cluster at head:6379")
    with pytest.raises(SurgsplatError, match=r"--cpus-per-clip 16 is more than the CPUs of any "
                                             r"node of the Ray cluster at head:6379 \(8\)"):
        check_nodes_hold(nodes, 16, 1, "the Ray cluster at head:6379")
    with pytest.raises(SurgsplatError, match=r"--cpus-per-clip 4 with --memory-gb 32: no node "
                                             r"of the Ray cluster at head:6379 has both"):
        check_nodes_hold(nodes, 4, 32, "the Ray cluster at head:6379")


@pytest.fixture
def small_ray():
    """A Ray instance of 1 CPU and 0.5 GiB of task memory, this process connected to it as a
    batch is to a cluster."""
    ray.init(num_cpus=1, _memory=GIB // 2, include_dashboard=False, log_to_driver=False,
             configure_logging=False)
    yield
    ray.shutdown()


@pytest.mark.slow
def test_a_batch_the_ray_instance_cannot_hold_is_refused_once_connected(
        cli, small_phantom, tmp_path, one_error_line, small_ray):
    for options, refusal in (
            (("--cpus-per-clip", "2"),
             "--cpus-per-clip 2 is more than the CPUs of the running Ray instance (1)"),
            (("--memory-gb", "1"),
             "--memory-gb 1 is more than the memory of the running Ray instance (0.5 GiB)")):
        line = one_error_line(cli("batch", str(small_phantom), "--out", str(tmp_path / "b"),
                                  "--iters", "2", *options, timeout=30))
        assert line == f"error: {refusal}; {NEVER}"
    assert not (tmp_path / "b" / small_phantom.name).exists()


def ray_runs_on_this_machine() -> bool:
    """Whether a Ray instance runs here (its GCS server), which `--ray-address auto` joins."""
    for name in Path("/proc").glob("[0-9]*/comm"):
        try:
            if name.read_text().strip() == "gcs_server":
                return True
        except OSError:  # the process ended
            continue
    return False


@pytest.mark.parametrize("address, refusal", [
    ("127.0.0.1:1", "cannot reach 127.0.0.1:1 (Connection refused); is the Ray cluster "
                    "running?"),
    ("head-node", "expected host:port (the head node's GCS), ray://host:port (its Ray Client "
                  "server) or auto"),
    ("ray://127.0.0.1:10001", 'a ray:// address needs Ray Client: pip install "ray[client]"'),
    ("auto", "no Ray cluster is running on this machine (start one with `ray start --head`, "
             "or omit --ray-address for a local instance)"),
], ids=["unreachable", "malformed", "ray-client", "auto"])
def test_a_ray_address_that_cannot_be_joined_is_one_line(cli, small_phantom, tmp_path,
                                                         one_error_line, address, refusal):
    if address.startswith("ray://") and importlib.util.find_spec("grpc") is not None:
        pytest.skip("Ray Client (ray[client]) is installed")
    if address == "auto" and ray_runs_on_this_machine():
        pytest.skip("a Ray instance runs on this machine: --ray-address auto would join it")
    line = one_error_line(cli("batch", str(small_phantom), "--out", str(tmp_path / "b"),
                              "--iters", "2", "--ray-address", address, timeout=60))
    assert line == f"error: --ray-address {address}: {refusal}"


@pytest.mark.slow
def test_sigterm_stops_a_batch_in_one_line(small_phantom, tmp_path, faults):
    out = tmp_path / "batch"
    process = faults.start("batch", str(small_phantom), "--out", str(out), "--iters", "5000",
                           "--num-cpus", "1", "--memory-gb", "0.5", "--no-geometry",
                           *faults.TRAIN_FAST)
    run = out / small_phantom.name / "run"
    faults.wait_for(lambda: faults.logged_iterations(run) or process.poll() is not None,
                    what="the clip's training to start")
    process.send_signal(signal.SIGTERM)
    stdout, stderr = process.communicate(timeout=120)
    line = faults.one_error_line(subprocess.CompletedProcess(process.args, process.returncode,
                                                             stdout, stderr))
    assert line == ("error: interrupted (Ctrl-C or SIGTERM) with 0 of 1 clips done, 0 failed; "
                    "run the same command again to go on: finished clips are skipped, the "
                    "others resume")
    assert not (out / small_phantom.name / STATUS_FILE).exists()


@pytest.fixture(scope="module")
def evaluated_run(small_phantom, tmp_path_factory, cli) -> Path:
    """A run of 2 iterations of the small phantom, evaluated."""
    run = tmp_path_factory.mktemp("evaluated") / "run"
    trained = cli("train", "--data", str(small_phantom), "--out", str(run), "--iters", "2",
                  "--set", "init.max_points=1500")
    assert trained.returncode == 0, trained.stderr
    evaluated = cli("eval", str(run), "--no-geometry")
    assert evaluated.returncode == 0, evaluated.stderr
    return run


def finished_clip(small_phantom: Path, evaluated_run: Path, clips: Path, out: Path,
                  name: str) -> Path:
    """The clip `clips/name` (a copy of the small phantom), recorded done in `out/name` with a
    copy of the evaluated run, as a batch leaves a clip it finished."""
    clip = shutil.copytree(small_phantom, clips / name)
    job = clip_jobs([clip], out, "deform3dgs", 2, 1, 5.0)[0]
    shutil.copytree(evaluated_run, job.run_dir)
    record_status(job, DONE, 1.0, 1)
    return clip


def test_a_batch_of_other_clips_keeps_the_finished_ones_in_its_summary(
        cli, small_phantom, evaluated_run, tmp_path):
    out = tmp_path / "batch"
    alpha = finished_clip(small_phantom, evaluated_run, tmp_path / "clips", out, "alpha")
    first = cli("batch", str(alpha), "--out", str(out), "--iters", "2")
    assert first.returncode == 0, first.stderr
    # beta finished by a batch stopped before it wrote its summary
    beta = finished_clip(small_phantom, evaluated_run, tmp_path / "clips", out, "beta")
    second = cli("batch", str(beta), "--out", str(out), "--iters", "2")
    assert second.returncode == 0, second.stderr
    with open(out / SUMMARY_FILE) as handle:
        rows = list(csv.DictReader(handle))
    assert [(row["name"], row["clip"], row["state"]) for row in rows] == \
        [("beta", str(beta.resolve()), DONE), ("alpha", str(alpha.resolve()), DONE)]
    assert all(float(row["psnr_tissue"]) > 0 for row in rows)
    report = (out / REPORT_FILE).read_text()
    assert "<h2>beta/run (" in report and "<h2>alpha/run (" in report


def test_a_clip_named_as_one_finished_from_another_source_is_refused(
        cli, small_phantom, evaluated_run, tmp_path, one_error_line):
    out = tmp_path / "batch"
    first = finished_clip(small_phantom, evaluated_run, tmp_path / "first", out, "liver")
    other = shutil.copytree(small_phantom, tmp_path / "second" / "liver")
    line = one_error_line(cli("batch", str(other), "--out", str(out), "--iters", "2"))
    assert line == (f"error: {other.resolve()}: {out.resolve() / 'liver'} holds the results of "
                    f"another clip of the same name, {first.resolve()}; rename the clip or "
                    "choose another --out")


def test_jobs_preparing_one_scene_at_once_share_it(tmp_path, monkeypatch):
    both_generating = threading.Barrier(2, timeout=10)

    def generate(*args: str) -> float:
        """`surgsplat phantom --out SCENE` once both jobs generate: the scene written beside
        SCENE, then renamed onto it, as the command does."""
        both_generating.wait()
        scene = Path(args[args.index("--out") + 1])
        part = scene.with_name(f"{scene.name}.part-{threading.get_ident()}")
        part.mkdir()
        (part / "poses_bounds.npy").write_bytes(b"poses")
        part.rename(scene)
        return 0.0

    monkeypatch.setattr(bench_methods, "surgsplat", generate)
    with ThreadPoolExecutor(max_workers=2) as pool:
        jobs = [pool.submit(bench_methods.phantom_dir, tmp_path, "pulling") for _ in range(2)]
        scenes = [job.result() for job in jobs]
    assert scenes == [tmp_path / "phantom-pulling"] * 2
    assert [path.name for path in tmp_path.iterdir()] == ["phantom-pulling"]
    assert (tmp_path / "phantom-pulling" / "poses_bounds.npy").read_bytes() == b"poses"
