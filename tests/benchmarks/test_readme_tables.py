"""The benchmark tables of the documentation (docs/benchmarks/*.md and the method pages) are
generated from the committed results by benchmarks/readme_tables.py, never typed."""

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "benchmarks"))
from readme_tables import (backward_efficiency, isa_ratio_lines, preset_region_parts,  # noqa: E402
                           preset_table, render_table, step_phases_table, train_table)


def test_the_pages_tables_match_the_committed_results():
    done = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "readme_tables.py"),
                           "--check"], capture_output=True, text=True, cwd=ROOT)
    assert done.returncode == 0, done.stderr[-2000:]


def test_train_table_shows_each_case_the_targets_and_the_plot():
    row = {"scene": "phantom-full-pulling", "preset": "surgsplat",
           "settings": ["train.coarse_factor=2"], "iterations": 3000, "test_psnr_tissue": 46.012,
           "seconds_to_minus_1db": 40.4, "seconds_to_minus_1db_scaled": 44.6,
           "seconds_to_minus_0p3db": 80.2, "seconds_to_minus_0p3db_scaled": 88.9,
           "wall_seconds_scaled": 150.3, "seconds_per_iter": 0.0312, "num_gaussians": 51234,
           "render_fps": 61.26, "profile": {"iterations": 200}}  # the first 200: not shown
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
            "| 80 | 89 | 150 | 0.031 | 51234 | 61.3 | 2026-12-01 |") in lines
    assert "| surgsplat: scaled wall seconds | 130 | <= 120 | **no** |" in lines
    assert "| surgsplat: final psnr_tissue >= 45.71 dB | 46.01 | >= 45.71 | yes |" in lines
    assert "| endogsg: scaled seconds_to_minus_0p3db | not reached | <= 90 | **no** |" in lines
    assert not any(line.startswith("Where a step") for line in lines)
    assert lines[-1] == ("![test psnr_tissue against scaled training seconds]"
                         "(benchmarks/results/bench_train-amd-epyc-avx512.png)")


def test_train_table_links_the_plot_relative_to_the_page():
    report = {"cpu": "AMD EPYC", "system": {"logical_cpus": 2, "isa": "avx2"}, "threads": 2,
              "date": "2026-12-01", "command": "python benchmarks/bench_train.py",
              "reference_probe_evals_per_s": 3.5e9, "plot": "plot.png", "rows": [],
              "targets": []}
    assert train_table(report, "../../benchmarks/results").splitlines()[-1].endswith(
        "(../../benchmarks/results/plot.png)")


def test_step_phases_table_gives_each_phase_its_scaled_seconds_and_the_rasteriser_apart():
    row = {"scene": "phantom-full-pulling", "preset": "deform3dgs", "iterations": 1000,
           "seconds_per_iter": 0.05, "probe_evals_per_s": 7e9,  # steps: 50 s, 100 scaled
           "min_visible_fraction": 0.9975,
           "profile": {"iterations": 1000, "step_samples": 4000,
                       "step_shares": {"rasterize backward": 0.25, "rasterize forward": 0.15,
                                       "Adam (optimiser)": 0.6}}}
    lines = step_phases_table(row, 3.5e9)
    assert "the share of the 100 scaled seconds of its 1000 steps" in lines[0]
    assert "| rasterize backward | 25.0% | 25.0 |" in lines
    assert "| Adam (optimiser) | 60.0% | 60.0 |" in lines
    assert "| **rasteriser, forward and backward** | 40.0% | 40.0 |" in lines
    assert "| **everything else** | 60.0% | 60.0 |" in lines
    assert lines[-1].endswith("touched at least 99.75% of the Gaussians: an optimiser step over "
                              "the visible Gaussians alone would leave out at most 0.25% of the "
                              "rows.")


def test_preset_table_keeps_one_method_its_columns_and_its_targets():
    rows = [{"case": "endogsg", "method": "endogsg", "iterations": 3000, "psnr_tissue": 45.94,
             "collisions": None},
            {"case": "endogsg-moving", "method": "endogsg", "iterations": 3000,
             "psnr_tissue": 45.87},
            {"case": "drawer", "method": "drawer", "iterations": 3000, "psnr_tissue": 44.53,
             "collisions": 18}]
    targets = [{"case": "endogsg", "metric": "psnr_tissue", "value": 45.94, "bound": 46.3,
                "rule": "psnr_tissue >= endogaussian -0.3", "met": False},
               {"case": "drawer", "metric": "psnr_tissue", "value": 44.53, "bound": 45.64,
                "rule": "psnr_tissue >= endogsg -0.3", "met": False}]
    report = {"cpu": "AMD EPYC", "system": {"logical_cpus": 2, "isa": "avx512"},
              "date": "2026-11-27", "command": "python benchmarks/bench_methods.py",
              "columns": ["psnr_tissue", "collisions"], "rows": rows, "targets": targets}
    lines = preset_table(report, "endogsg").splitlines()
    assert "| case | iterations | psnr_tissue |" in lines
    assert "| endogsg | 3000 | 45.94 |" in lines
    assert "| endogsg-moving | 3000 | 45.87 |" in lines
    assert "| endogsg | psnr_tissue >= endogaussian -0.3 | 45.94 | 46.30 | **no** |" in lines
    assert not [line for line in lines if "drawer" in line]


def test_a_report_without_the_presets_rows_gives_no_table():
    report = {"suite": "speed", "rows": [{"case": "drawer", "method": "drawer"}],
              "columns": ["psnr_tissue"]}
    assert preset_table(report, "endogsg") == ""


def test_a_preset_region_names_its_suite_and_its_preset():
    assert preset_region_parts("preset_fidelity_endogsg") == ("fidelity", "endogsg")
    assert preset_region_parts("preset_speed_deform3dgs") == ("speed", "deform3dgs")
    assert preset_region_parts("bench_methods_speed") is None


def test_a_merged_train_report_keeps_the_other_cases_with_their_dates():
    import bench_train

    previous = {"date": "2026-11-27T21:32:15+00:00", "system": {"isa": "avx512"},
                "rows": [{"scene": "phantom", "preset": "deform3dgs"},
                         {"scene": "phantom", "preset": "surgsplat"},
                         {"scene": "phantom", "preset": "surgsplat", "isa": "avx2"},
                         {"scene": "real", "preset": "surgsplat", "date": "2026-11-20"}]}
    kept = bench_train.kept_rows(previous, [
        {"scene": "phantom", "preset": "deform3dgs", "isa": "avx512"},
        {"scene": "phantom", "preset": "surgsplat", "isa": "avx2"}])
    assert kept == [
        {"scene": "phantom", "preset": "surgsplat", "isa": "avx512", "date": "2026-11-27"},
        {"scene": "real", "preset": "surgsplat", "isa": "avx512", "date": "2026-11-20"}]


def test_a_case_on_a_lesser_isa_is_compared_with_the_best_on_the_same_run():
    def row(isa: str, wall: float, psnr: float) -> dict:
        return {"scene": "phantom", "preset": "deform3dgs", "settings": [], "isa": isa,
                "wall_seconds_scaled": wall, "test_psnr_tissue": psnr}

    report = {"system": {"isa": "avx512"},
              "rows": [row("avx512", 200.0, 45.65), row("avx2", 260.0, 45.61),
                       {**row("avx2", 100.0, 40.0), "preset": "surgsplat"}]}  # no avx512 row
    lines = isa_ratio_lines(report)
    assert "| phantom | deform3dgs | avx2 | 260 | 200 | 1.30 | -0.04 |" in lines
    assert not any("surgsplat" in line for line in lines)
    assert isa_ratio_lines({"system": {"isa": "avx512"}, "rows": [row("avx512", 1.0, 1.0)]}) == []


def test_render_table_gives_the_backward_pass_its_own_efficiency():
    raster = {"isa": "avx2", "gaussians": 100_000, "channels": 3, "fwd_ms": 10.0,
              "fwdbwd_ms": 30.0, "efficiency_fwd": 1.5, "efficiency_fwdbwd": 0.5}
    step = {"isa": "avx2", "gaussians": 100_000, "channels": 3, "step_ms": 40.0}
    # the evaluations of 30 ms of forward and backward, in the 20 ms of the backward alone
    assert backward_efficiency(raster) == pytest.approx(0.75, rel=1e-12)
    assert backward_efficiency(step) is None
    report = {"cpu": "AMD EPYC", "width": 640, "height": 512, "repeats": 3,
              "date": "2026-12-01", "rows": [raster, step],
              "system": {"logical_cpus": 2, "torch_threads": 2, "available_isas": ["avx2"]}}
    lines = render_table(report).splitlines()
    assert lines[2].endswith("| efficiency fwd | efficiency bwd | efficiency fwd+bwd |")
    assert lines[4].endswith("| 1.50 | 0.75 | 0.50 |")
    assert lines[5].endswith("|  |  |  |")


def test_op_census_table_gives_each_preset_its_kinds_and_top_operators():
    from readme_tables import op_census_table

    row = {"preset": "surgsplat", "num_gaussians": 41513, "seconds_per_step": 0.2914,
           "aten_calls_per_step": 2517.0,
           "shares": {"native kernels": 0.4, "fused Adam": 0.05, "ATen operators": 0.5,
                      "framework": 0.05},
           "top": [{"operator": "aten::mul", "ms_per_step": 21.45, "calls_per_step": 157.0}]}
    report = {"cpu": "AMD EPYC", "system": {"logical_cpus": 2, "isa": "avx512"}, "threads": 2,
              "date": "2026-12-01T10:00:00+00:00", "command": "python benchmarks/op_census.py",
              "steps": 20, "warmup": 400, "rows": [row]}
    lines = op_census_table(report).splitlines()
    assert ("| preset | Gaussians | ms per step | ATen calls per step | native kernels "
            "| fused Adam | ATen operators | framework |") in lines
    assert "| surgsplat | 41513 | 291 | 2517 | 40% | 5% | 50% | 5% |" in lines
    assert "| surgsplat | `aten::mul` 21.4 (157) |" in lines
