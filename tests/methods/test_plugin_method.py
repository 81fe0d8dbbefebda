"""A method package outside surgsplat's tree joins through the entry-point group
`surgsplat.methods`: tests/plugin holds one (a component of its own and a preset) with the
dist-info that `pip install` would write, so that putting the folder on the path installs it.
Every command works on it with no file under surgsplat/ naming it; a package that fails to load
is reported when its method is asked for, and the others still load."""

from __future__ import annotations

import json
import os
from importlib.metadata import EntryPoint
from pathlib import Path

import pytest

from surgsplat.errors import SurgsplatError
from surgsplat.methods import registry
from surgsplat.methods.registry import BUILT_IN, ENTRY_POINT_GROUP, load_methods

PLUGIN = Path(__file__).resolve().parents[1] / "plugin"
PACKAGE = Path(__file__).resolve().parents[2] / "surgsplat"
ON_PATH = {"PYTHONPATH": os.pathsep.join(filter(None, (str(PLUGIN),
                                                        os.environ.get("PYTHONPATH"))))}


def entry(name: str, value: str) -> EntryPoint:
    return EntryPoint(name, value, ENTRY_POINT_GROUP)


@pytest.fixture
def plugin_on_path(monkeypatch):
    monkeypatch.syspath_prepend(str(PLUGIN))


def test_an_installed_method_is_listed_after_the_built_in_ones(plugin_on_path):
    presets, unloadable = load_methods((entry("toy", "toy_splat_method.method:PRESET"),))
    assert list(presets) == [*(e.name for e in BUILT_IN), "toy"] and not unloadable
    config = presets["toy"].build()
    assert config.components["sheen"].kind == "toy_sheen"


def test_the_plugin_is_found_through_its_dist_info(plugin_on_path):
    from importlib.metadata import entry_points
    found = {e.name: e.value for e in entry_points(group=ENTRY_POINT_GROUP)}
    assert found.get("toy") == "toy_splat_method.method:PRESET"


def test_a_method_that_fails_to_load_is_reported_when_asked_for(plugin_on_path, monkeypatch):
    presets, unloadable = load_methods((
        entry("missing", "no_such_package.method:PRESET"),
        entry("not_a_preset", "toy_splat_method.method:toy"),
        entry("toy", "toy_splat_method.method:PRESET")))
    assert "toy" in presets and set(unloadable) == {"missing", "not_a_preset"}
    assert "ModuleNotFoundError" in unloadable["missing"]
    assert "not a surgsplat.methods.config.Preset" in unloadable["not_a_preset"]
    monkeypatch.setattr(registry, "UNLOADABLE", unloadable)
    with pytest.raises(SurgsplatError, match="method 'missing': no_such_package.method:PRESET "
                                             "failed to load"):
        registry.method_config("missing")


def test_methods_names_a_method_that_failed_to_load(cli, monkeypatch):
    monkeypatch.setattr("surgsplat.cli.methods.UNLOADABLE",
                        {"broken": "pkg.mod:PRESET failed to load: ImportError: no"})
    listed = cli("methods")
    assert listed.returncode == 0, listed.stderr
    assert "not loaded: method 'broken': pkg.mod:PRESET failed to load" in listed.stdout


def test_the_plugin_adds_a_metric_family_and_a_product(plugin_on_path):
    from importlib.metadata import entry_points

    from surgsplat.eval.run_metrics import FAMILY_GROUP
    from surgsplat.pipeline.products import PRODUCT_GROUP
    assert {e.name for e in entry_points(group=FAMILY_GROUP)} == {"sheen"}
    assert {e.name for e in entry_points(group=PRODUCT_GROUP)} == {"sheen_quartiles"}


def test_a_taken_name_keeps_the_built_in_method(plugin_on_path):
    with pytest.warns(UserWarning, match="names 'deform3dgs', which is taken"):
        presets, _ = load_methods((entry("deform3dgs", "toy_splat_method.method:PRESET"),))
    assert presets["deform3dgs"] is registry.PRESETS["deform3dgs"]


def test_nothing_in_surgsplat_names_the_plugin():
    names = ("toy_splat_method", "toy_sheen")
    offences = [str(path.relative_to(PACKAGE)) for path in PACKAGE.rglob("*.py")
                if any(name in path.read_text() for name in names)]
    assert not offences


@pytest.mark.slow
def test_every_command_works_on_the_installed_method(cli, small_phantom, tmp_path):
    """methods, train, eval, render (its own channel too) and export, each in its own process
    with the plug-in on the path."""
    run = tmp_path / "run"
    listed = cli("methods", env=ON_PATH)
    assert listed.returncode == 0 and "toy_sheen" in listed.stdout, listed.stderr
    steps = (("train", "--method", "toy", "--data", str(small_phantom), "--out", str(run)),
             ("eval", str(run)), ("render", str(run), "--channels", "rgb,sheen"),
             ("export", str(run), "--ply", "--frames", "0"))
    for args in steps:
        done = cli("--threads", "1", *args, env=ON_PATH)
        assert done.returncode == 0, (args, done.stderr[-2000:])
    config = json.loads((run / "config.json").read_text())
    assert config["components"]["sheen"]["kind"] == "toy_sheen"
    log = [json.loads(line) for line in (run / "train_log.jsonl").read_text().splitlines()]
    assert log and all("sheen" in entry["terms"] for entry in log)
    metrics = json.loads((run / "metrics.json").read_text())
    assert metrics["psnr_tissue"] > 15
    assert 0.0 < metrics["sheen_tissue"] < 1.0 and metrics["frames_covered"]["sheen"] >= 1
    assert "metric_families_not_loaded" not in metrics
    assert len(json.loads((run / "sheen.json").read_text())["quartiles"]) == 3  # its product
    assert (run / "videos" / "sheen.mp4").stat().st_size > 0
    assert len(list((run / "export" / "ply").glob("*.ply"))) == 1
    without = cli("--threads", "1", "eval", str(run), process=True)
    assert without.returncode == 2 and "unknown component kind 'toy_sheen'" in without.stderr
