"""Point-to-triangle distance, exact point-to-surface search, surface metrics, depth RMSE and
back-projection."""

import math

import numpy as np
import pytest
import torch

from surgsplat.image.pinhole import backproject
from surgsplat.data.ply import read_ply_mesh
from surgsplat.data.scene import load_scene
from surgsplat.eval.geometry_families import collision_fractions, gaussian_geometry, seen_in_frame
from surgsplat.model.physics import ToolProxy
from surgsplat.eval.geometry_metrics import (chamfer_mm, depth_rmse, geometry_metrics,
                                             point_to_surface, point_triangle_distance,
                                             sample_surface, weighted_mean_median)
from surgsplat.eval.metric_family import gt_mesh_path


def grid_mesh(nx=21, ny=16, size=(20.0, 15.0), jitter=0.0, height=None, seed=0):
    """A triangulated grid over [0, sx] x [0, sy] (mm), optionally jittered in x/y and lifted."""
    xs, ys = np.meshgrid(np.linspace(0, size[0], nx), np.linspace(0, size[1], ny))
    rng = np.random.default_rng(seed)
    interior = np.zeros_like(xs, dtype=bool)
    interior[1:-1, 1:-1] = True
    step = min(size[0] / (nx - 1), size[1] / (ny - 1))
    xs = xs + interior * rng.uniform(-jitter, jitter, xs.shape) * step
    ys = ys + interior * rng.uniform(-jitter, jitter, ys.shape) * step
    zs = np.zeros_like(xs) if height is None else height(xs, ys)
    vertices = np.stack([xs, ys, zs], -1).reshape(-1, 3)
    idx = np.arange(nx * ny).reshape(ny, nx)
    a, b = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel()
    c, d = idx[1:, :-1].ravel(), idx[1:, 1:].ravel()
    faces = np.concatenate([np.stack([a, b, d], 1), np.stack([a, d, c], 1)])
    return vertices, faces


def sampled_triangle_distance(points, triangles, levels=120):
    """Brute force: min distance to a dense barycentric lattice of each triangle (an upper bound
    within about one lattice step of the exact distance)."""
    i, j = np.meshgrid(np.arange(levels + 1), np.arange(levels + 1), indexing="ij")
    keep = i + j <= levels
    u, v = i[keep] / levels, j[keep] / levels
    bary = np.stack([1 - u - v, u, v], 1)  # [L, 3]
    lattice = np.einsum("lk,mkd->mld", bary, triangles)  # [M, L, 3]
    return np.linalg.norm(lattice - points[:, None], axis=2).min(axis=1)


def test_point_triangle_distance_known_regions():
    tri = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]])
    cases = {  # point -> exact distance
        (0.2, 0.2, 0.7): 0.7,  # face
        (0.2, 0.2, 0.0): 0.0,  # on the face
        (0.5, -1.0, 0.5): math.hypot(1.0, 0.5),  # edge a-b
        (-2.0, 0.3, 0.0): 2.0,  # edge a-c
        (2.0, 2.0, 0.0): 1.5 * math.sqrt(2),  # edge b-c
        (-1.0, -1.0, 1.0): math.sqrt(3),  # vertex a
        (3.0, -1.0, 0.0): math.hypot(2.0, 1.0),  # vertex b
        (-0.5, 3.0, 2.0): math.sqrt(0.25 + 4 + 4),  # vertex c
    }
    points = np.array(list(cases))
    got = point_triangle_distance(points, np.repeat(tri[None], len(points), 0))
    np.testing.assert_allclose(got, list(cases.values()), atol=1e-12)


def test_point_triangle_distance_against_brute_force():
    rng = np.random.default_rng(0)
    triangles = rng.uniform(-1, 1, (300, 3, 3))
    # half near the triangle's plane (barycentric weights in [-0.6, 1.2]), half anywhere around
    weights = rng.uniform(-0.6, 1.2, (150, 3))
    weights /= weights.sum(axis=1, keepdims=True)
    near = triangles[:150]
    normal = np.cross(near[:, 1] - near[:, 0], near[:, 2] - near[:, 0])
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    points = np.concatenate([np.einsum("mk,mkd->md", weights, near)
                             + rng.normal(0, 0.3, (150, 1)) * normal,
                             rng.uniform(-2, 2, (150, 3))])
    exact = point_triangle_distance(points, triangles)
    sampled = sampled_triangle_distance(points, triangles)
    step = np.linalg.norm(triangles - np.roll(triangles, 1, axis=1), axis=2).max(axis=1) / 120
    assert (exact <= sampled + 1e-12).all()  # never above a true surface point's distance
    assert (sampled - exact <= step).all()  # and within a lattice step of the best one
    # the random cases cover the face, edge and vertex regions
    a, b, c = triangles[:, 0], triangles[:, 1], triangles[:, 2]
    near_vertex = np.isclose(exact, np.linalg.norm(triangles - points[:, None], axis=2).min(1))
    normal = np.cross(b - a, c - a)
    plane = np.abs(np.einsum("ij,ij->i", points - a, normal)) / np.linalg.norm(normal, axis=1)
    on_face = np.isclose(exact, plane)
    assert near_vertex.sum() > 20 and on_face.sum() > 20 and (~near_vertex & ~on_face).sum() > 20


def test_degenerate_triangle_reduces_to_its_edges():
    tri = np.array([[[0.0, 0, 0], [1, 0, 0], [2, 0, 0]], [[1.0, 1, 1], [1, 1, 1], [1, 1, 1]]])
    got = point_triangle_distance(np.array([[0.5, 1.0, 0.0], [1.0, 1.0, 3.0]]), tri)
    np.testing.assert_allclose(got, [1.0, 2.0], atol=1e-12)


def test_point_to_surface_is_exact_on_an_irregular_mesh():
    vertices, faces = grid_mesh(nx=12, ny=9, jitter=0.45, height=lambda x, y: np.sin(x / 3) * y / 5)
    rng = np.random.default_rng(1)
    points = np.concatenate([
        sample_surface(vertices, faces, 400, seed=2) + rng.normal(0, 0.8, (400, 3)),
        rng.uniform([-10, -10, -30], [30, 25, 30], (100, 3)),  # many far from the surface
    ])
    brute = np.array([point_triangle_distance(np.repeat(p[None], len(faces), 0),
                                              vertices[faces]).min() for p in points])
    np.testing.assert_allclose(point_to_surface(points, vertices, faces), brute, atol=1e-12)


def test_point_to_surface_finds_a_large_triangle_with_a_distant_centroid():
    vertices, faces = grid_mesh(nx=11, ny=11, size=(10.0, 10.0))  # small triangles at z = 0
    big = np.array([[-100.0, -100, 1], [300, -100, 1], [-100, 300, 1]])  # centroid (33, 33, 1)
    vertices = np.concatenate([vertices, big])
    faces = np.concatenate([faces, [[len(vertices) - 3, len(vertices) - 2, len(vertices) - 1]]])
    points = np.array([[5.0, 5.0, 1.2], [2.0, 7.0, 0.6], [3.0, 3.0, 0.3]])
    np.testing.assert_allclose(point_to_surface(points, vertices, faces), [0.2, 0.4, 0.3],
                               atol=1e-12)


def test_points_on_the_surface_and_offset_by_two_mm():
    vertices, faces = grid_mesh()  # 20 x 15 mm plane z = 0, 1 mm cells
    points = sample_surface(vertices, faces, 5000, seed=3)
    assert np.abs(points[:, 2]).max() < 1e-12
    assert points[:, :2].min() >= 0 and points[:, 0].max() <= 20 and points[:, 1].max() <= 15
    on = geometry_metrics(points, vertices, faces)
    assert set(on) == {"chamfer_mm", "p2s_mean_mm", "p2s_median_mm", "p2s_p95_mm", "fscore_1mm"}
    assert on["p2s_mean_mm"] < 1e-9 and on["p2s_p95_mm"] < 1e-9
    assert on["chamfer_mm"] < 0.15  # point-set gaps only (5000 points on 300 mm^2)
    assert on["fscore_1mm"] == 1.0

    off = geometry_metrics(points + [0.0, 0.0, 2.0], vertices, faces)
    for key in ("p2s_mean_mm", "p2s_median_mm", "p2s_p95_mm"):
        assert off[key] == pytest.approx(2.0, abs=1e-4)
    assert off["fscore_1mm"] == 0.0
    assert 2.0 <= off["chamfer_mm"] < 2.01


def test_partial_reconstruction_lowers_recall_only():
    vertices, faces = grid_mesh()
    points = sample_surface(vertices, faces, 5000, seed=4)
    half = points[points[:, 0] < 10]  # the left half of the plane
    metrics = geometry_metrics(half, vertices, faces, num_samples=20_000)
    # precision 1, recall ~ (10 + 1) / 20 (samples within 1 mm of the left half)
    recall = 11 / 20
    assert metrics["fscore_1mm"] == pytest.approx(2 * recall / (1 + recall), abs=0.02)
    assert metrics["p2s_mean_mm"] < 1e-9


def test_chamfer_of_point_sets():
    a = np.array([[0.0, 0, 0], [1, 0, 0]])
    b = np.array([[0.0, 0, 1], [1, 0, 1], [5, 0, 0]])
    # a -> b: 1, 1 (mean 1); b -> a: 1, 1, 4 (mean 2)
    assert chamfer_mm(a, b) == pytest.approx(1.5, abs=1e-12)


def test_rejects_bad_inputs():
    vertices, faces = grid_mesh(nx=3, ny=3)
    with pytest.raises(ValueError, match="points"):
        point_to_surface(np.zeros((4, 2)), vertices, faces)
    with pytest.raises(ValueError, match="faces"):
        point_to_surface(np.zeros((4, 3)), vertices, faces + 100)
    with pytest.raises(ValueError, match="NaN"):
        geometry_metrics(np.full((2, 3), np.nan), vertices, faces)


def test_depth_rmse_over_tissue_with_ground_truth():
    gt = torch.full((4, 5), 50.0)
    gt[0, :] = 0.0  # no ground truth: ignored
    pred = gt + 3.0
    pred[1, 1] = 1000.0  # a tool pixel: ignored
    pred[2, :] = gt[2, :] - 4.0
    tissue = torch.ones(4, 5, dtype=torch.bool)
    tissue[1, 1] = False
    # valid pixels: rows 1-3 minus (1, 1) = 14; errors 3 (9 px) and 4 (5 px)
    expected = math.sqrt((9 * 9 + 5 * 16) / 14)
    assert depth_rmse(pred, gt, tissue) == pytest.approx(expected, abs=1e-9)
    with pytest.raises(ValueError, match="positive ground-truth depth"):
        depth_rmse(pred, torch.zeros(4, 5), tissue)


def test_backproject_uses_pixel_centres():
    K = torch.tensor([[100.0, 0, 32], [0, 120.0, 24], [0, 0, 1]])
    depth = torch.zeros(48, 64)
    depth[10, 20] = 40.0
    depth[24, 31] = 60.0  # pixel centre (31.5, 24.5)
    depth[30, 40] = 50.0
    mask = torch.ones(48, 64, dtype=torch.bool)
    mask[30, 40] = False
    points = backproject(depth, K, mask)
    expected = torch.tensor([[(20.5 - 32) / 100 * 40, (10.5 - 24) / 120 * 40, 40.0],
                             [-0.5 / 100 * 60, 0.5 / 120 * 60, 60.0]])
    torch.testing.assert_close(points, expected, atol=1e-5, rtol=0)
    reprojected = (K @ points.T).T
    torch.testing.assert_close(reprojected[:, :2] / reprojected[:, 2:],
                               torch.tensor([[20.5, 10.5], [31.5, 24.5]]), atol=1e-4, rtol=0)


def test_backproject_into_the_world_with_the_frames_camera():
    """With camera_to_world, the points are in the world: mapping them back with the camera's
    world_to_camera and K lands on the pixel centres at their depths (off-centre principal
    point, non-square pixels)."""
    K = torch.tensor([[43.9, 0, 30.5], [0, 46.9, 21.0], [0, 0, 1]], dtype=torch.float64)
    angle = math.radians(7.0)
    world_to_camera = torch.eye(4, dtype=torch.float64)
    world_to_camera[:3, :3] = torch.tensor([[math.cos(angle), 0, math.sin(angle)], [0, 1, 0],
                                            [-math.sin(angle), 0, math.cos(angle)]])
    world_to_camera[:3, 3] = torch.tensor([3.0, -2.0, 5.0])
    camera_to_world = torch.linalg.inv(world_to_camera)
    depth = torch.zeros(40, 60, dtype=torch.float64)
    depth[10, 20], depth[30, 45] = 40.0, 70.0
    mask = torch.ones(40, 60, dtype=torch.bool)
    world = backproject(depth, K, mask, camera_to_world)
    camera_points = backproject(depth, K, mask)
    assert not torch.allclose(world, camera_points)
    back = world @ world_to_camera[:3, :3].T + world_to_camera[:3, 3]
    torch.testing.assert_close(back, camera_points, atol=1e-12, rtol=0)  # mm
    pixels = back @ K.T
    torch.testing.assert_close(pixels[:, :2] / pixels[:, 2:], torch.tensor(
        [[20.5, 10.5], [45.5, 30.5]], dtype=torch.float64), atol=1e-9, rtol=0)
    torch.testing.assert_close(back[:, 2], torch.tensor([40.0, 70.0], dtype=torch.float64),
                               atol=1e-12, rtol=0)


def test_normal_angles_are_orientation_free_and_masked():
    import math

    import torch

    from surgsplat.eval.normals import normal_angle_deg

    gt = torch.zeros(4, 5, 3)
    gt[..., 2] = -1.0  # towards the camera
    angle = math.radians(10.0)
    pred = torch.zeros(4, 5, 3)
    pred[..., 0], pred[..., 2] = math.sin(angle), math.cos(angle)  # away from it, tilted 10 deg
    mask = torch.ones(4, 5, dtype=torch.bool)
    mask[0] = False
    angles = normal_angle_deg(pred, gt, mask)
    assert angles.shape == (15,)
    assert torch.allclose(angles, torch.full((15,), 10.0, dtype=torch.float64), atol=1e-4)


def test_weighted_mean_and_lower_weighted_median():
    values = np.array([4.0, 1.0, 3.0, 2.0])
    assert weighted_mean_median(values, np.ones(4)) == pytest.approx((2.5, 2.0), abs=1e-12)
    # the weight of 4.0 outweighs the rest: mean (4 * 7 + 1 + 3 + 2) / 10, median 4
    assert weighted_mean_median(values, [7.0, 1.0, 1.0, 1.0]) == pytest.approx((3.4, 4.0),
                                                                              abs=1e-12)
    # a zero weight removes a value
    assert weighted_mean_median(values, [0.0, 1.0, 1.0, 1.0]) == pytest.approx((2.0, 2.0),
                                                                              abs=1e-12)
    for weights in ([0.0] * 4, [1.0, -1.0, 1.0, 1.0], [1.0] * 3):
        with pytest.raises(ValueError):
            weighted_mean_median(values, weights)


def test_opacity_weighted_gaussian_p2s_discounts_faded_floaters(small_phantom):
    """Centres on the gt mesh (opacity 1) and twice as many 5 mm floaters toward the camera
    (opacity 1e-3): the plain median is the floaters' 5 mm, the weighted median 0 and the weighted
    mean about 5 mm x 2e-3 / (1 + 2e-3) (tolerances: 1e-3 mm for the median, whose vertices are at
0; 2e-3 mm for the mean, as a floater may lie nearer than 5 mm where the surface curves)."""
    scene = load_scene(small_phantom)
    frame = scene.test_frames[0]
    vertices, faces = read_ply_mesh(gt_mesh_path(scene.root, frame.index))
    surface = torch.from_numpy(vertices).float()
    toward_camera = torch.nn.functional.normalize(
        frame.camera.camera_to_world[:3, 3] - surface, dim=1)
    floaters = surface + 5.0 * toward_camera
    means = torch.cat([surface, floaters, floaters])
    opacities = torch.cat([torch.ones(len(surface)), torch.full((2 * len(surface),), 1e-3)])
    row = gaussian_geometry(means, opacities, frame, vertices, faces, seed=0)
    assert row["gaussians_p2s_median_mm"] > 4.0
    assert row["gaussians_p2s_weighted_median_mm"] == pytest.approx(0.0, abs=1e-3)
    assert row["gaussians_p2s_weighted_mean_mm"] == pytest.approx(5.0 * 2e-3 / (1 + 2e-3),
                                                                 abs=2e-3)


def test_collision_fractions_count_the_seen_points_inside_the_tool_proxy(small_phantom):
    """Tissue points on a test frame's depth surface and one tool ball of radius 3 around one
    of them: the fraction inside is the brute-force share within 3 of the centre among the
    points seen in the field of view (exact); points behind the camera are not counted."""
    scene = load_scene(small_phantom)
    frame = next(f for f in scene.frames if f.is_test)
    camera = frame.camera
    surface = backproject(frame.depth, camera.K, frame.depth > 0, camera.camera_to_world)
    behind = surface[:50] - 1000.0 * camera.camera_to_world[:3, 2]  # far behind the camera
    centre = surface[len(surface) // 2]
    proxy = ToolProxy(centre[None], torch.tensor([3.0]))
    row = collision_fractions(proxy, {"tissue": torch.cat([surface, behind]),
                                      "none": behind}, frame)
    seen = seen_in_frame(surface, frame)
    inside = (surface[seen] - centre).norm(dim=1) < 3.0
    assert row["tissue"] == pytest.approx(float(inside.float().mean()), abs=0)
    assert 0 < row["tissue"] < 0.5
    assert "none" not in row
