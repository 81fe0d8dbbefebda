"""LumiState's reflectance x illumination decomposition as a component (`lumistate.txt` Section 2).

- Illumination estimation (Eq. 2-3): an `IlluminationUNet` on each training frame's brightness
  S_t = max(R, G, B), stored downsampled in the buffer `brightness` [F, h, w] at setup, so that
  checkpoints and resumed runs keep it. Its bottleneck gives the embedding e_t and its decoder
  the illumination map L_t [h, w] in [0, 1], upsampled bilinearly to the frame.
- Illumination-decoupled rendering (Eq. 4): `transform` modulates every Gaussian's SH
  coefficients c_i (degree 0 up to `sh_degree`) with c'_i = c_i exp(sigma_i) + delta_i / Y0,
  sigma_i and delta_i [K, 3] predicted by a 4-layer fusion MLP from e_t and the sinusoidal
  encoding of the Gaussian's deformed position (normalised by the initial point cloud's centre
  and extent). The position is what makes the modulation vary across the tissue, i.e. what
  models the near-field attenuation (Section 2.1). The position is detached, as in the
  Deformable-3DGS family the paper builds on: the modulation's colour loss moves colours and
  the MLP, never the geometry. Eq. 4 acts on the colour the coefficients
  represent, the SH convention's +0.5 included, so that exp(sigma) scales the reflectance colour
  itself. sigma is bounded to +-`max_log_gain` (a tanh). The MLP's last layer starts with zero
  weights, delta at 0 and every sigma at the log of the training frames' mean brightness S_t:
  training starts from one uniform illumination, so that Stage 1 fits base colours at the scale
  of a reflectance, not of the lit colour that Stage 2 would have to double (a deviation, see
  docs/methods/lumistate.md, Deviations).
- The fusion MLP runs on the occupied corners of a grid of `modulation_grid` cells per side over
  the normalised positions, and each Gaussian takes the trilinear interpolation of its cell's 8
  corners (a deviation: the paper evaluates the MLP at every Gaussian). Illumination is smooth,
  and the corners are about 30x fewer than the Gaussians of a tissue surface.
- The unmodulated (canonical) coefficients render the reflectance R_t as the channel
  `output.extras["reflectance"]` [H, W, 3]; each Gaussian's rendered colour over its reflectance
  colour (channel sums) renders the gain G_t, `output.extras["gain"]` [H, W, 1], the
  illumination the modulation carries.
- Embedding cache and Eq. 5: the UNet runs only in training steps (module in training mode and
  gradients on) on training frames: `before_render` encodes the step's frame once (a
  `StepIllumination`, whose features and e_t the step's transform and losses share) and stores
  its e_t in the buffer `embeddings` [F, E]; in Stage 2 the step's losses decode its L_t, which
  `after_step` stores in `illumination_maps` [F, h, w]; `transform` only reads them. Switching
  the module to evaluation mode (`eval()`, as a loaded run is) recomputes both caches for every
  training frame with the final UNet, once, so that no entry is left from an earlier state of
  the network.
  Every other render (evaluation, videos, test frames) takes e_t and L_t linearly interpolated
  between the two nearest training times (Eq. 5), with no UNet inference; such renders also
  carry the upsampled L_t as `output.extras["illumination"]` [H, W, 1]. A frame whose map Stage 2
  never computed keeps the map 1 (uniform light).
- Losses "retinex" (Eq. 7), "bright_channel" (Eq. 8) and "illumination_transfer" (G_t against
  L_t, a deviation, measured in docs/methods/lumistate.md, Deviations), see retinex.py. Stage 2
  is these terms' `start` (a fraction of the run) in the method config; before it the decoder
  never runs (Stage 1: "illumination is not explicitly predicted; only e_t modulates
  appearance").
- Relighting (the component provides `Relighting`, `model.capabilities`): `relit("uniform")`
  renders every time under the mean of the training frames' embeddings and maps (one constant
  illumination state); `relit(frame)` under frame `frame`'s.
- Shown channels (`channel_descriptors`): the reflectance (colour) and the illumination (grey
  over [0, 1]), under the standard names of a decomposition (`model.channels`).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from surgsplat.errors import SurgsplatError
from surgsplat.methods.lumistate.illumination import LEVELS, IlluminationUNet, brightness
from surgsplat.methods.lumistate.retinex import (bright_channel_loss, illumination_transfer_loss,
                                      retinex_loss)
from surgsplat.model.capabilities import UNIFORM, Relighting
from surgsplat.model.channels import (ILLUMINATION, REFLECTANCE, ChannelDescriptor, ChannelKind,
                                      Colormap)
from surgsplat.model.component import (Component, ComponentConfig, FrameTime, ParamGroup,
                                       RenderContext, SceneInfo, SetupContext)
from surgsplat.model.phases import Phase
from surgsplat.model.state import GaussianState
from surgsplat.model.timeline import interpolate_in_time
from surgsplat.render.sh import SH_C0, sh_colour

MAP_MULTIPLE = 2 ** (LEVELS - 1)
"""The illumination maps' sides are multiples of this (the UNet pools twice)."""
GAIN_FLOOR = 0.05
"""Smallest canonical colour (sum of the 3 channels) the gain channel divides by."""


@dataclass
class LumiStateConfig(ComponentConfig, kind="lumistate"):
    """The illumination network, the SH modulation and their learning rates."""

    map_side: int = field(default=32, metadata={"range": "[4, 1024]"})
    """Shorter side, pixels, of the brightness and illumination maps the UNet works on
    (rounded to a multiple of 4). Illumination is smooth, so a coarse map suffices; 32 (32 x 40
    for 640 x 512 frames) keeps the UNet's share of a CPU training step small."""
    unet_channels: int = field(default=8, metadata={"range": "[1, inf)"})
    """Feature maps of the UNet's first level (doubling at each of its 3 levels)."""
    embedding_dim: int = field(default=16, metadata={"range": "[1, inf)"})
    """Size of the illumination embedding e_t."""
    pe_frequencies: int = field(default=4, metadata={"range": "[0, 16]"})
    """Octaves of the sinusoidal positional encoding of the Gaussians' deformed means."""
    mlp_width: int = field(default=64, metadata={"range": "[1, inf)"})
    """Width of the fusion MLP's three hidden layers."""
    modulation_grid: int = field(default=32, metadata={"range": "[1, 256]"})
    """Cells per side of the grid (over the initial points' centre +- extent) on whose occupied
    corners the fusion MLP runs; each Gaussian takes the trilinear interpolation of its cell's
    corners. 32 samples the finest encoding octave (pe_frequencies 4) 4 times per period."""
    sh_degree: int = field(default=1, metadata={"range": "[0, 3]"})
    """Modulate the SH coefficients up to this degree (higher ones pass unchanged)."""
    max_log_gain: float = field(default=3.0, metadata={"range": "(0, inf)"})
    """Bound of |sigma_i| (the multiplicative term is at most exp of this)."""
    bright_radius: int = field(default=2, metadata={"range": "[0, inf)"})
    """r0 of the bright-channel prior's max-pooling window 2 r0 + 1 (Eq. 8), pixels."""
    unet_lr: float = field(default=1e-3, metadata={"range": "(0, inf)"})
    """Adam learning rate of the UNet at iteration 0 (decays to a tenth at the end)."""
    mlp_lr: float = field(default=1e-3, metadata={"range": "(0, inf)"})
    """Adam learning rate of the fusion MLP at iteration 0 (decays to a tenth at the end)."""
    num_frames: int = field(default=0, metadata={"range": "[0, inf)"})
    """Frames of the clip (set when resolved for a scene)."""
    map_height: int = field(default=0, metadata={"range": "[0, inf)"})
    """Height of the maps, pixels (set when resolved for a scene)."""
    map_width: int = field(default=0, metadata={"range": "[0, inf)"})
    """Width of the maps, pixels (set when resolved for a scene)."""

    def resolve(self, scene: SceneInfo) -> "LumiStateConfig":
        """This config for the scene: its frame count and the maps' size (aspect kept)."""
        scale = self.map_side / min(scene.width, scene.height)

        def side(pixels: int) -> int:
            return max(MAP_MULTIPLE, round(pixels * scale / MAP_MULTIPLE) * MAP_MULTIPLE)

        return dataclasses.replace(self, num_frames=scene.num_frames,
                                   map_height=side(scene.height), map_width=side(scene.width))

    def build(self) -> "LumiState":
        return LumiState(self)


def positional_encoding(points: Tensor, octaves: int) -> Tensor:
    """[N, 3] -> [N, 3 + 6 octaves]: the points and sin, cos of 2^k pi points, k < octaves."""
    scales = math.pi * 2.0 ** torch.arange(octaves, dtype=points.dtype)  # [octaves]
    angles = (points[:, None, :] * scales[:, None]).flatten(1)  # [N, 3 octaves]
    return torch.cat([points, angles.sin(), angles.cos()], dim=1)


CORNERS = torch.tensor([[i >> 2 & 1, i >> 1 & 1, i & 1] for i in range(8)])
"""[8, 3] offsets of a grid cell's corners from its lowest one."""


def grid_corners(points: Tensor, cells: int) -> tuple[Tensor, Tensor, Tensor]:
    """What trilinear interpolation at points [N, 3] needs from a grid of spacing 2 / cells
    (a corner at 0): (corners [U, 3], the distinct corners of the cells holding a point; index
    [N, 8] into them; weights [N, 8], non-negative, summing to 1 per point), so that a function
    f sampled at the corners interpolates as sum_k weights[:, k] f(corners[index[:, k]]).
    Points may lie anywhere: only occupied cells count."""
    grid = (points + 1.0) * (cells / 2)  # grid units
    lowest = grid.floor()
    fraction = grid - lowest  # [N, 3] in [0, 1)
    lowest = lowest.long()
    origin = lowest.min(dim=0).values
    cell_ids = lowest - origin  # [N, 3] >= 0
    sides = cell_ids.max(dim=0).values + 2  # corner ids reach one past the last cell
    strides = torch.stack([sides[1] * sides[2], sides[2], torch.ones_like(sides[2])])  # [3]
    cells_used, cell_of_point = torch.unique(cell_ids @ strides, return_inverse=True)  # [V], [N]
    cell_coords = torch.stack([cells_used // strides[0], cells_used // strides[1] % sides[1],
                               cells_used % sides[2]], dim=1)  # [V, 3]
    corner_keys = ((cell_coords[:, None] + CORNERS) @ strides).flatten()  # [V * 8]
    keys, corner_of_cell = torch.unique(corner_keys, return_inverse=True)  # [U], [V * 8]
    corner_coords = torch.stack([keys // strides[0], keys // strides[1] % sides[1],
                                 keys % sides[2]], dim=1) + origin  # [U, 3]
    index = corner_of_cell.view(-1, 8)[cell_of_point]  # [N, 8]
    x, y, z = torch.stack([1.0 - fraction, fraction], dim=2).unbind(1)  # [N, 2] each
    weights = (x[:, :, None, None] * y[:, None, :, None] * z[:, None, None, :]).flatten(1)
    return corner_coords.to(points.dtype) * (2.0 / cells) - 1.0, index, weights


def interpolate_corners(at_corners: Tensor, index: Tensor, weights: Tensor) -> Tensor:
    """[N, C]: sum_k weights[:, k] at_corners[index[:, k]], for at_corners [U, C] (with
    gradients), index [N, 8] and weights [N, 8] (constants) from `grid_corners`. The same values
    and gradients as F.embedding_bag(index, at_corners, per_sample_weights=weights, mode="sum"),
    with the gradient computed as a sparse product: 3 to 5 times faster on a CPU than the
    embedding bag's own backward (48600 Gaussians, 1511 corners, 24 channels)."""
    return _InterpolateCorners.apply(at_corners, index, weights)


class _InterpolateCorners(torch.autograd.Function):
    @staticmethod
    def forward(ctx, at_corners: Tensor, index: Tensor, weights: Tensor) -> Tensor:
        ctx.save_for_backward(index, weights)
        ctx.corners = at_corners.shape[0]
        return F.embedding_bag(index, at_corners, per_sample_weights=weights, mode="sum")

    @staticmethod
    def backward(ctx, grad: Tensor) -> tuple[Tensor, None, None]:
        index, weights = ctx.saved_tensors
        points = torch.arange(index.shape[0]).repeat_interleave(index.shape[1])
        transposed = torch.sparse_coo_tensor(  # indices in range by construction
            torch.stack([index.reshape(-1), points]), weights.reshape(-1),
            (ctx.corners, index.shape[0]), check_invariants=False)
        return torch.sparse.mm(transposed, grad.contiguous()), None, None


class FusionMLP(nn.Module):
    """F_psi: (positional encoding [N, P], embedding [E]) -> (sigma, delta) [N, K, 3] each; four
    linear layers, the first applied to the concatenation [pe, e] (computed as two products so
    that the embedding's part is computed once)."""

    def __init__(self, encoding_dim: int, embedding_dim: int, width: int, coeffs: int):
        super().__init__()
        self.encoding_dim, self.coeffs = encoding_dim, coeffs
        self.first = nn.Linear(encoding_dim + embedding_dim, width)
        self.hidden = nn.Sequential(nn.ReLU(), nn.Linear(width, width), nn.ReLU(),
                                    nn.Linear(width, width), nn.ReLU())
        self.last = nn.Linear(width, 2 * coeffs * 3)
        nn.init.zeros_(self.last.weight)
        nn.init.zeros_(self.last.bias)

    def forward(self, encoding: Tensor, embedding: Tensor) -> Tensor:
        """[N, 2 K 3]: sigma then delta, each [K, 3] flattened."""
        weight = self.first.weight
        from_embedding = embedding @ weight[:, self.encoding_dim:].T + self.first.bias  # [W]
        x = encoding @ weight[:, :self.encoding_dim].T + from_embedding  # [N, W]
        return self.last(self.hidden(x))


@dataclass
class StepIllumination:
    """LumiState's work on the frame of a training step, kept from `before_render` to
    `after_step`."""

    index: int  # the frame
    features: list[Tensor]  # the UNet encoder's feature maps of its brightness (step's graph)
    embedding: Tensor  # e_t [E] (step's graph)
    low: Tensor | None = None  # L_t [h, w] as the step's Stage-2 losses decoded it (detached)


class LumiState(Component):
    """See the module docstring."""
    phase = Phase.ILLUMINATION
    provides = (Relighting,)

    def __init__(self, config: LumiStateConfig):
        super().__init__()
        if (config.num_frames < 1 or config.map_height < MAP_MULTIPLE
                or config.map_width < MAP_MULTIPLE):
            raise SurgsplatError("lumistate: the config must be resolved for a scene (num_frames, "
                                 "map_height, map_width) before it is built")
        if not 0 <= config.sh_degree <= 3:
            raise SurgsplatError(f"lumistate sh_degree must be 0..3, got {config.sh_degree}")
        if config.modulation_grid < 1:
            raise SurgsplatError(f"lumistate modulation_grid must be >= 1 cell, got "
                                 f"{config.modulation_grid}")
        self.config = config
        frames, height, width = config.num_frames, config.map_height, config.map_width
        self.unet = IlluminationUNet(config.unet_channels, config.embedding_dim)
        self.fusion = FusionMLP(3 + 6 * config.pe_frequencies, config.embedding_dim,
                                config.mlp_width, (config.sh_degree + 1) ** 2)
        self.register_buffer("brightness", torch.zeros(frames, height, width))  # [F, h, w]
        self.register_buffer("embeddings", torch.zeros(frames, config.embedding_dim))  # [F, E]
        self.register_buffer("illumination_maps", torch.ones(frames, height, width))  # [F, h, w]
        self.register_buffer("known", torch.zeros(frames, dtype=torch.bool))  # training frames
        self.register_buffer("mapped", torch.zeros(frames, dtype=torch.bool))  # Stage 2 saw it
        self.register_buffer("centre", torch.zeros(3))  # initial points' centroid
        self.register_buffer("extent", torch.ones(()))  # their largest distance from it
        self.relight_source: str | int | None = None
        self._step: StepIllumination | None = None  # from before_render to after_step

    # ---- setup ----
    def setup(self, context: SetupContext) -> None:
        self.centre.copy_(context.points.mean(dim=0))
        self.extent.fill_(max(context.scene_extent, 1e-6))
        for frame in context.frames:
            self.known[frame.index] = True
            self.brightness[frame.index] = self.downsample(brightness(frame.image))
        with torch.no_grad():  # every sigma starts at the log mean brightness (module docstring)
            bound = self.config.max_log_gain
            log_mean = self.brightness[self.known].mean().clamp_min(1e-3).log() / bound
            start = bound * log_mean.clamp(-0.9, 0.0).atanh()
            self.fusion.last.bias[:self.fusion.coeffs * 3] = start
        self.refresh_caches()

    def train(self, mode: bool = True) -> "LumiState":
        """nn.Module.train; leaving training mode refreshes the caches (module docstring)."""
        if self.training and not mode:
            self.refresh_caches()
        return super().train(mode)

    @torch.no_grad()
    def refresh_caches(self) -> None:
        """Recompute e_t of every training frame, and L_t of those Stage 2 has seen, with the
        current UNet."""
        index = self.known.nonzero()[:, 0]
        features, embeddings = self.unet.encode(self.brightness[index])
        self.embeddings[index] = embeddings
        mapped = self.mapped[index]
        if mapped.any():
            self.illumination_maps[index[mapped]] = self.unet.decode(features)[mapped]

    def downsample(self, image_map: Tensor) -> Tensor:
        """[H, W] full-resolution map -> [h, w] (area average)."""
        size = (self.config.map_height, self.config.map_width)
        return F.interpolate(image_map[None, None], size=size, mode="area")[0, 0]

    def param_groups(self) -> list[ParamGroup]:
        config = self.config
        return [ParamGroup("illumination_unet", list(self.unet.parameters()), config.unet_lr,
                           config.unet_lr / 10),
                ParamGroup("illumination_fusion", list(self.fusion.parameters()), config.mlp_lr,
                           config.mlp_lr / 10)]

    # ---- illumination state of a moment ----
    def is_live(self, when: FrameTime) -> bool:
        """Whether the UNet runs for `when`: a training step on a training frame."""
        return (self.training and torch.is_grad_enabled() and self.relight_source is None
                and bool(self.known[when.index]))

    def embedding(self, when: FrameTime) -> Tensor:
        """e_t [E] of `when`: the UNet's in a training step, else cached / interpolated."""
        if self.is_live(when):
            return self.step_of(when.index).embedding
        return self.cached_state(self.embeddings, when)

    def encode(self, index: int) -> StepIllumination:
        """The UNet's encoding of training frame `index`, differentiable in the UNet."""
        features, embedding = self.unet.encode(self.brightness[index][None])
        return StepIllumination(index, features, embedding[0])

    def step_of(self, index: int) -> StepIllumination:
        """The encoding of training frame `index` in this step: the one `before_render` kept,
        or else a new one (not kept)."""
        if self._step is not None and self._step.index == index:
            return self._step
        return self.encode(index)

    def cached_state(self, table: Tensor, when: FrameTime) -> Tensor:
        """table's entry [...] for `when` under the relight source: Eq. 5's interpolation
        between the nearest training frames, or their mean for "uniform"."""
        index = self.known.nonzero()[:, 0]
        if self.relight_source == UNIFORM:
            return table[index].mean(dim=0)
        time = when.time if self.relight_source is None else \
            self.relight_source / self.config.num_frames
        return interpolate_in_time(table[index], index.to(torch.float64) / self.config.num_frames,
                                   time)

    @contextmanager
    def relit(self, source: str | int) -> Iterator[None]:
        """Render under illumination `source` while the block runs: "uniform" or a frame index."""
        if source != UNIFORM and not (isinstance(source, int)
                                      and 0 <= source < self.config.num_frames):
            raise SurgsplatError(f"relight source must be {UNIFORM!r} or a frame index in "
                                 f"[0, {self.config.num_frames}), got {source!r}")
        previous, self.relight_source = self.relight_source, source
        try:
            yield
        finally:
            self.relight_source = previous

    # ---- the component contract ----
    def before_render(self, gaussians, when: FrameTime) -> None:
        """In a training step (`is_live`), encode its frame once for the step and cache e_t."""
        if self.is_live(when):
            self._step = self.encode(when.index)
            self.embeddings[when.index] = self._step.embedding.detach()

    def after_step(self, gaussians, iteration: int) -> None:
        """Cache the L_t that the step's losses decoded (Stage 2); forget the step."""
        step, self._step = self._step, None
        if step is not None and step.low is not None:
            self.illumination_maps[step.index] = step.low
            self.mapped[step.index] = True

    def transform(self, state: GaussianState, gaussians, when: FrameTime) -> GaussianState:
        """Eq. 4 on the coefficients up to `sh_degree` (see the module docstring)."""
        embedding = self.embedding(when)
        points = (state.means.detach() - self.centre) / self.extent  # no gradient to geometry
        corners, index, weights = grid_corners(points, self.config.modulation_grid)
        at_corners = self.fusion(positional_encoding(corners, self.config.pe_frequencies),
                                 embedding)  # [U, 2 K 3]
        out = interpolate_corners(at_corners, index, weights)  # [N, 2 K 3]
        log_gain, offset = out.view(-1, 2, self.fusion.coeffs, 3).unbind(1)  # [N, K, 3] each
        coeffs = min(self.fusion.coeffs, state.sh.shape[1])
        bound = self.config.max_log_gain
        log_gain = bound * torch.tanh(log_gain[:, :coeffs] / bound)
        grey = torch.zeros_like(state.sh[:1, :coeffs])  # the +0.5 of the SH colour, as a DC term
        grey[0, 0] = 0.5 / SH_C0
        modulated = (state.sh[:, :coeffs] + grey) * log_gain.exp() - grey \
            + offset[:, :coeffs] / SH_C0
        return state.replace(sh=torch.cat([modulated, state.sh[:, coeffs:]], dim=1))

    def render_channels(self, state: GaussianState, gaussians, camera,
                        when: FrameTime) -> dict[str, Tensor]:
        """The reflectance: the canonical (unmodulated) coefficients' colour [N, 3]; the gain
        [N, 1]: the rendered (modulated, exposed) colour's channel sum over the reflectance's,
        i.e. the illumination each Gaussian carries. A training step's render holds each only
        when a loss of the step reads it (the reflectance "retinex", the gain
        "illumination_transfer"): outside Stage 2 they would cost the rasteriser 4 channels for
        nothing."""
        channels = {}
        wants_gain = when.serves("illumination_transfer")
        if not (when.serves("retinex") or wants_gain):
            return channels
        reflectance = sh_colour(state.sh_degree, gaussians.sh_coeffs(), state.means,
                                camera.world_to_camera)  # [N, 3]
        if when.serves("retinex"):
            channels[REFLECTANCE] = reflectance
        if wants_gain:
            lit = sh_colour(state.sh_degree, state.sh, state.means, camera.world_to_camera)
            gain = lit.sum(dim=1) / reflectance.sum(dim=1).clamp_min(GAIN_FLOOR)  # [N]
            channels["gain"] = gain[:, None]
        return channels

    def channel_descriptors(self) -> tuple[ChannelDescriptor, ...]:
        return (ChannelDescriptor(REFLECTANCE, ChannelKind.COLOUR),
                ChannelDescriptor(ILLUMINATION, ChannelKind.SCALAR, Colormap.GRAY, (0.0, 1.0)))

    def finish_render(self, output, camera, when: FrameTime) -> None:
        if not self.is_live(when):
            low = self.cached_state(self.illumination_maps, when)
            output.extras[ILLUMINATION] = self.upsample(low, camera.height, camera.width)[..., None]

    @staticmethod
    def upsample(low: Tensor, height: int, width: int) -> Tensor:
        """[h, w] map -> [height, width] (bilinear)."""
        return F.interpolate(low[None, None], size=(height, width), mode="bilinear",
                             align_corners=False)[0, 0]

    def loss_names(self) -> tuple[str, ...]:
        return ("retinex", "bright_channel", "illumination_transfer")

    def losses(self, context: RenderContext, active: frozenset[str]) -> dict[str, Tensor]:
        """Stage 2's terms from this step's L_t (the decoder on the step's UNet features), which
        the step keeps for `after_step` to cache."""
        frame = context.frame
        step = self.step_of(context.when.index)
        low = self.unet.decode(step.features)[0]  # [h, w]
        step.low = low.detach()
        illumination = self.upsample(low, frame.image.shape[0], frame.image.shape[1])
        terms = {}
        if "retinex" in active:
            terms["retinex"] = retinex_loss(context.output.extras[REFLECTANCE], illumination,
                                            frame.image, frame.tissue)
        if "bright_channel" in active:
            terms["bright_channel"] = bright_channel_loss(illumination, frame.image, frame.tissue,
                                                          self.config.bright_radius)
        if "illumination_transfer" in active:
            terms["illumination_transfer"] = illumination_transfer_loss(
                context.output.extras["gain"], illumination, context.output.alpha, frame.tissue)
        return terms
