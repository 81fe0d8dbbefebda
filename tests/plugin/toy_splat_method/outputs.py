"""The toy method's metric family and product after training: the mean rendered sheen over the
tissue of the scored frames, and RUN/sheen.json with the Gaussians' sheen quartiles. Both apply
to every model with a component that provides SheenSource."""

from __future__ import annotations

import json

import torch

from surgsplat.eval.metric_family import FrameView, MetricFamily
from surgsplat.pipeline.products import RunProduct
from surgsplat.train.run import TrainedRun
from toy_splat_method.method import SHEEN, SheenSource

SHEEN_FILE = "sheen.json"


class SheenFamily(MetricFamily):
    """sheen_tissue: the rendered sheen's mean over a frame's tissue pixels."""

    name = "sheen"

    def score(self, view: FrameView) -> dict[str, float]:
        if view.run.model.find(SheenSource) is None:
            return {}
        sheen = view.render.extras["sheen"][..., 0]
        return {"sheen_tissue": float(sheen[view.frame.tissue].mean())}

    def conventions(self) -> dict[str, str]:
        return {"sheen_tissue": "mean rendered sheen over the tissue pixels"}


def write_sheen_quartiles(run: TrainedRun) -> str:
    """RUN/sheen.json: the quartiles of the Gaussians' sheen; one line saying so."""
    sheen = torch.sigmoid(run.model.gaussians.params[SHEEN].detach())
    quartiles = torch.quantile(sheen, torch.tensor([0.25, 0.5, 0.75])).tolist()
    (run.run_dir / SHEEN_FILE).write_text(json.dumps({"quartiles": quartiles}))
    return f"sheen quartiles: {run.run_dir / SHEEN_FILE}"


SHEEN_QUARTILES = RunProduct("sheen quartiles",
                             applies=lambda model: model.find(SheenSource) is not None,
                             make=write_sheen_quartiles)
