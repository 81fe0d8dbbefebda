"""The README's benchmark tables are generated from the committed results, never typed."""

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def test_readme_tables_match_the_committed_results():
    done = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "readme_tables.py"),
                           "--check"], capture_output=True, text=True, cwd=ROOT)
    assert done.returncode == 0, done.stderr[-2000:]
