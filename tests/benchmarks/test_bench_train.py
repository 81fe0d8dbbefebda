"""The training benchmark's case: its curve, the seconds read off it, the scaled times, and the
targets it checks."""

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
import bench_train  # noqa: E402

from surgsplat.render import native  # noqa: E402

SCALED = ("seconds_to_minus_1db", "seconds_to_minus_0p3db", "train_seconds", "wall_seconds")


@pytest.mark.skipif(native.native_module() is None, reason="the native module is not built")
def test_a_case_reads_its_times_off_its_curve(small_phantom, tmp_path):
    row = bench_train.run_case(small_phantom, "deform3dgs", tmp_path / "run", curve_every=10,
                               iterations=20, startup_seconds=1.5)
    assert {"preset", "iterations", "test_psnr_tissue", "seconds_per_iter", "num_gaussians",
            "peak_rss_mb", "render_fps", "setup_seconds", "min_visible_fraction", "probe_evals_per_s_before",
            "probe_evals_per_s_after", "probe_evals_per_s", "curve", *SCALED,
            *(f"{key}_scaled" for key in SCALED)} <= row.keys()
    curve = row["curve"]
    assert [point[0] for point in curve] == [0, 10, 20] and row["iterations"] == 20
    seconds = [point[1] for point in curve]
    assert seconds[0] >= 1.5 and all(a < b for a, b in zip(seconds, seconds[1:]))
    assert row["test_psnr_tissue"] == curve[-1][2] and row["train_seconds"] == seconds[-1]
    assert row["wall_seconds"] >= row["train_seconds"]
    assert 0.5 < row["min_visible_fraction"] <= 1.0  # the phantom is in view of every frame
    for key, drop in (("seconds_to_minus_1db", 1.0), ("seconds_to_minus_0p3db", 0.3)):
        first = next(i for i, point in enumerate(curve)
                     if point[2] >= row["test_psnr_tissue"] - drop)
        assert row[key] == curve[first][1]
        assert all(point[2] < row["test_psnr_tissue"] - drop for point in curve[:first])
    probe = row["probe_evals_per_s"]
    assert min(row["probe_evals_per_s_before"], row["probe_evals_per_s_after"]) <= probe
    for key in SCALED:
        assert row[f"{key}_scaled"] == pytest.approx(row[key] * probe / 3.5e9)


def case(preset: str, final: float, curve: list[list[float]], probe: float = 3.5e9) -> dict:
    """A phantom row as run_case makes them, from its curve."""
    row = {"scene": bench_train.PHANTOM, "preset": preset, "test_psnr_tissue": final,
           "curve": curve, "probe_evals_per_s": probe}
    row["seconds_to_minus_0p3db_scaled"] = \
        bench_train.seconds_to(curve, final - 0.3) * probe / 3.5e9
    row["wall_seconds_scaled"] = (curve[-1][1] + 2.0) * probe / 3.5e9  # checkpoint writes
    return row


def test_targets_bound_the_whole_run_its_final_quality_and_the_others_time_to_quality():
    rows = [case("deform3dgs", 45.6, [[0, 5.0, 20.0], [100, 50.0, 45.4], [200, 110.0, 45.6]],
                 probe=1.75e9),
            case("surgsplat", 45.6, [[0, 5.0, 20.0], [100, 100.0, 45.4], [200, 130.0, 45.6]]),
            case("endogaussian", 40.0, [[0, 5.0, 20.0], [100, 89.0, 39.8], [200, 95.0, 40.0]]),
            case("endogsg", 41.0, [[0, 5.0, 20.0], [100, 91.0, 40.8]])]
    avx2 = {**case("deform3dgs", 45.6, [[0, 5.0, 20.0], [200, 900.0, 45.6]]), "isa": "avx2"}
    targets = {t["rule"]: t for t in bench_train.check_targets(rows + [avx2], "avx512")}
    time = targets["deform3dgs: scaled wall seconds of the default schedule"]
    assert time["value"] == 56.0 and time["met"]
    quality = targets["deform3dgs: final psnr_tissue >= 45.35 dB (45.65 - 0.3)"]
    assert quality["value"] == 45.6 and quality["met"]
    assert not targets["surgsplat: scaled wall seconds of the default schedule"]["met"]
    assert not targets["surgsplat: final psnr_tissue >= 45.71 dB (46.01 - 0.3)"]["met"]
    others = {rule.split(":")[0]: t for rule, t in targets.items()
              if "x deform3dgs's" in rule}
    assert others["endogaussian"]["bound"] == 1.5 * 25.0 and not others["endogaussian"]["met"]
    assert set(others) == {"endogaussian", "endogsg"}
