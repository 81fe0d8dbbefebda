"""Frames decoded on demand: a bounded cache, background prefetch, errors naming the file, and
training identical whatever the cache holds."""

from __future__ import annotations

import shutil
import time

import pytest
import torch

from surgsplat.data.frame_store import MIN_CACHED_FRAMES
from surgsplat.data.scene import load_scene
from surgsplat.errors import DataError
from surgsplat.fields.deformation import time_capacity
from surgsplat.fields.gaussian_basis import GaussianBasisConfig
from surgsplat.fields.hexplane import HexPlaneConfig
from surgsplat.methods.registry import method_config
from surgsplat.model.component import SceneInfo
from surgsplat.model.init_points import fusion_frames
from surgsplat.train.trainer import Trainer


def test_a_small_cache_holds_few_frames_and_gives_the_same_pixels(small_phantom):
    whole = load_scene(small_phantom)
    bounded = load_scene(small_phantom, cache_bytes=1)
    store = bounded.frames[0]._store
    assert len(store) == MIN_CACHED_FRAMES < len(bounded.frames)
    assert len(whole.frames[0]._store) == len(whole.frames)
    for kept, decoded in zip(whole.frames, bounded.frames):
        for name in ("image", "depth", "tool", "fov", "tissue"):
            assert torch.equal(getattr(kept, name), getattr(decoded, name)), name
        assert decoded.image.dtype == torch.float32 and decoded.image.shape[-1] == 3
    assert len(store) == MIN_CACHED_FRAMES
    assert bounded.fingerprint == whole.fingerprint


def test_prefetch_decodes_in_the_background(small_phantom):
    scene = load_scene(small_phantom, cache_bytes=1)
    frame = scene.frames[0]  # decoded first, evicted since
    assert not frame._store.is_cached(0)
    frame.prefetch()
    deadline = time.monotonic() + 20
    while not frame._store.is_cached(0) and time.monotonic() < deadline:
        time.sleep(0.01)
    assert frame._store.is_cached(0)


def test_a_file_damaged_after_loading_is_named_when_its_frame_is_used(small_phantom, tmp_path):
    root = shutil.copytree(small_phantom, tmp_path / "scene")
    scene = load_scene(root, cache_bytes=1)
    broken = root / "images" / "000002.png"
    broken.write_bytes(broken.read_bytes()[:300])
    with pytest.raises(DataError, match=r"000002\.png: cannot be read as an image: truncated"):
        scene.frames[2].image


@pytest.mark.slow
def test_training_is_identical_whatever_the_cache_holds(small_phantom, tmp_path):
    config = method_config("deform3dgs")
    config.train.iterations = 6
    losses = []
    for cache_bytes in (2**30, 1):
        trainer = Trainer(config, load_scene(small_phantom, cache_bytes=cache_bytes),
                          run_dir=tmp_path / str(cache_bytes))
        losses.append([trainer.step().loss for _ in range(6)])
    assert losses[0] == losses[1]


@pytest.mark.parametrize("frames, expected", [(3, 2), (16, 8), (64, 25), (250, 25), (500, 50),
                                              (7500, 300)])
def test_hexplane_time_cells_grow_with_long_clips(frames, expected):
    info = SceneInfo(num_frames=frames, width=64, height=48, train_indices=tuple(range(frames)))
    resolved = HexPlaneConfig().resolve(info)
    assert resolved.time_resolution == expected
    assert resolved.resolve(info) == resolved


def test_gaussian_basis_count_grows_slowly_and_is_capped():
    counts = [GaussianBasisConfig().resolve(
        SceneInfo(num_frames=n, width=64, height=48, train_indices=(0,))).num_basis
        for n in (4, 100, 2000, 3000, 7500, 100_000)]
    assert counts == [2, 8, 8, 12, 16, 16]
    assert time_capacity(10, 8, 0, 4) == 5  # frames_per_unit 0 is taken as 1


def test_point_fusion_reads_a_bounded_number_of_evenly_spaced_frames():
    frames = list(range(10))
    assert fusion_frames(frames, 4) == [0, 3, 6, 9]
    assert fusion_frames(frames, 10) is frames
