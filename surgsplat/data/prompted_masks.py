"""Tool masks from a person's clicks, carried through the clip (`surgsplat import --tool-prompts`).

A prompt file names, on one or more frames, points on the tools and optionally points on the
tissue (`read_prompts`). From them every frame's mask follows:

- *A unary* per pixel, its tool log-odds, learned on each prompted frame (`fit_model`): the
  log-likelihood ratio of its CIELAB colour (histograms of the tool's and the tissue's
  colours), plus that of the automatic segmenter's appearance log-odds
  (`auto_tool_masks.appearance_evidence`: how colourless and structured the pixel is against
  the frame) learned from the clicked pixels, plus those log-odds themselves, bounded and
  weighted by how much of an instrument the automatic segmenter found about the clicks.
  Nothing in it is fitted to a clip: the clicks say which statistics are the tool's, and
  whether the generic cues hold here. Tissue clicks weigh as much as all the other tissue.
- *Graph cuts* decide each frame: the unary against a contrast-sensitive Potts smoothness
  (Boykov and Jolly), solved exactly by max-flow (PyMaxflow). On a prompted frame the clicks
  are hard constraints; the first cut is of the automatic segmenter's log-odds, then the
  model and the cut are re-estimated in turns (GrabCut's scheme, with histograms), keeping
  the parts connected to a tool click.
- *Propagation*: the previous frame's mask, carried into the frame by dense optical flow (DIS)
  and blurred by the flow's uncertainty, is a prior added to the unary. Each frame is decided
  from its nearest prompted frame, forwards or backwards, with that frame's model; a new
  prompt re-anchors the clip from there.
- *A tool that returns*: where the prior is empty, a region of the cut is kept if it enters
  from the rim of the field of view (instruments come in from outside) and is not tiny, so a
  tool that left the view is found again from its appearance, without a new click.

Per-frame confidence (0..1): the mean decision margin |2 sigmoid(u) - 1| of the unary u over
the band of pixels next to the mask's boundary (where the cut was decided); 1 for a frame
whose unary nowhere favours the tool.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Iterable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path

import cv2
import maxflow
import numpy as np

from surgsplat.data.auto_tool_masks import (AutoMaskConfig, appearance_evidence, snap_to_edges,
                                            working_size)
from surgsplat.data.frame_motion import FlowEstimator, MotionConfig, warp_from
from surgsplat.errors import DataError, SurgsplatError


PROMPTED_CONFIDENCE_MEANING = ("0..1 per frame: mean decision margin |2 sigmoid(u) - 1| of the "
                               "tool log-odds u beside the mask's boundary; 1 = no pixel "
                               "favours the tool")
"""What a frame's confidence means, as scene.json records it."""


@dataclass(frozen=True)
class ToolPrompt:
    """One entry of a prompt file: clicks on one frame, in source-frame pixels."""

    frame: int
    """Position of the frame among the imported frames."""
    tool: tuple[tuple[float, float], ...]
    """(x, y) points on tools (at least one)."""
    tissue: tuple[tuple[float, float], ...] = ()
    """(x, y) points on tissue (optional)."""

    def describe(self) -> dict:
        """The entry as the prompt file writes it (for scene.json)."""
        return {"frame": self.frame, "tool": [list(point) for point in self.tool],
                "tissue": [list(point) for point in self.tissue]}


@dataclass
class PromptConfig:
    """How clicks become masks and how the masks are carried through the clip."""

    click_radius: float = 0.01
    """Radius of the disk a click marks as certain, as a share of the frame's width."""
    colour_bins: int = 16
    """Bins per CIELAB channel of the colour histograms."""
    smoothness: float = 3.0
    """Weight (log-odds units) of the Potts term between neighbouring pixels of equal colour;
    it falls with their colour difference."""
    prior_weight: float = 3.0
    """Log-odds that a pixel the carried mask surely covers (or surely misses) adds."""
    prior_blur: float = 0.006
    """Standard deviation of the blur of the carried mask (flow error), share of the width."""
    anchor_rounds: int = 4
    """Rounds of model re-estimation and cut on a prompted frame, after the first cut (of the
    automatic segmenter's log-odds)."""
    uncertain_band: float = 0.03
    """Width, as a share of the frame's width, of the band about the tool found so far that
    a prompted frame's tissue model does not learn from."""
    refind_share: float = 0.003
    """A region no carried mask supports is kept only if it touches the rim of the field of
    view and covers at least this share of it."""
    appearance: AutoMaskConfig = field(default_factory=AutoMaskConfig)
    """The automatic segmenter's settings: its working width is the one frames are segmented
    at, its appearance evidence is a feature here, and its guided filter snaps the masks to the
    full-size frame's edges."""
    motion: MotionConfig = field(default_factory=lambda: MotionConfig(preset="ultrafast"))
    """Optical flow that carries the masks."""

    def validate(self) -> None:
        """Raise SurgsplatError for impossible values."""
        if self.colour_bins < 2:
            raise SurgsplatError("tool prompts need colour_bins >= 2")
        if not (0 < self.click_radius < 0.5 and 0 <= self.prior_blur < 0.5
                and 0 <= self.uncertain_band < 0.5 and 0 <= self.refind_share < 1):
            raise SurgsplatError("tool prompts need click_radius in (0, 0.5), prior_blur and "
                                 "uncertain_band in [0, 0.5) and refind_share in [0, 1)")
        if self.smoothness < 0 or self.prior_weight < 0 or self.anchor_rounds < 1:
            raise SurgsplatError("tool prompts need smoothness >= 0, prior_weight >= 0 and "
                                 "anchor_rounds >= 1")
        self.appearance.validate()
        self.motion.validate()

    def describe(self) -> dict:
        """JSON-ready parameters for scene.json."""
        return asdict(self)


# ---- the prompt file ----
def read_prompts(path: Path, frame_count: int, source_size: tuple[int, int]
                 ) -> list[ToolPrompt]:
    """The prompts of the JSON file `path` for an import of `frame_count` frames of source
    size (H, W), sorted by frame; DataError naming the entry for anything else. Whether the
    points lie in the field of view is the importer's check, once it knows the view."""
    try:
        entries = json.loads(Path(path).read_text())
    except FileNotFoundError:
        raise DataError(path, "no such prompt file") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as err:
        raise DataError(path, f"is not a JSON prompt file ({err})") from None
    if not isinstance(entries, list) or not entries:
        raise DataError(path, 'expected a non-empty JSON list of {"frame": INDEX, "tool": '
                              '[[x, y], ...], "tissue": [[x, y], ...]}')
    prompts, frames = [], set()
    for number, entry in enumerate(entries):
        prompt = _parse_entry(path, number, entry, frame_count, source_size)
        if prompt.frame in frames:
            raise DataError(path, f"entry {number}: frame {prompt.frame} is prompted twice; "
                                  "put all its clicks in one entry")
        frames.add(prompt.frame)
        prompts.append(prompt)
    return sorted(prompts, key=lambda prompt: prompt.frame)


def _parse_entry(path: Path, number: int, entry, frame_count: int,
                 source_size: tuple[int, int]) -> ToolPrompt:
    where = f"entry {number}"
    if not isinstance(entry, dict) or not {"frame", "tool"} <= entry.keys():
        raise DataError(path, f'{where}: expected {{"frame": INDEX, "tool": [[x, y], ...]}} '
                              'with optional "tissue": [[x, y], ...]')
    unknown = sorted(set(entry) - {"frame", "tool", "tissue"})
    if unknown:
        raise DataError(path, f"{where}: unknown key {unknown[0]!r} (expected frame, tool, "
                              "tissue)")
    frame = entry["frame"]
    if isinstance(frame, bool) or not isinstance(frame, int):
        raise DataError(path, f"{where}: frame must be an integer index, got {frame!r}")
    if not 0 <= frame < frame_count:
        raise DataError(path, f"{where}: frame {frame} is out of range: the import has "
                              f"{frame_count} frames (0..{frame_count - 1})")
    tool = _parse_points(path, where, "tool", entry["tool"], source_size)
    if not tool:
        raise DataError(path, f"{where}: needs at least one tool point")
    tissue = _parse_points(path, where, "tissue", entry.get("tissue", []), source_size)
    return ToolPrompt(frame, tool, tissue)


def _parse_points(path: Path, where: str, kind: str, points, source_size: tuple[int, int]
                  ) -> tuple[tuple[float, float], ...]:
    height, width = source_size
    if not isinstance(points, list):
        raise DataError(path, f"{where}: {kind} must be a list of [x, y] points")
    parsed = []
    for point in points:
        if (not isinstance(point, list) or len(point) != 2
                or not all(isinstance(value, (int, float)) and not isinstance(value, bool)
                           for value in point)):
            raise DataError(path, f"{where}: {kind} point {point!r} is not [x, y]")
        x, y = float(point[0]), float(point[1])
        if not (0 <= x < width and 0 <= y < height):
            raise DataError(path, f"{where}: {kind} point [{point[0]}, {point[1]}] lies outside "
                                  f"the {width}x{height} (WxH) source frame")
        parsed.append((x, y))
    return tuple(parsed)


def click_disk(point: tuple[float, float], source_size: tuple[int, int],
               radius: float) -> np.ndarray:
    """bool [H, W] at the source size (H, W): the disk a click at `point` (x, y) marks as
    certain, `radius` a share of the width."""
    height, width = source_size
    disk = np.zeros((height, width), np.uint8)
    cv2.circle(disk, (int(point[0]), int(point[1])), max(1, round(radius * width)), 1,
               thickness=-1)
    return disk > 0


def seed_mask(prompt: ToolPrompt, kind: str, source_size: tuple[int, int],
              radius: float) -> np.ndarray:
    """bool [H, W]: the union of the disks of the clicks of `kind` ("tool" or "tissue")."""
    seeds = np.zeros(source_size, bool)
    for point in getattr(prompt, kind):
        seeds |= click_disk(point, source_size, radius)
    return seeds


def farthest_inside(mask: np.ndarray) -> tuple[float, float]:
    """(x, y) of the pixel of the bool mask [H, W] farthest from its boundary: where a script
    clicks a labelled tool (benchmarks, tests)."""
    if not mask.any():
        raise ValueError("farthest_inside: the mask is empty")
    distance = cv2.distanceTransform(np.pad(mask, 1).astype(np.uint8), cv2.DIST_L2, 5)[1:-1, 1:-1]
    row, column = np.unravel_index(int(np.argmax(distance)), distance.shape)
    return float(column), float(row)


# ---- the region model ----
@dataclass
class RegionModel:
    """What the clicks taught: the tool's colours and appearance against the tissue's."""

    colour: np.ndarray  # float32 [B, B, B] log p(colour | tool) - log p(colour | tissue)
    evidence: np.ndarray  # float32 [EVIDENCE_BINS] the same of the appearance log-odds
    trust: float
    """0..1, the weight of the automatic segmenter's own (bounded) log-odds: 1 - the share of
    the clicks' pixels in the first cut (of those log-odds), so 0 where it saw no instrument
    beyond the clicks, near 1 where it found a whole one about them."""


EVIDENCE_BINS = 24
EVIDENCE_RANGE = 12.0
"""The appearance log-odds are binned into EVIDENCE_BINS over -EVIDENCE_RANGE..EVIDENCE_RANGE."""


@dataclass
class _WorkFrame:
    """One frame at the working size, with the features the model reads."""

    colour_bin: np.ndarray  # int32 [h, w] flat index of the pixel's CIELAB bin
    evidence: np.ndarray  # float32 [h, w] the automatic segmenter's appearance log-odds
    evidence_bin: np.ndarray  # int32 [h, w] its bin
    grey: np.ndarray  # uint8 [h, w]
    lab: np.ndarray  # float32 [h, w, 3]

    def unary(self, model: RegionModel) -> np.ndarray:
        """float32 [h, w] tool log-likelihood ratio under `model`."""
        return (model.colour.reshape(-1)[self.colour_bin] + model.evidence[self.evidence_bin]
                + model.trust * np.clip(self.evidence, -TRUST_BOUND, TRUST_BOUND))


@dataclass
class PromptedMask:
    """The answer for one frame, at the working size."""

    mask: np.ndarray
    """bool [h, w] tool pixels at the working size."""
    confidence: float
    """0..1: the decision margin beside the mask's boundary (module docstring)."""

    def at_frame_size(self, image: np.ndarray, fov: np.ndarray | None,
                      config: PromptConfig) -> np.ndarray:
        """bool [H, W]: the mask at the size of its uint8 RGB frame `image` [H, W, 3], snapped
        to the frame's edges, inside the field of view `fov` (bool [H, W]; None = all)."""
        guide = cv2.cvtColor(image, cv2.COLOR_RGB2GRAY).astype(np.float32) / 255.0
        full = snap_to_edges(self.mask, guide, config.appearance.edge_radius,
                             config.appearance.edge_eps)
        return full if fov is None else full & fov


def _work_frame(small: np.ndarray, inside: np.ndarray, config: PromptConfig) -> _WorkFrame:
    """The features of a frame already at the working size (uint8 RGB [h, w, 3])."""
    lab8 = cv2.cvtColor(small, cv2.COLOR_RGB2LAB)
    bins = config.colour_bins
    quantised = (lab8.astype(np.int32) * bins) // 256  # [h, w, 3] in 0..bins-1
    colour_bin = (quantised[..., 0] * bins + quantised[..., 1]) * bins + quantised[..., 2]
    evidence = appearance_evidence(small, inside, config.appearance)
    scaled = (evidence + EVIDENCE_RANGE) * (EVIDENCE_BINS / (2 * EVIDENCE_RANGE))
    evidence_bin = np.clip(scaled.astype(np.int32), 0, EVIDENCE_BINS - 1)
    return _WorkFrame(colour_bin, evidence, evidence_bin,
                      cv2.cvtColor(small, cv2.COLOR_RGB2GRAY),
                      lab8.astype(np.float32))


def _log_density(sample: np.ndarray, size: int, cube: int | None) -> np.ndarray:
    """float32 [size]: log of the density of the bins `sample` (1-D int indices), the
    histogram smoothed over the neighbouring bins of each axis when the bins are a `cube` of
    that side (colours); a tenth of the mass is spread evenly over the bins, so a bin the
    sample never shows has the same density, 0.1 / size / 1.1, in every model."""
    counts = np.bincount(sample, minlength=size).astype(np.float32)
    if cube is not None:
        counts = counts.reshape(cube, cube, cube)
        for axis in range(3):
            counts = (counts + np.roll(counts, 1, axis) + np.roll(counts, -1, axis)) / 3
        counts = counts.reshape(-1)
    total = max(float(counts.sum()), 1.0)
    return np.log((counts + 0.1 * total / size) / (1.1 * total)).astype(np.float32)


def fit_model(frame: _WorkFrame, tool: np.ndarray, tissue: np.ndarray,
              tool_clicks: np.ndarray, tissue_clicks: np.ndarray, trust: float,
              config: PromptConfig) -> RegionModel:
    """The region model of `frame` (every mask bool [h, w]):

    - colour: the log ratio of the colour densities of `tool` and `tissue`;
    - appearance: the same of the automatic segmenter's log-odds, of `tool_clicks` (the tool
      clicks' pixels) against `tissue`. It is learned from the clicks alone: a cut that began
      from the appearance would teach it its own bias;
    - trust (given): how far the automatic segmenter's own log-odds are believed here.

    Where there are tissue clicks, the tissue density is an even mixture of theirs and the rest
    of the tissue's: what a person marked as not tool weighs as much as all the tissue. The
    densities are smoothed histograms; a bin neither class shows is neutral (0)."""
    bins = config.colour_bins

    def log_ratio(values: np.ndarray, size: int, cube: int | None) -> np.ndarray:
        tool_density = _log_density(values[tool if cube else tool_clicks], size, cube)
        tissue_density = _log_density(values[tissue & ~tissue_clicks], size, cube)
        if tissue_clicks.any():
            tissue_density = np.logaddexp(tissue_density,
                                          _log_density(values[tissue_clicks], size, cube))
            tissue_density -= np.log(2.0)
        return tool_density - tissue_density

    return RegionModel(log_ratio(frame.colour_bin, bins ** 3, bins).reshape(bins, bins, bins),
                       log_ratio(frame.evidence_bin, EVIDENCE_BINS, None), trust)


TRUST_BOUND = 4.0
"""Bound of the automatic segmenter's log-odds where they enter the unary: out of the
conditions it was tuned on (a uniform black instrument) they reach +-12 and more."""


# ---- graph cuts ----
def graph_cut(unary: np.ndarray, lab: np.ndarray, inside: np.ndarray, smoothness: float,
              tool_seeds: np.ndarray | None = None,
              tissue_seeds: np.ndarray | None = None) -> np.ndarray:
    """bool [h, w]: the labelling minimising sum of -u over tool pixels (u = `unary` [h, w],
    tool log-odds) plus the contrast-sensitive Potts term between 4-neighbours (weight
    smoothness * exp(-|dLab|^2 / (2 mean |dLab|^2))) over the pixels `inside`; seeds (bool
    [h, w]) are fixed to their label."""
    unary = np.where(inside, unary, -1e3).astype(np.float64)
    if tool_seeds is not None:
        unary = np.where(tool_seeds & inside, 1e3, unary)
    if tissue_seeds is not None:
        unary = np.where(tissue_seeds, -1e3, unary)
    right = sum(np.square(np.diff(lab[..., c], axis=1)) for c in range(3))  # [h, w-1]
    down = sum(np.square(np.diff(lab[..., c], axis=0)) for c in range(3))  # [h-1, w]
    scale = 2.0 * max(float(right.sum() + down.sum()) / (right.size + down.size), 1e-6)
    graph = maxflow.Graph[float]()
    nodes = graph.add_grid_nodes(unary.shape)
    weight_right = np.zeros(unary.shape)
    weight_right[:, :-1] = smoothness * np.exp(-right / scale)
    weight_down = np.zeros(unary.shape)
    weight_down[:-1, :] = smoothness * np.exp(-down / scale)
    graph.add_grid_edges(nodes, weights=weight_right, structure=_RIGHT, symmetric=True)
    graph.add_grid_edges(nodes, weights=weight_down, structure=_DOWN, symmetric=True)
    # source side = tool: cutting a pixel off the source (labelling it tissue) costs u where
    # u > 0, cutting it off the sink (labelling it tool) costs -u where u < 0
    graph.add_grid_tedges(nodes, np.maximum(unary, 0.0), np.maximum(-unary, 0.0))
    graph.maxflow()
    return ~graph.get_grid_segments(nodes) & inside


_RIGHT = np.array([[0, 0, 0], [0, 0, 1], [0, 0, 0]])
_DOWN = np.array([[0, 0, 0], [0, 0, 0], [0, 1, 0]])


def _components_touching(mask: np.ndarray, keep: np.ndarray) -> np.ndarray:
    """bool [h, w]: the 8-connected components of `mask` that share a pixel with `keep`."""
    count, labels = cv2.connectedComponents(mask.astype(np.uint8), connectivity=8)
    chosen = np.zeros(count, bool)
    chosen[np.unique(labels[keep & mask])] = True
    chosen[0] = False
    return chosen[labels]


def _margin_confidence(unary: np.ndarray, mask: np.ndarray, inside: np.ndarray) -> float:
    """Mean |2 sigmoid(u) - 1| over the pixels beside the mask's boundary (see the module
    docstring); 1 when the mask is empty and the unary nowhere favours the tool."""
    ring = np.ones((3, 3), np.uint8)
    band = (cv2.dilate(mask.astype(np.uint8), ring) != cv2.erode(mask.astype(np.uint8), ring))
    band &= inside
    if not band.any():
        band = inside & (unary > 0)
        if not band.any():
            return 1.0
    return float(np.abs(np.tanh(unary[band] / 2.0)).mean())


def segment_prompted(frame: _WorkFrame, inside: np.ndarray, tool_seeds: np.ndarray,
                     tissue_seeds: np.ndarray, config: PromptConfig
                     ) -> tuple[np.ndarray, RegionModel, np.ndarray]:
    """(mask, model, unary) of a prompted frame. The first cut is of the automatic
    segmenter's appearance log-odds alone, with the clicks as hard constraints: the region
    about a tool click that looks like an instrument at all. Then the region model is learned
    from the cut and the cut re-made with it, in turns. The tissue sample is the field of view
    less a band about the tool found so far (its unfound rim would otherwise teach the tissue
    model the tool's colours); only the parts of a cut connected to a tool click are tool."""
    tool_seeds = tool_seeds & inside
    side = 2 * max(1, round(config.uncertain_band * inside.shape[1])) + 1
    band = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (side, side))
    mask = _components_touching(graph_cut(frame.evidence, frame.lab, inside,
                                          config.smoothness, tool_seeds, tissue_seeds),
                                tool_seeds)
    # the automatic segmenter is trusted as far as it found the instrument about the clicks
    trust = 1.0 - float(tool_seeds.sum()) / max(float(mask.sum()), 1.0)
    for _ in range(config.anchor_rounds):
        near = cv2.dilate(mask.astype(np.uint8), band) > 0
        model = fit_model(frame, mask, (inside & ~near) | tissue_seeds, tool_seeds,
                          tissue_seeds & inside, trust, config)
        unary = frame.unary(model)
        mask = _components_touching(graph_cut(unary, frame.lab, inside, config.smoothness,
                                              tool_seeds, tissue_seeds), tool_seeds)
    return mask, model, unary


def carry(previous_mask: np.ndarray, previous: _WorkFrame, frame: _WorkFrame,
          inside: np.ndarray, model: RegionModel, flows: FlowEstimator,
          config: PromptConfig) -> tuple[np.ndarray, np.ndarray]:
    """(mask, unary) of `frame` from the neighbouring frame's mask, carried by the flow, and
    the region model."""
    flow = flows.flow(frame.grey, previous.grey)  # this frame -> the neighbour
    carried = warp_from(previous_mask.astype(np.float32), flow)
    sigma = config.prior_blur * inside.shape[1]
    if sigma > 0:
        carried = cv2.GaussianBlur(carried, (0, 0), sigma)
    unary = frame.unary(model) + config.prior_weight * (2.0 * carried - 1.0)
    cut = graph_cut(unary, frame.lab, inside, config.smoothness)
    supported = _components_touching(cut, carried > 0.5)
    return supported | _entering(cut & ~supported, inside, config), unary


def _entering(regions: np.ndarray, inside: np.ndarray, config: PromptConfig) -> np.ndarray:
    """bool [h, w]: the components of `regions` that touch the rim of the field of view and
    cover at least `refind_share` of it (a tool coming back into view)."""
    count, labels, stats, _ = cv2.connectedComponentsWithStats(regions.astype(np.uint8),
                                                               connectivity=8)
    rim = inside & ~(cv2.erode(inside.astype(np.uint8), np.ones((5, 5), np.uint8),
                               borderType=cv2.BORDER_CONSTANT, borderValue=0) > 0)
    keep = np.zeros(count, bool)
    keep[np.unique(labels[rim & regions])] = True
    keep &= stats[:, cv2.CC_STAT_AREA] >= config.refind_share * inside.sum()
    keep[0] = False
    return keep[labels]


# ---- the clip ----
def prompted_tool_masks(frames: Iterable[np.ndarray], fov: np.ndarray | None,
                        prompts: Sequence[tuple[int, np.ndarray, np.ndarray]],
                        config: PromptConfig | None = None,
                        progress: Callable[[int, int], None] | None = None
                        ) -> list[PromptedMask]:
    """Working-size masks and confidences of the uint8 RGB frames [H, W, 3] of one clip
    inside the field of view `fov` (bool [H, W], None = whole frame); `PromptedMask.
    at_frame_size` brings one to its frame's size. `prompts` are (frame index, tool seeds,
    tissue seeds), the seeds bool [H, W] at the frames' size. Every frame is decided from its
    nearest prompted frame (ties: the earlier one). Holds the clip at the working size
    (3 bytes a working pixel); `progress(done, total)` counts decided frames."""
    config = config or PromptConfig()
    config.validate()
    if not prompts:
        raise SurgsplatError("tool prompts: at least one prompted frame is needed")
    smalls: list[np.ndarray] = []  # uint8 [h, w, 3] per frame
    inside = None  # bool [h, w] the field of view at the working size
    for image in frames:
        if inside is None:
            size = working_size(image.shape[:2], config.appearance)
            inside = _resize_mask(np.ones(image.shape[:2], bool) if fov is None else fov, size,
                                  touched=False)
        smalls.append(cv2.resize(image, inside.shape[::-1], interpolation=cv2.INTER_AREA))
    if inside is None:
        raise SurgsplatError("tool prompts: the clip has no frames")
    flows = FlowEstimator(config.motion)
    decided: list[PromptedMask | None] = [None] * len(smalls)
    done = 0
    anchors = sorted(prompts, key=lambda prompt: prompt[0])
    for number, (index, tool_seeds, tissue_seeds) in enumerate(anchors):
        anchor = _work_frame(smalls[index], inside, config)
        mask, model, unary = segment_prompted(
            anchor, inside, _resize_mask(tool_seeds, inside.shape, touched=True),
            _resize_mask(tissue_seeds, inside.shape, touched=True), config)
        decided[index] = PromptedMask(mask, _margin_confidence(unary, mask, inside))
        done += 1
        # the frames nearer this prompted frame than the others (ties: the earlier one)
        first = (anchors[number - 1][0] + index) // 2 + 1 if number > 0 else 0
        last = ((index + anchors[number + 1][0]) // 2 if number + 1 < len(anchors)
                else len(smalls) - 1)
        for chain in (range(index - 1, first - 1, -1), range(index + 1, last + 1)):
            current, previous = mask, anchor
            for target in chain:
                frame = _work_frame(smalls[target], inside, config)
                current, unary = carry(current, previous, frame, inside, model, flows, config)
                decided[target] = PromptedMask(current, _margin_confidence(unary, current,
                                                                           inside))
                previous, done = frame, done + 1
                if progress is not None:
                    progress(done, len(smalls))
    assert all(result is not None for result in decided)
    return decided


def _resize_mask(mask: np.ndarray, size: tuple[int, int], touched: bool) -> np.ndarray:
    """bool `mask` at size (h, w): a pixel is inside where more than half its area is
    (`touched` False), or any of it (True: small click disks are kept)."""
    if mask.shape == size:
        return mask.copy()
    resized = cv2.resize(mask.astype(np.float32), size[::-1], interpolation=cv2.INTER_AREA)
    return resized > 0 if touched else resized > 0.5
