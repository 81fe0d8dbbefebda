"""3DGS PLY export: the file holds the standard layout, reads back, and renders the run's image."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from plyfile import PlyData

from surgsplat.data.scene import load_scene
from surgsplat.errors import DataError
from surgsplat.export.ply import read_gaussian_ply, write_gaussian_ply
from surgsplat.methods.registry import method_config
from surgsplat.model.component import FrameTime
from surgsplat.model.dynamic import render_frame
from surgsplat.model.state import GaussianState
from surgsplat.render.render import render
from surgsplat.train.trainer import Trainer


def render_state(state: GaussianState, camera):
    return render(state.means, state.scales, state.quats, state.opacities, state.sh, camera.K,
                  camera.width, camera.height, world_to_camera=camera.world_to_camera,
                  sh_degree=state.sh_degree)


@pytest.fixture(scope="module")
def trained(small_phantom, tmp_path_factory):
    config = method_config("endoplanar")
    config.train.iterations = 30
    config.init.max_points = 3000
    config.gaussians.sh_degree = 2
    trainer = Trainer(config, load_scene(small_phantom), tmp_path_factory.mktemp("run") / "run")
    trainer.fit()
    return trainer


def test_layout_round_trip_and_render(trained, tmp_path):
    frame = trained.scene.frames[9]
    when = FrameTime(frame.index, frame.time)
    with torch.no_grad():
        state = trained.model.state_at(when)
    path = tmp_path / "frame9.ply"
    write_gaussian_ply(state, path)
    element = PlyData.read(str(path))["vertex"]
    names = element.data.dtype.names
    assert names[:9] == ("x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2")
    assert names[9:9 + 24] == tuple(f"f_rest_{i}" for i in range(24))  # degree 2: 8 per channel
    assert names[33:] == ("opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2",
                          "rot_3")
    assert all(element.data.dtype[n] == np.dtype("<f4") for n in names)
    assert PlyData.read(str(path)).byte_order == "<" and not PlyData.read(str(path)).text

    loaded = read_gaussian_ply(path)
    assert loaded.sh_degree == 2 and loaded.means.shape == state.means.shape
    # the red channel's first higher coefficient is f_rest_0 (channel-major, as 3DGS stores it)
    torch.testing.assert_close(torch.from_numpy(np.asarray(element["f_rest_0"])), state.sh[:, 1, 0])
    expected = render_frame(trained.model, frame.camera, when)
    again = render_state(loaded, frame.camera)
    assert (again.rgb - expected.rgb).abs().max() < 1e-4
    assert (again.alpha - expected.alpha).abs().max() < 1e-4


def test_cli_export_frames(trained, cli, tmp_path):
    run = trained.run_dir
    done = cli("export", str(run), "--ply", "--frames", "0,9", "--out", str(tmp_path / "ply"))
    assert done.returncode == 0, done.stderr
    assert sorted(p.name for p in (tmp_path / "ply").glob("*.ply")) == ["000000.ply",
                                                                        "000009.ply"]
    one = cli("export", str(run), "--ply", "--time", "0.5", "--out", str(tmp_path / "t"))
    assert one.returncode == 0 and (tmp_path / "t" / "time_0.5000.ply").is_file()
    for args, message in (((), "nothing to export"), (("--frames", "99"), "has frames 0..15"),
                          (("--frames", "a,b"), "expected 'all' or frame indices"),
                          (("--time", "2"), "--time must be in")):
        failed = cli("export", str(run), *(["--ply"] if args else []), *args)
        assert failed.returncode == 2 and message in failed.stderr, failed.stderr


def test_not_a_gaussian_ply(tmp_path):
    (tmp_path / "junk.ply").write_text("hello")
    with pytest.raises(DataError, match="junk.ply: cannot be read as a PLY"):
        read_gaussian_ply(tmp_path / "junk.ply")
