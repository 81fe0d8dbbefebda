"""Replays recorded calls of a native module on another build of it, with NumPy only (no torch,
no surgsplat), so that it runs in an aarch64 Python under qemu-aarch64 as well as on the host.

    python native_replay.py MODULE_FILE CALLS_DIR OUT_DIR

CALLS_DIR/calls.json lists the calls in order: {"function": name, "args": [spec, ...]}, where a
spec is ["array", file] (an .npy file in CALLS_DIR, the array as it was before the call), ["list",
[spec, ...]], ["result", i] (the object call i returned, e.g. the rasteriser's tile bins) or
["scalar", value]. Every array argument is written to OUT_DIR/<file> after the call (the kernels
write their outputs into arguments), and the calls' number returns (a float or int, or a tuple of
them, as a list) to OUT_DIR/returns.json.
"""

import importlib.util
import json
import sys
from pathlib import Path

import numpy as np


def load_module(path: Path):
    name = path.name.split(".")[0]  # _native_<isa>, which its PyInit_ function is named after
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def replay(module, calls_dir: Path, out_dir: Path) -> None:
    calls = json.loads((calls_dir / "calls.json").read_text())
    results, returns = {}, {}
    for index, call in enumerate(calls):
        arrays = {}

        def value(spec):
            kind, content = spec
            if kind == "array":
                arrays[content] = np.load(calls_dir / content)
                return arrays[content]
            if kind == "list":
                return [value(item) for item in content]
            if kind == "result":
                return results[content]
            return content

        results[index] = getattr(module, call["function"])(*[value(s) for s in call["args"]])
        numbers = results[index] if isinstance(results[index], tuple) else (results[index],)
        if all(isinstance(number, (int, float)) for number in numbers):
            returns[str(index)] = list(numbers)
        for name, array in arrays.items():
            np.save(out_dir / name, array)
    (out_dir / "returns.json").write_text(json.dumps(returns))


if __name__ == "__main__":
    replay(load_module(Path(sys.argv[1])), Path(sys.argv[2]), Path(sys.argv[3]))
