"""The rigid surgical tool: a cylindrical shaft and two box jaws on a revolute joint.

Rays are given as (x/z, y/z) per pixel, i.e. direction (xn, yn, 1) from the camera centre, so a
ray parameter is directly the hit's depth z (mm). Intersections are analytic: ray-cylinder for
the shaft (side and front cap) and slab tests for the two oriented-box jaws.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

SHAFT, JAW = 1, 2
"""Part labels of a tool hit (0 = no hit)."""


@dataclass(frozen=True)
class ToolGeometry:
    """Dimensions of the tool, mm."""

    shaft_radius: float = 4.0
    """Radius of the cylindrical shaft (an 8 mm instrument)."""
    shaft_length: float = 160.0
    """Length of the shaft behind the joint; long enough to leave the view."""
    jaw_length: float = 12.0
    """Length of each jaw from the joint to its tip."""
    jaw_width: float = 3.6
    """Extent of each jaw along the joint's hinge axis."""
    jaw_thickness: float = 1.6
    """Extent of each jaw in the opening direction; closed jaws touch along their length."""


@dataclass(frozen=True)
class ToolPose:
    """Where the tool is in camera space at one instant."""

    joint: np.ndarray
    """[3] mm, the revolute joint at the front end of the shaft."""
    forward: np.ndarray
    """[3] unit vector from the shaft into the jaws (the shaft runs along -forward)."""
    hinge: np.ndarray
    """[3] unit joint axis, perpendicular to forward."""
    jaw_deg: float
    """Opening angle between the jaws, degrees (0 = closed)."""


@dataclass(frozen=True)
class ToolHit:
    """Nearest tool intersection per ray."""

    depth: np.ndarray
    """[...] depth z of the hit, mm; inf where the ray misses the tool."""
    normal: np.ndarray
    """[..., 3] unit outward surface normal at the hit (zeros on a miss)."""
    part: np.ndarray
    """[...] int8: SHAFT, JAW or 0 for a miss."""


def jaw_boxes(geometry: ToolGeometry,
              pose: ToolPose) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """The two jaws as oriented boxes (centre [3], axes [3, 3] as rows, half extents [3])."""
    opening = np.cross(pose.forward, pose.hinge)
    half_angle = np.radians(pose.jaw_deg) / 2
    half = np.array([geometry.jaw_length, geometry.jaw_thickness, geometry.jaw_width]) / 2
    boxes = []
    for side in (1.0, -1.0):
        c, s = np.cos(half_angle), side * np.sin(half_angle)
        along = c * pose.forward + s * opening
        across = c * opening - s * pose.forward
        centre = pose.joint + half[0] * along + side * half[1] * across
        boxes.append((centre, np.stack([along, across, pose.hinge]), half))
    return boxes


def intersect_tool(geometry: ToolGeometry, pose: ToolPose, xn: np.ndarray,
                   yn: np.ndarray) -> ToolHit:
    """Nearest hit of rays (xn, yn, 1) [...] with the shaft and the jaws."""
    rays = np.stack([xn, yn, np.ones_like(xn)], axis=-1)  # [..., 3]
    depth, normal = _intersect_shaft(geometry, pose, rays)
    part = np.where(np.isfinite(depth), SHAFT, 0).astype(np.int8)
    ray_length2 = xn * xn + yn * yn + 1.0
    for centre, axes, half in jaw_boxes(geometry, pose):
        # Only rays passing the box's bounding sphere can hit it.
        along = xn * centre[0] + yn * centre[1] + centre[2]
        near = centre @ centre - along * along / ray_length2 <= half @ half
        box_depth, box_normal = _intersect_box(centre, axes, half, rays[near])  # [M], [M, 3]
        nearer = box_depth < depth[near]
        index = tuple(i[nearer] for i in np.nonzero(near))
        depth[index] = box_depth[nearer]
        normal[index] = box_normal[nearer]
        part[index] = JAW
    return ToolHit(depth=depth, normal=normal, part=part)


def _intersect_shaft(geometry: ToolGeometry, pose: ToolPose,
                     rays: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Depth [...] and normal [..., 3] of rays hitting the shaft: a cylinder from the joint
    back along -forward, closed by a cap at the joint."""
    axis = -pose.forward
    origin = -pose.joint  # camera centre relative to the joint
    d_par = rays @ axis  # [...]
    o_par = origin @ axis
    d_perp = rays - d_par[..., None] * axis  # [..., 3]
    o_perp = origin - o_par * axis  # [3]
    a = np.einsum("...i,...i->...", d_perp, d_perp)
    b = 2 * (d_perp @ o_perp)
    c = o_perp @ o_perp - geometry.shaft_radius ** 2
    disc = b * b - 4 * a * c
    with np.errstate(invalid="ignore", divide="ignore"):
        side = (-b - np.sqrt(disc)) / (2 * a)
    along = o_par + side * d_par
    side_ok = (disc >= 0) & (side > 0) & (along >= 0) & (along <= geometry.shaft_length)
    side = np.where(side_ok, side, np.inf)
    with np.errstate(invalid="ignore", divide="ignore"):
        cap = -o_par / d_par
    radial = o_perp + np.where(np.isfinite(cap), cap, 0.0)[..., None] * d_perp
    cap_ok = np.isfinite(cap) & (cap > 0) & (np.einsum("...i,...i->...", radial, radial)
                                             <= geometry.shaft_radius ** 2)
    cap = np.where(cap_ok, cap, np.inf)
    depth = np.minimum(side, cap)
    radial_side = o_perp + np.where(side_ok, side, 0.0)[..., None] * d_perp
    side_normal = radial_side / np.maximum(np.linalg.norm(radial_side, axis=-1, keepdims=True),
                                           1e-12)
    normal = np.where((cap < side)[..., None], pose.forward, side_normal)
    normal = np.where(np.isfinite(depth)[..., None], normal, 0.0)
    return depth, normal


def _intersect_box(centre: np.ndarray, axes: np.ndarray, half: np.ndarray,
                   rays: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Depth [...] and normal [..., 3] of rays entering an oriented box (slab test)."""
    origin = axes @ (-centre)  # [3] camera centre in box coordinates
    direction = rays @ axes.T  # [..., 3]
    safe = np.where(np.abs(direction) < 1e-12, 1e-12, direction)
    t0 = (-half - origin) / safe
    t1 = (half - origin) / safe
    near = np.minimum(t0, t1)  # [..., 3]
    far = np.maximum(t0, t1)
    entry = near.max(axis=-1)
    exit_ = far.min(axis=-1)
    hit = (entry <= exit_) & (entry > 0)
    depth = np.where(hit, entry, np.inf)
    face = near.argmax(axis=-1)  # the slab entered last is the face hit
    sign = -np.sign(np.take_along_axis(direction, face[..., None], axis=-1))  # [..., 1]
    normal = sign * axes[face]  # [..., 3]
    return depth, np.where(hit[..., None], normal, 0.0)
