"""Running `surgsplat` as a user does: a subprocess, its exit status and its output."""

import subprocess
import sys

import pytest


def run_cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "surgsplat.cli.main", *args],
                          capture_output=True, text=True, timeout=300)


@pytest.fixture
def cli():
    """cli(*args) runs `surgsplat *args` and returns the CompletedProcess."""
    return run_cli
