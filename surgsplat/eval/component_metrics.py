"""The metrics a method's components contribute themselves (`Component.frame_diagnostics`, e.g.
tool collisions or strain), with the conventions each component states for them."""

from __future__ import annotations

from surgsplat.eval.metric_family import EvalOptions, MetricFamily, FrameView
from surgsplat.train.run import TrainedRun


class ComponentFamily(MetricFamily):
    """The components' measurements of the Gaussians at each test frame: their averaged values
    are scored per frame, their summed ones (counts) pooled over the frames."""

    name = "diagnostics"

    def __init__(self, run: TrainedRun, options: EvalOptions):
        super().__init__(run, options)
        self.summed: dict[str, float] = {}  # counts stay int
        self.stated: dict[str, str] = {}  # the components' conventions

    def score(self, view: FrameView) -> dict[str, float]:
        diagnostics = view.run.model.diagnostics(view.when)
        for key, value in diagnostics.summed.items():
            self.summed[key] = self.summed.get(key, 0) + value
        self.stated.update(diagnostics.conventions)
        return diagnostics.averaged

    def pooled(self) -> dict:
        return dict(self.summed)

    def conventions(self) -> dict[str, str]:
        return dict(self.stated)
