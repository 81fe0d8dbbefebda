"""Which scene a run may be read with, and which folders a command may write into.

A run is read with its own scene only: a scene passed in its place (`--data`) must match the
identity the run saved (RUN/scene.json). A command writes only into folders surgsplat owns: the
run folder and what lies inside it, or a folder that was absent or empty when a command claimed
it and marked it as surgsplat's (OWNED_MARK); train recognises its run folders by their own
files instead (`check_output_folder`'s `identifying`). A folder holding anything else holds a
user's files, which the command would replace.
"""

from __future__ import annotations

from pathlib import Path

from surgsplat.atomic import write_text_atomic
from surgsplat.errors import DataError, SurgsplatError
from surgsplat.train.run import TrainedRun, load_trained_run
from surgsplat.train.trainer import SCENE_FILE, SCENE_ID_FILE

OWNED_MARK = ".surgsplat"
"""FOLDER/.surgsplat: marks a folder outside any run that a surgsplat command created or found
empty and writes into (videos, exports), so that a later command may write into it again."""
OWNED_TEXT = "surgsplat writes into this folder and may replace its files of the same names\n"
"""What OWNED_MARK says to a user who opens it."""


def load_run(run_dir: Path, data: Path | None = None) -> TrainedRun:
    """The trained run in `run_dir` (`load_trained_run`), with its scene read from `data` when
    given; DataError when the run no longer holds the identity of its scene (RUN/scene.json) to
    check `data` against, since any scene of the same frame count would then pass as its own."""
    record = Path(run_dir) / SCENE_ID_FILE
    if data is not None and not record.is_file():
        raise DataError(record, f"missing: the run's record of its scene is gone, so --data "
                                f"{data} cannot be checked to be the scene it was trained on; "
                                f"leave out --data to use the scene named in "
                                f"{Path(run_dir) / SCENE_FILE}")
    return load_trained_run(run_dir, data)


def check_output_folder(folder: Path, option: str, writes: str,
                        identifying: tuple[str, ...] = (OWNED_MARK,),
                        kind: str = "a folder surgsplat writes into") -> None:
    """SurgsplatError naming `option` unless `folder` may receive a command's files: absent
    (or not a folder: creating it then fails and says so), empty, or holding every one of
    `identifying` (a folder of the same kind, written before). `writes` says what the command
    writes there, for the message."""
    folder = Path(folder)
    if not folder.is_dir() or not any(folder.iterdir()):
        return
    if not all((folder / name).is_file() for name in identifying):
        raise SurgsplatError(f"{folder}: is not empty and is not {kind}; choose a new or empty "
                             f"{option} ({writes} there, replacing files of the same name)")


def claim_output_folder(folder: Path, run_dir: Path, option: str, writes: str) -> None:
    """Make `folder` one that a command reading the run in `run_dir` may write into: a folder
    inside the run folder is the run's already; any other is checked (`check_output_folder`),
    then created and marked as surgsplat's (OWNED_MARK)."""
    folder = Path(folder)
    if folder.resolve().is_relative_to(Path(run_dir).resolve()):
        return
    check_output_folder(folder, option, writes)
    folder.mkdir(parents=True, exist_ok=True)
    if not (folder / OWNED_MARK).is_file():
        write_text_atomic(folder / OWNED_MARK, OWNED_TEXT)
