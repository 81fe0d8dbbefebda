"""Fault injection through real processes: `surgsplat` runs as a user runs it (a subprocess of
this interpreter), and is killed, stopped, raced, starved of disk or denied writes."""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path
from types import SimpleNamespace

import pytest

TRAIN_FAST = ("--set", "init.max_points=1500", "--set", "densify.start=0",
              "--set", "densify.every=5")
"""Settings that keep the phantom runs of these tests to a few seconds."""

PATCHED_MAIN = """
import errno, os, sys
{patch}
from surgsplat.cli.main import main
sys.argv = ["surgsplat", *sys.argv[1:]]
main()
"""


def start(*args: str) -> subprocess.Popen:
    """`surgsplat *args` started in the background."""
    return subprocess.Popen([sys.executable, "-m", "surgsplat.cli.main", *args],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def run_patched(patch: str, *args: str) -> subprocess.CompletedProcess:
    """`surgsplat *args` in a process where the Python code `patch` ran first (to inject a
    fault such as a full disk)."""
    return subprocess.run([sys.executable, "-c", PATCHED_MAIN.format(patch=patch), *args],
                          capture_output=True, text=True, timeout=300)


def wait_for(condition, timeout: float = 120.0, what: str = "condition") -> None:
    deadline = time.monotonic() + timeout
    while not condition():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out waiting for {what}")
        time.sleep(0.05)


def logged_iterations(run: Path) -> list[int]:
    """Iterations of RUN/train_log.jsonl (a line cut by a kill is skipped)."""
    path = run / "train_log.jsonl"
    if not path.is_file():
        return []
    found = []
    for line in path.read_text().splitlines():
        try:
            found.append(json.loads(line)["iteration"])
        except (json.JSONDecodeError, KeyError):
            pass
    return found


def strictly_increasing(values: list[int]) -> bool:
    return all(a < b for a, b in zip(values, values[1:]))


@pytest.fixture
def faults(one_error_line):
    """The helpers of this folder, as attributes; processes it started that are still running
    at the end of the test are killed."""
    started: list[subprocess.Popen] = []

    def start_tracked(*args: str) -> subprocess.Popen:
        started.append(start(*args))
        return started[-1]

    yield SimpleNamespace(start=start_tracked, run_patched=run_patched, wait_for=wait_for,
                          logged_iterations=logged_iterations,
                          strictly_increasing=strictly_increasing,
                          one_error_line=one_error_line, TRAIN_FAST=TRAIN_FAST)
    for process in started:
        if process.poll() is None:
            process.kill()
        process.communicate()
