"""The one loader of every entry-point group (surgsplat.plugins): built-in extensions first,
installed ones after them, each failure or wrong kind reported by name, a taken name ignored."""

from importlib.metadata import EntryPoint

import pytest

from surgsplat.eval.metric_family import MetricFamily
from surgsplat.eval.run_metrics import BUILT_IN_FAMILIES, METRIC_FAMILIES
from surgsplat.plugins import load_extensions

GROUP = "surgsplat.test_extensions"


def entry(name: str, value: str) -> EntryPoint:
    return EntryPoint(name, value, GROUP)


def test_built_in_extensions_come_first_then_the_installed_ones():
    loaded, unloadable = load_extensions(
        GROUP, [entry("image", "surgsplat.eval.render_families:ImageFamily")], MetricFamily,
        installed=[entry("depth", "surgsplat.eval.render_families:DepthFamily")])
    assert list(loaded) == ["image", "depth"] and not unloadable
    assert loaded["depth"].name == "depth"


def test_an_installed_extension_that_fails_or_is_of_another_kind_is_left_out_by_name():
    loaded, unloadable = load_extensions(GROUP, [], MetricFamily, installed=[
        entry("missing", "no_such_package.module:Family"),
        entry("not_a_family", "surgsplat.eval.metric_family:EvalOptions"),
        entry("an_instance", "surgsplat.eval.run_metrics:CONVENTIONS")])
    assert not loaded
    assert "ModuleNotFoundError" in unloadable["missing"]
    assert "not a surgsplat.eval.metric_family.MetricFamily" in unloadable["not_a_family"]
    assert "is a dict" in unloadable["an_instance"]


def test_a_taken_name_keeps_the_first_extension():
    built_in = [entry("image", "surgsplat.eval.render_families:ImageFamily")]
    with pytest.warns(UserWarning, match="names 'image', which is taken"):
        loaded, _ = load_extensions(GROUP, built_in, MetricFamily, installed=[
            entry("image", "surgsplat.eval.render_families:DepthFamily")])
    assert loaded["image"].name == "image"


def test_a_broken_built_in_extension_raises():
    with pytest.raises(ModuleNotFoundError):
        load_extensions(GROUP, [entry("x", "no_such_package.module:Family")], MetricFamily,
                        installed=[])


def test_every_built_in_metric_family_is_registered_under_its_own_name():
    names = [e.name for e in BUILT_IN_FAMILIES]
    assert list(METRIC_FAMILIES)[:len(names)] == names
    assert all(METRIC_FAMILIES[name].name == name for name in names)
