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
from surgsplat.export.mesh import MAX_RESOLUTION, MESH_FORMATS, MIN_RESOLUTION, MeshOptions
from surgsplat.model.component import FrameTime
from surgsplat.pipeline.export import Moment, export_meshes, export_ply, export_sim
from surgsplat.pipeline.run_folders import claim_output_folder, load_run
from surgsplat.train.run import run_lock


def frame_indices(text: str, count: int) -> list[int]:
    """--frames "all" or "i,j,..." -> the frame indices, each in [0, count) and named once;
    SurgsplatError otherwise."""
    if text == "all":
        return list(range(count))
    try:
        indices = [int(part) for part in text.split(",") if part.strip()]
    except ValueError:
        raise SurgsplatError(f"--frames: expected 'all' or frame indices like 0,8,16; got "
                             f"{text!r}") from None
    if not indices or any(not 0 <= i < count for i in indices):
        raise SurgsplatError(f"--frames: the scene has frames 0..{count - 1}; got {text!r}")
    repeated = sorted({i for i in indices if indices.count(i) > 1})
    if repeated:
        raise SurgsplatError(f"--frames: frame {repeated[0]} is named more than once in "
                             f"{text!r}; name each frame once")
    return indices


def chosen_moments(scene: Scene, frames: str | None, time: float | None) -> list[Moment]:
    """(file stem, moment) pairs: frames "all" (None) or "i,j,..." (`frame_indices`), or one
    time T in [0, 1] (the nearest frame's index goes with it)."""
    count = len(scene.frames)
    if time is not None:
        index = min(round(time * count), count - 1)
        return [(f"time_{time:.4f}", FrameTime(index, time))]
    return [(frame_stem(i), FrameTime(i, scene.frames[i].time))
            for i in frame_indices("all" if frames is None else frames, count)]


def check_export_options(ply: bool, mesh: bool, sim: Path | None, frames: str | None,
                         time: float | None, frame: int | None, out: Path | None,
                         mesh_format: str, options: MeshOptions) -> None:
    """SurgsplatError for a choice of options that exports nothing, that one of them would be
    ignored in (--frames with --time, either without --ply or --mesh, --frame without --sim),
    whose files would overwrite each other (--ply and --mesh --format ply into one --out), or
    with a value out of its range."""
    if not (ply or mesh or sim):
        raise SurgsplatError("nothing to export: pass --ply, --mesh and/or --sim DIR")
    if time is not None and frames is not None:
        raise SurgsplatError("--frames and --time both choose the moments to export; pass one")
    if time is not None and not 0.0 <= time <= 1.0:
        raise SurgsplatError(f"--time must be in [0, 1], got {time}")
    if (time is not None or frames is not None) and not (ply or mesh):
        raise SurgsplatError("--frames and --time choose what --ply and --mesh export; --sim "
                             "exports the one --frame")
    if frame is not None and not sim:
        raise SurgsplatError("--frame chooses the frame --sim exports; --ply and --mesh export "
                             "--frames or --time")
    if mesh_format not in MESH_FORMATS:
        raise SurgsplatError(f"--format: expected one of {', '.join(MESH_FORMATS)}, got "
                             f"{mesh_format!r}")
    if ply and mesh and out is not None and mesh_format == "ply":
        raise SurgsplatError("--ply and --mesh --format ply would write the same file names into "
                             "one --out; export them one at a time, or leave out --out")
    if not MIN_RESOLUTION <= options.resolution <= MAX_RESOLUTION:
        raise SurgsplatError(f"--mesh-resolution must be in {MIN_RESOLUTION}..{MAX_RESOLUTION} "
                             f"(memory grows with its cube), got {options.resolution}")
    if not options.fit_radius >= 0:
        raise SurgsplatError(f"--mesh-fit-radius must be >= 0, got {options.fit_radius}")


def export_command(
    run_dir: Annotated[Path, typer.Argument(help="Run folder written by `surgsplat train`.")],
    ply: Annotated[bool, typer.Option(
        "--ply", help="Write the Gaussians at each chosen moment as a standard 3D Gaussian "
                      "Splatting PLY (binary little-endian float32: x y z, nx ny nz, f_dc_*, "
                      "f_rest_*, opacity logit, log scale_*, rot_* wxyz), the layout that "
                      "SuperSplat, the gsplat.js and antimatter15 web viewers and nerfstudio's "
                      "splat tools open.")] = False,
    frames: Annotated[str | None, typer.Option(
        help="Frames --ply and --mesh export: 'all' (default) or frame indices, each once, e.g. "
             "0,8,16.")] = None,
    time: Annotated[float | None, typer.Option(
        help="One time in [0, 1] that --ply and --mesh export, instead of --frames.")] = None,
    mesh: Annotated[bool, typer.Option(
        "--mesh", help="Write the tissue surface at each chosen moment as a triangle mesh in the "
                       "scene's unit and world frame, cropped to what the frame's camera sees: "
                       "marching cubes of the signed distance field for methods that have one, "
                       "the rendered depth triangulated for the others.")] = False,
    mesh_resolution: Annotated[int, typer.Option(
        help=f"Marching-cubes cells along the SDF box's longest side, {MIN_RESOLUTION} to "
             f"{MAX_RESOLUTION} (memory grows with its cube: 0.3 GB at the default, 5.4 GB at "
             f"{MAX_RESOLUTION}).")] = MeshOptions.resolution,
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
                      "written first when missing. A new or empty folder, or one surgsplat "
                      "wrote into before.")] = None,
    frame: Annotated[int | None, typer.Option(help="The frame --sim exports (default 0).")]
        = None,
    out: Annotated[Path | None, typer.Option(
        help="Folder (default RUN/export/ply and RUN/export/mesh): a new or empty one, or one "
             "surgsplat wrote into before.")] = None,
    data: Annotated[Path | None, typer.Option(
        help="Scene folder (default: the run's; its content must be the run's scene).")] = None,
) -> None:
    """Export a trained run's deformed Gaussians, tissue meshes and simulation scenes."""
    options = MeshOptions(resolution=mesh_resolution, fit_radius=mesh_fit_radius)
    check_export_options(ply, mesh, sim, frames, time, frame, out, mesh_format, options)
    console = Console()
    ply_folder = out or Path(run_dir) / "export" / "ply"
    mesh_folder = out or Path(run_dir) / "export" / "mesh"
    with run_lock(run_dir):
        run = load_run(run_dir, data)
        moments = chosen_moments(run.scene, frames, time)
        for chosen, folder, option, writes in (
                (ply, ply_folder, "--out", "export --ply writes 000000.ply, ..."),
                (mesh, mesh_folder, "--out", f"export --mesh writes 000000.{mesh_format}, ..."),
                (sim, sim, "--sim", ("export --sim writes scene.xml, tool.urdf, tissue.obj, "
                                     "gaussians.ply and sim.json"))):
            if chosen:
                claim_output_folder(folder, run_dir, option, writes)
        if ply:
            export_ply(run, moments, ply_folder)
            console.print(f"{len(moments)} PLY file(s), {run.model.gaussians.num_gaussians} "
                          f"Gaussians each, in {ply_folder}")
        if mesh:
            route, faces = export_meshes(run, moments, mesh_folder, options, mesh_format)
            console.print(f"{len(moments)} mesh file(s) ({route} route, {faces} faces on "
                          f"average) in {mesh_folder}")
        if sim:
            index = frame or 0
            meta = export_sim(run, sim, index, options)
            console.print(f"simulation scene of frame {index} in {sim}: scene.xml (MJCF), "
                          f"tool.urdf, tissue.obj ({meta['tissue_faces']} faces), gaussians.ply "
                          f"({meta['gaussians']} Gaussians); scale "
                          f"{meta['scale_m_per_unit']:g} m per {meta['scene_unit']}",
                          markup=False, highlight=False)
