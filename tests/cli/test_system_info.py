"""`surgsplat info --system` and the global `--threads`: what runs the kernels, as a user sees
it."""

import json

from surgsplat.render import native


def test_info_system_reports_cpu_isa_and_threads(cli):
    result = cli("--threads", "1", "info", "--system", "--json")
    assert result.returncode == 0, result.stderr
    info = json.loads(result.stdout)
    assert info["cpu"] == native.cpu_model()
    assert info["isa"] == native.active_isa()
    assert info["available_isas"] == native.available_isas()
    assert info["torch_threads"] == 1
    if info["isa"] is not None:
        assert info["native_threads"] == 1
    assert info["omp_wait_policy"]  # PASSIVE unless the environment chose


def test_info_system_table_and_missing_scene(cli):
    table = cli("info", "--system")
    assert table.returncode == 0 and "isa" in table.stdout and "threads" in table.stdout
    missing = cli("info")
    assert missing.returncode == 2 and "--system" in missing.stderr


def test_threads_must_be_positive(cli):
    assert cli("--threads", "0", "info", "--system").returncode != 0
