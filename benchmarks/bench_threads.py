"""Thread waiting benchmark: wall time of `surgsplat train --method deform3dgs` on the small
phantom (100 iterations) under three OpenMP wait policies, alone and beside a process that
keeps one core busy:

- `surgsplat`: no setting, so surgsplat's own default applies (OMP_WAIT_POLICY=PASSIVE);
- `libgomp`: libgomp's default spinning (GOMP_SPINCOUNT=300000, which surgsplat then leaves);
- `active`: OMP_WAIT_POLICY=ACTIVE, threads spin while idle.

    python benchmarks/bench_threads.py [--repeats 3] [--iters 100] [--out FILE]

Runs alternate between the policies, each training in its own process; medians are reported,
and the ratio of each to the `surgsplat` default of the same competition setting. Results go to
benchmarks/results/bench_threads-<cpu>-<best ISA>.json.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from datetime import datetime, timezone
from pathlib import Path

from bench_render import results_path

from surgsplat.render import native

POLICIES = {
    "surgsplat": {},
    "libgomp": {"GOMP_SPINCOUNT": "300000"},
    "active": {"OMP_WAIT_POLICY": "ACTIVE"},
}
BURN = "while True: pass"


def surgsplat_command(*args: str) -> list[str]:
    return [sys.executable, "-m", "surgsplat.cli.main", *args]


def train_seconds(phantom: Path, out: Path, iters: int, policy: dict[str, str]) -> float:
    env = {k: v for k, v in os.environ.items() if k not in ("OMP_WAIT_POLICY", "GOMP_SPINCOUNT")}
    env.update(policy)
    command = surgsplat_command("train", "--method", "deform3dgs", "--data", str(phantom),
                                "--out", str(out), "--iters", str(iters))
    started = time.perf_counter()
    subprocess.run(command, env=env, check=True, capture_output=True)
    return time.perf_counter() - started


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--iters", type=int, default=100)
    parser.add_argument("--out", type=Path)
    args = parser.parse_args()
    rows = []
    load_at_start = os.getloadavg()[0]  # other work on the machine, besides the benchmark's own
    with tempfile.TemporaryDirectory() as tmp:
        phantom = Path(tmp) / "phantom"
        subprocess.run(surgsplat_command("phantom", "--out", str(phantom), "--preset", "small"),
                       check=True, capture_output=True)
        for competing in (False, True):
            burner = subprocess.Popen([sys.executable, "-c", BURN]) if competing else None
            try:
                times: dict[str, list[float]] = {name: [] for name in POLICIES}
                for r in range(args.repeats):
                    for name, policy in POLICIES.items():
                        run = Path(tmp) / f"run-{name}-{int(competing)}-{r}"
                        times[name].append(train_seconds(phantom, run, args.iters, policy))
            finally:
                if burner is not None:
                    burner.kill()
                    burner.wait()
            base = statistics.median(times["surgsplat"])
            for name, values in times.items():
                rows.append({"policy": name, "competing_process": competing,
                             "train_s": statistics.median(values), "runs_s": values,
                             "ratio_to_surgsplat_default": statistics.median(values) / base})
                print(json.dumps(rows[-1]), file=sys.stderr)
    info = native.system_info()
    report = {"benchmark": "bench_threads", "cpu": info["cpu"], "system": info,
              "date": datetime.now(timezone.utc).isoformat(timespec="seconds"),
              "command": "surgsplat train --method deform3dgs (small phantom)",
              "iters": args.iters, "repeats": args.repeats,
              "load_average_1min": {"start": load_at_start, "end": os.getloadavg()[0]},
              "rows": rows}
    out = args.out or results_path("bench_threads", info)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(report, indent=1) + "\n")
    print(f"{'policy':>10} {'competing':>9} {'train s':>8} {'ratio':>6}")
    for row in rows:
        print(f"{row['policy']:>10} {str(row['competing_process']):>9} {row['train_s']:>8.2f} "
              f"{row['ratio_to_surgsplat_default']:>6.2f}")
    print(f"written to {out}")


if __name__ == "__main__":
    main()
