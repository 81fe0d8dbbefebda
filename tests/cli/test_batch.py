"""`surgsplat batch` on a real local Ray instance: three small phantoms, one corrupt."""

from __future__ import annotations

import csv
import shutil
from pathlib import Path

import pytest
import ray
import typer

from surgsplat.cli.batch import batch_command
from surgsplat.pipeline.batch import SUMMARY_FILE, clip_jobs, run_batch, write_summary
from surgsplat.pipeline.batch_stages import DONE, FAILED


@pytest.fixture(scope="module")
def local_ray():
    """One local Ray instance for the module (its start-up takes seconds), 2 CPUs."""
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False, configure_logging=False)
    yield
    ray.shutdown()


@pytest.mark.slow
def test_batch_on_ray_records_failure_and_skips_finished_clips(local_ray, small_phantom,
                                                               tmp_path, capsys):
    clips = []
    for name in ("liver", "gallbladder", "corrupt"):
        clips.append(shutil.copytree(small_phantom, tmp_path / "clips" / name))
    broken = clips[2] / "images" / "000003.png"
    broken.write_bytes(broken.read_bytes()[:200])
    out = tmp_path / "batch"
    jobs = clip_jobs(clips, out, "deform3dgs", iterations=4, threads=1, fps=5.0, geometry=False)

    statuses = {Path(s["clip"]).name: s for s in
                run_batch(jobs, None, None, memory_gb=0.5, retries=1)}
    assert {name: s["state"] for name, s in statuses.items()} == \
        {"liver": DONE, "gallbladder": DONE, "corrupt": FAILED}
    failed = statuses["corrupt"]
    assert failed["stage"] == "import" and failed["attempts"] == 2
    assert "000003.png" in failed["error"] and "truncated" in failed["error"]
    for name in ("liver", "gallbladder"):
        run = out / name / "run"
        assert (run / "metrics.json").is_file() and (run / "videos" / "rgb.mp4").stat().st_size
    rows = write_summary(jobs, out)
    with open(out / SUMMARY_FILE) as handle:
        table = {row["name"]: row for row in csv.DictReader(handle)}
    assert [row["name"] for row in rows] == ["liver", "gallbladder", "corrupt"]
    assert float(table["liver"]["psnr_tissue"]) > 5 and table["corrupt"]["state"] == FAILED
    assert "000003.png" in table["corrupt"]["error"]

    assert (out / "report.html").stat().st_size
    before = {p: p.stat().st_mtime_ns for p in out.rglob("*") if p.is_file()}
    capsys.readouterr()
    with pytest.raises(typer.Exit) as stopped:  # a clip failed: exit status 1
        batch_command(clips, out, iters=4, geometry=False)  # as `surgsplat batch` calls it
    assert stopped.value.exit_code == 1
    printed = capsys.readouterr().out
    assert "3 of 3 clips already finished; skipped" in printed
    assert "2 of 3 clips done, 1 failed" in printed
    after = {p: p.stat().st_mtime_ns for p in before}
    assert after == before  # no file was touched: no work done
