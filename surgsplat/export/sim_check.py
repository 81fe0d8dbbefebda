"""Run an exported simulation scene in MuJoCo and PyBullet and measure what it does.

- `jaw_sweep`: from the scene's "frame" keyframe, each jaw's position actuator is commanded
  through its whole joint range and back (a cosine sweep over the given number of steps); the
  trace of commanded and achieved angles, the tracking error after the first `settle` steps,
  how far the joints ever leave their limits, and whether the state stayed finite.
- `probe_drop`: a sphere dropped from above the tissue (against gravity) over the hollow of
  the tissue's collider nearest its middle, simulated until it rests; its final speed and its
  distance to the mesh surface (sphere centre to nearest mesh point, minus the radius).
- `urdf_sweep`: the tool.urdf in PyBullet (DIRECT mode), each jaw driven to the ends of its
  range by position control; the angles reached.

The engines come with the optional extra `sim` (`pip install -e .[sim]`).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from surgsplat.errors import SurgsplatError
from surgsplat.eval.geometry_metrics import point_to_surface


def _engine(name: str):
    """Import the simulation package `name`; SurgsplatError naming the extra when missing."""
    try:
        return __import__(name)
    except ImportError:
        raise SurgsplatError(f"{name} is not installed; install the optional extra: "
                             "pip install -e .[sim]") from None


def load_mujoco(scene_xml: Path):
    """(model, data) of an MJCF file, reset to its "frame" keyframe."""
    mujoco = _engine("mujoco")
    model = mujoco.MjModel.from_xml_path(str(scene_xml))
    data = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, data, 0)
    mujoco.mj_forward(model, data)
    return model, data


def jaw_sweep(scene_xml: Path, steps: int = 1000, settle: int = 100) -> dict:
    """Sweep both jaws through their ranges (see the module docstring)."""
    mujoco = _engine("mujoco")
    model, data = load_mujoco(scene_xml)
    ranges = model.actuator_ctrlrange.copy()  # [A, 2]
    joints = model.actuator_trnid[:, 0]
    addresses = model.jnt_qposadr[joints]
    limits = model.jnt_range[joints]
    start = data.qpos[addresses].copy()
    commanded, achieved = np.zeros((steps, len(joints))), np.zeros((steps, len(joints)))
    finite = True
    for step in range(steps):
        phase = 2 * np.pi * step / steps  # low -> high -> low, starting from the frame's angle
        target = ranges[:, 0] + (ranges[:, 1] - ranges[:, 0]) * (1 - np.cos(phase)) / 2
        blend = min(step / settle, 1.0)
        data.ctrl[:] = (1 - blend) * start + blend * target
        mujoco.mj_step(model, data)
        commanded[step], achieved[step] = data.ctrl, data.qpos[addresses]
        finite &= bool(np.isfinite(data.qpos).all() and np.isfinite(data.qvel).all())
    error = np.abs(np.degrees(achieved - commanded))[settle:]
    beyond = np.maximum(limits[:, 0] - achieved, achieved - limits[:, 1]).max()
    samples = np.linspace(0, steps - 1, 9).astype(int)
    return {"steps": steps, "timestep_s": float(model.opt.timestep),
            "names": [model.actuator(i).name for i in range(model.nu)],
            "range_deg": np.degrees(ranges).tolist(),
            "max_tracking_error_deg": float(error.max()),
            "mean_tracking_error_deg": float(error.mean()),
            "max_beyond_limits_deg": float(max(np.degrees(beyond), 0.0)),
            "finite": finite,
            "trace": {"step": samples.tolist(),
                      "commanded_deg": np.degrees(commanded[samples]).round(3).tolist(),
                      "achieved_deg": np.degrees(achieved[samples]).round(3).tolist()}}


def probe_drop(scene_xml: Path, tissue_obj: Path, radius: float = 2e-3, height: float = 0.005,
               steps: int = 1500) -> dict:
    """Drop a probe sphere of `radius` (m), with rolling friction, over a hollow of the
    tissue from `height` (m) above the highest tissue point, for `steps` steps (see the module
    docstring)."""
    mujoco = _engine("mujoco")
    trimesh = _engine("trimesh")
    tissue = trimesh.load(str(tissue_obj), process=False, force="mesh")
    spec = mujoco.MjSpec.from_file(str(scene_xml))
    model = spec.compile()
    gravity = np.array(model.opt.gravity)
    down = gravity / np.linalg.norm(gravity)
    vertices = np.asarray(tissue.vertices)
    hollow = _hollow(model, mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM,
                                              "tissue_collider"), down, vertices, radius)
    above = float(((hollow - vertices) @ down).max())  # the highest tissue above the hollow
    start = hollow - (above + height + radius) * down
    body = spec.worldbody.add_body(name="probe", pos=start.tolist())
    body.add_freejoint()
    body.add_geom(type=mujoco.mjtGeom.mjGEOM_SPHERE, size=[radius, 0, 0], density=1000.0,
                  contype=1, conaffinity=1, condim=6,  # touches the tissue only
                  friction=[1.0, 0.05, 0.05],  # rolling friction: it settles
                  solref=[4 * model.opt.timestep, 1.0])  # stiff: MuJoCo's default 20 ms
    # contact time constant lets a falling probe sink metres-per-second x 20 ms deep
    for key in spec.keys:  # the probe's free joint comes after the jaws in qpos
        key.qpos = [*key.qpos, *start, 1.0, 0.0, 0.0, 0.0]
    model = spec.compile()
    data = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, data, 0)
    probe = model.body("probe").id
    for _ in range(steps):
        mujoco.mj_step(model, data)
    position = data.xpos[probe].copy()
    speed = float(np.linalg.norm(data.cvel[probe][3:]))
    distance = point_to_surface(position[None], vertices, np.asarray(tissue.faces))
    return {"start_m": start.tolist(), "rest_m": position.tolist(), "radius_m": radius,
            "fell_m": float((position - start) @ down), "speed_m_s": speed,
            "contact_distance_mm": float((distance[0] - radius) * 1e3),
            "finite": bool(np.isfinite(data.qpos).all())}


def _hollow(model, geom: int, down: np.ndarray, vertices: np.ndarray, radius: float,
            window: int = 21) -> np.ndarray:
    """[3] world point of the tissue height field where a ball of `radius` settles on the mesh
    `vertices` [V, 3]: among the grid points whose surroundings (the ball's footprint) the mesh
    covers (no hole, which the height field bridges), at least `window` cells from the border,
    the ones deepest along `down` in their `window` x `window` neighbourhood (heights smoothed
    over a quarter window: broad valleys, not narrow grooves), the one nearest the grid's
    centre; without such a hollow, the deepest covered point."""
    from scipy.ndimage import binary_erosion, gaussian_filter, maximum_filter
    from scipy.spatial import cKDTree

    mujoco = _engine("mujoco")
    field = model.geom_dataid[geom]
    rows, cols = model.hfield_nrow[field], model.hfield_ncol[field]
    size = model.hfield_size[field]
    first = model.hfield_adr[field]
    heights = model.hfield_data[first:first + rows * cols].reshape(rows, cols) * size[2]
    ys, xs = np.meshgrid(np.linspace(-size[1], size[1], rows),
                         np.linspace(-size[0], size[0], cols), indexing="ij")
    local = np.stack([xs, ys, heights], axis=-1)  # [rows, cols, 3] row 0 at the smallest y
    rotation = np.empty(9)
    mujoco.mju_quat2Mat(rotation, model.geom_quat[geom])
    world = local @ rotation.reshape(3, 3).T + model.geom_pos[geom]  # [rows, cols, 3]
    step = 2 * size[0] / max(cols - 1, 1)
    distance, _ = cKDTree(vertices).query(world.reshape(-1, 3))
    covered = (distance <= 1.5 * step).reshape(rows, cols)
    footprint = max(int(np.ceil(2 * radius / step)), 1)
    covered = binary_erosion(covered, np.ones((2 * footprint + 1,) * 2))
    covered[:window], covered[-window:], covered[:, :window], covered[:, -window:] = (False,) * 4
    if not covered.any():
        raise SurgsplatError("the tissue mesh has no place wide enough for the probe")
    depth = gaussian_filter(world @ down, sigma=window / 4)
    settled = covered & (depth >= maximum_filter(depth, size=window, mode="nearest"))
    if not settled.any():
        settled = covered & (depth == depth[covered].max())
    row, col = np.nonzero(settled)
    nearest = np.argmin((row / rows - 0.5) ** 2 + (col / cols - 0.5) ** 2)
    return world[row[nearest], col[nearest]]


def urdf_sweep(tool_urdf: Path, steps: int = 480) -> dict:
    """Drive each jaw of tool.urdf to its lower then upper limit in PyBullet (DIRECT)."""
    pybullet = _engine("pybullet")
    client = pybullet.connect(pybullet.DIRECT)
    try:
        robot = pybullet.loadURDF(str(tool_urdf), useFixedBase=True, physicsClientId=client)
        joints = [j for j in range(pybullet.getNumJoints(robot, physicsClientId=client))
                  if pybullet.getJointInfo(robot, j, physicsClientId=client)[2]
                  == pybullet.JOINT_REVOLUTE]
        limits = [pybullet.getJointInfo(robot, j, physicsClientId=client)[8:10] for j in joints]
        reached = {}
        for end in (0, 1):
            for joint, limit in zip(joints, limits):
                pybullet.setJointMotorControl2(robot, joint, pybullet.POSITION_CONTROL,
                                               targetPosition=limit[end], force=1.0,
                                               physicsClientId=client)
            for _ in range(steps // 2):
                pybullet.stepSimulation(physicsClientId=client)
            reached["upper" if end else "lower"] = [
                pybullet.getJointState(robot, j, physicsClientId=client)[0] for j in joints]
        return {"joints": [pybullet.getJointInfo(robot, j, physicsClientId=client)[1].decode()
                           for j in joints],
                "limits_rad": [list(limit) for limit in limits], "reached_rad": reached}
    finally:
        pybullet.disconnect(client)
