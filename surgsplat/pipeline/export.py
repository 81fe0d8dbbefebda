"""Export a trained run: the deformed Gaussians of chosen moments as 3DGS PLY files, the tissue
surface of chosen moments as triangle meshes, and one frame as a simulation scene (see
`export.sim`)."""

from __future__ import annotations

from pathlib import Path

import torch

from surgsplat.errors import SurgsplatError
from surgsplat.export.articulation import ARTICULATION_FILE, tool_motion
from surgsplat.export.mesh import MeshExtractor, MeshOptions, write_mesh
from surgsplat.export.ply import write_gaussian_ply
from surgsplat.export.sim import write_sim_scene
from surgsplat.model.component import FrameTime
from surgsplat.pipeline.articulate import saved_or_new_articulation
from surgsplat.train.run import TrainedRun

Moment = tuple[str, FrameTime]
"""A moment to export: its file stem and its frame and time."""


def export_ply(run: TrainedRun, moments: list[Moment], folder: Path) -> None:
    """FOLDER/<stem>.ply: the run's Gaussians at each moment."""
    with torch.no_grad():
        for stem, when in moments:
            write_gaussian_ply(run.model.state_at(when), folder / f"{stem}.ply")


def export_meshes(run: TrainedRun, moments: list[Moment], folder: Path, options: MeshOptions,
                  mesh_format: str) -> tuple[str, int]:
    """FOLDER/<stem>.<mesh_format>: the tissue mesh at each moment; the meshes' route ("sdf"
    or "depth") and their mean face count."""
    extractor = MeshExtractor(run.model, options, run.background)
    faces = 0
    for stem, when in moments:
        frame_mesh = extractor.frame_mesh(run.scene.frames[when.index], when)
        write_mesh(frame_mesh, folder / f"{stem}.{mesh_format}")
        faces += len(frame_mesh.faces)
    return extractor.route, faces // max(len(moments), 1)


def export_sim(run: TrainedRun, folder: Path, index: int, options: MeshOptions) -> dict:
    """Frame `index` of `run` as a simulation scene in `folder` (RUN/articulation.json is
    estimated and written first when missing); the scene's sim.json content."""
    count = len(run.scene.frames)
    if not 0 <= index < count:
        raise SurgsplatError(f"--frame: the scene has frames 0..{count - 1}; got {index}")
    tool_motion(run)  # the method must have a tool to export
    articulation = saved_or_new_articulation(run)
    if len(articulation["frames"]) != count:
        raise SurgsplatError(f"{run.run_dir / ARTICULATION_FILE} describes "
                             f"{len(articulation['frames'])} frames, the scene has {count}; "
                             "delete it and run `surgsplat articulate RUN`")
    chosen = run.scene.frames[index]
    extractor = MeshExtractor(run.model, options, run.background)
    tissue_only = FrameTime(index, chosen.time, tissue_only=True)
    with torch.no_grad():
        tissue = extractor.frame_mesh(chosen, tissue_only)
        gaussians = run.model.state_at(FrameTime(index, chosen.time))
    camera_to_world = chosen.camera.camera_to_world.double().numpy()
    return write_sim_scene(folder, articulation, index, tissue, gaussians,
                           view_direction=camera_to_world[:3, 2], right=camera_to_world[:3, 0],
                           unit=run.scene.depth_unit)
