"""PhysioSplat's tool / tissue decomposition as a component (`physiosplat.txt` Section 2.2).

- Per-Gaussian semantic logit s (attribute `semantic_logit`, read by this module alone): tissue
  when p = sigmoid(s) >= tau = 0.5 (the paper's threshold), i.e. s >= 0; the others are the tool
  Gaussians it declares (`tool_members`, which every other module asks through
  `model.membership`). The rendered channel `tool_probability` blends 1 - sigmoid(s); the loss
  term "mask" is its binary cross-entropy against the frame's tool mask over the field of view.
- Tool Gaussians move rigidly (Eq. 1): mu(t) = R(t) mu + T(t), with their rotation turned by R(t)
  and their canonical scales. With `motion = "articulated"` (not in the paper) the tool is a
  shaft and two jaws on one hinge (`tool_joints`): each jaw first turns about the hinge by its
  own learnable angle at t, then the whole tool takes R(t), T(t). The hinge and the first
  angles are estimated at set-up from the training frames' tool pixels (`model.articulation`),
  which also corrects the registered poses to the shaft's; where that estimate cannot be made
  (no depth, jaws never seen open) the field stays rigid. tissue Gaussians keep what the components before this one (the
  deformation field) made of them. R(t), T(t) map the canonical tool, which is the tool of the
  reference frame (the training frame with the most tool pixels), to frame t; composing the
  paper's per-frame increments gives the same map. Each frame has its own learnable pose (rotation
  vector, translation); held-out frames interpolate their training neighbours. The poses are the
  component's `tool_motion`, from which the tool's articulation is estimated.
- Initial tool Gaussians are the reference frame's tool pixels back-projected with the observed
  depth (which sees the tool); without depth (monocular), at a fixed fraction of the initial
  points' median depth. Initial poses register, frame by frame in time order from the
  reference, the canonical tool to each frame's back-projected tool pixels (point-to-point ICP,
  observed point to nearest model point, started from the neighbouring frame's pose). Frames that
  show no tool put it behind their camera, where it is culled.
- Tool-free rendering (Eq. 2): with `when.tissue_only` every tool Gaussian gets opacity 0, which
  composites exactly as the tissue subset alone.
- Tissue no training frame shows (not in the paper; `fill_never_seen`, static cameras): the
  pixels a tool covers in every training frame get tissue Gaussians at the depth and colour
  continued from around them (`data.never_seen`), so that the tool-free view has no hole there;
  they are rendered FILLED_OPACITY opaque. No loss reaches them through the tool's pixels, so
  they stay the guess they are. Each
  Gaussian's attribute `observed` (0 for these, 1 for every other, inherited by densification)
  is rendered as the channel `observed` (`model.channels.OBSERVED`) outside training.
- Hidden tissue learns only where it is seen: no loss of a training step reaches a tissue
  Gaussian through the frame's tool pixels (`gradient_weights`, see `losses`); from the pixels where
  it shows, every Gaussian learns.
- Densification (`densify_weights`): none where the tool proxy's signed distance is below the
  margin (tool Gaussians and tissue touching the tool; with `densify_tool` the tissue alone); a
  tissue Gaussian whose projected centre
  lies behind rendered tool (tool probability > 0.5, rendered depth nearer than it) has its
  gradient weighted by omega = exp(-|c - c_adj|_1 / (3 sigma)), its diffuse colour c against
  c_adj, the most recent training observation of that pixel as tissue (a static-view stand-in for
  the nearest unoccluded frame).
- Diagnostics at test frames: `collisions` (tissue Gaussians inside the tool proxy, summed over
  test frames) and `arap_strain_mean` (Eq. 4 per tissue Gaussian over a fresh canonical 16-NN
  graph, averaged; scene units squared).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
import torch
import torch.nn.functional as F
from scipy.ndimage import distance_transform_edt
from torch import Tensor, nn

from surgsplat.data.never_seen import FilledTissue, fill_never_seen
from surgsplat.image.pinhole import backproject
from surgsplat.methods.physiosplat.tool_joints import (Hinge, InitialJoints, initial_joints,
                                                       jaw_parts, turn_jaws)
from surgsplat.model.articulation import Articulation, Observation
from surgsplat.model.channels import (OBSERVED, TOOL_PROBABILITY, ChannelDescriptor,
                                      ChannelKind, Colormap)
from surgsplat.model.capabilities import (DensifyWeighting, GradientWeighting, PointSource,
                                          ToolMembership, ToolMotion)
from surgsplat.model.component import (Component, ComponentConfig, Diagnostics, FrameTime,
                                       InitialPoints, ParamGroup, RenderContext, SceneInfo,
                                       SetupContext)
from surgsplat.model.gaussians import GaussianModel
from surgsplat.model.phases import Phase
from surgsplat.model.physics import (PHANTOM_EXTENT_MM, ToolProxy, arap_strain, neighbour_graph,
                                     tool_proxy)
from surgsplat.model.state import GaussianState
from surgsplat.render.pixel_weights import PixelWeights
from surgsplat.render.rotation import (axis_angle_to_quaternion, quaternion_multiply,
                                       quaternion_to_matrix)
from surgsplat.render.sh import SH_C0

SEMANTIC_KEY = "semantic_logit"
"""Per-Gaussian attribute holding the semantic logit s ([N]; sigmoid(s) = tissue probability)."""
TOOL_CHANNEL = TOOL_PROBABILITY
"""Rendered channel [H, W, 1]: blended tool probability 1 - sigmoid(s)."""
FILLED_OPACITY = 0.99
"""Opacity of the Gaussians that fill never-seen tissue: no loss reaches them through the tool's
pixels, so they would keep their initial, translucent opacity and leave the hole speckled."""
OBSERVED_KEY = "observed"
"""Per-Gaussian attribute ([N], fixed): 0 for the Gaussians filling never-seen tissue, else 1
(`fill_never_seen`)."""


@dataclass
class ToolFieldConfig(ComponentConfig, kind="tool_field"):
    """Tool Gaussians with per-frame rigid or articulated motion, semantic logits and tool-free
    rendering, optionally with the never-seen tissue filled."""

    num_frames: int = field(default=0, metadata={"range": "[0, inf)"})
    """Frames of the clip (one rigid pose each); set from the scene when resolved."""
    max_points: int = field(default=4000, metadata={"range": "[1, inf)"})
    """At most this many initial tool Gaussians (a seeded subsample of the reference frame's
    tool pixels)."""
    pixel_stride: int = field(default=2, metadata={"range": "[1, inf)"})
    """Use every stride-th tool pixel in x and y."""
    monocular_tool_depth: float = field(default=0.8, metadata={"range": "(0, 1]"})
    """Scenes without depth: tool pixels are placed at this fraction of the initial points'
    median camera depth (in front of the tissue)."""
    init_logit: float = field(default=4.0, metadata={"range": "[0, inf)"})
    """Initial |s|: tissue Gaussians start at +init_logit, tool Gaussians at -init_logit."""
    semantic_lr: float = field(default=0.005, metadata={"range": "[0, inf)"})
    """Adam learning rate of the semantic logits. Adam moves a logit by about this per step
    whatever the gradient's size, and the mask loss pushes tissue Gaussians seen through the
    tool towards the tool: at ten times this rate they flip within tens of visits and leave
    holes in the tool-free render; 0.005 keeps the initial split (measured:
    docs/methods/physiosplat.md, Deviations)."""
    rotation_lr: float = field(default=1e-3, metadata={"range": "[0, inf)"})
    """Adam learning rate of the per-frame rotation vectors (radians)."""
    translation_lr: float = field(default=1e-3, metadata={"range": "[0, inf)"})
    """Adam learning rate of the per-frame translations, in units of the scene extent."""
    motion: Literal["rigid", "articulated"] = "rigid"
    """How the tool Gaussians move: one rigid pose per frame (the paper), or a shaft with two
    jaws turning about a hinge (see the module docstring)."""
    jaw_lr: float = field(default=2e-4, metadata={"range": "[0, inf)"})
    """Adam learning rate of the per-frame jaw angles (radians; articulated motion); ten times
    this lets them wander from their set-up estimate (measured: docs/methods/physiosplat.md)."""
    max_observed_points: int = field(default=8000, metadata={"range": "[1, inf)"})
    """At most this many tool pixels per frame (a seeded subsample) enter the set-up's
    articulation estimate."""
    icp_iterations: int = field(default=30, metadata={"range": "[0, inf)"})
    """Point-to-point ICP iterations per frame when the initial poses are registered."""
    min_tool_opacity: float = field(default=0.1, metadata={"range": "[0, 1]"})
    """Tool Gaussians at least this opaque make up the tool proxy (`model.physics.ToolProxy`)."""
    densify_margin: float = field(default=2.0 / PHANTOM_EXTENT_MM, metadata={"range": "[0, 1)"})
    """No densification where the tool proxy's signed distance is below this fraction of the
    scene extent, in [0, 1) (the paper's epsilon, 2 mm on the phantom: 0.0259)."""
    densify_tool: bool = False
    """Let the tool Gaussians densify too: the margin then keeps out only the tissue Gaussians
    touching the tool (the paper's rule read for tissue; by default it also keeps the tool at
    its initial Gaussians)."""
    occlusion_sigma: float = field(default=0.1, metadata={"range": "(0, inf)"})
    """Colour difference (mean over RGB) at which an occluded Gaussian's weight is 1/e."""
    strain_neighbours: int = field(default=16, metadata={"range": "[1, inf)"})
    """k of the canonical kNN graph of the arap_strain_mean diagnostic."""
    fill_never_seen: bool = False
    """Add tissue Gaussians where a tool covers the same pixels in every training frame (static
    camera), at the depth and colour continued from around them, and render the `observed`
    channel (see the module docstring)."""
    edge_band_px: float = field(default=0.0, metadata={"range": "[0, inf)"})
    """Tissue Gaussians learn from the tissue pixels within this distance (pixels) of the
    frame's tool mask with a gradient weight rising linearly from 0 at the mask to 1 at this
    distance, where the rendered tool's rim covers them (`gradient_weights`); 0: from every
    tissue pixel whole."""

    def resolve(self, scene: SceneInfo) -> "ToolFieldConfig":
        return dataclasses.replace(self, num_frames=scene.num_frames)

    def build(self) -> "ToolField":
        return ToolField(self)


class ToolField(Component):
    """See the module docstring. rotations, translations: [F, 3] per frame; jaw_angles: [F, 2]
    per frame (radians, articulated motion); known [F] bool: frames with a registered pose
    (training frames); seen [F] bool: frames that show the tool; articulated: bool, the hinge
    buffers hold an estimated hinge (`Hinge`: hinge_point, hinge_axis, hinge_forward [3],
    canonical_jaws [2])."""

    phase = Phase.TOOL
    separates_tool = True
    provides = (ToolMembership, ToolMotion, PointSource, GradientWeighting, DensifyWeighting)

    def __init__(self, config: ToolFieldConfig):
        super().__init__()
        self.config = config
        frames = max(config.num_frames, 1)
        self.rotations = nn.Parameter(torch.zeros(frames, 3))
        self.translations = nn.Parameter(torch.zeros(frames, 3))  # units of `unit`
        self.jaw_angles = nn.Parameter(torch.zeros(frames, 2))
        self.register_buffer("articulated", torch.zeros((), dtype=torch.bool))
        self.register_buffer("hinge_point", torch.zeros(3))
        self.register_buffer("hinge_axis", torch.tensor([0.0, 0.0, 1.0]))
        self.register_buffer("hinge_forward", torch.tensor([1.0, 0.0, 0.0]))
        self.register_buffer("canonical_jaws", torch.zeros(2))
        self.register_buffer("unit", torch.ones(()))
        self.register_buffer("known", torch.zeros(frames, dtype=torch.bool))
        self.register_buffer("seen", torch.zeros(frames, dtype=torch.bool))
        # [H, W, 3] the latest training observation of each pixel as tissue (densify_weights);
        # saved, so that a resumed run densifies as the uninterrupted one does
        self.register_buffer("last_tissue_image", torch.zeros(0, 0, 3))
        self._reference: tuple[Tensor, Tensor] | None = None  # canonical tool (means, colours)
        self._fill: InitialPoints | None = None  # tissue no training frame shows (means, colours)
        # (frame index, H, W) -> [H, W] tissue gradient weights (edge_band_px)
        self._tissue_weights: dict[tuple[int, ...], Tensor] = {}

    # ---- set-up ----
    def setup(self, context: SetupContext) -> None:
        self.unit.fill_(max(context.scene_extent, 1e-6))
        frames = list(context.frames)
        depths = {f.index: self._depth_map(f, context.points) for f in frames}
        clouds = {f.index: self._tool_pixels(f, depths[f.index], self.config.pixel_stride)
                  for f in frames}
        counted = {index: cloud[0].shape[0] for index, cloud in clouds.items()}
        if not counted or max(counted.values()) < 4:
            return
        reference = max(counted, key=counted.get)
        means, colors = clouds[reference]
        if means.shape[0] > self.config.max_points:
            generator = torch.Generator().manual_seed(0)
            keep = torch.randperm(means.shape[0], generator=generator)[:self.config.max_points]
            means, colors = means[keep], colors[keep]
        self._reference = (means, colors)
        self._register_poses(means, {f.index: f for f in frames}, clouds, reference)
        if self.config.fill_never_seen:
            filled = fill_never_seen(frames, depths)
            if filled is not None:
                self._fill = self._fill_points(filled, frames[0].camera)
        if self.config.motion == "articulated":
            self._articulate(means, frames, depths, reference)

    @torch.no_grad()
    def _articulate(self, model: Tensor, frames: list, depths: dict, reference: int) -> None:
        """Hinge, jaw angles and shaft-corrected poses from every tool pixel of the `frames`
        (back-projected with `depths`, index -> [H, W]) mapped into the canonical tool `model`
        [K, 3] by the registered poses; the field stays rigid when that cannot be estimated."""
        generator = torch.Generator().manual_seed(0)
        observations = []
        for frame in sorted(frames, key=lambda frame: frame.index):
            index = frame.index
            if not self.seen[index]:
                continue
            points, _ = self._tool_pixels(frame, depths[index], stride=1)
            if points.shape[0] > self.config.max_observed_points:
                keep = torch.randperm(points.shape[0], generator=generator)
                points = points[keep[:self.config.max_observed_points]]
            rotvec, translation = self.pose(index)
            rotation = quaternion_to_matrix(axis_angle_to_quaternion(rotvec))
            observations.append(Observation(index, ((points - translation) @ rotation).double()
                                            .numpy()))
        try:
            joints = initial_joints(model, observations, reference)
        except ValueError:
            return
        self._take_joints(joints)

    def _take_joints(self, joints: InitialJoints) -> None:
        """Set the hinge, the frames' jaw angles, and compose each frame's pose with its shaft
        correction (the correction first, in the canonical frame)."""
        from scipy.spatial.transform import Rotation

        hinge = joints.hinge
        self.hinge_point.copy_(hinge.point)
        self.hinge_axis.copy_(hinge.axis)
        self.hinge_forward.copy_(hinge.forward)
        self.canonical_jaws.copy_(hinge.canonical_angles)
        self.articulated.fill_(True)
        self.jaw_angles[:] = hinge.canonical_angles
        for index, angles in joints.angles.items():
            self.jaw_angles[index] = angles
            correction = joints.shaft_corrections[index]
            rotation = Rotation.from_rotvec(self.rotations[index].double().numpy()).as_matrix()
            translation = self.translations[index].double().numpy() * float(self.unit)
            self.rotations[index] = torch.from_numpy(
                Rotation.from_matrix(rotation @ correction[:3, :3]).as_rotvec()).float()
            self.translations[index] = torch.from_numpy(
                rotation @ correction[:3, 3] + translation).float() / self.unit

    def _fill_points(self, filled: FilledTissue, camera) -> InitialPoints:
        """Tissue points (every pixel_stride-th in x and y) of the filled never-seen pixels,
        back-projected from the static `camera` at the filled depth, with the filled colours."""
        grid = torch.zeros_like(filled.never_seen)
        grid[::self.config.pixel_stride, ::self.config.pixel_stride] = True
        mask = filled.never_seen & grid & (filled.depth > 0)
        points = backproject(filled.depth, camera.K, mask, camera.camera_to_world)
        return InitialPoints(points, filled.colour[mask])

    def _depth_map(self, frame, points: Tensor) -> Tensor:
        """[H, W] depth of the frame's tool pixels: the observed depth, or without one
        (monocular) `monocular_tool_depth` x the median camera depth of the initial points."""
        if frame.depth is not None:
            return frame.depth
        world_to_camera = frame.camera.world_to_camera
        depths = points @ world_to_camera[2, :3] + world_to_camera[2, 3]  # [M]
        depth = self.config.monocular_tool_depth * float(depths.median())
        return torch.full(frame.tool.shape, depth)

    def _tool_pixels(self, frame, depth: Tensor, stride: int) -> tuple[Tensor, Tensor]:
        """World points [K, 3] and colours [K, 3] of the frame's tool pixels with depth > 0 in
        `depth` [H, W], every stride-th in x and y."""
        grid = torch.zeros_like(frame.tool)
        grid[::stride, ::stride] = True
        mask = frame.tool & frame.fov & grid & (depth > 0)
        points = backproject(depth, frame.camera.K, mask, frame.camera.camera_to_world)
        return points, frame.image[mask]

    @torch.no_grad()
    def _register_poses(self, model: Tensor, frames: dict, clouds: dict, reference: int) -> None:
        """Initial pose of every training frame: ICP of the canonical tool `model` [K, 3] to the
        frame's tool pixels, tracked outwards in time from `reference`."""
        from scipy.spatial import cKDTree
        from scipy.spatial.transform import Rotation

        tree = cKDTree(model.double().numpy())
        order = sorted(frames)
        start = order.index(reference)
        for direction in (range(start, len(order)), range(start, -1, -1)):
            rotation, translation = np.eye(3), np.zeros(3)
            for position in direction:
                index = order[position]
                target = clouds[index][0].double().numpy()
                if target.shape[0] >= 4:
                    rotation, translation = _icp(tree, model.double().numpy(), target, rotation,
                                                 translation, self.config.icp_iterations)
                    self.rotations[index] = torch.from_numpy(
                        Rotation.from_matrix(rotation).as_rotvec()).float()
                    self.translations[index] = torch.from_numpy(translation).float() / self.unit
                    self.seen[index] = True
                else:
                    self._hide(model, frames[index], rotation, translation)
                self.known[index] = True

    def _hide(self, model: Tensor, frame, rotation: np.ndarray, translation: np.ndarray) -> None:
        """A pose for a frame without tool: the last pose pushed behind the frame's camera."""
        from scipy.spatial.transform import Rotation

        world_to_camera = frame.camera.world_to_camera.double().numpy()
        placed = model.double().numpy() @ rotation.T + translation
        depth = placed @ world_to_camera[2, :3] + world_to_camera[2, 3]
        push = float(depth.max()) + float(self.unit)
        behind = translation - push * world_to_camera[2, :3]  # camera z axis in the world
        rotvec = Rotation.from_matrix(rotation).as_rotvec()
        self.rotations[frame.index] = torch.from_numpy(rotvec).float()
        self.translations[frame.index] = torch.from_numpy(behind).float() / self.unit

    def initial_points(self, context: SetupContext) -> InitialPoints | None:
        """The canonical tool, then the tissue filling never-seen pixels (if any)."""
        if self._reference is None:
            return None
        if self._fill is None:
            return InitialPoints(*self._reference)
        return InitialPoints(torch.cat([self._reference[0], self._fill.means]),
                             torch.cat([self._reference[1], self._fill.colors]))

    def initial_attributes(self, context: SetupContext) -> dict[str, Tensor]:
        count = context.points.shape[0]
        logits = torch.full((count,), self.config.init_logit)
        added = context.rows_added_by(self)
        start = 0 if added.start is None else added.start
        tool = slice(start, start + (0 if self._reference is None else
                                     self._reference[0].shape[0]))
        logits[tool] = -self.config.init_logit
        attributes = {SEMANTIC_KEY: logits}
        if self.config.fill_never_seen:
            observed = torch.ones(count)
            observed[tool.stop:added.stop] = 0.0
            attributes[OBSERVED_KEY] = observed
        return attributes

    def attribute_lrs(self) -> dict[str, float]:
        lrs = {SEMANTIC_KEY: self.config.semantic_lr}
        if self.config.fill_never_seen:
            lrs[OBSERVED_KEY] = 0.0
        return lrs

    def param_groups(self) -> list[ParamGroup]:
        groups = [ParamGroup("tool_rotation", [self.rotations], self.config.rotation_lr),
                  ParamGroup("tool_translation", [self.translations], self.config.translation_lr)]
        if self.config.motion == "articulated":
            groups.append(ParamGroup("tool_jaws", [self.jaw_angles], self.config.jaw_lr))
        return groups

    # ---- membership and capabilities ----
    def tool_members(self, gaussians: GaussianModel) -> Tensor:
        """[N] bool: p = sigmoid(s) < tau = 0.5, i.e. not s >= 0."""
        return ~(gaussians.params[SEMANTIC_KEY].detach() >= 0.0)

    def channel_descriptors(self) -> tuple[ChannelDescriptor, ...]:
        tool = ChannelDescriptor(TOOL_CHANNEL, ChannelKind.PROBABILITY, Colormap.INFERNO)
        if not self.config.fill_never_seen:
            return (tool,)
        return (tool, ChannelDescriptor(OBSERVED, ChannelKind.PROBABILITY, Colormap.GRAY))

    # ---- motion ----
    def pose(self, index: int) -> tuple[Tensor, Tensor]:
        """Rotation vector [3] and translation [3] (scene units) of frame `index` (`_at`)."""
        rotation, translation = self._at(index, self.rotations, self.translations)
        return rotation, translation * self.unit

    def _at(self, index: int, *per_frame: Tensor) -> tuple[Tensor, ...]:
        """Each of the per-frame tensors [F, ...] at frame `index`: its own row when registered;
        else linear between the registered neighbours when both show the tool, the nearer
        one's otherwise (ties: one without the tool, so that no tool is drawn over tissue on the
        evidence of one side only)."""
        index = min(max(index, 0), self.known.shape[0] - 1)
        if self.known[index] or not self.known.any():
            return tuple(values[index] for values in per_frame)
        registered = self.known.nonzero()[:, 0]
        before, after = registered[registered < index], registered[registered > index]
        sides = [int(side) for side in (before[-1:], after[:1]) if side.numel()]
        if len(sides) == 2 and self.seen[sides[0]] and self.seen[sides[1]]:
            weight = (index - sides[0]) / (sides[1] - sides[0])
            first, last = sides
            return tuple(torch.lerp(values[first], values[last], weight) for values in per_frame)
        nearest = min(sides, key=lambda side: (abs(side - index), bool(self.seen[side])))
        return tuple(values[nearest] for values in per_frame)

    def hinge(self) -> Hinge:
        """The canonical tool's hinge (meaningful when `articulated`)."""
        return Hinge(self.hinge_point, self.hinge_axis, self.hinge_forward, self.canonical_jaws)

    @torch.no_grad()
    def articulation(self, gaussians: GaussianModel) -> Articulation | None:
        """The tool's own articulation (`ToolMotion.articulation`): its hinge, the parts of its
        tool Gaussians at least min_tool_opacity opaque, and the registered frames' jaw angles;
        None when rigid."""
        if not bool(self.articulated):
            return None
        params = gaussians.params
        opaque = torch.sigmoid(params["opacity_logits"]) >= self.config.min_tool_opacity
        means = params["means"][self.tool_members(gaussians) & opaque]
        frames = (self.known & self.seen).nonzero()[:, 0].numpy()
        hinge = self.hinge()
        return Articulation(
            points=means.double().numpy(), labels=jaw_parts(means, hinge).numpy(),
            axis=hinge.axis.double().numpy(), hinge_point=hinge.point.double().numpy(),
            forward=hinge.forward.double().numpy(), frames=frames,
            shaft_motion=np.repeat(np.eye(4)[None], len(frames), axis=0),
            jaw_angles_deg=np.degrees(self.jaw_angles[frames].double().numpy()),
            jaw_observed=np.ones((len(frames), 2), dtype=bool),
            canonical_jaw_deg=np.degrees(hinge.canonical_angles.double().numpy()))

    def _load_from_state_dict(self, state_dict, prefix, *args, **kwargs) -> None:
        # the image's size is the saved run's frames'; checkpoints written before it was saved
        # start from no observation, as a new run does
        key = prefix + "last_tissue_image"
        self.last_tissue_image = torch.empty_like(state_dict.setdefault(key, torch.zeros(0, 0, 3)))
        super()._load_from_state_dict(state_dict, prefix, *args, **kwargs)

    def gradient_weights(self, gaussians: GaussianModel, when: FrameTime) -> PixelWeights | None:
        """A training render keeps the tissue Gaussians from the gradients of the frame's tool
        pixels, weight 0 there and 1 elsewhere (`losses` says why); the tool Gaussians learn
        from every pixel."""
        if when.tool_pixels is None:
            return None
        return PixelWeights(self._tissue_weights_of(when), ~self.tool_members(gaussians))

    def _tissue_weights_of(self, when: FrameTime) -> Tensor:
        """[H, W] the tissue Gaussians' gradient weights in a training render at `when`: 0 on
        the tool pixels, rising to 1 over edge_band_px beyond them (computed once per frame)."""
        band = self.config.edge_band_px
        if band <= 0:
            return (~when.tool_pixels).float()
        key = (when.index, *when.tool_pixels.shape)  # a coarse stage renders smaller
        if key not in self._tissue_weights:
            distance = distance_transform_edt(~when.tool_pixels.numpy())
            self._tissue_weights[key] = torch.from_numpy(np.minimum(distance / band, 1.0)).float()
        return self._tissue_weights[key]

    def transform(self, state: GaussianState, gaussians: GaussianModel,
                  when: FrameTime) -> GaussianState:
        """Tool Gaussians moved to `when`, their jaws turned first when articulated (dropped
        with `when.tissue_only`)."""
        tool = self.tool_members(gaussians)  # [N]
        if not tool.any():
            return state
        rotvec, translation, jaws = self._at(when.index, self.rotations, self.translations,
                                             self.jaw_angles)
        quat = axis_angle_to_quaternion(rotvec)  # [4]
        params = gaussians.params
        means, quats = params["means"], F.normalize(params["quats"], dim=-1)
        if bool(self.articulated):  # only the tool rows turn: a tenth of the Gaussians
            hinge, rows = self.hinge(), tool.nonzero()[:, 0]
            turned_means, turned_quats = turn_jaws(
                means[rows], quats[rows], jaw_parts(means[rows], hinge),
                jaws - hinge.canonical_angles, hinge)
            means = means.index_put((rows,), turned_means)
            quats = quats.index_put((rows,), turned_quats)
        rigid_means = means @ quaternion_to_matrix(quat).T + translation * self.unit  # [N, 3]
        rigid_quats = quaternion_multiply(quat.expand_as(quats), quats)
        column = tool[:, None]
        opacities = state.opacities
        if self.config.fill_never_seen:  # the fill is a surface: opaque (no loss reaches it)
            filled = params[OBSERVED_KEY] == 0
            opacities = torch.where(filled, torch.full_like(opacities, FILLED_OPACITY), opacities)
        if when.tissue_only:
            opacities = torch.where(tool, torch.zeros_like(opacities), opacities)
        return state.replace(means=torch.where(column, rigid_means, state.means),
                             quats=torch.where(column, rigid_quats, state.quats),
                             scales=torch.where(column, params["log_scales"].exp(), state.scales),
                             opacities=opacities)

    def proxy(self, state: GaussianState, gaussians: GaussianModel) -> ToolProxy | None:
        """The tool proxy (`model.physics`) of the tool Gaussians in `state` at least
        min_tool_opacity opaque."""
        return tool_proxy(state.means, state.scales, state.opacities,
                          self.tool_members(gaussians), self.config.min_tool_opacity)

    # ---- semantic channel and its loss ----
    def render_channels(self, state, gaussians: GaussianModel, camera, when) -> dict[str, Tensor]:
        probability = 1.0 - torch.sigmoid(gaussians.params[SEMANTIC_KEY])  # [N]
        channels = {TOOL_CHANNEL: probability}
        if self.config.fill_never_seen and when.losses is None:  # no loss reads it
            channels[OBSERVED] = gaussians.params[OBSERVED_KEY].detach()
        return channels

    def loss_names(self) -> tuple[str, ...]:
        return ("mask",)

    def losses(self, context: RenderContext, active: frozenset[str]) -> dict[str, Tensor]:
        """"mask": BCE of the rendered tool probability against the tool mask over the field
        of view. No loss of a training step reaches a tissue Gaussian through the frame's tool
        pixels (`gradient_weights`): there the render is the tool's to explain.
        - Where the rendered tool is thinner than the frame's, the mask loss would ask for more
          tool probability at the tissue Gaussians under it: fade, shrink and move them, or
          flip their logits (per-Gaussian Adam moves a logit by about the learning rate per
          step whatever the gradient's size).
        - Through the tool's residual transmittance the photometric loss would paint the
          hidden tissue in the tool's colours (without a gate the tool-free render shows a
          dark tool-shaped smear; measured: docs/methods/physiosplat.md, Deviations), and move
          it out from behind the tool and shrink it.
        The hidden tissue learns from the pixels where it shows around the tool, and its
        position from the biomechanical energies, which act on the state, not through the
        render."""
        frame = context.frame
        probability = context.output.extras[TOOL_CHANNEL][..., 0].clamp(1e-4, 1.0 - 1e-4)
        return {"mask": masked_binary_cross_entropy(probability, frame.tool, frame.fov)}

    # ---- densification ----
    @torch.no_grad()
    def densify_weights(self, context: RenderContext) -> Tensor | None:
        state, frame = context.state, context.frame
        tool = self.tool_members(context.gaussians)
        weights = torch.ones(tool.shape[0])
        proxy = self.proxy(state, context.gaussians)
        if proxy is not None:
            margin = self.config.densify_margin * float(self.unit)
            near = proxy.sdf(state.means, 2 * margin) < margin
            weights[near & ~tool if self.config.densify_tool else near] = 0.0
        self._remember_tissue(frame)
        occluded, pixels = self._occluded(context, tool)
        if occluded.any():
            observed = self.last_tissue_image[pixels[occluded, 1], pixels[occluded, 0]]
            colour = (state.sh[occluded, 0] * SH_C0 + 0.5).clamp(0, 1)
            difference = (colour - observed).abs().mean(dim=1)
            weights[occluded] *= torch.exp(-difference / self.config.occlusion_sigma)
        return weights

    def _remember_tissue(self, frame) -> None:
        """Keep, per pixel, the latest training observation of it as tissue."""
        if self.last_tissue_image.shape != frame.image.shape:
            self.last_tissue_image = frame.image.clone()
        self.last_tissue_image = torch.where(frame.tissue[..., None], frame.image,
                                             self.last_tissue_image)

    def _occluded(self, context: RenderContext, tool: Tensor) -> tuple[Tensor, Tensor]:
        """[N] bool: tissue Gaussians whose projected centre is behind rendered tool; [N, 2]
        long pixel (column, row) of every Gaussian's centre (clamped into the image)."""
        projection, output = context.output.projection, context.output
        height, width = output.depth.shape
        centre = projection.means2d.detach().floor().long()
        inside = ((centre[:, 0] >= 0) & (centre[:, 0] < width) & (centre[:, 1] >= 0)
                  & (centre[:, 1] < height) & (projection.radii > 0))
        pixels = torch.stack([centre[:, 0].clamp(0, width - 1),
                              centre[:, 1].clamp(0, height - 1)], dim=1)
        behind_tool = output.extras[TOOL_CHANNEL][pixels[:, 1], pixels[:, 0], 0] > 0.5
        nearer = output.depth.detach()[pixels[:, 1], pixels[:, 0]] < projection.depths.detach()
        return inside & ~tool & behind_tool & nearer, pixels

    # ---- diagnostics ----
    @torch.no_grad()
    def frame_diagnostics(self, state: GaussianState, gaussians: GaussianModel,
                          when: FrameTime) -> Diagnostics:
        tool = self.tool_members(gaussians)
        tissue = ~tool
        proxy = self.proxy(state, gaussians)
        collisions = 0
        if proxy is not None and tissue.any():
            collisions = int((proxy.sdf(state.means[tissue], 1.0) < 0).sum())
        graph = neighbour_graph(gaussians.params["means"], tissue, self.config.strain_neighbours)
        strain = 0.0
        if tissue.any():
            strain = float(arap_strain(state.means, gaussians.params["means"], graph).mean())
        return Diagnostics(summed={"collisions": collisions},
                           averaged={"arap_strain_mean": strain},
                           conventions=self.diagnostics_conventions())

    def diagnostics_conventions(self) -> dict[str, str]:
        """What `frame_diagnostics` measures, for metrics.json's conventions."""
        return {"collisions": "tissue Gaussians inside the tool proxy (balls of the tool "
                              "Gaussians' smallest scale), summed over test frames (methods "
                              "with a tool field)",
                "arap_strain_mean": "Eq. 4 ARAP strain per tissue Gaussian over its canonical "
                                    f"{self.config.strain_neighbours} nearest neighbours, scene "
                                    "units squared, mean over test frames"}


def masked_binary_cross_entropy(probability: Tensor, target: Tensor, mask: Tensor) -> Tensor:
    """Mean binary cross-entropy of probabilities [H, W] in (0, 1) against the bool target
    [H, W] over the pixels of the bool mask [H, W] (0 without any). The log of the probability
    of each pixel's own label, on the whole image: the same value and gradient as
    F.binary_cross_entropy of the masked pixels, without gathering them (a third of the time
    on a CPU)."""
    weights = mask.to(probability.dtype)
    likelihood = torch.where(target, probability, 1.0 - probability)
    return -(likelihood.log() * weights).sum() / weights.sum().clamp_min(1.0)


def _icp(tree, model: np.ndarray, target: np.ndarray, rotation: np.ndarray,
         translation: np.ndarray, iterations: int) -> tuple[np.ndarray, np.ndarray]:
    """Rigid (rotation [3, 3], translation [3]) taking `model` [K, 3] (in `tree`) onto the
    observed `target` [M, 3]: each iteration matches every target point, mapped back into the
    model frame, to its nearest model point and solves the best rigid fit (Kabsch)."""
    from scipy.spatial.transform import Rotation

    for _ in range(iterations):
        back = (target - translation) @ rotation  # target in the model frame
        _, nearest = tree.query(back, workers=1)
        source = model[nearest]
        source_centre, target_centre = source.mean(0), target.mean(0)
        fitted, _ = Rotation.align_vectors(target - target_centre, source - source_centre)
        rotation = fitted.as_matrix()
        translation = target_centre - rotation @ source_centre
    return rotation, translation
