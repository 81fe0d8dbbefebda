"""`surgsplat export RUN --ply | --mesh | --sim DIR`: the deformed Gaussians of chosen frames as
3DGS PLY files, the tissue surface of chosen frames as triangle meshes, and one frame as a
simulation scene (MJCF + URDF + PLY, see `export.sim`)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console

from surgsplat.data.layout import frame_stem
from surgsplat.data.scene import Scene
from surgsplat.errors import SurgsplatError
from surgsplat.export.mesh import MESH_FORMATS, MeshOptions
from surgsplat.model.component import FrameTime
from surgsplat.pipeline.export import Moment, export_meshes, export_ply, export_sim
from surgsplat.train.run import load_trained_run, run_lock


def chosen_moments(scene: Scene, frames: str, time: float | None) -> list[Moment]:
    """(file stem, moment) pairs: frames "all" or "i,j,...", or one time T in [0, 1] (the
    nearest frame's index goes with it)."""
    count = len(scene.frames)
    if time is not None:
        if not 0.0 <= time <= 1.0:
            raise SurgsplatError(f"--time must be in [0, 1], got {time}")
        index = min(round(time * count), count - 1)
        return [(f"time_{time:.4f}", FrameTime(index, time))]
    if frames == "all":
        indices = list(range(count))
    else:
        try:
            indices = [int(part) for part in frames.split(",") if part.strip()]
        except ValueError:
            raise SurgsplatError(f"--frames: expected 'all' or frame indices like 0,8,16; got "
                                 f"{frames!r}") from None
        bad = [i for i in indices if not 0 <= i < count]
        if bad or not indices:
            raise SurgsplatError(f"--frames: the scene has frames 0..{count - 1}; got {frames!r}")
    return [(frame_stem(i), FrameTime(i, scene.frames[i].time)) for i in indices]


def export_command(
    run_dir: Annotated[Path, typer.Argument(help="Run folder written by `surgsplat train`.")],
    ply: Annotated[bool, typer.Option(
        "--ply", help="Write the Gaussians at each chosen moment as a standard 3D Gaussian "
                      "Splatting PLY (binary little-endian float32: x y z, nx ny nz, f_dc_*, "
                      "f_rest_*, opacity logit, log scale_*, rot_* wxyz), the layout that "
                      "SuperSplat, the gsplat.js and antimatter15 web viewers and nerfstudio's "
                      "splat tools open.")] = False,
    frames: Annotated[str, typer.Option(help="'all' or frame indices, e.g. 0,8,16.")] = "all",
    time: Annotated[float | None, typer.Option(
        help="One time in [0, 1] instead of --frames.")] = None,
    mesh: Annotated[bool, typer.Option(
        "--mesh", help="Write the tissue surface at each chosen moment as a triangle mesh in the "
                       "scene's unit and world frame, cropped to what the frame's camera sees: "
                       "marching cubes of the signed distance field for methods that have one, "
                       "the rendered depth triangulated for the others.")] = False,
    mesh_resolution: Annotated[int, typer.Option(
        help="Marching-cubes cells along the SDF box's longest side.")] = MeshOptions.resolution,
    mesh_fit_radius: Annotated[float, typer.Option(
        help="SDF meshes: each vertex moves along its normal onto the canonical tissue "
             "Gaussians within this many marching-cubes cells; 0 (default) keeps the SDF's "
             "zero level.")] = MeshOptions.fit_radius,
    mesh_format: Annotated[str, typer.Option(
        "--format", help=f"Mesh file format: {', '.join(MESH_FORMATS)}.")] = "ply",
    sim: Annotated[Path | None, typer.Option(
        "--sim", help="Write one frame as a simulation scene into this folder: scene.xml (MJCF: "
                      "tissue collider + visual mesh, grasper with revolute jaws and position "
                      "actuators), tool.urdf, tissue.obj, gaussians.ply and sim.json, in metres. "
                      "Needs a method with a tool field; RUN/articulation.json is estimated and "
                      "written first when missing.")] = None,
    frame: Annotated[int, typer.Option(help="The frame --sim exports.")] = 0,
    out: Annotated[Path | None, typer.Option(
        help="Folder (default RUN/export/ply and RUN/export/mesh).")] = None,
    data: Annotated[Path | None, typer.Option(
        help="Scene folder (default: the run's; its content must be the run's scene).")] = None,
) -> None:
    """Export a trained run's deformed Gaussians, tissue meshes and simulation scenes."""
    if not (ply or mesh or sim):
        raise SurgsplatError("nothing to export: pass --ply, --mesh and/or --sim DIR")
    if mesh_format not in MESH_FORMATS:
        raise SurgsplatError(f"--format: expected one of {', '.join(MESH_FORMATS)}, got "
                             f"{mesh_format!r}")
    if mesh_resolution < 8:
        raise SurgsplatError(f"--mesh-resolution must be at least 8, got {mesh_resolution}")
    if not mesh_fit_radius >= 0:
        raise SurgsplatError(f"--mesh-fit-radius must be >= 0, got {mesh_fit_radius}")
    options = MeshOptions(resolution=mesh_resolution, fit_radius=mesh_fit_radius)
    console = Console()
    with run_lock(run_dir):
        run = load_trained_run(run_dir, data)
        moments = chosen_moments(run.scene, frames, time)
        if ply:
            folder = out or Path(run_dir) / "export" / "ply"
            export_ply(run, moments, folder)
            console.print(f"{len(moments)} PLY file(s), {run.model.gaussians.num_gaussians} "
                          f"Gaussians each, in {folder}")
        if mesh:
            folder = out or Path(run_dir) / "export" / "mesh"
            route, faces = export_meshes(run, moments, folder, options, mesh_format)
            console.print(f"{len(moments)} mesh file(s) ({route} route, {faces} faces on "
                          f"average) in {folder}")
        if sim:
            meta = export_sim(run, sim, frame, options)
            console.print(f"simulation scene of frame {frame} in {sim}: scene.xml (MJCF), "
                          f"tool.urdf, tissue.obj ({meta['tissue_faces']} faces), gaussians.ply "
                          f"({meta['gaussians']} Gaussians); scale "
                          f"{meta['scale_m_per_unit']:g} m per {meta['scene_unit']}",
                          markup=False, highlight=False)
