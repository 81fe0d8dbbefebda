"""Choosing the ISA variant of the native kernels: the fastest the CPU runs by default,
SURGSPLAT_ISA or use_isa() to force one, clear errors and warnings for one that cannot run."""

import math

import pytest
import torch

from surgsplat.fields.gaussian_basis import deformation_channels

from surgsplat.render import native

needs_native = pytest.mark.skipif(native.native_module() is None,
                                  reason="native module not built")


@needs_native
def test_default_is_the_fastest_available(monkeypatch):
    monkeypatch.delenv(native.ISA_ENV, raising=False)
    native.use_isa(None)
    available = native.available_isas()
    assert available and available[-1] in ("baseline", "neon")  # the portable one runs anywhere
    assert native.active_isa() == available[0]


def test_native_isa_fixture_switches_the_module(native_isa):
    assert native.active_isa() == native_isa
    assert native.native_module().isa == native_isa


@needs_native
def test_environment_variable_forces_a_variant(monkeypatch):
    portable = native.available_isas()[-1]
    monkeypatch.setenv(native.ISA_ENV, portable)
    native.use_isa(None)
    try:
        assert native.active_isa() == portable
    finally:
        monkeypatch.delenv(native.ISA_ENV)
        native.use_isa(None)


@needs_native
def test_unusable_variant_from_the_environment_warns_and_falls_back(monkeypatch):
    missing = [isa for isa in native.ISAS if native.isa_unavailable(isa) is not None]
    monkeypatch.setenv(native.ISA_ENV, missing[0] if missing else "vax")
    native.use_isa(None)
    try:
        with pytest.warns(RuntimeWarning, match="ignored"):
            assert native.active_isa() == native.available_isas()[0]
    finally:
        monkeypatch.delenv(native.ISA_ENV)
        native.use_isa(None)


def test_use_isa_rejects_unknown_and_unavailable_variants():
    with pytest.raises(ValueError, match="unknown ISA"):
        native.use_isa("vax")
    missing = [isa for isa in native.ISAS if native.isa_unavailable(isa) is not None]
    if missing:
        with pytest.raises(ValueError, match=missing[0]):
            native.use_isa(missing[0])


@needs_native
def test_variant_module_gives_any_runnable_variant_beside_the_one_in_use():
    portable, in_use = native.available_isas()[-1], native.active_isa()
    assert native.variant_module(portable).isa == portable
    assert native.active_isa() == in_use
    missing = [isa for isa in native.ISAS if native.isa_unavailable(isa) is not None]
    if missing:
        with pytest.raises(ValueError, match=missing[0]):
            native.variant_module(missing[0])


@needs_native
def test_probe_counts_work_and_set_threads(native_isa):
    module = native.native_module()
    assert module.composite_probe(2, 8, 3) > 0.0
    with pytest.raises(ValueError):
        module.composite_probe(0, 8, 3)
    before = module.max_threads()
    native.set_threads(1)
    try:
        assert module.max_threads() == 1
    finally:
        native.set_threads(before)


@needs_native
def test_a_build_with_only_the_portable_variant_uses_it(monkeypatch):
    """As after `SURGSPLAT_ISA_TARGETS=baseline`: only the portable module exists."""
    import sys

    import surgsplat.render

    portable = native.available_isas()[-1]
    for isa in native.ISAS:
        if isa != portable:
            monkeypatch.setitem(sys.modules, f"surgsplat.render._native_{isa}", None)
            monkeypatch.delattr(surgsplat.render, f"_native_{isa}", raising=False)
    native.isa_unavailable.cache_clear()
    native.use_isa(None)
    try:
        assert native.available_isas() == [portable]
        assert native.active_isa() == portable
    finally:
        monkeypatch.undo()
        native.isa_unavailable.cache_clear()
        native.use_isa(None)


@needs_native
@pytest.mark.parametrize("threads", [1, 2])
def test_the_kernels_threads_flush_subnormals_to_zero(threads):
    """Products of 1e-20 and 1e-20 (1e-40, subnormal in float32) come out as 0 from every
    thread of a native kernel; the calling thread's torch arithmetic does the same."""
    before = native.native_module().max_threads()
    native.set_threads(threads)
    try:
        n, basis = 20000, 8
        weights = torch.full((n, 3, basis), 1e-20)
        offset = math.sqrt(-2.0 * math.log(1e-20))  # the basis value is 1e-20 there
        centres = torch.full((n, basis), 0.5 - offset)
        channels = deformation_channels(weights, centres, torch.zeros(n, basis), 0.5,
                                        backend="native")
        reference = deformation_channels(weights.double(), centres.double(),
                                         torch.zeros(n, basis, dtype=torch.float64), 0.5,
                                         backend="reference")
        assert float(reference.min()) > 1e-40  # not zero in float64: the flush made the zeros
        assert int(torch.count_nonzero(channels)) == 0
        assert float(torch.tensor([1e-39]) * 1.0) == 0.0
    finally:
        native.set_threads(before)
