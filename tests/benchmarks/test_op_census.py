"""The operator census: each profiler event's kind and the per-step figures of a census."""

import sys
from pathlib import Path
from types import SimpleNamespace

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
import op_census  # noqa: E402


def test_events_are_sorted_into_native_kernels_adam_aten_and_framework():
    assert op_census.operator_kind("_NativeRasterizeBackward") == "native kernels"
    assert op_census.operator_kind("aten::_fused_adam_") == "fused Adam"
    assert op_census.operator_kind("aten::mul") == "ATen operators"
    assert op_census.operator_kind("Optimizer.step#Adam.step") == "framework"
    assert op_census.operator_kind("_WeightedAbsSum") == "framework"  # torch ops inside


def test_a_census_gives_per_step_times_calls_and_shares():
    def event(key: str, count: int, self_us: float):
        return SimpleNamespace(key=key, count=count, self_cpu_time_total=self_us)

    events = [event("_NativeRasterize", 4, 40_000.0), event("aten::mul", 400, 20_000.0),
              event("aten::add_", 100, 10_000.0), event("aten::_fused_adam_", 40, 10_000.0),
              event("run_backward", 4, 20_000.0)]
    row = op_census.census(events, steps=4, step_seconds=0.03)
    assert row["self_ms_per_step"] == pytest.approx(25.0, rel=1e-12)
    assert row["aten_calls_per_step"] == 125.0  # mul and add_, not Adam
    assert row["shares"] == pytest.approx({"native kernels": 0.4, "fused Adam": 0.1,
                                           "ATen operators": 0.3, "framework": 0.2}, rel=1e-12)
    assert [op["operator"] for op in row["top"][:2]] == ["_NativeRasterize", "aten::mul"]
    assert row["top"][1]["calls_per_step"] == 100.0 and row["top"][1]["ms_per_step"] == 5.0
