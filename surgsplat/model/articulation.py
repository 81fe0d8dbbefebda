"""A grasper's articulation from per-frame observations of its surface, as a shaft with two
revolute jaws.

The tool field moves all tool Gaussians with ONE rigid pose per frame, so the jaws' own motion
is not in the model. It is recovered after training from what each frame observed: the frame's
tool pixels back-projected with its depth and mapped into the canonical tool frame by the
inverse of the tool field's pose ("observations"). That pose is not exact: a cylindrical shaft
does not pin down its roll about its own axis or its slide along it, and the tool field drifts
in both (degrees of roll, millimetres of slide on the phantom). So every frame's shaft frame is
measured from its own observation, and the roll from the jaws:

1. The shaft, per frame: a cylinder fitted to the observed points (robust least squares, the
   jaws are outliers). Its surface points fill the axis densely (a jaw crossing the cylinder
   leaves only sparse ones); the front end of that dense run is the hinge point. The cylinder
   is fitted again without the points beyond the run. The forward direction (shaft into jaws) points to the end
   whose off-cylinder points (cap and jaws) outnumber the other's, voted over all frames.
   Frames whose fitted radius is off the median (too little shaft seen) are left out.
   The observed points ahead of the hinge are the jaws.
2. Jaw templates from one frame where the jaws are open: the frame whose jaw points spread
   most across the shaft (largest ratio of their two spreads normal to it). There the points
   are split by the side of the opening they lie on, each jaw's long axis is its principal
   direction, the hinge axis is normal to both long axes, and each jaw's angle is its long
   axis's angle from forward about the hinge axis (right-hand rule). Each jaw's points turned
   back to angle 0 are its template; jaw a is the one at the smaller angle. Seen from one
   side, the long axes put the hinge's roll off by degrees, and templates built about a
   wrong hinge are tilted, so they fit frames at other angles worse: the roll is searched
   (+-roll_search_deg) for the templates that fit all frames best (step 3).
3. Tracking, outwards in time from the template frame: per frame, the hinge axis's roll about
   the shaft and the two jaw angles are fitted jointly (Gauss-Newton ICP, 3 unknowns) so that
   the templates, turned to those angles, cover the frame's jaw points; each observed point
   belongs to the template it lies nearest (so a jaw keeps its name over time) and matches
   beyond trim_factor x the median are dropped. A jaw matched by fewer than min_points
   observed points, or whose fitted template is less than min_coverage covered by them, is
   not observed in that frame (the fit is redone without it; its angle is left to
   interpolation, not invented); a frame whose fit leaves an RMS distance above max_fit_rms, or that sees no jaw,
   is left out.
4. Parts of the canonical tool: the tool Gaussians (and the template frame's observed points)
   behind the hinge of the template frame are the shaft, the others belong to the nearer jaw
   template.

Everything is in the canonical tool frame and the scene's unit; `Articulation` holds the result.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation, Slerp

from surgsplat.data.phantom.kinematics import hinge_frame

SHAFT, JAW_A, JAW_B = 0, 1, 2
"""Part labels of the canonical tool points."""
PART_NAMES = ("shaft", "jaw_a", "jaw_b")
MIN_TURN_DEG = 5.0
"""The jaws' opening must change by at least this over the frames for them to be a joint."""
_X, _Z = np.array([1.0, 0.0, 0.0]), np.array([0.0, 0.0, 1.0])


@dataclass(frozen=True)
class ArticulationOptions:
    """How the articulation is estimated (lengths in scene units)."""

    surface_tolerance: float = 0.25
    """Observed points this near the fitted cylinder are the shaft's surface (also the scale
    of the fit's robust loss)."""
    bin_width: float = 1.0
    """The shaft's surface points are counted along its axis in bins this wide; its surface is
    the run of bins around the middle holding at least a quarter of the median count
    (surface-near points beyond, e.g. of a jaw crossing the cylinder, are not shaft)."""
    radius_tolerance: float = 0.05
    """Frames whose fitted shaft radius is off the median radius by more than this fraction
    are left out (too little shaft in view to fit it)."""
    hinge_margin: float = 0.2
    """Observed points more than this ahead of the shaft's front end are jaw points."""
    min_points: int = 12
    """A frame needs this many observed points of a jaw for that jaw's angle to be fitted."""
    min_template_points: int = 60
    """The template frame needs this many jaw points."""
    min_template_opening_deg: float = 10.0
    """The template frame's jaws must be at least this far apart (else they cannot be told
    apart and the hinge axis is undetermined)."""
    roll_search_deg: float = 8.0
    """The template frame's hinge roll is searched this far (degrees) around the normal of its
    jaws' long axes."""
    min_coverage: float = 0.3
    """A jaw is seen in a frame when at least this fraction of its template, fitted, lies
    within coverage_distance of the frame's points (else a hidden jaw's template could settle
    on the other jaw)."""
    coverage_distance: float = 0.5
    """See min_coverage."""
    icp_iterations: int = 30
    """Gauss-Newton ICP iterations per frame."""
    trim_factor: float = 3.0
    """ICP drops matches farther than this times the median match distance."""
    max_fit_rms: float = 0.5
    """Frames whose jaw fit leaves a larger RMS match distance are left out."""


@dataclass(frozen=True)
class Observation:
    """What one frame saw of the tool, in the canonical tool frame."""

    index: int
    """Frame index."""
    points: np.ndarray
    """[M, 3] observed tool points (scene units) mapped into the canonical tool frame."""


@dataclass
class Articulation:
    """A shaft with two revolute jaws, in the canonical tool frame (scene units, degrees)."""

    points: np.ndarray
    """[P, 3] the canonical tool points (tool Gaussians, then the template frame's observed
    points), labelled in `labels`."""
    labels: np.ndarray
    """[P] int: SHAFT, JAW_A or JAW_B per point."""
    axis: np.ndarray
    """[3] unit hinge axis of the template frame (the canonical one)."""
    hinge_point: np.ndarray
    """[3] the hinge point of the template frame (the shaft's front end on its axis)."""
    forward: np.ndarray
    """[3] unit shaft direction towards the jaws, normal to the axis."""
    frames: np.ndarray
    """[F] frame indices with an estimate."""
    shaft_motion: np.ndarray
    """[F, 4, 4] per frame, canonical -> canonical motion taking the template frame's shaft
    frame to that frame's (the residual of the tool field's pose)."""
    jaw_angles_deg: np.ndarray
    """[F, 2] each jaw's angle from `forward` about `axis`, right-hand rule."""
    jaw_observed: np.ndarray
    """[F, 2] bool: the frame saw enough of the jaw for its angle to be fitted."""
    canonical_jaw_deg: np.ndarray
    """[2] the jaws' angles in the template frame."""

    def jaw_angles_at(self, index: int) -> np.ndarray:
        """[2] each jaw's angle (degrees) at frame `index`: linear in frame index between the
        frames that saw the jaw, the nearest one's outside them."""
        return np.array([np.interp(index, self.frames[self.jaw_observed[:, j]],
                                   self.jaw_angles_deg[self.jaw_observed[:, j], j])
                         for j in range(2)])

    def shaft_motion_at(self, index: int) -> np.ndarray:
        """[4, 4] the shaft's motion at frame `index`: estimated there, else interpolated
        between the estimated frames around it (rotation slerped, translation linear in frame
        index), the nearest one's outside them."""
        after = int(np.searchsorted(self.frames, index))
        if after < len(self.frames) and self.frames[after] == index:
            return self.shaft_motion[after]
        if after == 0 or after == len(self.frames):
            return self.shaft_motion[min(after, len(self.frames) - 1)]
        pair = self.shaft_motion[after - 1:after + 1]  # [2, 4, 4]
        weight = (index - self.frames[after - 1]) / (self.frames[after] - self.frames[after - 1])
        motion = np.eye(4)
        motion[:3, :3] = Slerp([0.0, 1.0], Rotation.from_matrix(pair[:, :3, :3]))(
            weight).as_matrix()
        motion[:3, 3] = (1 - weight) * pair[0, :3, 3] + weight * pair[1, :3, 3]
        return motion


@dataclass(frozen=True)
class Cylinder:
    """A cylinder fitted to points."""

    centre: np.ndarray
    """[3] a point on the axis (near the points' centroid)."""
    direction: np.ndarray
    """[3] unit axis direction."""
    radius: float


@dataclass(frozen=True)
class _Shaft:
    """One frame's shaft with the hinge's roll still free."""

    frame: np.ndarray
    """[4, 4] canonical frame: origin the hinge point, x forward, z a fixed reference
    direction made normal to x (the hinge axis is z turned about x by the roll)."""
    jaws: np.ndarray
    """[J, 3] the frame's observed points ahead of the hinge, in `frame`."""


def _wrap_deg(angles: np.ndarray) -> np.ndarray:
    """Angles (degrees) wrapped into [-180, 180)."""
    return (np.asarray(angles) + 180.0) % 360.0 - 180.0


def estimate_articulation(canonical: np.ndarray, observations: list[Observation],
                          options: ArticulationOptions = ArticulationOptions()) -> Articulation:
    """The articulation of the tool whose canonical points are `canonical` [K, 3] (the tool
    Gaussians), from per-frame `observations`; ValueError when the data cannot support it
    (too little shaft seen, jaws never seen open, jaws that never turn)."""
    canonical = np.asarray(canonical, dtype=np.float64)
    shafts = _shafts(observations, _principal(canonical), options)
    if len(shafts) < 2:
        raise ValueError(f"the shaft could be fitted in {len(shafts)} of {len(observations)} "
                         "frames; at least two are needed")
    reference = _template_frame(shafts, options)
    side, along, roll = _open_jaws(shafts[reference].jaws)
    fit = _best_roll(shafts, reference, side, along, roll, options)
    if fit is None:
        raise ValueError("the jaw templates fit no frame")
    pose, templates, tracked = fit
    if np.degrees(abs(pose[2] - pose[1])) < options.min_template_opening_deg:
        raise ValueError(f"the jaws are never seen open by "
                         f"{options.min_template_opening_deg:g} degrees or more: they cannot "
                         "be told apart")
    frames = np.array(sorted(tracked))
    poses = np.array([tracked[i][0] for i in frames])  # [F, 3] roll, angle a, angle b
    opening = np.degrees(poses[:, 2] - poses[:, 1])
    if np.ptp(opening) < MIN_TURN_DEG:
        raise ValueError(f"the jaws never turn relative to each other by more than "
                         f"{MIN_TURN_DEG:g} degrees: they do not articulate")
    observed = np.array([tracked[i][1] for i in frames])  # [F, 2]
    if not observed.any(axis=0).all():
        raise ValueError("one jaw is never seen well enough to fit its angle")
    hinge_frames = np.stack([_hinge_frame(shafts[i].frame, tracked[i][0][0]) for i in frames])
    start = _hinge_frame(shafts[reference].frame, pose[0])  # [4, 4] canonical shaft frame
    points, labels = _label_parts(canonical, start, pose, templates, observations, reference,
                                  options)
    return Articulation(points=points, labels=labels, axis=start[:3, 2],
                        hinge_point=start[:3, 3], forward=start[:3, 0], frames=frames,
                        shaft_motion=hinge_frames @ np.linalg.inv(start),
                        jaw_angles_deg=_wrap_deg(np.degrees(poses[:, 1:])),
                        jaw_observed=observed,
                        canonical_jaw_deg=np.degrees(np.array(pose[1:])))


# ---- the shaft ----
def fit_cylinder(points: np.ndarray, direction: np.ndarray, tolerance: float) -> Cylinder:
    """The cylinder fitting points [N, 3] best (Cauchy loss of the distance to its surface,
    scale `tolerance`), its axis started along `direction` [3] through their centroid."""
    centroid = points.mean(axis=0)
    first, second = _normal_pair(direction)

    def unpack(parameters: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
        axis = direction + parameters[0] * first + parameters[1] * second
        return (centroid + parameters[2] * first + parameters[3] * second,
                axis / np.linalg.norm(axis), parameters[4])

    def residual(parameters: np.ndarray) -> np.ndarray:
        centre, axis, radius = unpack(parameters)
        return _distance_to_line(points, centre, axis) - radius

    start = float(np.median(_distance_to_line(points, centroid, direction)))
    fit = least_squares(residual, np.array([0.0, 0.0, 0.0, 0.0, start]), loss="cauchy",
                        f_scale=tolerance)
    centre, axis, radius = unpack(fit.x)
    return Cylinder(centre, axis, float(radius))


def _shafts(observations: list[Observation], direction: np.ndarray,
            options: ArticulationOptions) -> dict[int, _Shaft]:
    """Per frame index, the frame's shaft (frames where it cannot be fitted left out);
    direction [3]: the canonical tool's long axis, to start the fits and orient them."""
    fits = {}
    for observation in observations:
        if observation.points.shape[0] >= 3 * options.min_points:
            fit = _fit_shaft(observation.points, direction, options)
            if fit is not None:
                fits[observation.index] = fit
    if not fits:
        return {}
    forward_is_axis = sum(fit[4] for fit in fits.values()) >= 0
    radius = np.median([fit[0].radius for fit in fits.values()])
    reference = np.eye(3)[np.argmin(np.abs(direction))]  # fixed, never along the shaft
    shafts = {}
    for observation in observations:
        if observation.index not in fits:
            continue
        cylinder, axis, low, high, _ = fits[observation.index]
        if abs(cylinder.radius - radius) > options.radius_tolerance * radius:
            continue
        forward, end = (axis, high) if forward_is_axis else (-axis, -low)
        frame = _frame(forward, cylinder.centre + end * forward, reference)
        local = (observation.points - frame[:3, 3]) @ frame[:3, :3]  # [M, 3]
        shafts[observation.index] = _Shaft(frame, local[local[:, 0] > options.hinge_margin])
    return shafts


def _fit_shaft(points: np.ndarray, direction: np.ndarray, options: ArticulationOptions
               ) -> tuple[Cylinder, np.ndarray, float, float, int] | None:
    """(cylinder, its axis [3] oriented along `direction`, low and high end of its surface
    points along that axis, vote: off-surface points at the high end minus those at the low
    end) of one frame's points [M, 3]; the cylinder is fitted twice, the second time without
    the points beyond its surface's ends. None when too few points lie on it."""
    cylinder = fit_cylinder(points, direction, options.surface_tolerance)
    for refit in (True, False):
        axis = cylinder.direction if cylinder.direction @ direction >= 0 else -cylinder.direction
        along = (points - cylinder.centre) @ axis  # [M]
        surface = np.abs(_distance_to_line(points, cylinder.centre, axis)
                         - cylinder.radius) <= options.surface_tolerance
        if surface.sum() < 3 * options.min_points:
            return None
        low, high = _dense_run(along[surface], options.bin_width)
        if refit:
            within = (along >= low - options.bin_width) & (along <= high + options.bin_width)
            cylinder = fit_cylinder(points[within], axis, options.surface_tolerance)
    vote = int((~surface & (along > high - options.bin_width)).sum()
               - (~surface & (along < low + options.bin_width)).sum())
    return cylinder, axis, low, high, vote


def _dense_run(values: np.ndarray, width: float) -> tuple[float, float]:
    """(low, high) of the values [N] in the run of bins `width` wide around their median whose
    counts reach a quarter of the median count of the occupied bins (the shaft's surface; a
    jaw crossing the cylinder leaves sparser points)."""
    edges = np.arange(values.min(), values.max() + width, width)
    counts, edges = np.histogram(values, bins=edges if len(edges) > 1 else 1)
    dense = counts >= 0.25 * np.median(counts[counts > 0])
    middle = min(int(np.searchsorted(edges, np.median(values), side="right")) - 1,
                 len(counts) - 1)
    first = middle
    while first > 0 and dense[first - 1]:
        first -= 1
    last = middle
    while last < len(counts) - 1 and dense[last + 1]:
        last += 1
    chosen = values[(values >= edges[first]) & (values <= edges[last + 1])]
    return float(chosen.min()), float(chosen.max())


def _frame(forward: np.ndarray, origin: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """[4, 4] shaft frame (`hinge_frame`) at `origin` with x `forward` and z `reference` made
    normal to it."""
    z = reference - (reference @ forward) * forward
    return hinge_frame(forward, z / np.linalg.norm(z), origin)


def _hinge_frame(frame: np.ndarray, roll: float) -> np.ndarray:
    """[4, 4] the shaft frame `frame` turned about its x axis by `roll` (radians): z becomes
    the hinge axis."""
    turned = frame.copy()
    turned[:3, :3] = frame[:3, :3] @ _rotation(roll, _X)
    return turned


# ---- the jaws ----
def _template_frame(shafts: dict[int, _Shaft], options: ArticulationOptions) -> int:
    """Index of the frame whose jaw points spread most across the shaft (the most open)."""
    spreads = {}
    for index, shaft in shafts.items():
        if shaft.jaws.shape[0] >= options.min_template_points:
            across = shaft.jaws[:, 1:] - shaft.jaws[:, 1:].mean(axis=0)  # [J, 2]
            singular = np.linalg.svd(across, compute_uv=False)
            spreads[index] = singular[0] / max(singular[1], 1e-12)
    if not spreads:
        raise ValueError(f"no frame shows {options.min_template_points} or more points ahead "
                         "of the shaft: the jaws are not seen")
    return max(spreads, key=spreads.get)


def _open_jaws(jaws: np.ndarray) -> tuple[np.ndarray, list[np.ndarray], float]:
    """(side [J] bool, long axes [2] of the two sides' points, hinge roll about x in radians)
    of open jaws' points [J, 3] in their shaft frame (x forward): split by the side of the
    opening, the hinge normal to both long axes."""
    across = jaws[:, 1:] - jaws[:, 1:].mean(axis=0)
    _, _, axes = np.linalg.svd(across, full_matrices=False)
    side = jaws[:, 1:] @ axes[0] > 0  # [J] which side of the opening
    along = [_principal(jaws[~side]), _principal(jaws[side])]
    hinge = np.cross(along[0], along[1])
    return side, along, float(np.arctan2(-hinge[1], hinge[2]))  # roll turns z onto the hinge


def _templates(jaws: np.ndarray, side: np.ndarray, along: list[np.ndarray], roll: float
               ) -> tuple[np.ndarray, list[np.ndarray]]:
    """(pose [3]: roll, angle of jaw a, angle of jaw b in radians; templates [2] each [T_k, 3]
    at angle 0) of the template frame's jaw points [J, 3] split by `side` with long axes
    `along`, for the hinge at `roll`. Jaw a is the one at the smaller angle."""
    back = _rotation(roll, _X).T
    angles = []
    for direction in along:
        flat = back @ direction
        flat = flat - (flat @ _Z) * _Z
        angles.append(float(np.arctan2(np.cross(_X, flat) @ _Z, _X @ flat)))
    parts = [~side, side]
    if angles[0] > angles[1]:
        parts, angles = parts[::-1], angles[::-1]
    templates = [jaws[part] @ _rotation(roll, _X) @ _rotation(angle, _Z)
                 for part, angle in zip(parts, angles)]
    return np.array([roll, *angles]), templates


def _best_roll(shafts: dict[int, _Shaft], reference: int, side: np.ndarray,
               along: list[np.ndarray], roll: float, options: ArticulationOptions
               ) -> tuple[np.ndarray, list[np.ndarray], dict] | None:
    """(pose [3], templates, tracked frames as `_track`) for the template frame's hinge roll
    that lets the templates fit all frames best (least mean squared fit RMS). The roll of
    the long axes' normal errs by degrees (the jaws are seen from one side); a wrong roll
    tilts the templates, which then fit frames at other angles worse. Searched over
    +-roll_search_deg around it: a grid of five, then the parabola through the best and its
    neighbours."""
    jaws = shafts[reference].jaws

    def fit(offset: float) -> tuple[float, tuple]:
        pose, templates = _templates(jaws, side, along, roll + np.radians(offset))
        tracked = _track(shafts, reference, pose, templates, options)
        if not tracked:
            return np.inf, None
        return float(np.mean([rms ** 2 for _, _, rms in tracked.values()])), (pose, templates,
                                                                              tracked)

    offsets = np.linspace(-1.0, 1.0, 5) * options.roll_search_deg
    fits = [fit(offset) for offset in offsets]
    costs = np.array([cost for cost, _ in fits])
    best = int(np.argmin(costs))
    if 0 < best < len(offsets) - 1 and np.isfinite(costs[best - 1:best + 2]).all():
        left, middle, right = costs[best - 1:best + 2]
        curvature = left - 2 * middle + right
        if curvature > 0:
            step = offsets[1] - offsets[0]
            refined = fit(offsets[best] + 0.5 * step * (left - right) / curvature)
            if refined[0] < costs[best]:
                return refined[1]
    return fits[best][1]


def _track(shafts: dict[int, _Shaft], reference: int, pose: np.ndarray,
           templates: list[np.ndarray], options: ArticulationOptions
           ) -> dict[int, tuple[np.ndarray, np.ndarray, float]]:
    """Per accepted frame index, (pose [3] roll, angle a, angle b in radians; observed [2]
    bool per jaw; fit RMS), fitted outwards in time from the reference frame, each frame started from
    the last accepted one."""
    order = sorted(shafts)
    at = order.index(reference)
    tracked = {}
    for sequence in (order[at:], order[at::-1]):
        current = pose
        for index in sequence:
            jaws = shafts[index].jaws
            if jaws.shape[0] < options.min_points:
                continue
            active = np.ones(2, dtype=bool)
            fitted, observed, rms = _fit_jaws(jaws, templates, current, active, options)
            if observed.any() and not observed.all():  # refit without the jaw not in view
                fitted, observed, rms = _fit_jaws(jaws, templates, current, observed, options)
            if rms > options.max_fit_rms or not observed.any():
                continue
            tracked[index] = (fitted, observed, rms)
            current = fitted
    return tracked


def _fit_jaws(observed: np.ndarray, templates: list[np.ndarray], pose: np.ndarray,
              active: np.ndarray, options: ArticulationOptions
              ) -> tuple[np.ndarray, np.ndarray, float]:
    """(pose [3], seen [2] bool per jaw, RMS match distance): the hinge roll and the
    `active` [2] jaws' angles (radians) turning the jaw `templates` (each [T_k, 3], at angle 0)
    onto the `observed` jaw points [J, 3] (shaft frame), Gauss-Newton ICP from `pose`. A jaw
    is seen when min_points observed points match it and min_coverage of its template lies
    within coverage_distance of an observed point."""
    trees = [cKDTree(template) for template in templates]
    pose = np.array(pose, dtype=np.float64)
    jaws = np.nonzero(active)[0]
    for _ in range(options.icp_iterations):
        turns = [_rotation(pose[0], _X) @ _rotation(pose[1 + k], _Z) for k in range(2)]
        matches = [trees[k].query(observed @ turns[k], workers=1) for k in jaws]
        distance = np.stack([m[0] for m in matches], axis=1)  # [J, active]
        owner = distance.argmin(axis=1)
        nearest = distance.min(axis=1)
        keep = nearest <= options.trim_factor * max(float(np.median(nearest)), 1e-9)
        hinge = _rotation(pose[0], _X) @ _Z
        rows, residuals, counts = [], [], np.zeros(2, dtype=int)
        for column, k in enumerate(jaws):
            chosen = keep & (owner == column)
            counts[k] = chosen.sum()
            model = templates[k][matches[column][1][chosen]] @ turns[k].T  # [n, 3] shaft frame
            jacobian = np.zeros((model.shape[0], 3, 3))
            jacobian[:, :, 0] = np.cross(_X, model)  # roll about the shaft
            jacobian[:, :, 1 + k] = np.cross(hinge, model)  # this jaw about the hinge
            rows.append(jacobian.reshape(-1, 3))
            residuals.append((observed[chosen] - model).reshape(-1))
        step, *_ = np.linalg.lstsq(np.concatenate(rows), np.concatenate(residuals), rcond=None)
        step[1:][counts == 0] = 0.0
        pose = pose + step
        if np.abs(step).max() < 1e-7:
            break
    tree = cKDTree(observed)
    coverage = np.array([(tree.query(template @ turn.T, workers=1)[0]
                          <= options.coverage_distance).mean()
                         for template, turn in zip(templates, turns)])
    seen = active & (counts >= options.min_points) & (coverage >= options.min_coverage)
    return pose, seen, float(np.sqrt((nearest[keep] ** 2).mean()))


def _label_parts(canonical: np.ndarray, frame: np.ndarray, pose: np.ndarray,
                 templates: list[np.ndarray], observations: list[Observation], reference: int,
                 options: ArticulationOptions) -> tuple[np.ndarray, np.ndarray]:
    """(points [P, 3], labels [P]): the canonical points and the reference frame's observed
    points; behind the hinge of `frame` (the reference's hinge frame) shaft, else the jaw
    whose template (at the reference `pose`) is nearer."""
    observed = next(o.points for o in observations if o.index == reference)
    points = np.concatenate([canonical, observed])
    local = (points - frame[:3, 3]) @ frame[:3, :3]  # [P, 3] hinge coordinates
    distance = np.stack([cKDTree(template @ _rotation(angle, _Z).T).query(local, workers=1)[0]
                         for template, angle in zip(templates, pose[1:])], axis=1)
    labels = np.where(distance[:, 0] <= distance[:, 1], JAW_A, JAW_B)
    labels[local[:, 0] <= options.hinge_margin] = SHAFT
    return points, labels


# ---- geometry helpers ----
def _principal(points: np.ndarray) -> np.ndarray:
    """Unit principal direction of points [N, 3], oriented away from the origin."""
    centroid = points.mean(axis=0)
    _, _, axes = np.linalg.svd(points - centroid, full_matrices=False)
    return axes[0] if axes[0] @ centroid >= 0 else -axes[0]


def _normal_pair(direction: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors normal to `direction` [3] and to each other."""
    first = np.cross(direction, np.eye(3)[np.argmin(np.abs(direction))])
    first = first / np.linalg.norm(first)
    return first, np.cross(direction, first)


def _distance_to_line(points: np.ndarray, point: np.ndarray, direction: np.ndarray
                      ) -> np.ndarray:
    """[N] distance of points [N, 3] from the line through `point` along unit `direction`."""
    offset = points - point
    return np.linalg.norm(offset - np.outer(offset @ direction, direction), axis=1)


def _rotation(angle: float, axis: np.ndarray) -> np.ndarray:
    """[3, 3] rotation by `angle` (radians) about the unit `axis`."""
    return Rotation.from_rotvec(angle * axis).as_matrix()
