"""`surgsplat info --system` and the global `--threads`: what runs the kernels, as a user sees
it."""

import json
import os
import subprocess
import sys

from surgsplat.render import native


def test_info_system_reports_cpu_isa_and_threads(cli):
    # a process of its own: --threads set before torch starts its threads, as a user sets it
    result = cli("--threads", "1", "info", "--system", "--json", process=True)
    assert result.returncode == 0, result.stderr
    info = json.loads(result.stdout)
    assert info["cpu"] == native.cpu_model()
    assert info["isa"] == native.active_isa()
    assert info["available_isas"] == native.available_isas()
    assert info["torch_threads"] == 1
    if info["isa"] is not None:
        assert info["native_threads"] == 1
    assert info["omp_wait_policy"] == os.environ.get("OMP_WAIT_POLICY", "PASSIVE")


def test_info_system_table_and_missing_scene(cli):
    table = cli("info", "--system")
    assert table.returncode == 0 and "isa" in table.stdout and "threads" in table.stdout
    missing = cli("info")
    assert missing.returncode == 2 and "--system" in missing.stderr


def test_threads_must_be_positive(cli):
    assert cli("--threads", "0", "info", "--system").returncode != 0


def _wait_policy_in_child(code: str) -> subprocess.CompletedProcess:
    """Runs `code` in a fresh Python whose environment names no OpenMP wait policy."""
    env = {k: v for k, v in os.environ.items() if k not in ("OMP_WAIT_POLICY", "GOMP_SPINCOUNT")}
    return subprocess.run([sys.executable, "-W", "always", "-c", code], env=env,
                          capture_output=True, text=True, timeout=120)


def test_wait_policy_is_passive_when_surgsplat_comes_first():
    child = _wait_policy_in_child(
        "import surgsplat, os, torch; "
        "print(surgsplat.OPENMP_WAIT_POLICY, os.environ['OMP_WAIT_POLICY'])")
    assert child.returncode == 0, child.stderr
    assert child.stdout.split() == ["PASSIVE", "PASSIVE"]
    assert "RuntimeWarning" not in child.stderr


def test_torch_imported_first_is_reported_not_hidden():
    child = _wait_policy_in_child(
        "import torch, surgsplat; from surgsplat.render.native import system_info; "
        "print(system_info()['omp_wait_policy'])")
    assert child.returncode == 0, child.stderr
    assert "idle threads spin" in child.stdout
    assert "RuntimeWarning" in child.stderr and "import surgsplat first" in child.stderr


def test_a_users_own_policy_is_kept_without_warning():
    child = _wait_policy_in_child(
        "import os; os.environ['OMP_WAIT_POLICY'] = 'ACTIVE'; import torch, surgsplat; "
        "print(surgsplat.OPENMP_WAIT_POLICY)")
    assert child.returncode == 0, child.stderr
    assert child.stdout.split() == ["ACTIVE"]
    assert "RuntimeWarning" not in child.stderr
