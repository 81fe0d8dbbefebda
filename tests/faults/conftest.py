"""Fault injection: `surgsplat` is killed, stopped, raced, starved of disk or denied writes.
What needs a process of its own runs in one, a subprocess of this interpreter (`start`): a
command killed or stopped by a signal, a writer racing another. The rest runs in this process
through the `cli` fixture of tests/conftest.py, with the same messages and exit status: the
commands that meet a fault's result, and those a fault is patched into (`run_patched`)."""

from __future__ import annotations

import functools
import importlib
import json
import shutil
import subprocess
import sys
import time
from pathlib import Path
from types import SimpleNamespace

import pytest

TRAIN_FAST = ("--set", "init.max_points=1500", "--set", "densify.start=0",
              "--set", "densify.every=5")
"""Settings that keep the phantom runs of these tests to a few seconds."""

PATCH_PRELUDE = "import errno, os, sys\n"
"""What a fault's patch may use without importing it."""

PATCHABLE = ("builtins", "io", "os", "numpy", "torch")
"""The modules whose functions a patch replaces (open, os.open, os.mkdir, numpy.save,
torch.save...)."""


def start(*args: str) -> subprocess.Popen:
    """`surgsplat *args` started in the background."""
    return subprocess.Popen([sys.executable, "-m", "surgsplat.cli.main", *args],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def run_patched(cli, patch: str, *args: str) -> subprocess.CompletedProcess:
    """`surgsplat *args` with the Python code `patch` run first (to inject a fault such as a
    full disk), through `cli` (the fixture of tests/conftest.py: in this process); what the
    patch replaced in the PATCHABLE modules is put back afterwards. surgsplat looks these
    functions up when it calls them (no module of it binds one at import, as `from os import
    mkdir` would), so the patch acts as it would in a fresh process where it ran first."""
    modules = [importlib.import_module(name) for name in PATCHABLE]
    before = [dict(vars(module)) for module in modules]

    def replaced() -> list[set]:
        return [{key for key, value in vars(module).items()
                 if key not in old or old[key] is not value}
                for module, old in zip(modules, before)]

    def put_back(changed: list[set]) -> None:
        for module, old, keys in zip(modules, before, changed):
            for key in keys:
                if key in old:
                    setattr(module, key, old[key])
                else:
                    delattr(module, key)

    try:
        exec(compile(PATCH_PRELUDE + patch, "<fault patch>", "exec"), {"__name__": "patch"})
    except BaseException:
        put_back(replaced())
        raise
    changed = replaced()
    try:
        return cli(*args)
    finally:
        put_back(changed)


@pytest.fixture(scope="module")
def pristine(small_phantom, tmp_path_factory, cli):
    """A run of 4 iterations with checkpoints at 2 and 4 (previous.pt holds iteration 2)."""
    run = tmp_path_factory.mktemp("trained") / "run"
    done = cli("train", "--data", str(small_phantom), "--out", str(run), "--iters", "4",
               "--set", "train.checkpoint_every=2", *TRAIN_FAST)
    assert done.returncode == 0, done.stderr
    return run


@pytest.fixture
def trained(pristine, tmp_path):
    """A copy of that run, which the test may change."""
    return shutil.copytree(pristine, tmp_path / "run")


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
def faults(one_error_line, cli):
    """The helpers of this folder, as attributes; processes it started that are still running
    at the end of the test are killed."""
    started: list[subprocess.Popen] = []

    def start_tracked(*args: str) -> subprocess.Popen:
        started.append(start(*args))
        return started[-1]

    yield SimpleNamespace(start=start_tracked, run_patched=functools.partial(run_patched, cli),
                          wait_for=wait_for, logged_iterations=logged_iterations,
                          strictly_increasing=strictly_increasing,
                          one_error_line=one_error_line, TRAIN_FAST=TRAIN_FAST)
    for process in started:
        if process.poll() is None:
            process.kill()
        process.communicate()
