"""The README's benchmark tables are generated from the committed results, never typed."""

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "benchmarks"))
from readme_tables import train_table  # noqa: E402


def test_readme_tables_match_the_committed_results():
    done = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "readme_tables.py"),
                           "--check"], capture_output=True, text=True, cwd=ROOT)
    assert done.returncode == 0, done.stderr[-2000:]


def test_train_table_shows_each_case_the_targets_and_the_plot():
    row = {"scene": "phantom-full-pulling", "preset": "surgsplat",
           "settings": ["train.coarse_factor=2"], "iterations": 3000, "test_psnr_tissue": 46.012,
           "seconds_to_minus_1db": 40.4, "seconds_to_minus_1db_scaled": 44.6,
           "seconds_to_minus_0p3db": 80.2, "seconds_to_minus_0p3db_scaled": 88.9,
           "wall_seconds_scaled": 150.3, "seconds_per_iter": 0.0312, "num_gaussians": 51234,
           "render_fps": 61.26}
    report = {"cpu": "AMD EPYC", "system": {"logical_cpus": 2, "isa": "avx512"}, "threads": 2,
              "date": "2026-12-01T10:00:00+00:00", "command": "python benchmarks/bench_train.py",
              "reference_probe_evals_per_s": 3.5e9, "plot": "bench_train-amd-epyc-avx512.png",
              "rows": [row],
              "targets": [{"rule": "surgsplat: scaled wall seconds", "value": 130.4,
                           "relation": "<=", "bound": 120.0, "met": False},
                          {"rule": "surgsplat: final psnr_tissue >= 45.71 dB", "value": 46.012,
                           "relation": ">=", "bound": 45.71, "met": True},
                          {"rule": "endogsg: scaled seconds_to_minus_0p3db", "value": None,
                           "relation": "<=", "bound": 90.0, "met": False}]}
    lines = train_table(report).splitlines()
    assert ("| phantom-full-pulling | surgsplat `train.coarse_factor=2` | 3000 | 46.01 | 40 | 45 "
            "| 80 | 89 | 150 | 0.031 | 51234 | 61.3 |") in lines
    assert "| surgsplat: scaled wall seconds | 130 | <= 120 | **no** |" in lines
    assert "| surgsplat: final psnr_tissue >= 45.71 dB | 46.01 | >= 45.71 | yes |" in lines
    assert "| endogsg: scaled seconds_to_minus_0p3db | not reached | <= 90 | **no** |" in lines
    assert lines[-1] == ("![test psnr_tissue against scaled training seconds]"
                         "(benchmarks/results/bench_train-amd-epyc-avx512.png)")
