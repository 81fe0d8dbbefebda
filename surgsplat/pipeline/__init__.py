"""Pipelines over a run folder: train (train.py), articulate the tool (articulate.py), evaluate
(evaluate.py), render videos (render.py) and export (export.py). The `surgsplat` commands, the
batch stages and the tests call these functions; they print nothing (the caller shows progress
and notes through the callbacks it passes) and write the files they own."""
