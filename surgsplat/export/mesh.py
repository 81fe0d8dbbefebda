"""Per-frame tissue meshes of a trained run, in the scene's unit and world frame.

Two routes, chosen by the method:
- a method with a signed distance field (a component that provides `SignedDistanceField`,
  `model.capabilities`, such as a neural SDF that gives the Gaussians their opacity): marching
  cubes (scikit-image) of the canonical SDF once (with `fit_radius` > 0, each vertex then moved
  along its normal onto the canonical tissue Gaussians near it, `fit_to_points`; off by default:
  the mesh is the SDF's own surface), the vertices carried to the frame's time by the Gaussians'
  own motion (each vertex moves with the inverse-distance-weighted displacement of its nearest
  Gaussians from their canonical centres, which works for any deformation component and leaves
  out what is no motion, such as the anchor clip of mesh-anchored Gaussians), then cropped to
  what the frame's camera sees: faces inside the image and the field of view, on the rendered
  surface (within `surface_tolerance` of the rendered depth, where the render is opaque);
- any other method: the rendered depth map triangulated (every `stride`-th pixel, two triangles per
  grid square), keeping pixels inside the field of view where the render is opaque, and culling
  triangles with an edge longer than `edge_factor` times the pixel grid's spacing at that depth
  (the jumps at depth discontinuities).

Vertex colours come from the rendered image. Files are written with trimesh (ply, obj, glb).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import torch
from scipy.spatial import cKDTree
from torch import Tensor

from surgsplat.atomic import write_atomic
from surgsplat.data.scene import Frame
from surgsplat.errors import SurgsplatError
from surgsplat.fields.level_set import marching_cubes, mesh_library
from surgsplat.image.pinhole import backproject_camera, inside_image, project_points
from surgsplat.model.capabilities import SignedDistanceField
from surgsplat.model.component import FrameTime
from surgsplat.model.dynamic import SplatModel, render_frame
from surgsplat.render.render import RenderOutput

MESH_FORMATS = ("ply", "obj", "glb")
MIN_RESOLUTION = 8
"""Fewest marching-cubes cells along the SDF box's longest side."""
MAX_RESOLUTION = 512
"""Most marching-cubes cells along the SDF box's longest side. The sampled grid holds up to
(R + 1)^3 points (a cubic box), about 40 bytes each while it is built and meshed: 0.3 GB at the
default 192, 5.4 GB at 512 (43 GB at 1024)."""


@dataclass(frozen=True)
class MeshOptions:
    """How meshes are extracted."""

    resolution: int = 192
    """Marching-cubes cells along the longest side of the SDF's box."""
    surface_tolerance: float = 3.0
    """SDF route: a face is kept when its vertices lie within this many marching-cubes cells of
    the rendered depth."""
    neighbours: int = 8
    """SDF route: canonical Gaussians whose displacement carries each vertex."""
    fit_radius: float = 0.0
    """SDF route: each canonical vertex moves along its normal to the weighted mean normal
    offset of the canonical tissue Gaussians within this many marching-cubes cells (weights:
    rendered opacity times a Gaussian kernel of the distance); 0 (default) keeps the SDF's zero
    level, which, with the centres pulled onto it, lies nearer the tissue than the fit."""
    stride: int = 2
    """Depth route: pixels between grid vertices."""
    edge_factor: float = 4.0
    """Depth route: longest kept edge, in grid spacings at the vertex's depth."""
    min_alpha: float = 0.5
    """Pixels (and SDF faces) count as observed surface where the render's alpha is above this."""


@dataclass
class FrameMesh:
    """A triangle mesh of one frame: world frame, scene units."""

    vertices: np.ndarray  # [V, 3] float32
    faces: np.ndarray  # [F, 3] int64 vertex indices
    colors: np.ndarray  # [V, 3] uint8 RGB
    cell: float  # grid spacing of the extraction (marching-cubes cell or pixel grid), scene units
    route: str  # "sdf" or "depth"


class MeshExtractor:
    """Meshes of any frame of one trained model; the canonical SDF mesh is extracted once."""

    def __init__(self, model: SplatModel, options: MeshOptions = MeshOptions(),
                 background: Tensor | None = None):
        self.model = model
        self.options = options
        self.background = background
        self.field = model.find(SignedDistanceField)
        self._canonical: tuple[np.ndarray, np.ndarray, float] | None = None
        self._weights: tuple[np.ndarray, np.ndarray] | None = None  # canonical vertices' anchors

    @property
    def route(self) -> str:
        return "depth" if self.field is None else "sdf"

    @torch.no_grad()
    def frame_mesh(self, frame: Frame, when: FrameTime | None = None) -> FrameMesh:
        """The tissue mesh seen by `frame`'s camera (as the model renders the frame:
        `SplatModel.camera_at`), at `when` (default the frame's own time)."""
        when = when or FrameTime(frame.index, frame.time)
        output = render_frame(self.model, frame.camera, when, self.background)
        frame = frame.seen_by(self.model.camera_at(frame.camera, when))
        if self.field is None:
            return depth_mesh(output, frame, self.options)
        vertices, faces, cell = self.canonical_mesh()
        moved = self._carry(vertices, when)
        keep = faces_on_rendered_surface(moved, faces, output, frame,
                                         self.options.surface_tolerance * cell,
                                         self.options.min_alpha)
        used, faces = compact(faces[keep], len(moved))
        moved = moved[used]
        return FrameMesh(moved.astype(np.float32), faces, vertex_colors(moved, output, frame),
                         cell, "sdf")

    def canonical_mesh(self) -> tuple[np.ndarray, np.ndarray, float]:
        """Marching cubes of the canonical SDF: vertices [V, 3], faces [F, 3], cell size."""
        if self._canonical is None:
            vertices, faces, cell = marching_cubes(self.field.signed_distance, self.field.box,
                                                   self.options.resolution)
            if self.options.fit_radius > 0 and len(faces):
                centres, opacities = self._tissue_gaussians()
                vertices = fit_to_points(vertices, vertex_normals(vertices, faces), centres,
                                         opacities, self.options.fit_radius * cell)
            self._canonical = vertices, faces, cell
        return self._canonical

    def _tissue_gaussians(self) -> tuple[np.ndarray, np.ndarray]:
        """Canonical centres [N, 3] and rendered opacities [N] of the tissue Gaussians (all
        Gaussians unless a component marks some as tool)."""
        params = self.model.gaussians.params
        opacity = torch.sigmoid(params["opacity_logits"].detach())
        factor = self.model.opacity_factor()
        if factor is not None:
            opacity = opacity * factor
        tissue = self.model.tissue_members()
        keep = slice(None) if tissue is None else tissue
        return self._canonical_centres()[keep].numpy(), opacity[keep].numpy()

    def _canonical_centres(self) -> Tensor:
        """[N, 3] the canonical centres (`SplatModel.canonical_means`: the anchored ones for
        mesh-anchored Gaussians), from which the deformation's displacement is measured."""
        return self.model.canonical_means().detach()

    def _carry(self, vertices: np.ndarray, when: FrameTime) -> np.ndarray:
        """Canonical vertices [V, 3] -> their positions at `when`: each moved by the weighted
        displacement of its nearest Gaussians from their canonical centres."""
        canonical = self._canonical_centres()
        if self._weights is None:
            self._weights = anchor_weights(vertices, canonical.numpy(), self.options.neighbours)
        moved = self.model.state_at(when).means.detach()
        index, weights = self._weights
        return vertices + np.einsum("pk,pkc->pc", weights, (moved - canonical).numpy()[index])


def anchor_weights(points: np.ndarray, anchors: np.ndarray,
                   neighbours: int) -> tuple[np.ndarray, np.ndarray]:
    """The `neighbours` nearest anchors [M, 3] of each point [P, 3] and their inverse-distance
    weights: (index [P, k], weights [P, k] summing to 1)."""
    k = min(neighbours, len(anchors))
    distance, index = cKDTree(anchors).query(points, k=k)
    distance, index = distance.reshape(len(points), k), index.reshape(len(points), k)
    weights = 1.0 / np.maximum(distance, 1e-9)
    return index, weights / weights.sum(axis=1, keepdims=True)


def vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """[V, 3] unit normals: the area-weighted sum of the normals of each vertex's faces
    (zero for an unused vertex)."""
    corners = vertices[faces]  # [F, 3, 3]
    face_normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    normals = np.zeros_like(vertices)
    for corner in range(3):
        np.add.at(normals, faces[:, corner], face_normals)
    length = np.linalg.norm(normals, axis=1, keepdims=True)
    return normals / np.maximum(length, 1e-12)


def fit_to_points(vertices: np.ndarray, normals: np.ndarray, points: np.ndarray,
                  weights: np.ndarray, radius: float, neighbours: int = 16) -> np.ndarray:
    """Vertices [V, 3] moved along their unit normals [V, 3] by the weighted mean of the normal
    offsets n . (p - v) of the points [P, 3] within `radius` (at most `neighbours` nearest),
    each weighted by its weight [P] times exp(-2 d^2 / radius^2): one moving-least-squares
    projection onto the points' surface. Vertices with no point in reach stay."""
    if len(points) == 0:
        return vertices
    k = min(neighbours, len(points))
    distance, index = cKDTree(points).query(vertices, k=k, distance_upper_bound=radius)
    distance, index = distance.reshape(len(vertices), k), index.reshape(len(vertices), k)
    reached = np.isfinite(distance)
    index = np.where(reached, index, 0)
    kernel = np.where(reached, np.exp(-2.0 * (np.where(reached, distance, 0.0) / radius) ** 2),
                      0.0) * weights[index]
    offsets = np.einsum("vkc,vc->vk", points[index] - vertices[:, None, :], normals)
    total = kernel.sum(axis=1)
    shift = (kernel * offsets).sum(axis=1) / np.maximum(total, 1e-12)
    return vertices + np.where(total > 1e-9, shift, 0.0)[:, None] * normals


def faces_on_rendered_surface(vertices: np.ndarray, faces: np.ndarray, output: RenderOutput,
                              frame: Frame, tolerance: float, min_alpha: float) -> np.ndarray:
    """[F] bool: faces whose three vertices project inside the image and the field of view, onto
    opaque rendered pixels, within `tolerance` (scene units) of the rendered depth."""
    camera = frame.camera
    pixel, z = project_points(torch.from_numpy(vertices).float(), camera.K,
                              camera.world_to_camera)
    inside = inside_image(pixel, z, camera.width, camera.height)
    rows = pixel[:, 1].clamp(0, camera.height - 1)
    columns = pixel[:, 0].clamp(0, camera.width - 1)
    on_surface = (inside & frame.fov[rows, columns] & (output.alpha[rows, columns] > min_alpha)
                  & ((z - output.depth[rows, columns]).abs() <= tolerance))
    return on_surface.numpy()[faces].all(axis=1)


def compact(faces: np.ndarray, num_vertices: int) -> tuple[np.ndarray, np.ndarray]:
    """Drop unused vertices: (indices [U] of the vertices kept, faces [F, 3] renumbered)."""
    marked = np.zeros(num_vertices, dtype=bool)
    marked[faces.ravel()] = True
    used = np.flatnonzero(marked)
    renumber = np.full(num_vertices, -1, dtype=np.int64)
    renumber[used] = np.arange(len(used))
    return used, renumber[faces]


def vertex_colors(vertices: np.ndarray, output: RenderOutput, frame: Frame) -> np.ndarray:
    """[V, 3] uint8: the rendered colour at each vertex's pixel."""
    camera = frame.camera
    pixel, _ = project_points(torch.from_numpy(vertices).float(), camera.K, camera.world_to_camera)
    rows = pixel[:, 1].clamp(0, camera.height - 1)
    columns = pixel[:, 0].clamp(0, camera.width - 1)
    rgb = output.rgb[rows, columns].clamp(0, 1)
    return (rgb * 255.0 + 0.5).to(torch.uint8).numpy()


def depth_mesh(output: RenderOutput, frame: Frame, options: MeshOptions) -> FrameMesh:
    """The rendered depth of `frame` triangulated on a pixel grid; see the module docstring."""
    camera, stride = frame.camera, options.stride
    depth = output.depth[::stride, ::stride]
    valid = ((frame.fov & (output.alpha > options.min_alpha))[::stride, ::stride]
             & (depth > 0)).numpy()
    # grid vertices at the chosen pixels' centres: scale K to the strided grid
    K = camera.K.clone()
    K[:2] /= stride
    points = backproject_camera(depth, K).reshape(-1, 3)
    pose = camera.camera_to_world
    world = (points @ pose[:3, :3].T + pose[:3, 3]).numpy()
    rows, columns = valid.shape
    index = np.arange(rows * columns).reshape(rows, columns)
    a, b = index[:-1, :-1].ravel(), index[:-1, 1:].ravel()
    c, d = index[1:, :-1].ravel(), index[1:, 1:].ravel()
    faces = np.concatenate([np.stack([a, c, b], 1), np.stack([b, c, d], 1)])
    flat_valid = valid.ravel()
    faces = faces[flat_valid[faces].all(axis=1)]
    spacing = depth.numpy().ravel() * stride / camera.fx  # grid spacing at each vertex's depth
    corners = world[faces]  # [F, 3, 3]
    edges = np.linalg.norm(corners - np.roll(corners, 1, axis=1), axis=2)  # [F, 3]
    limit = options.edge_factor * spacing[faces].max(axis=1)
    faces = faces[(edges <= limit[:, None]).all(axis=1)]
    used, faces = compact(faces, len(world))
    world = world[used]
    colors = (output.rgb[::stride, ::stride].clamp(0, 1).reshape(-1, 3)[torch.from_numpy(used)]
              * 255.0 + 0.5).to(torch.uint8).numpy()
    cell = float(np.median(spacing[used])) if len(used) else 0.0
    return FrameMesh(world.astype(np.float32), faces, colors, cell, "depth")


def coverage(mesh: FrameMesh, frame: Frame) -> tuple[float, float]:
    """How completely the mesh covers the frame's tissue pixels, seen by its camera, one grid cell
    in from the mask's border: (fraction of those pixels covered, area of the largest uncovered
    connected region of them in grid cells, a cell being the extraction's spacing projected at
    the mesh's median depth)."""
    camera = frame.camera
    covered = np.zeros((camera.height, camera.width), dtype=np.uint8)
    if len(mesh.faces):
        pose = camera.world_to_camera.double().numpy()
        points = mesh.vertices.astype(np.float64) @ pose[:3, :3].T + pose[:3, 3]
        K = camera.K.double().numpy()
        z = np.maximum(points[:, 2], 1e-9)
        uv = np.stack([K[0, 0] * points[:, 0] / z + K[0, 2], K[1, 1] * points[:, 1] / z + K[1, 2]],
                      axis=1)
        shift = 4  # fractional bits for sub-pixel triangle corners
        corners = np.round(uv[mesh.faces] * (1 << shift) - 0.5 * (1 << shift)).astype(np.int32)
        for triangle in corners:
            cv2.fillConvexPoly(covered, triangle, 1, lineType=cv2.LINE_8, shift=shift)
        depth = float(np.median(z))
    else:
        depth = 1.0
    cell_pixels = max((mesh.cell * camera.fx / depth) ** 2, 1.0)
    # the tissue mask less one cell at its border, which no grid of that spacing reaches
    border = int(np.ceil(np.sqrt(cell_pixels)))
    tissue = cv2.erode(frame.tissue.numpy().astype(np.uint8), np.ones((3, 3), np.uint8),
                       iterations=border, borderType=cv2.BORDER_CONSTANT,
                       borderValue=0).astype(bool)
    holes = (tissue & (covered == 0)).astype(np.uint8)
    fraction = float(1.0 - holes.sum() / max(int(tissue.sum()), 1))
    count, _, stats, _ = cv2.connectedComponentsWithStats(holes, connectivity=4)
    largest = int(stats[1:, cv2.CC_STAT_AREA].max()) if count > 1 else 0
    return fraction, largest / cell_pixels


def to_trimesh(mesh: FrameMesh):
    """The mesh as a trimesh.Trimesh (vertex colours kept; nothing merged or reordered)."""
    return mesh_library("trimesh").Trimesh(vertices=mesh.vertices, faces=mesh.faces,
                                           vertex_colors=mesh.colors, process=False)


def write_mesh(mesh: FrameMesh, path: Path) -> None:
    """Write `mesh` atomically in the format its suffix names (.ply, .obj or .glb)."""
    file_type = path.suffix.lstrip(".")
    if file_type not in MESH_FORMATS:
        raise SurgsplatError(f"{path}: mesh formats are {', '.join(MESH_FORMATS)}")
    encoded = to_trimesh(mesh).export(file_type=file_type)
    data = encoded.encode() if isinstance(encoded, str) else encoded
    write_atomic(path, lambda handle: handle.write(data))
