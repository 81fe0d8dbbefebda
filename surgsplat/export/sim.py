"""A simulation-ready scene of one frame, for MuJoCo and PyBullet.

`write_sim_scene` writes into one folder, everything in metres (the scene's unit times
`scale`, stated in every file):

    scene.xml       MJCF: the tissue of the frame as a static body, the grasper as a mocap-driven
                    shaft with two revolute jaws and a position actuator on each, a keyframe
                    "frame" holding the frame's jaw angles; gravity along the normal of the
                    tissue's best-fit plane, into the tissue (the tissue lies "flat")
    tissue.obj      the tissue surface (visual mesh of the MJCF; the collider is below)
    tool.urdf       the grasper alone: shaft base link, jaws on revolute joints with their limits
    gaussians.ply   the frame's Gaussians as a standard 3DGS PLY, in metres
    sim.json        metadata: scale, unit, frame, joint names and limits, the collider's grid

Tissue collision: MuJoCo collides a mesh geom as its convex hull, which would lid every concave
fold of a tissue surface. The collider is therefore a height field sampled from the tissue mesh
along that normal (MuJoCo height fields collide exactly as the piecewise-linear
surface of their grid): a fixed collider that follows the mesh to within the grid's
interpolation error, the mesh itself kept as the visual geom.

The tool does not collide with the static tissue (the reconstructed grasper may intersect the
tissue it grasps, and a static collider would lock its jaws), nor with itself; it does collide
with any dynamic body added to the scene.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from scipy.interpolate import NearestNDInterpolator
from scipy.spatial.transform import Rotation

from surgsplat.atomic import write_text_atomic
from surgsplat.errors import SurgsplatError
from surgsplat.export.mesh import FrameMesh, write_mesh
from surgsplat.export.ply import write_gaussian_ply
from surgsplat.model.state import GaussianState

METRES_PER_UNIT = {"mm": 1e-3, "cm": 1e-2, "m": 1.0}
"""Scene depth units the export understands, in metres."""
JAW_NAMES = ("jaw_a", "jaw_b")
STEEL_DENSITY = 7900.0
"""kg / m^3 of the tool's parts."""


@dataclass(frozen=True)
class SimOptions:
    """How the simulation scene is built."""

    grid_step: float = 1e-3
    """Spacing of the tissue height field's grid, metres."""
    limit_margin_deg: float = 2.0
    """The jaws' joint limits are their estimated range widened by this on each side."""
    jaw_kp: float = 0.5
    """Stiffness of the jaws' position actuators, N m / rad."""
    jaw_armature: float = 1e-6
    """Joint armature of the jaws, kg m^2 (keeps the tiny jaws' dynamics stable at 1 ms)."""
    timestep: float = 1e-3
    """MuJoCo time step, seconds."""


def metres_per_unit(unit: str) -> float:
    """Metres per scene unit; SurgsplatError for a unit the export does not know."""
    if unit not in METRES_PER_UNIT:
        raise SurgsplatError(f"the scene's depth unit is {unit!r}; the simulation export needs "
                             f"one of {', '.join(METRES_PER_UNIT)} (scene.json depth_unit)")
    return METRES_PER_UNIT[unit]


@dataclass(frozen=True)
class HeightField:
    """The tissue as a height field in a frame whose z is the height (towards the camera)."""

    to_world: np.ndarray
    """[4, 4] the height field's frame in the world (metres); its origin is the grid's centre
    at the lowest height."""
    heights: np.ndarray
    """[rows, cols] metres above the origin, row 0 at the largest y (MJCF's order)."""
    half_size: tuple[float, float]
    """Half extents of the grid in x and y, metres."""


def into_tissue(vertices: np.ndarray, view_direction: np.ndarray) -> np.ndarray:
    """[3] unit normal of the best-fit plane of `vertices` [V, 3], pointing away from the
    camera (along `view_direction`): the scene's "down"."""
    _, _, axes = np.linalg.svd(vertices - vertices.mean(axis=0), full_matrices=False)
    normal = axes[2]
    return normal if normal @ view_direction >= 0 else -normal


def height_field(vertices: np.ndarray, down: np.ndarray, right: np.ndarray,
                 step: float) -> HeightField:
    """Sample the surface `vertices` [V, 3] (metres) on a grid of spacing `step` as heights
    against `down`: each grid point takes the mean height of the vertices nearest to it (its
    cell), a point without vertices (a hole, or outside the surface) the nearest held one's.
    (A linear interpolation over the vertices' triangulation would be smoother, but scipy's
    point location falls back to a scan of every triangle for each point outside the hull.)"""
    up = -down / np.linalg.norm(down)
    x_axis = right - (right @ up) * up
    x_axis /= np.linalg.norm(x_axis)
    rotation = np.stack([x_axis, np.cross(up, x_axis), up], axis=1)  # columns: frame axes
    local = vertices @ rotation  # [V, 3]
    low, high = local.min(axis=0), local.max(axis=0)
    centre = (low + high) / 2
    cols = max(int(np.ceil((high[0] - low[0]) / step)) + 1, 2)
    rows = max(int(np.ceil((high[1] - low[1]) / step)) + 1, 2)
    xs = np.linspace(low[0], high[0], cols)
    ys = np.linspace(high[1], low[1], rows)  # row 0 at the largest y
    grid = np.stack(np.meshgrid(xs, ys), axis=-1).reshape(-1, 2)  # [rows * cols, 2]
    col = np.rint((local[:, 0] - low[0]) / (xs[1] - xs[0])).astype(int)
    row = np.rint((high[1] - local[:, 1]) / (ys[0] - ys[1])).astype(int)
    cell = row * cols + col  # [V]
    counts = np.bincount(cell, minlength=rows * cols)
    heights = np.bincount(cell, local[:, 2], minlength=rows * cols) / np.maximum(counts, 1)
    held = counts > 0
    if not held.all():
        heights[~held] = NearestNDInterpolator(grid[held], heights[held])(grid[~held])
    heights = heights.reshape(rows, cols) - low[2]
    to_world = np.eye(4)
    to_world[:3, :3] = rotation
    to_world[:3, 3] = rotation @ np.array([centre[0], centre[1], low[2]])
    return HeightField(to_world, heights, ((high[0] - low[0]) / 2, (high[1] - low[1]) / 2))


def _quat(matrix: np.ndarray) -> str:
    """MJCF quaternion (w x y z) of a rotation [3, 3]."""
    x, y, z, w = Rotation.from_matrix(matrix).as_quat()
    return f"{w:.9g} {x:.9g} {y:.9g} {z:.9g}"


def _vec(values) -> str:
    return " ".join(f"{float(v):.9g}" for v in values)


@dataclass(frozen=True)
class ToolModel:
    """The grasper in metres, from an articulation.json (lengths scaled)."""

    shaft_to_world: np.ndarray
    """[4, 4] the frame's shaft pose: origin at the hinge, x forward, z the hinge axis."""
    shaft_radius: float
    shaft_length: float
    jaw_length: float
    jaw_width: float
    jaw_thickness: float
    limits: tuple[tuple[float, float], tuple[float, float]]
    """Each jaw's joint range, radians."""
    angles: tuple[float, float]
    """The frame's jaw angles, radians (inside the limits)."""

    @classmethod
    def from_articulation(cls, articulation: dict, index: int, scale: float,
                          margin_deg: float) -> "ToolModel":
        geometry = articulation["geometry"]
        record = articulation["frames"][index]
        pose = np.array(record["shaft_to_world"], dtype=np.float64)
        pose[:3, 3] *= scale
        limits = tuple((np.radians(low - margin_deg), np.radians(high + margin_deg))
                       for low, high in articulation["limits_deg"])
        angles = tuple(float(np.clip(np.radians(angle), low, high))
                       for angle, (low, high) in zip(record["jaw_angles_deg"], limits))
        return cls(pose, geometry["shaft_radius"] * scale, geometry["shaft_length"] * scale,
                   geometry["jaw_length"] * scale, geometry["jaw_width"] * scale,
                   geometry["jaw_thickness"] * scale, limits, angles)

    def jaw_sides(self) -> tuple[float, float]:
        """Which side of the shaft's x axis each jaw's box lies at angle 0 (-1: -y): the jaw
        whose range lies lower turns towards -y."""
        middles = [low + high for low, high in self.limits]
        return (-1.0, 1.0) if middles[0] <= middles[1] else (1.0, -1.0)


def mjcf(tool: ToolModel, field: HeightField, gravity: np.ndarray, scale: float, unit: str,
         index: int, options: SimOptions) -> str:
    """The MJCF scene (see the module docstring)."""
    rows, cols = field.heights.shape
    top = float(field.heights.max())
    elevation = " ".join(f"{v:.6g}" for v in (field.heights / max(top, 1e-9)).ravel())
    base = max(top, 0.01)  # thick prisms under the surface: a fast probe cannot pass them
    half_jaw = np.array([tool.jaw_length, tool.jaw_thickness, tool.jaw_width]) / 2
    jaws = []
    for name, side, (low, high) in zip(JAW_NAMES, tool.jaw_sides(), tool.limits):
        jaws.append(f"""      <body name="{name}">
        <joint name="{name}" type="hinge" axis="0 0 1" range="{low:.9g} {high:.9g}" limited="true"
               damping="{2 * np.sqrt(options.jaw_kp * options.jaw_armature):.6g}" armature="{options.jaw_armature:.6g}"/>
        <geom name="{name}" type="box" pos="{_vec([half_jaw[0], side * half_jaw[1], 0])}" size="{_vec(half_jaw)}"
              density="{STEEL_DENSITY}" contype="2" conaffinity="2" rgba="0.75 0.75 0.8 1"/>
      </body>""")
    actuators = "\n".join(
        f'    <position name="{name}" joint="{name}" kp="{options.jaw_kp}" '
        f'ctrlrange="{low:.9g} {high:.9g}" ctrllimited="true"/>'
        for name, (low, high) in zip(JAW_NAMES, tool.limits))
    pose = tool.shaft_to_world
    angles = _vec(tool.angles)
    return f"""<mujoco model="surgsplat frame {index}">
  <!-- Exported by surgsplat export --sim from frame {index}. Units: metres, kilograms, seconds,
       radians. Scene lengths were in {unit}; scale = {scale:g} m per {unit}. World frame = the
       scene's world frame (OpenCV camera axes of frame 0) scaled to metres. Gravity points into the
       tissue along the normal of its best-fit plane (facing the camera of frame {index}). -->
  <compiler angle="radian" autolimits="true"/>
  <option timestep="{options.timestep}" gravity="{_vec(gravity)}" integrator="implicitfast"/>
  <asset>
    <mesh name="tissue" file="tissue.obj"/>
    <hfield name="tissue" nrow="{rows}" ncol="{cols}" size="{field.half_size[0]:.9g} {field.half_size[1]:.9g} {max(top, 1e-9):.9g} {base:.9g}"
            elevation="{elevation}"/>
  </asset>
  <worldbody>
    <body name="tissue">
      <geom name="tissue_visual" type="mesh" mesh="tissue" contype="0" conaffinity="0" rgba="0.85 0.45 0.45 1"/>
      <geom name="tissue_collider" type="hfield" hfield="tissue" pos="{_vec(field.to_world[:3, 3])}"
            quat="{_quat(field.to_world[:3, :3])}" contype="1" conaffinity="1" rgba="0.85 0.45 0.45 0"/>
    </body>
    <body name="tool" mocap="true" pos="{_vec(pose[:3, 3])}" quat="{_quat(pose[:3, :3])}">
      <!-- shaft frame: origin at the hinge, x from the shaft into the jaws, z the hinge axis -->
      <geom name="shaft" type="cylinder" fromto="0 0 0 {-tool.shaft_length:.9g} 0 0" size="{tool.shaft_radius:.9g}"
            contype="2" conaffinity="2" rgba="0.6 0.6 0.65 1"/>
{chr(10).join(jaws)}
    </body>
  </worldbody>
  <contact>
    <exclude body1="{JAW_NAMES[0]}" body2="{JAW_NAMES[1]}"/>
  </contact>
  <actuator>
{actuators}
  </actuator>
  <keyframe>
    <key name="frame" qpos="{angles}" ctrl="{angles}" mpos="{_vec(pose[:3, 3])}" mquat="{_quat(pose[:3, :3])}"/>
  </keyframe>
</mujoco>
"""


def _box_inertia(mass: float, size: np.ndarray) -> str:
    """URDF inertia of a solid box of full extents `size` [3] about its centre."""
    x, y, z = size
    return (f'<inertia ixx="{mass * (y * y + z * z) / 12:.6g}" ixy="0" ixz="0" '
            f'iyy="{mass * (x * x + z * z) / 12:.6g}" iyz="0" izz="{mass * (x * x + y * y) / 12:.6g}"/>')


def urdf(tool: ToolModel, scale: float, unit: str) -> str:
    """The grasper alone as a URDF, in its shaft frame (origin at the hinge, z the hinge)."""
    radius, length = tool.shaft_radius, tool.shaft_length
    shaft_mass = STEEL_DENSITY * np.pi * radius * radius * length
    shaft_inertia = (f'<inertia ixx="{shaft_mass * (3 * radius ** 2 + length ** 2) / 12:.6g}" '
                     f'ixy="0" ixz="0" iyy="{shaft_mass * (3 * radius ** 2 + length ** 2) / 12:.6g}"'
                     f' iyz="0" izz="{shaft_mass * radius ** 2 / 2:.6g}"/>')
    size = np.array([tool.jaw_length, tool.jaw_thickness, tool.jaw_width])
    jaw_mass = STEEL_DENSITY * float(np.prod(size))
    links = [f"""  <link name="shaft">
    <inertial><origin xyz="{-length / 2:.9g} 0 0" rpy="0 1.5707963 0"/><mass value="{shaft_mass:.6g}"/>{shaft_inertia}</inertial>
    <visual><origin xyz="{-length / 2:.9g} 0 0" rpy="0 1.5707963 0"/><geometry><cylinder radius="{radius:.9g}" length="{length:.9g}"/></geometry></visual>
    <collision><origin xyz="{-length / 2:.9g} 0 0" rpy="0 1.5707963 0"/><geometry><cylinder radius="{radius:.9g}" length="{length:.9g}"/></geometry></collision>
  </link>"""]
    for name, side, (low, high) in zip(JAW_NAMES, tool.jaw_sides(), tool.limits):
        centre = _vec([size[0] / 2, side * size[1] / 2, 0])
        box = f'<geometry><box size="{_vec(size)}"/></geometry>'
        links.append(f"""  <link name="{name}">
    <inertial><origin xyz="{centre}"/><mass value="{jaw_mass:.6g}"/>{_box_inertia(jaw_mass, size)}</inertial>
    <visual><origin xyz="{centre}"/>{box}</visual>
    <collision><origin xyz="{centre}"/>{box}</collision>
  </link>
  <joint name="{name}" type="revolute">
    <parent link="shaft"/><child link="{name}"/>
    <origin xyz="0 0 0"/><axis xyz="0 0 1"/>
    <limit lower="{low:.9g}" upper="{high:.9g}" effort="1" velocity="10"/>
  </joint>""")
    return f"""<?xml version="1.0"?>
<!-- Exported by surgsplat export --sim. Units: metres, kilograms, radians; scene lengths were in
     {unit}, scale = {scale:g} m per {unit}. Frame: the shaft frame (origin at the hinge, x from the
     shaft into the jaws, z the hinge axis); a jaw's angle is its turn about z from x. -->
<robot name="grasper">
{chr(10).join(links)}
</robot>
"""


def write_sim_scene(folder: Path, articulation: dict, index: int, tissue: FrameMesh,
                    gaussians: GaussianState, view_direction: np.ndarray, right: np.ndarray,
                    unit: str, options: SimOptions = SimOptions()) -> dict:
    """Write the frame `index`'s simulation scene into `folder` (see the module docstring);
    `tissue` and `gaussians` in the scene's world frame and unit; view_direction, right: the
    frame camera's z and x axes in the world. Returns sim.json's content."""
    scale = metres_per_unit(unit)
    if len(tissue.faces) == 0:
        raise SurgsplatError(f"frame {index}: the tissue mesh is empty; nothing to collide with")
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    tool = ToolModel.from_articulation(articulation, index, scale, options.limit_margin_deg)
    vertices = tissue.vertices.astype(np.float64) * scale
    down = into_tissue(vertices, view_direction)
    field = height_field(vertices, down, right, options.grid_step)
    gravity = 9.81 * down
    write_mesh(replace(tissue, vertices=vertices.astype(np.float32)), folder / "tissue.obj")
    write_text_atomic(folder / "scene.xml", mjcf(tool, field, gravity, scale, unit, index,
                                                options))
    write_text_atomic(folder / "tool.urdf", urdf(tool, scale, unit))
    write_gaussian_ply(gaussians.replace(means=gaussians.means * scale,
                                         scales=gaussians.scales * scale),
                       folder / "gaussians.ply")
    meta = {"frame": index, "scale_m_per_unit": scale, "scene_unit": unit, "units": "SI (m, kg, s, rad)",
            "world": "the scene's world frame, scaled to metres",
            "files": {"mjcf": "scene.xml", "urdf": "tool.urdf", "tissue_mesh": "tissue.obj",
                      "gaussians": "gaussians.ply"},
            "joints": {name: {"limits_rad": list(limits), "angle_rad": angle}
                       for name, limits, angle in zip(JAW_NAMES, tool.limits, tool.angles)},
            "tissue_collider": {"type": "hfield", "rows": int(field.heights.shape[0]),
                                "cols": int(field.heights.shape[1]),
                                "grid_step_m": options.grid_step},
            "gravity": gravity.tolist(), "tissue_faces": int(len(tissue.faces)),
            "gaussians": int(gaussians.means.shape[0])}
    write_text_atomic(folder / "sim.json", json.dumps(meta, indent=1) + "\n")
    return meta
