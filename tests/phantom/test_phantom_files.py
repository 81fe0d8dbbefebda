"""The small phantom on disk: the loader accepts it, and its ground truth is self-consistent."""

import json
from pathlib import Path

import numpy as np
import pytest

from surgsplat.data.layout import frame_stem
from surgsplat.data.phantom import PRESETS, PhantomConfig, generate_phantom
from surgsplat.data.phantom.scene import PhantomScene
from surgsplat.data.phantom.tool import intersect_tool
from surgsplat.data.ply import read_ply_mesh
from surgsplat.data.scene import load_scene, read_depth, read_image, read_tool_mask
from surgsplat.errors import SurgsplatError

SMALL = PRESETS["small"]


@pytest.fixture(scope="module")
def phantom(small_phantom) -> Path:
    """The small pulling phantom, seed 0 (PhantomConfig()): the session's, which these tests
    only read."""
    return small_phantom


def gt(root: Path, folder: str, index: int, suffix: str) -> Path:
    return root / "gt" / folder / f"{frame_stem(index)}{suffix}"


def rays() -> np.ndarray:
    u = (np.arange(SMALL.width) + 0.5 - SMALL.width / 2) / SMALL.focal
    v = (np.arange(SMALL.height) + 0.5 - SMALL.height / 2) / SMALL.focal
    xn, yn = np.meshgrid(u, v)
    return np.stack([xn, yn, np.ones_like(xn)], axis=-1)  # [H, W, 3]


def test_loader_round_trip(phantom: Path):
    scene = load_scene(phantom)
    assert len(scene.frames) == SMALL.num_frames == 16
    assert (scene.camera.width, scene.camera.height) == (160, 128)
    assert scene.camera.focal == pytest.approx(569.4682 / 4, rel=1e-6)
    assert scene.depth_unit == "mm" and scene.has_depth and scene.has_masks
    extra = scene.meta.extra
    assert (extra["preset"], extra["motion"], extra["seed"]) == ("small", "pulling", 0)
    assert {"light", "exposure"} <= set(extra)
    tool_shares = []
    for frame in scene.frames:
        tissue_depth = frame.depth[frame.tissue]
        assert 60.0 < tissue_depth.min() and tissue_depth.max() < 125.0  # mm
        tool_shares.append(1.0 - frame.tissue.float().mean().item())
    assert max(tool_shares) > 0.01 and min(tool_shares) == 0.0
    assert max(tool_shares) < 0.5


def test_progress_is_reported(tmp_path: Path):
    calls = []
    generate_phantom(PhantomConfig(num_frames=2), tmp_path / "p", lambda i, n: calls.append((i, n)))
    assert calls == [(1, 2), (2, 2)]


def test_gt_files_have_documented_shapes(phantom: Path):
    exposures = json.loads((phantom / "gt" / "exposure.json").read_text())
    assert len(exposures) == 16 and all(0.85 <= e <= 1.15 for e in exposures)
    assert max(exposures) - min(exposures) > 0.05  # the exposure changes over time
    for index in (0, 15):
        assert read_image(gt(phantom, "tissue_images", index, ".png")).shape == (128, 160, 3)
        assert read_image(gt(phantom, "albedo", index, ".png")).shape == (128, 160, 3)
        depth = np.load(gt(phantom, "tissue_depth", index, ".npy"))
        normals = np.load(gt(phantom, "normals", index, ".npy"))
        assert depth.dtype == normals.dtype == np.float32
        assert depth.shape == (128, 160) and normals.shape == (128, 160, 3)


def test_same_seed_same_bytes_other_seed_other_texture(phantom: Path, tmp_path: Path):
    first = generate_phantom(PhantomConfig(num_frames=3), tmp_path / "a")
    second = generate_phantom(PhantomConfig(num_frames=3), tmp_path / "b")
    for folder in ("images", "depth", "masks"):
        for a in sorted((first / folder).iterdir()):
            assert a.read_bytes() == (second / folder / a.name).read_bytes(), a
    # Frame 0 is at time 0 whatever the frame count.
    name = f"{frame_stem(0)}.png"
    assert (first / "images" / name).read_bytes() == (phantom / "images" / name).read_bytes()
    other = generate_phantom(PhantomConfig(seed=1, num_frames=1), tmp_path / "c")
    albedo_0 = read_image(gt(first, "albedo", 0, ".png")).astype(float) / 255
    albedo_1 = read_image(gt(other, "albedo", 0, ".png")).astype(float) / 255
    assert np.abs(albedo_0 - albedo_1).mean() > 0.03


def test_mesh_vertices_lie_on_the_depth_maps(phantom: Path):
    """Each vertex projects onto a pixel centre whose tissue depth is the vertex's z."""
    for index in (0, 9):
        vertices, faces = read_ply_mesh(gt(phantom, "meshes", index, ".ply"))
        depth = np.load(gt(phantom, "tissue_depth", index, ".npy"))
        u = SMALL.focal * vertices[:, 0] / vertices[:, 2] + SMALL.width / 2 - 0.5
        v = SMALL.focal * vertices[:, 1] / vertices[:, 2] + SMALL.height / 2 - 0.5
        np.testing.assert_allclose(u, np.rint(u), atol=1e-3)  # pixels
        np.testing.assert_allclose(v, np.rint(v), atol=1e-3)
        at_pixel = depth[np.rint(v).astype(int), np.rint(u).astype(int)]
        np.testing.assert_allclose(vertices[:, 2], at_pixel, atol=1e-4)  # mm
        assert len(vertices) >= (160 // 4) * (128 // 4)  # about one vertex per 4 px
        # Faces are wound towards the camera.
        a, b, c = (vertices[faces[:, k]].astype(np.float64) for k in range(3))
        assert (np.einsum("fi,fi->f", np.cross(b - a, c - a), a) < 0).all()


def mesh_depth(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Depth [H, W] of the nearest mesh surface through each pixel centre (inf where none):
    a z-buffer rasteriser interpolating 1/z linearly in the image, which is exact for planar
    triangles under perspective."""
    u = SMALL.focal * vertices[:, 0] / vertices[:, 2] + SMALL.width / 2
    v = SMALL.focal * vertices[:, 1] / vertices[:, 2] + SMALL.height / 2
    inv_z = 1.0 / vertices[:, 2].astype(np.float64)
    depth = np.full((SMALL.height, SMALL.width), np.inf)
    for face in faces:
        fu, fv, fz = u[face], v[face], inv_z[face]
        cols = np.arange(max(int(np.floor(fu.min() - 0.5)), 0),
                         min(int(np.ceil(fu.max() - 0.5)), SMALL.width - 1) + 1)
        rows = np.arange(max(int(np.floor(fv.min() - 0.5)), 0),
                         min(int(np.ceil(fv.max() - 0.5)), SMALL.height - 1) + 1)
        pu, pv = np.meshgrid(cols + 0.5, rows + 0.5)
        area = (fu[1] - fu[0]) * (fv[2] - fv[0]) - (fu[2] - fu[0]) * (fv[1] - fv[0])
        w1 = ((pu - fu[0]) * (fv[2] - fv[0]) - (fu[2] - fu[0]) * (pv - fv[0])) / area
        w2 = ((fu[1] - fu[0]) * (pv - fv[0]) - (pu - fu[0]) * (fv[1] - fv[0])) / area
        w0 = 1.0 - w1 - w2
        inside = (w0 >= -1e-4) & (w1 >= -1e-4) & (w2 >= -1e-4)  # float32 vertices
        z = 1.0 / (w0 * fz[0] + w1 * fz[1] + w2 * fz[2])
        block = depth[np.ix_(rows, cols)]
        depth[np.ix_(rows, cols)] = np.where(inside, np.minimum(block, z), block)
    return depth


def test_tissue_depth_agrees_with_mesh(phantom: Path):
    """Pixels back-projected at their tissue depth lie on the mesh: median |dz| < 0.05 mm."""
    for index in (0, 9):
        vertices, faces = read_ply_mesh(gt(phantom, "meshes", index, ".ply"))
        depth = np.load(gt(phantom, "tissue_depth", index, ".npy"))
        from_mesh = mesh_depth(vertices, faces)
        assert np.isfinite(from_mesh).all()  # the mesh covers the whole view
        error = np.abs(from_mesh - depth)
        assert np.median(error) < 0.05 and np.percentile(error, 99) < 0.15, (
            index, np.median(error), np.percentile(error, 99))


def test_observed_depth_is_tissue_depth_outside_the_tool(phantom: Path):
    saw_tool = False
    for index in range(16):
        observed = read_depth(phantom / "depth" / f"{frame_stem(index)}.png", 0.01)
        tissue = np.load(gt(phantom, "tissue_depth", index, ".npy"))
        tool = read_tool_mask(phantom / "masks" / f"{frame_stem(index)}.png")
        # PNG depth is stored in steps of 0.01 mm.
        np.testing.assert_allclose(observed[~tool], tissue[~tool], atol=0.005 + 1e-4)
        assert (observed[tool] < tissue[tool]).all()
        saw_tool |= bool(tool.any())
    assert saw_tool


def test_tool_mask_is_where_the_tool_is_nearer(phantom: Path):
    """Re-cast the tool alone and compare with the stored tissue depth."""
    scene = PhantomScene(SMALL.width, SMALL.height, SMALL.focal, 16, "pulling", seed=0)
    for index in range(16):
        hit = intersect_tool(scene.geometry, scene.tool_pose(scene.time(index)), scene.xn,
                             scene.yn)
        tissue = np.load(gt(phantom, "tissue_depth", index, ".npy"))
        tool = read_tool_mask(phantom / "masks" / f"{frame_stem(index)}.png")
        np.testing.assert_array_equal(tool, hit.depth < tissue)


def test_image_is_tissue_image_outside_the_tool(phantom: Path):
    for index in (0, 5, 9):
        stem = frame_stem(index)
        image = read_image(phantom / "images" / f"{stem}.png")
        tissue_image = read_image(gt(phantom, "tissue_images", index, ".png"))
        tool = read_tool_mask(phantom / "masks" / f"{stem}.png")
        np.testing.assert_array_equal(image[~tool], tissue_image[~tool])
        if tool.any():
            assert np.abs(image[tool].astype(int) - tissue_image[tool]).mean() > 10


def test_normals_are_unit_face_the_camera_and_match_the_depth(phantom: Path):
    directions = rays()
    for index in (0, 9, 15):
        normals = np.load(gt(phantom, "normals", index, ".npy")).astype(np.float64)
        np.testing.assert_allclose(np.linalg.norm(normals, axis=-1), 1.0, atol=1e-5)
        assert (np.einsum("hwi,hwi->hw", normals, directions) < 0).all()
        # Normals of the back-projected depth map (finite differences), away from the border.
        points = np.load(gt(phantom, "tissue_depth", index, ".npy"))[..., None] * directions
        along_u = points[1:-1, 2:] - points[1:-1, :-2]
        along_v = points[2:, 1:-1] - points[:-2, 1:-1]
        from_depth = np.cross(along_u, along_v)
        from_depth /= -np.linalg.norm(from_depth, axis=-1, keepdims=True)
        cos = np.einsum("hwi,hwi->hw", from_depth, normals[1:-1, 1:-1])
        angle = np.degrees(np.arccos(np.clip(cos, -1, 1)))
        assert np.median(angle) < 0.1 and np.percentile(angle, 99) < 0.5, (
            np.median(angle), np.percentile(angle, 99))


def test_pulling_lifts_the_tissue_towards_the_camera(phantom: Path):
    start = np.load(gt(phantom, "tissue_depth", 0, ".npy"))
    lifted = np.load(gt(phantom, "tissue_depth", 9, ".npy"))  # t = 0.56, near the highest lift
    assert (start - lifted).max() > 7.0  # mm; breathing alone moves the tissue by < 2.5 mm


def test_invalid_requests_name_the_valid_values(tmp_path: Path):
    with pytest.raises(SurgsplatError, match="small, full"):
        generate_phantom(PhantomConfig(preset="huge"), tmp_path / "a")
    with pytest.raises(SurgsplatError, match="pulling, cutting"):
        generate_phantom(PhantomConfig(motion="stretching"), tmp_path / "b")
    with pytest.raises(SurgsplatError, match=r"in 1\.\.10000, got 0"):
        generate_phantom(PhantomConfig(num_frames=0), tmp_path / "c")
    (tmp_path / "d").mkdir()
    (tmp_path / "d" / "keep.txt").write_text("x")
    with pytest.raises(SurgsplatError, match="not an empty folder"):
        generate_phantom(PhantomConfig(num_frames=1), tmp_path / "d")


def test_a_stopped_generation_leaves_nothing_half_written(tmp_path):
    from surgsplat.data.phantom import PhantomConfig, generate_phantom

    def stop(done, total):
        if done == 3:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        generate_phantom(PhantomConfig(preset="small"), tmp_path / "ph", progress=stop)
    assert list(tmp_path.iterdir()) == []  # neither the phantom nor its partial folder
    root = generate_phantom(PhantomConfig(preset="small", num_frames=4), tmp_path / "ph")
    assert (root / "poses_bounds.npy").is_file() and list(tmp_path.iterdir()) == [root]


def test_a_phantom_written_meanwhile_by_another_process_is_named(tmp_path, monkeypatch):
    """Two `phantom --out X` at once: the one that finishes second finds X written."""
    from surgsplat.data.phantom import generate as module

    write = module._write_phantom

    def racing(config, preset, num_frames, folder, progress):
        write(config, preset, num_frames, folder, progress)
        (tmp_path / "out").mkdir()
        (tmp_path / "out" / "images").mkdir()  # the other process's phantom, renamed in place

    monkeypatch.setattr(module, "_write_phantom", racing)
    with pytest.raises(SurgsplatError, match="another process wrote into it"):
        generate_phantom(PhantomConfig(num_frames=1), tmp_path / "out")
    assert [path.name for path in tmp_path.iterdir()] == ["out"]  # no partial folder left
