"""Whether a change of the code leaves training bit-identical: every preset trained a few
iterations on the small phantom, on one thread, and everything that training produced written
to a file (the checkpoint's state: parameters, buffers, component state, optimiser moments,
densification statistics, random generators; every step's loss and loss terms; the colour,
depth and extra channels of the first test frame rendered at the end). Run it before a change
and after it, then compare the two files: equality is torch.equal, no tolerance.

    python benchmarks/identical_training.py --out before.pt [--iterations 12] [--presets ...]
                                            [--set densify.every=4 ...]
    python benchmarks/identical_training.py --out after.pt
    python benchmarks/identical_training.py --compare before.pt after.pt

Both runs must be on one machine (the kernels' ISA variant and the thread count decide the
float rounding).
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import tempfile
from pathlib import Path

import surgsplat  # noqa: F401  (before torch: sets OpenMP's wait policy, see surgsplat/__init__)
import torch
from surgsplat.data.phantom import PhantomConfig, generate_phantom
from surgsplat.data.scene import load_scene
from surgsplat.methods.overrides import build_method_config
from surgsplat.methods.registry import PRESETS
from surgsplat.model.component import FrameTime
from surgsplat.model.dynamic import render_frame
from surgsplat.render import native
from surgsplat.train.trainer import Trainer

VARYING = ("elapsed_seconds", "peak_rss_mb")
"""State entries that measure the machine, not the training."""


def flattened(value, key: str = "") -> dict[str, torch.Tensor]:
    """Every tensor and number in `value` (nested dicts, lists, tuples and dataclasses) by
    dotted key, numbers as 0-d float64 tensors."""
    if isinstance(value, torch.Tensor):
        return {key: value.detach()}
    if isinstance(value, bool | int | float):
        return {key: torch.tensor(float(value), dtype=torch.float64)}
    if dataclasses.is_dataclass(value):
        value = vars(value)
    items = (value.items() if isinstance(value, dict)
             else enumerate(value) if isinstance(value, list | tuple) else ())
    return {name: tensor for part, entry in items
            for name, tensor in flattened(entry, f"{key}.{part}" if key else str(part)).items()}


def trained_digest(preset: str, scene_dir: Path, iterations: int,
                   settings: list[str]) -> dict[str, torch.Tensor]:
    """What `iterations` steps of `preset` with `settings` (`--set` assignments) produce, by
    dotted key (see the module doc)."""
    config = build_method_config(preset, None, [*settings, f"train.iterations={iterations}"])
    with tempfile.TemporaryDirectory() as run_dir:
        trainer = Trainer(config, load_scene(scene_dir), Path(run_dir))
        steps = [trainer.step() for _ in range(iterations)]
        state = {key: value for key, value in trainer.state_dict().items() if key not in VARYING}
        frame = trainer.scene.test_frames[0]
        rendered = render_frame(trainer.model, frame.camera, FrameTime(frame.index, frame.time))
    log = {f"step{step.iteration}": {"loss": step.loss, "psnr": step.psnr, **step.terms}
           for step in steps}
    return {**flattened(state, "state"), **flattened(log, "log"),
            **flattened(rendered, "render")}


def compare(before: dict, after: dict) -> list[str]:
    """Per preset, the keys whose tensors differ, are missing or are new."""
    lines = []
    for preset in sorted(before.keys() | after.keys()):
        old, new = before.get(preset, {}), after.get(preset, {})
        differing = [key for key in sorted(old.keys() & new.keys())
                     if old[key].shape != new[key].shape or not torch.equal(old[key], new[key])]
        missing, added = sorted(old.keys() - new.keys()), sorted(new.keys() - old.keys())
        for label, keys in (("differ", differing), ("missing", missing), ("new", added)):
            if keys:
                shown = ", ".join(keys[:6]) + (f" and {len(keys) - 6} more" if len(keys) > 6
                                              else "")
                lines.append(f"{preset}: {len(keys)} {label}: {shown}")
    return lines


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, help="write the digests of every preset here")
    parser.add_argument("--compare", type=Path, nargs=2, metavar=("BEFORE", "AFTER"))
    parser.add_argument("--iterations", type=int, default=12)
    parser.add_argument("--presets", nargs="+", default=sorted(PRESETS))
    parser.add_argument("--set", action="append", default=[], dest="settings",
                        help="a setting of every preset, as `train --set` takes it (e.g. "
                             "densify.every=4 to densify within the few iterations)")
    args = parser.parse_args()
    if args.compare:
        differences = compare(*(torch.load(path) for path in args.compare))
        print("\n".join(differences) or "identical: every tensor of every preset is equal")
        sys.exit(1 if differences else 0)
    if args.out is None:
        parser.error("give --out FILE or --compare BEFORE AFTER")
    torch.set_num_threads(1)
    native.set_threads(1)
    with tempfile.TemporaryDirectory() as work:
        scene_dir = generate_phantom(PhantomConfig(preset="small", motion="pulling"),
                                     Path(work) / "phantom")
        digests = {}
        for preset in args.presets:
            digests[preset] = trained_digest(preset, scene_dir, args.iterations, args.settings)
            print(f"{preset}: {len(digests[preset])} tensors", file=sys.stderr)
    torch.save(digests, args.out)
    print(f"written to {args.out}")


if __name__ == "__main__":
    main()
