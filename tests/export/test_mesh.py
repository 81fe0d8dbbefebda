"""Tissue meshes: marching cubes of an SDF, the depth-map route, carrying, files, the CLI."""

from types import SimpleNamespace

import numpy as np
import pytest
import torch

from surgsplat.data.scene import Camera, Frame, load_scene
from surgsplat.export.mesh import (MeshExtractor, MeshOptions, anchor_weights, coverage,
                                   depth_mesh, fit_to_points, vertex_normals)
from surgsplat.fields.level_set import marching_cubes
from surgsplat.methods.registry import method_config
from surgsplat.model.dynamic import SplatModel
from surgsplat.train.trainer import Trainer

trimesh = pytest.importorskip("trimesh")


def test_marching_cubes_of_a_sphere_lies_on_the_sphere():
    box = torch.tensor([[-3.0, -3.0, -3.0], [3.0, 3.0, 3.0]])
    radius = 2.03  # not a multiple of the cell: no grid sample exactly on the surface
    vertices, faces, cell = marching_cubes(lambda p: p.norm(dim=1) - radius, box, resolution=60)
    assert cell == pytest.approx(0.1)
    radii = np.linalg.norm(vertices, axis=1)
    assert np.abs(radii - radius).max() < 0.005  # linear interpolation of an exact SDF
    mesh = trimesh.Trimesh(vertices, faces)
    assert mesh.is_watertight and mesh.euler_number == 2
    assert mesh.area == pytest.approx(4 * np.pi * radius ** 2, rel=0.005)


def test_anchor_weights_pick_the_nearest_anchors_by_inverse_distance():
    anchors = np.array([[0.0, 0, 0], [1.0, 0, 0], [10.0, 0, 0]])
    index, weights = anchor_weights(np.array([[0.25, 0, 0]]), anchors, neighbours=2)
    assert sorted(index[0]) == [0, 1]
    np.testing.assert_allclose(weights[0][np.argsort(index[0])], [0.75, 0.25], atol=1e-12)


def test_vertices_fitted_to_points_move_along_their_normals_onto_them():
    """A bumpy sphere (the zero level of an SDF that is off by up to 0.15 between samples)
    fitted to points on the true sphere lands on it to 0.01; vertices without points in reach
    stay; the normals of a sphere mesh are radial (to 1e-3)."""
    box = torch.tensor([[-3.0, -3.0, -3.0], [3.0, 3.0, 3.0]])
    radius = 2.03  # off the grid's samples: no zero-area faces

    def bumpy(p):
        return p.norm(dim=1) - radius - 0.15 * torch.sin(5 * p[:, 0]) * torch.cos(4 * p[:, 1])

    smooth, smooth_faces, _ = marching_cubes(lambda p: p.norm(dim=1) - radius, box, 60)
    normals = vertex_normals(smooth, smooth_faces)
    radial = smooth / np.linalg.norm(smooth, axis=1, keepdims=True)
    assert np.abs(np.linalg.norm(normals, axis=1) - 1).max() < 1e-6
    assert np.abs(np.abs((normals * radial).sum(axis=1)) - 1).max() < 1e-3
    vertices, faces, cell = marching_cubes(bumpy, box, resolution=60)
    normals = vertex_normals(vertices, faces)
    generator = np.random.default_rng(0)
    directions = generator.normal(size=(40000, 3))
    points = radius * directions / np.linalg.norm(directions, axis=1, keepdims=True)
    points = points[points[:, 2] > 0]  # the upper half only
    before = np.abs(np.linalg.norm(vertices, axis=1) - radius)
    fitted = fit_to_points(vertices, normals, points, np.ones(len(points)), 4 * cell)
    after = np.abs(np.linalg.norm(fitted, axis=1) - radius)
    upper, lower = vertices[:, 2] > 0.5, vertices[:, 2] < -0.5
    assert before[upper].max() > 0.1 and np.median(after[upper]) < 0.01
    assert after[upper].max() < 0.05
    np.testing.assert_array_equal(fitted[lower], vertices[lower])


def step_frame(width: int = 40, height: int = 30):
    """A frame and a render of a plane at z = 100 with a step to z = 130 on its right half."""
    K = torch.tensor([[50.0, 0, width / 2], [0, 50.0, height / 2], [0, 0, 1]])
    camera = Camera(K=K, world_to_camera=torch.eye(4), width=width, height=height)
    depth = torch.full((height, width), 100.0)
    depth[:, width // 2:] = 130.0
    frame = Frame(index=0, time=0.0, image=torch.zeros(height, width, 3), depth=depth,
                  is_test=False, camera=camera, tool=torch.zeros(height, width, dtype=torch.bool),
                  fov=torch.ones(height, width, dtype=torch.bool))
    output = SimpleNamespace(depth=depth, alpha=torch.ones(height, width),
                             rgb=torch.full((height, width, 3), 0.5))
    return frame, output


def test_depth_mesh_keeps_the_planes_and_cuts_the_step():
    frame, output = step_frame()
    mesh = depth_mesh(output, frame, MeshOptions(stride=1))
    z = mesh.vertices[:, 2]
    assert set(np.round(np.unique(z))) == {100.0, 130.0}
    assert not (z[mesh.faces].max(axis=1) - z[mesh.faces].min(axis=1) > 1).any()  # no bridge
    assert mesh.colors.shape == (len(mesh.vertices), 3) and (mesh.colors == 128).all()
    # the gap between the planes is the width between two pixel centres: the triangles on each
    # side reach their last pixels, so every pixel is covered
    assert coverage(mesh, frame) == (1.0, 0.0)
    # without the right half, its pixels are one hole of 20 x 30 pixels less the 1-pixel border
    left = depth_mesh(SimpleNamespace(depth=output.depth, rgb=output.rgb,
                                      alpha=torch.where(torch.arange(40) < 20, 1.0, 0.0)
                                      .expand(30, 40)), frame, MeshOptions(stride=1))
    covered, largest_hole = coverage(left, frame)
    assert largest_hole == (40 - 20 - 1) * (30 - 2)
    assert covered == pytest.approx(1 - largest_hole / (38 * 28))


@pytest.fixture(scope="module")
def trained(small_phantom, tmp_path_factory):
    config = method_config("endogsg")
    config.train.iterations = 20
    config.init.max_points = 3000
    config.components["sdf"].resolutions = (16, 32)
    config.components["sdf"].fit_steps = 60
    config.components["sdf"].samples_per_step = 2048
    trainer = Trainer(config, load_scene(small_phantom), tmp_path_factory.mktemp("run") / "run")
    trainer.fit()
    return trainer


def test_both_routes_give_meshes_near_the_rendered_surface(trained):
    frame = trained.scene.frames[9]
    with_sdf = MeshExtractor(trained.model, MeshOptions(resolution=64))
    components = {k: v for k, v in trained.model.components.items() if k != "sdf"}
    without_sdf = MeshExtractor(SplatModel(trained.model.gaussians, components))
    assert (with_sdf.route, without_sdf.route) == ("sdf", "depth")
    for extractor in (with_sdf, without_sdf):
        mesh = extractor.frame_mesh(frame)
        assert len(mesh.faces) > 100
        # the tissue lies 60-130 mm in front of the phantom's camera
        assert 50 < np.median(mesh.vertices[:, 2]) < 140


def test_cli_writes_meshes_that_trimesh_reloads(trained, cli, one_error_line, tmp_path):
    run = str(trained.run_dir)
    for file_format in ("ply", "obj", "glb"):
        done = cli("export", run, "--mesh", "--frames", "0,9", "--format", file_format,
                   "--mesh-resolution", "48", "--out", str(tmp_path / file_format))
        assert done.returncode == 0, done.stderr
        for stem in ("000000", "000009"):
            mesh = trimesh.load(tmp_path / file_format / f"{stem}.{file_format}", force="mesh")
            assert len(mesh.faces) > 100 and np.isfinite(mesh.vertices).all()
    assert "--format" in one_error_line(cli("export", run, "--mesh", "--format", "stl"))
    assert "--mesh-resolution" in one_error_line(cli("export", run, "--mesh",
                                                     "--mesh-resolution", "1"))
    assert "--mesh-fit-radius" in one_error_line(cli("export", run, "--mesh",
                                                     "--mesh-fit-radius", "-1"))
    assert "--frames" in one_error_line(cli("export", run, "--mesh", "--frames", ""))
