"""Gaussians anchored on the faces of the mesh of the method's signed distance field (DRAWER,
`drawer-supplement.txt` Section B.2).

The mesh is the zero level set of the method's signed distance field (the component that
provides `SignedDistanceField`, `model.capabilities`; `fields.level_set.marching_cubes`),
extracted before the first render (`before_render`) and again after every `reanchor_every`
training steps (`after_step`). Each Gaussian is mapped to a face k (per-Gaussian buffer
`anchor_face`, carried by densification with the rows: a clone or split child keeps its parent's
face): the nearest face (among the `candidate_faces` faces of nearest centroid) to its canonical
centre when it is anchored. Until the first mesh exists the Gaussians are left as they are.

Face frame (the supplement's): e0 = (v1 - v0) / |.|, e1 = (v2 - v1) / |.|, n = e0 x e1 / |.|;
x_k = e0, y_k = n x e0, z_k = n, with origin v0. A Gaussian's learnable canonical mean, scales
and rotation are its parameters before the clip; the anchored Gaussian that is rendered is
- mean: the centre in face coordinates (x, y, z) = F_k^T (mu - v0); the in-plane point's
  barycentric coordinates clipped to [0, 1] and renormalised to sum 1 (so it lies in the
  triangle), z clipped to [-e_alpha r_k, e_alpha r_k], back to world: v0 + F_k (x', y', z');
- scales: the two first axes clipped to s_alpha r_k, the third (the Gaussian's normal axis) to
  s_alpha s_beta r_k;
- rotation: the third axis tilted at most phi_max from the face normal (either orientation: a
  Gaussian is symmetric), by the smallest rotation that brings it within the cone; the rotation
  about the normal is free;
where r_k is the face's inradius, at least `min_face_radius` marching-cubes cells (slivers of
marching cubes would otherwise pin their Gaussians to zero size). The centre's clip is
straight-through: the forward pass uses the clipped value, the backward pass the identity
(sg(clip(p)) + p - sg(p)), so the photometric gradient keeps moving the raw centre, whose drift
off the surface the SDF's projection loss pulls back.

Deviation: the scales and rotation are not clipped straight-through as the supplement does, but
projected: the anchored tissue Gaussians' scale and rotation parameters are set to their clipped
values after every training step (`after_step`) and whenever Gaussians get a face
(`before_render`), so every render draws its parameters as they are and each step starts from
the shape that is rendered (projected gradient; `transform` leaves the shapes alone). With a
straight-through clip nothing pulls them back: the raw scales grow past their clip, the raw
shapes no longer render the scene, and densification, which splits by the raw scales along the
raw axes, works from shapes that were never rendered (measured: docs/methods/drawer.md,
Deviations). The centres keep the straight-through clip: the SDF's losses use the raw centres
(see `fields.sdf`).

The supplement gives no value for two of the clips, the normal-scale ratio s_beta and the tilt
phi_max. Their defaults, 1 and 90 degrees, leave both open (the normal scale clipped as the
in-face ones, the tilt free): the surface a simulator uses is the SDF's mesh, which the
Gaussians' flatness does not improve, and flat, face-aligned shapes cost tissue PSNR (measured:
docs/methods/drawer.md, Deviations).

How the Gaussians follow the deforming surface: this component's phase (anchor) comes first, so
it turns the canonical Gaussians into anchored canonical Gaussians; the deformation field then
moves the anchored centres (evaluated there, `fields.deformation`), so over time each Gaussian
moves with the tissue around its face. The mesh itself is canonical; the mesh export carries its
vertices to a frame by the displacement of the nearby Gaussians from their anchored canonical
centres (`canonical_means`; `export.mesh`), i.e. by the same field. The method's SDF evaluates
its bell and its losses at the raw means (see `fields.sdf`): its projection loss pulls them back
onto the zero level, which keeps the clip small.

Gaussians that a component of the method marks as tool (`model.membership`) are left as they are.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np
import torch
import torch.nn.functional as F
from scipy.spatial import cKDTree
from torch import Tensor

from surgsplat.errors import SurgsplatError
from surgsplat.fields.level_set import marching_cubes
from surgsplat.model.capabilities import CanonicalPlacement, SignedDistanceField
from surgsplat.model.component import (Component, ComponentConfig, FrameTime, SetupContext,
                                       providers)
from surgsplat.model.gaussians import GaussianModel
from surgsplat.model.membership import tissue_members
from surgsplat.model.phases import Phase
from surgsplat.model.state import GaussianState
from surgsplat.render.rotation import (axis_angle_to_quaternion, quaternion_multiply,
                                       quaternion_third_axis)

ANCHOR_KEY = "anchor_face"
"""Per-Gaussian buffer [N] int64: index of the face the Gaussian is anchored to; -1 = not
anchored yet (the next render's `before_render` anchors it)."""


@dataclass
class MeshAnchorConfig(ComponentConfig, kind="mesh_anchor"):
    """The mesh extraction, its schedule and the clipping band of anchored Gaussians."""

    resolution: int = field(default=128, metadata={"range": "[2, 1024]"})
    """Marching-cubes cells along the longest side of the SDF's box."""
    reanchor_every: int = field(default=100, metadata={"range": "[1, inf)"})
    """Re-extract the mesh and re-anchor every Gaussian after every this many training steps."""
    offset_band: float = field(default=2.0, metadata={"range": "[0, inf)"})
    """e_alpha: the normal offset is clipped to +- this many face radii."""
    scale_limit: float = field(default=4.0, metadata={"range": "(0, inf)"})
    """s_alpha: the two in-face scales are clipped to this many face radii."""
    normal_scale_ratio: float = field(default=1.0, metadata={"range": "(0, inf)"})
    """s_beta: the third (normal) scale is clipped to s_alpha s_beta face radii. The supplement
    gives no value; 1 (no flattening beyond the in-face clip) measured best
    (docs/methods/drawer.md, Deviations)."""
    max_tilt_deg: float = field(default=90.0, metadata={"range": "[0, 90]"})
    """phi_max: largest angle between a Gaussian's third axis and its face's normal, degrees
    (90: free). The supplement gives no value; 90 measured best (docs/methods/drawer.md,
    Deviations)."""
    min_face_radius: float = field(default=0.25, metadata={"range": "(0, inf)"})
    """Face radius used for the clips: the inradius, at least this many marching-cubes cells."""
    candidate_faces: int = field(default=8, metadata={"range": "[1, inf)"})
    """Faces of nearest centroid among which a Gaussian's nearest face is looked for."""

    def build(self) -> "MeshAnchor":
        return MeshAnchor(self)


def face_frames(corners: Tensor) -> Tensor:
    """corners [..., 3, 3] (v0, v1, v2 as rows) -> [..., 3, 3] orthonormal frames whose columns are
    x_k = e0, y_k = n x e0 and z_k = n (the face normal, by the corners' winding)."""
    v0, v1, v2 = corners.unbind(-2)
    e0 = F.normalize(v1 - v0, dim=-1)
    e1 = F.normalize(v2 - v1, dim=-1)
    normal = F.normalize(torch.cross(e0, e1, dim=-1), dim=-1)
    return torch.stack([e0, torch.cross(normal, e0, dim=-1), normal], dim=-1)


def to_face_local(points: Tensor, corners: Tensor) -> Tensor:
    """World points [..., 3] -> their coordinates (x, y, z) [..., 3] in the frames of faces
    corners [..., 3, 3] (origin v0)."""
    return to_local(points, corners[..., 0, :], face_frames(corners))


def to_local(points: Tensor, origin: Tensor, frame: Tensor) -> Tensor:
    """World points [..., 3] -> coordinates [..., 3] in frames [..., 3, 3] (axes as columns)
    placed at origin [..., 3]."""
    return ((points - origin).unsqueeze(-2) @ frame).squeeze(-2)


def to_world(local: Tensor, origin: Tensor, frame: Tensor) -> Tensor:
    """The inverse of `to_local`."""
    return origin + (frame @ local.unsqueeze(-1)).squeeze(-1)


def planar_corners(corners: Tensor) -> tuple[Tensor, Tensor]:
    """The corners v1, v2 in 2D face coordinates, [..., 2] each (v0 is the origin)."""
    local = to_face_local(corners, corners.unsqueeze(-3).expand(*corners.shape[:-1], 3, 3))
    return local[..., 1, :2], local[..., 2, :2]


def inradius(corners: Tensor) -> Tensor:
    """[...] inradius of faces corners [..., 3, 3]: twice the area over the perimeter."""
    v0, v1, v2 = corners.unbind(-2)
    double_area = torch.cross(v1 - v0, v2 - v0, dim=-1).norm(dim=-1)
    perimeter = (v1 - v0).norm(dim=-1) + (v2 - v1).norm(dim=-1) + (v0 - v2).norm(dim=-1)
    return double_area / perimeter.clamp_min(1e-30)


def clip_in_triangle(local: Tensor, p1: Tensor, p2: Tensor, band: Tensor) -> Tensor:
    """Face coordinates [..., 3] clipped into the triangle (0, p1, p2) of 2D face coordinates
    p1, p2 [..., 2]: the in-plane point's barycentric coordinates clipped to [0, 1] and
    renormalised, z clipped to [-band, band] (band [...])."""
    point = local[..., :2]
    double_area = p1[..., 0] * p2[..., 1] - p1[..., 1] * p2[..., 0]
    lambda1 = (point[..., 0] * p2[..., 1] - point[..., 1] * p2[..., 0]) / double_area
    lambda2 = (p1[..., 0] * point[..., 1] - p1[..., 1] * point[..., 0]) / double_area
    weights = torch.stack([1.0 - lambda1 - lambda2, lambda1, lambda2], dim=-1).clamp(0.0, 1.0)
    weights = weights / weights.sum(dim=-1, keepdim=True)
    planar = weights[..., 1:2] * p1 + weights[..., 2:3] * p2
    offset = torch.maximum(torch.minimum(local[..., 2], band), -band)
    return torch.cat([planar, offset.unsqueeze(-1)], dim=-1)


@dataclass
class FaceGeometry:
    """What the clips need of each face of a mesh, computed once per mesh: origin v0 [F, 3],
    frame [F, 3, 3] (`face_frames`), corners v1, v2 in 2D face coordinates p1, p2 [F, 2], and
    inradius [F]."""

    origin: Tensor
    frame: Tensor
    p1: Tensor
    p2: Tensor
    inradius: Tensor

    @classmethod
    def of(cls, corners: Tensor) -> "FaceGeometry":
        """Of the faces corners [F, 3, 3]."""
        return cls(corners[:, 0], face_frames(corners), *planar_corners(corners),
                   inradius(corners))

    def __getitem__(self, index: Tensor) -> "FaceGeometry":
        """The geometry of faces `index` [N] int64 (gathered; index_select is several times
        faster than advanced indexing on the CPU)."""
        return FaceGeometry(*(value.index_select(0, index) for value in
                              (self.origin, self.frame, self.p1, self.p2, self.inradius)))


def clip_tilt(quats: Tensor, normals: Tensor, max_tilt: float) -> Tensor:
    """Rotations quats [N, 4] whose third axis is turned, by the smallest rotation, to within
    max_tilt radians of the line of normals [N, 3] (unit; either direction); unit quaternions."""
    quats = F.normalize(quats, dim=-1)
    axis3 = quaternion_third_axis(quats)  # [N, 3]
    cosine = (axis3 * normals).sum(dim=-1)
    target = normals * torch.where(cosine < 0, -1.0, 1.0)[:, None]
    tilt = torch.arccos(cosine.abs().clamp(max=1.0))
    excess = (tilt - max_tilt).clamp_min(0.0)
    turn = F.normalize(torch.cross(axis3, target, dim=-1), dim=-1)
    return quaternion_multiply(axis_angle_to_quaternion(turn * excess[:, None]), quats)


def straight_through(clipped: Tensor, raw: Tensor) -> Tensor:
    """The clipped value forward, the identity backward: sg(clipped) + raw - sg(raw)."""
    return raw + (clipped - raw).detach()


def nearest_faces(points: Tensor, centroids: Tensor, geometry: FaceGeometry,
                  candidates: int) -> Tensor:
    """[P] index of the face nearest to each point [P, 3], among the `candidates` faces of
    nearest centroid (centroids [F, 3], geometry of the F faces); the distance is to the point
    clipped into the face (`clip_in_triangle`), measured in face coordinates (the frames are
    orthonormal)."""
    count, k = points.shape[0], min(candidates, centroids.shape[0])
    _, index = cKDTree(centroids.double().numpy()).query(points.detach().double().numpy(), k=k)
    index = torch.from_numpy(np.asarray(index, dtype=np.int64).reshape(count, k))
    faces = geometry[index.reshape(-1)]  # [P k, ...]
    local = to_local(points.detach().repeat_interleave(k, dim=0), faces.origin, faces.frame)
    on_face = clip_in_triangle(local, faces.p1, faces.p2, torch.zeros(count * k))
    best = (on_face - local).norm(dim=-1).view(count, k).argmin(dim=1)
    return index.gather(1, best[:, None])[:, 0]


class MeshAnchor(Component):
    """See the module docstring. Buffers: vertices [V, 3] and faces [F, 3] of the canonical mesh
    the Gaussians are anchored to, cell (the marching-cubes cell, scene units)."""
    phase = Phase.ANCHOR
    provides = (CanonicalPlacement,)

    def __init__(self, config: MeshAnchorConfig):
        super().__init__()
        if config.resolution < 2 or config.reanchor_every < 1:
            raise SurgsplatError("mesh_anchor needs resolution >= 2 and reanchor_every >= 1")
        self.config = config
        self.register_buffer("vertices", torch.zeros(0, 3))
        self.register_buffer("faces", torch.zeros(0, 3, dtype=torch.long))
        self.register_buffer("cell", torch.zeros(()))
        # the method's signed distance field and components, as plain references in tuples (a
        # module held directly would become a submodule, its state saved twice)
        self._surface: tuple[SignedDistanceField, ...] = ()
        self._method: tuple[Component, ...] = ()
        self._geometry = FaceGeometry.of(torch.zeros(0, 3, 3))  # of the current mesh's faces

    def bind(self, components: Mapping[str, Component]) -> None:
        self._surface = tuple(providers(components.values(), SignedDistanceField))[:1]
        if not self._surface:
            raise SurgsplatError("mesh_anchor needs a component with a signed distance field "
                                 "(e.g. 'sdf') in the same method")
        self._method = tuple(components.values())

    def _load_from_state_dict(self, state_dict, prefix, *args, **kwargs) -> None:
        # the mesh's size is that of the saved run's last extraction
        for name in ("vertices", "faces"):
            saved = state_dict.get(prefix + name)
            if saved is not None:
                setattr(self, name, torch.empty_like(saved))
        super()._load_from_state_dict(state_dict, prefix, *args, **kwargs)
        self._geometry = FaceGeometry.of(self.vertices[self.faces])

    # ---- the mesh and the anchors ----
    @torch.no_grad()
    def extract(self) -> None:
        """The zero level set of the SDF as the mesh, without degenerate faces."""
        field = self._surface[0]
        vertices, faces, cell = marching_cubes(field.signed_distance, field.box,
                                               self.config.resolution)
        vertices = torch.from_numpy(vertices).float()
        faces = torch.from_numpy(faces)
        corners = vertices[faces]
        double_area = torch.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0],
                                  dim=-1).norm(dim=-1)
        self.vertices = vertices
        self.faces = faces[double_area > 1e-6 * cell * cell]
        self.cell.fill_(cell)
        self._geometry = FaceGeometry.of(self.vertices[self.faces])

    @torch.no_grad()
    def anchor(self, gaussians: GaussianModel, rows: Tensor | None = None) -> None:
        """Map the Gaussians `rows` (default all) to their nearest faces of the current mesh."""
        anchors = gaussians.buffer_dict[ANCHOR_KEY]
        rows = torch.arange(anchors.shape[0]) if rows is None else rows
        if rows.numel():
            means = gaussians.params["means"][rows]
            centroids = self.vertices[self.faces].mean(dim=1)
            anchors[rows] = nearest_faces(means, centroids, self._geometry,
                                          self.config.candidate_faces).to(anchors.dtype)

    def has_face(self, gaussians: GaussianModel) -> Tensor:
        """[N] bool: the Gaussians with a valid face of the current mesh."""
        anchors = gaussians.buffer_dict[ANCHOR_KEY]
        return (anchors >= 0) & (anchors < self.faces.shape[0])

    def unanchored(self, gaussians: GaussianModel) -> Tensor:
        """Indices of the Gaussians without a valid face of the current mesh."""
        return (~self.has_face(gaussians)).nonzero()[:, 0]

    def face_geometry(self, gaussians: GaussianModel) -> FaceGeometry:
        """The geometry of every Gaussian's face [N, ...] (the mesh's, computed when the mesh is
        extracted or loaded)."""
        return self._geometry[gaussians.buffer_dict[ANCHOR_KEY].long()]

    def face_radius(self, faces: FaceGeometry) -> Tensor:
        """[N] r_k of the clips: the inradius, at least min_face_radius cells."""
        return faces.inradius.clamp_min(self.config.min_face_radius * float(self.cell))

    def _clipped_means(self, means: Tensor, faces: FaceGeometry, radius: Tensor) -> Tensor:
        """Centres [N, 3] clipped into their faces and normal bands of offset_band face radii
        radius [N] (forward value only; see `straight_through`)."""
        local = clip_in_triangle(to_local(means, faces.origin, faces.frame), faces.p1, faces.p2,
                                 self.config.offset_band * radius)
        return to_world(local, faces.origin, faces.frame)

    def canonical_means(self, gaussians: GaussianModel) -> Tensor | None:
        """[N, 3] the anchored canonical centres (tool Gaussians' as they are), straight-through
        to params["means"]: where this component puts the canonical Gaussians before any
        deformation. The mesh export measures the deformation's displacement from there (not
        from the raw means, whose clip offset is no motion). None before the first mesh."""
        if self.faces.shape[0] == 0:
            return None
        means = gaussians.params["means"]
        faces = self.face_geometry(gaussians)
        clipped = self._clipped_means(means, faces, self.face_radius(faces))
        tissue = tissue_members(self._method, gaussians)
        if tissue is not None:
            clipped = torch.where(tissue[:, None], clipped, means)
        return straight_through(clipped, means)

    # ---- the component contract ----
    def initial_attributes(self, context: SetupContext) -> dict[str, Tensor]:
        """The face each Gaussian is anchored to (state: no rate), -1 until anchored."""
        return {ANCHOR_KEY: torch.full((context.points.shape[0],), -1, dtype=torch.long)}

    def before_render(self, gaussians: GaussianModel, when: FrameTime) -> None:
        """Extract the first mesh when there is none yet, and anchor the Gaussians without a
        face of the current mesh (the initial ones), whose shapes are then projected."""
        if self.faces.shape[0] == 0:
            self.extract()
        missing = self.unanchored(gaussians)
        if missing.numel():
            self.anchor(gaussians, missing)
            self.project_shapes(gaussians)

    def after_step(self, gaussians: GaussianModel, iteration: int) -> None:
        if iteration % self.config.reanchor_every == 0:
            self.extract()
            self.anchor(gaussians)
        self.project_shapes(gaussians)

    @torch.no_grad()
    def project_shapes(self, gaussians: GaussianModel) -> None:
        """Clip the anchored tissue Gaussians' scale and rotation parameters in place (projected
        gradient; see the module docstring): the two in-face scales to s_alpha r_k, the normal
        scale to s_alpha s_beta r_k, the third axis to within phi_max of the face's normal."""
        if self.faces.shape[0] == 0:
            return
        config = self.config
        params = gaussians.params
        faces = self.face_geometry(gaussians)
        ratios = torch.tensor([1.0, 1.0, config.normal_scale_ratio])
        log_limits = (self.face_radius(faces)[:, None] * (config.scale_limit * ratios)).log()
        rows = self._anchored_tissue(gaussians)[:, None]  # [N, 1]
        log_scales, quats = params["log_scales"], params["quats"]
        log_scales.copy_(torch.where(rows, torch.minimum(log_scales, log_limits), log_scales))
        if config.max_tilt_deg < 90.0:
            tilted = clip_tilt(quats, faces.frame[..., 2], math.radians(config.max_tilt_deg))
            quats.copy_(torch.where(rows, tilted, quats))

    def _anchored_tissue(self, gaussians: GaussianModel) -> Tensor:
        """[N] bool: the tissue Gaussians with a face of the current mesh."""
        valid = self.has_face(gaussians)
        tissue = tissue_members(self._method, gaussians)
        return valid if tissue is None else valid & tissue

    def transform(self, state: GaussianState, gaussians: GaussianModel,
                  when: FrameTime) -> GaussianState:
        """The anchored canonical Gaussians: centres clipped straight-through, shapes as their
        parameters, which `project_shapes` keeps clipped (see the module docstring); tool
        Gaussians as they are, and every Gaussian before the first mesh."""
        if self.faces.shape[0] == 0:
            return state
        faces = self.face_geometry(gaussians)
        means = self._clipped_means(state.means, faces, self.face_radius(faces))
        tissue = tissue_members(self._method, gaussians)
        if tissue is not None:
            means = torch.where(tissue[:, None], means, state.means)
        return state.replace(means=straight_through(means, state.means))
