"""Shared test fixtures."""

import subprocess
import sys
from pathlib import Path

import pytest

SHARED = Path(__file__).resolve().parents[1].parent / "shared"


@pytest.fixture
def shared_data() -> Path:
    """The real data samples beside the repository; skips the test when they are absent."""
    data = SHARED / "data"
    if not data.is_dir():
        pytest.skip(f"real data samples not found at {data}")
    return data


@pytest.fixture(scope="session")
def small_phantom(tmp_path_factory) -> Path:
    """The small 'pulling' phantom (160x128, 16 frames), generated once per test session."""
    from surgsplat.data.phantom import PhantomConfig, generate_phantom

    return generate_phantom(PhantomConfig(preset="small", motion="pulling"),
                            tmp_path_factory.mktemp("phantom") / "small")


@pytest.fixture(params=["avx512", "avx2", "baseline", "neon"])
def native_isa(request) -> str:
    """Runs the test once per ISA variant of the native kernels, with that variant in use;
    skips the variants this machine lacks (not built, or the CPU cannot run them)."""
    from surgsplat.render import native

    reason = native.isa_unavailable(request.param)
    if reason is not None:
        pytest.skip(reason)
    native.use_isa(request.param)
    yield request.param
    native.use_isa(None)


def run_cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "surgsplat.cli.main", *args],
                          capture_output=True, text=True, timeout=300)


@pytest.fixture
def cli():
    """cli(*args) runs `surgsplat *args` as a user does (a subprocess) and returns the
    CompletedProcess: its exit status and its output."""
    return run_cli
