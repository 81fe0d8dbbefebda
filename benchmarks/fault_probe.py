"""Fault cases run as a user runs `surgsplat`: a subprocess with a time limit, optionally with
a fault patched in first, and the judgement of how a case ended (the benchmarks' shared part:
bench_faults runs the cases)."""

from __future__ import annotations

import hashlib
import os
import subprocess
import sys
from pathlib import Path

CASE_SECONDS = 180
"""A case still running after this long is a hang."""
FAST = ("--iters", "6", "--set", "init.max_points=1500", "--set", "densify.start=0",
        "--set", "densify.every=5")
"""Training settings that keep a case's run to seconds."""
PATCHED = """
import errno, os, sys
{patch}
from surgsplat.cli.main import main
sys.argv = ["surgsplat", *sys.argv[1:]]
main()
"""
FULL_DISK_ON = """
import builtins, io
real_open = builtins.open
def full_disk_open(file, mode="r", *args, **kwargs):
    name = os.fsdecode(file) if isinstance(file, (str, bytes, os.PathLike)) else ""
    if "w" in mode and {suffix!r} in name:
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), name)
    return real_open(file, mode, *args, **kwargs)
builtins.open = io.open = full_disk_open
"""
"""Writing a file whose name holds `suffix` fails as on a full disk (open and Path.open)."""


def surgsplat_command(*args: str) -> list[str]:
    return [sys.executable, "-m", "surgsplat.cli.main", *args]


def cli(*args: str, patch: str = "", env: dict | None = None,
        seconds: float = CASE_SECONDS) -> subprocess.CompletedProcess | None:
    """`surgsplat *args` as a user runs it (after the Python code `patch`, to inject a fault);
    None when it is still running after `seconds` (it is then killed)."""
    command = ([sys.executable, "-c", PATCHED.format(patch=patch)] if patch
               else [sys.executable, "-m", "surgsplat.cli.main"])
    try:
        return subprocess.run([*command, *args], capture_output=True, text=True,
                              timeout=seconds, env={**os.environ, **(env or {})})
    except subprocess.TimeoutExpired:
        return None


def contents(folder: Path) -> dict[str, str]:
    """Digest of every file under `folder` by relative path (hidden files left out)."""
    return {str(p.relative_to(folder)): hashlib.blake2b(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file() and not p.name.startswith(".")}


def outcome(result: subprocess.CompletedProcess | None, status: int, names: str,
            wrong: bool = False, overwrote: bool = False) -> dict:
    """A case's outcome: handled when it ended with `status`, its output names `names` (an
    error: exactly one line on stderr, `error: ...`), with no traceback, no hang, no silent
    wrong result and no overwritten user file."""
    if result is None:
        return {"handled": False, "hang": True, "traceback": False, "silent_wrong": wrong,
                "overwrote": overwrote, "said": "(killed: still running at its time limit)"}
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    traceback = "Traceback" in result.stderr
    said = lines[-1] if lines else ""
    one_line = status == 0 or (len(lines) == 1 and said.startswith("error:"))
    handled = (result.returncode == status and names in result.stderr + result.stdout
               and one_line and not traceback and not wrong and not overwrote)
    return {"handled": handled, "hang": False, "traceback": traceback, "silent_wrong": wrong,
            "overwrote": overwrote, "status": result.returncode, "said": said[:300]}


def summarise(rows: list[dict]) -> dict:
    """The totals of case rows (each with "class" and the keys of `outcome`): cases, handled and
    each bad outcome, and per class the cases and those handled."""
    totals = {key: sum(bool(row[key]) for row in rows)
              for key in ("handled", "silent_wrong", "overwrote", "traceback", "hang")}
    by_class = {str(c): {"cases": sum(r["class"] == c for r in rows),
                         "handled": sum(r["class"] == c and r["handled"] for r in rows)}
                for c in sorted({r["class"] for r in rows})}
    return {"cases": len(rows), **totals, "by_class": by_class, "case_rows": rows}
