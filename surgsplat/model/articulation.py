"""A grasper's articulation from its canonical points and per-frame observations (DRAWER
Section C adapted to a shaft with two revolute jaws).

The tool field moves all tool Gaussians with ONE rigid pose per frame, so the jaws' own motion
is not in the model. It is recovered after training from what each frame observed: the frame's
tool pixels back-projected with its depth and mapped into the canonical tool frame by the
inverse of the tool field's pose ("observations"). In that frame the shaft stays (nearly) still
and each jaw turns about the hinge. The estimate:

1. Motion clustering into parts. The whole tool is first registered to each frame's
   observation (trimmed ICP, which the shaft dominates); frames where it does not register
   (too few observed points near it) are left out. Every canonical point then gets a
   residual trajectory: per frame that sees it, its distance to the nearest observed point.
   Points whose 95th-percentile residual is high (above a two-class Otsu split and above the
   inlier distance) move relative to the tool; their largest spatially linked group is the
   jaws, the rest is the shaft. The moving points are split into two jaws by 2-means of their
   displacement trajectories (per frame, the vector to the nearest observed point): the jaws
   move in opposite ways.
   The tool Gaussians are sparse on the small jaws, so the canonical points are then densified
   with the observation of the frame the labelled jaws fit best (the frame nearest the
   canonical tool), each added point labelled as its nearest canonical point. Then
   rounds of expectation-maximisation: each part's rigid motion per frame by ICP of its points
   to the observed points it explains best (observed -> model matching, trimmed), and each
   point reassigned to the part whose motions keep it on the observed surface over all frames
   (sum of capped residuals): clustering by motion.
2. The revolute axis: both jaws turn about one hinge, so does one jaw's motion relative to
   the other's (which is free of the shaft's own registration error, e.g. its roll). The
   axis direction is the principal eigenvector of sum(phi^2 w w^T) over these relative
   rotation vectors phi * w (orientation-free); a point on it solves (I - R) p = t in least
   squares over the relative motions, its component along the axis set at the jaws' centroid.
3. Per-frame angles, constrained: with the hinge fixed, each jaw's angle in each frame is
   refitted as a single rotation about it (ICP whose step is the closed-form planar rotation
   about the axis), on top of the shaft's motion of that frame.
4. Absolute angles: the shaft's forward direction (its principal axis, oriented towards the
   jaws' centroid) and each jaw's long axis (principal axis of its points, oriented away from
   the hinge), both trimmed of the 20% of points farthest from the line and projected onto the
   plane normal to the axis; a jaw's angle in a frame is its canonical angle from forward
   (right-hand rule about the axis) plus its fitted rotation there, wrapped to [-180, 180).

Everything is in the canonical tool frame and the scene's unit; `Articulation` holds the result.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

SHAFT, JAW_A, JAW_B = 0, 1, 2
"""Part labels of the canonical tool points."""
PART_NAMES = ("shaft", "jaw_a", "jaw_b")
MIN_TURN_DEG = 5.0
"""The jaws must turn relative to each other by at least this in some frame for a hinge."""


@dataclass(frozen=True)
class ArticulationOptions:
    """How the articulation is estimated."""

    em_rounds: int = 3
    """Rounds of (per-part ICP, reassignment by motion)."""
    icp_iterations: int = 12
    """ICP iterations per part, frame and round (and for the constrained angle fit)."""
    residual_cap: float = 3.0
    """Residuals are capped at this (scene units) when points are scored against a motion."""
    trim_factor: float = 3.0
    """ICP drops matches farther than this times the median match distance."""
    inlier_distance: float = 1.0
    """Observed points this near (scene units) the registered canonical tool are inliers."""
    min_inliers: float = 0.6
    """Frames whose whole-tool registration leaves fewer inliers than this fraction are left
    out (e.g. a shaft slid along its own axis, which a cylinder cannot pin down)."""
    moving_quantile: float = 0.95
    """Points are split into moving and still by this quantile of their residual trajectory
    (jaws move in some frames only; a shaft's silhouette errs a little in all)."""
    cluster_radius: float = 1.0
    """Moving points closer than this (scene units) are linked; the largest linked group is
    the jaws (scattered silhouette errors along the shaft are not)."""
    min_points: int = 12
    """A part needs this many canonical points, and a frame this many observed points of a
    part, for the part's motion in that frame to be fitted."""


@dataclass(frozen=True)
class Observation:
    """What one frame saw of the tool, in the canonical tool frame."""

    index: int
    """Frame index."""
    points: np.ndarray
    """[M, 3] observed tool points (scene units) mapped into the canonical tool frame."""
    visible: np.ndarray
    """[K] bool: canonical points the frame could have seen (inside its image, not hidden)."""


@dataclass
class Articulation:
    """A shaft with two revolute jaws, in the canonical tool frame (scene units, degrees)."""

    points: np.ndarray
    """[P, 3] the canonical tool points the parts were fitted with (the canonical points and
    the densifying observation, see step 1)."""
    labels: np.ndarray
    """[P] int: SHAFT, JAW_A or JAW_B per point."""
    axis: np.ndarray
    """[3] unit hinge axis."""
    hinge_point: np.ndarray
    """[3] a point on the hinge axis (at the jaws' middle along it)."""
    forward: np.ndarray
    """[3] unit shaft direction towards the jaws, normal to the axis."""
    frames: np.ndarray
    """[F] frame indices with an estimate (the observations' frames)."""
    shaft_motion: np.ndarray
    """[F, 4, 4] the shaft's rigid motion per frame, canonical -> canonical (the residual of
    the tool field's pose)."""
    jaw_angles_deg: np.ndarray
    """[F, 2] each jaw's angle from `forward` about `axis`, right-hand rule."""
    jaw_observed: np.ndarray
    """[F, 2] bool: the frame saw enough of the jaw for its angle to be fitted (else the
    angle is carried from the nearest fitted frame)."""
    canonical_jaw_deg: np.ndarray
    """[2] the jaws' angles in the canonical tool."""

    @property
    def opening_deg(self) -> np.ndarray:
        """[F] angle between the two jaws."""
        return np.abs(_wrap_deg(self.jaw_angles_deg[:, 1] - self.jaw_angles_deg[:, 0]))


def _wrap_deg(angles: np.ndarray) -> np.ndarray:
    """Angles (degrees) wrapped into [-180, 180)."""
    return (np.asarray(angles) + 180.0) % 360.0 - 180.0


def estimate_articulation(canonical: np.ndarray, observations: list[Observation],
                          options: ArticulationOptions = ArticulationOptions()) -> Articulation:
    """The articulation of the tool whose canonical points are `canonical` [K, 3], from
    per-frame `observations`; ValueError when the data cannot support it (too few points,
    jaws that never turn)."""
    canonical = np.asarray(canonical, dtype=np.float64)
    usable = [o for o in observations if o.points.shape[0] >= options.min_points]
    if canonical.shape[0] < 3 * options.min_points or len(usable) < 2:
        raise ValueError(f"too little tool to articulate: {canonical.shape[0]} canonical "
                         f"points, {len(usable)} frames with observed tool points")
    whole = [_icp(canonical[o.visible], o.points, np.eye(4), options) for o in usable]
    registered = [_inlier_fraction(canonical[o.visible], o.points, motion, options)
                  >= options.min_inliers for o, motion in zip(usable, whole)]
    usable = [o for o, good in zip(usable, registered) if good]
    whole = np.stack([motion for motion, good in zip(whole, registered) if good])  # [F, 4, 4]
    if len(usable) < 2:
        raise ValueError("fewer than two frames where the canonical tool registers to the "
                         "observed tool")
    trees = [cKDTree(o.points) for o in usable]
    labels = _initial_parts(canonical, usable, trees, whole, options)
    start = int(np.argmin([np.nanmean(r) for r in _residuals(
        canonical, usable, trees, options.residual_cap, whole)[labels != SHAFT].T]))
    canonical, labels, usable = _densify(canonical, labels, usable, start, whole[start])
    motions = np.repeat(whole[:, None], 3, axis=1)  # [F, part, 4, 4]
    for round_ in range(options.em_rounds):
        for f, previous in _tracking_order(len(usable), start):
            if round_ == 0 and previous is not None:  # start from the neighbour's jaws
                carried = motions[f, SHAFT] @ np.linalg.inv(motions[previous, SHAFT])
                motions[f, 1:] = carried @ motions[previous, 1:]
            _fit_parts(canonical, labels, motions[f], usable[f].points, options)
        labels = _reassign(canonical, labels, motions, usable, trees, options)
    between = np.linalg.inv(motions[:, JAW_A]) @ motions[:, JAW_B]  # [F, 4, 4] jaw b in jaw a
    axis, point = _hinge(between, canonical, labels)
    forward = _principal(canonical[labels == SHAFT], towards=canonical[labels != SHAFT].mean(0),
                         normal=axis)
    canonical_deg = np.array([_signed_angle(forward, _principal(
        canonical[labels == part], away=point, normal=axis), axis) for part in (JAW_A, JAW_B)])
    turns, observed = _constrained_angles(canonical, labels, motions, usable, axis, point,
                                          options)
    return Articulation(points=canonical, labels=labels, axis=axis, hinge_point=point,
                        forward=forward,
                        frames=np.array([o.index for o in usable]),
                        shaft_motion=motions[:, SHAFT],
                        jaw_angles_deg=_wrap_deg(canonical_deg[None, :] + np.degrees(turns)),
                        jaw_observed=observed, canonical_jaw_deg=canonical_deg)


# ---- parts ----
def _residuals(points: np.ndarray, observations: list[Observation], trees: list,
               cap: float, motions: np.ndarray | None = None) -> np.ndarray:
    """[K, F] capped distance of each point (moved by motions[f] [F, 4, 4] when given) to the
    frame's nearest observed point; NaN where the frame cannot see the point."""
    out = np.full((points.shape[0], len(observations)), np.nan)
    for f, (observation, tree) in enumerate(zip(observations, trees)):
        moved = points if motions is None else _apply(motions[f], points)
        visible = observation.visible
        distance, _ = tree.query(moved[visible], distance_upper_bound=cap, workers=-1)
        out[visible, f] = np.minimum(distance, cap)
    return out


def _initial_parts(canonical: np.ndarray, observations: list[Observation], trees: list,
                   whole: np.ndarray, options: ArticulationOptions) -> np.ndarray:
    """[K] labels: moving points (high mean residual under the whole tool's motion `whole`
    [F, 4, 4]) split into two jaws across their long axis; the rest shaft."""
    residual = _residuals(canonical, observations, trees, options.residual_cap, whole)
    seen = np.isfinite(residual).sum(axis=1) > 0
    high = np.zeros(canonical.shape[0])  # [K] a high quantile of each point's residuals
    high[seen] = np.nanquantile(residual[seen], options.moving_quantile, axis=1)
    moving = seen & (high > max(_otsu(high[seen]), options.inlier_distance))
    moving[moving] = _largest_cluster(canonical[moving], options.cluster_radius)
    labels = np.full(canonical.shape[0], SHAFT)
    if moving.sum() < 2 * options.min_points:
        raise ValueError("no part of the tool moves relative to the rest: the jaws' motion "
                         "cannot be separated")
    side = _two_means(_displacements(canonical[moving], observations, trees, whole,
                                     [o.visible[moving] for o in observations]))
    labels[np.nonzero(moving)[0]] = np.where(side, JAW_B, JAW_A)
    return labels


def _displacements(points: np.ndarray, observations: list[Observation], trees: list,
                   whole: np.ndarray, visible: list[np.ndarray]) -> np.ndarray:
    """[J, 3F] per frame, the vector from each point (moved by the whole tool's motion) to its
    nearest observed point, zero where the frame cannot see it: the points' motion
    relative to the tool, to cluster."""
    columns = []
    for observation, tree, motion, seen in zip(observations, trees, whole, visible):
        moved = _apply(motion, points)
        _, nearest = tree.query(moved, workers=-1)
        columns.append(np.where(seen[:, None], observation.points[nearest] - moved, 0.0))
    return np.concatenate(columns, axis=1)


def _densify(canonical: np.ndarray, labels: np.ndarray, observations: list[Observation],
             start: int, motion: np.ndarray
             ) -> tuple[np.ndarray, np.ndarray, list[Observation]]:
    """The canonical points [K, 3] with the observed points of frame `start` (brought into the
    canonical frame by the inverse of its whole-tool `motion`) appended; labels and
    visibility of each added point are those of its nearest canonical point."""
    added = _apply(np.linalg.inv(motion), observations[start].points)
    _, nearest = cKDTree(canonical).query(added, workers=-1)
    dense = [Observation(o.index, o.points, np.concatenate([o.visible, o.visible[nearest]]))
             for o in observations]
    return (np.concatenate([canonical, added]), np.concatenate([labels, labels[nearest]]),
            dense)


def _largest_cluster(points: np.ndarray, radius: float) -> np.ndarray:
    """[N] bool: the largest group of points [N, 3] linked by steps of at most `radius`."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    pairs = cKDTree(points).query_pairs(radius, output_type="ndarray")  # [P, 2]
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])),
                       shape=(len(points), len(points)))
    _, component = connected_components(graph, directed=False)
    return component == np.bincount(component).argmax()


def _otsu(values: np.ndarray, bins: int = 64) -> float:
    """The threshold splitting `values` [N] into two classes with the most between-class
    variance."""
    counts, edges = np.histogram(values, bins=bins)
    centres = (edges[:-1] + edges[1:]) / 2
    weight = np.cumsum(counts)
    total = weight[-1]
    mass = np.cumsum(counts * centres)
    below = weight[:-1]
    above = total - below
    valid = (below > 0) & (above > 0)
    mean_below = np.where(valid, mass[:-1] / np.maximum(below, 1), 0)
    mean_above = np.where(valid, (mass[-1] - mass[:-1]) / np.maximum(above, 1), 0)
    between = np.where(valid, below * above * (mean_below - mean_above) ** 2, -1)
    return float(edges[1:-1][int(np.argmax(between))])


def _two_means(points: np.ndarray, iterations: int = 20) -> np.ndarray:
    """[N] bool: 2-means of points [N, D], seeded by the sign along their principal axis."""
    centred = points - points.mean(axis=0)
    _, _, axes = np.linalg.svd(centred, full_matrices=False)
    side = centred @ axes[0] > 0
    for _ in range(iterations):
        if side.all() or not side.any():
            break
        a, b = points[~side].mean(axis=0), points[side].mean(axis=0)
        new = ((points - b) ** 2).sum(1) < ((points - a) ** 2).sum(1)
        if (new == side).all():
            break
        side = new
    return side


def _assign_observed(canonical: np.ndarray, labels: np.ndarray, motions: np.ndarray,
                     observed: np.ndarray) -> np.ndarray:
    """[M] part whose moved points (motions [3, 4, 4]) lie nearest each observed point."""
    distances = np.full((observed.shape[0], 3), np.inf)
    for part in range(3):
        members = canonical[labels == part]
        if members.shape[0]:
            distances[:, part], _ = cKDTree(_apply(motions[part], members)).query(
                observed, workers=-1)
    return distances.argmin(axis=1)


def _reassign(canonical: np.ndarray, labels: np.ndarray, motions: np.ndarray,
              observations: list[Observation], trees: list,
              options: ArticulationOptions) -> np.ndarray:
    """[K] part whose per-frame motions keep each point on the observed surface (least summed
    capped residual over the frames that see it); unseen points keep their label."""
    cost = np.stack([np.nansum(_residuals(canonical, observations, trees, options.residual_cap,
                                          motions[:, part]), axis=1) for part in range(3)],
                    axis=1)  # [K, 3]
    new = cost.argmin(axis=1)
    tie = np.ptp(cost, axis=1) <= 1e-12
    new[tie] = labels[tie]
    for part in range(3):  # a part that lost (nearly) all its points keeps its old ones
        if (new == part).sum() < 3:
            new[labels == part] = part
    return new


def _tracking_order(count: int, start: int) -> list[tuple[int, int | None]]:
    """(frame, neighbour already fitted) pairs: `start` first, then outwards in time."""
    order = [(start, None)]
    order += [(f, f - 1) for f in range(start + 1, count)]
    order += [(f, f + 1) for f in range(start - 1, -1, -1)]
    return order


# ---- rigid fits ----
def _inlier_fraction(model: np.ndarray, observed: np.ndarray, motion: np.ndarray,
                     options: ArticulationOptions) -> float:
    """Fraction of observed points [M, 3] within inlier_distance of the moved model [K, 3]."""
    if model.shape[0] == 0:
        return 0.0
    distance, _ = cKDTree(_apply(motion, model)).query(observed, workers=-1)
    return float((distance <= options.inlier_distance).mean())


def _fit_parts(canonical: np.ndarray, labels: np.ndarray, motions: np.ndarray,
               observed: np.ndarray, options: ArticulationOptions) -> None:
    """Refit, in place, each part's motion [3, 4, 4] of one frame to the observed points
    [M, 3] it explains best: the shaft first, then the jaws against what the shaft leaves."""
    for part in range(3):
        owner = _assign_observed(canonical, labels, motions, observed)
        model, target = canonical[labels == part], observed[owner == part]
        if model.shape[0] >= options.min_points and target.shape[0] >= options.min_points:
            motions[part] = _icp(model, target, motions[part], options)


def _apply(motion: np.ndarray, points: np.ndarray) -> np.ndarray:
    """points [N, 3] moved by the rigid motion [4, 4]."""
    return points @ motion[:3, :3].T + motion[:3, 3]


def _icp(model: np.ndarray, target: np.ndarray, motion: np.ndarray,
         options: ArticulationOptions) -> np.ndarray:
    """Rigid motion [4, 4] taking `model` [K, 3] onto the observed `target` [M, 3], from
    `motion`: each observed point, mapped back, matched to its nearest model point; matches
    beyond trim_factor x their median distance dropped; Kabsch."""
    tree = cKDTree(model)
    motion = motion.copy()
    for _ in range(options.icp_iterations):
        back = (target - motion[:3, 3]) @ motion[:3, :3]
        distance, nearest = tree.query(back, workers=-1)
        keep = distance <= options.trim_factor * max(float(np.median(distance)), 1e-9)
        if keep.sum() < 3:
            break
        source, observed = model[nearest[keep]], target[keep]
        source_centre, observed_centre = source.mean(0), observed.mean(0)
        fitted, _ = Rotation.align_vectors(observed - observed_centre, source - source_centre)
        motion[:3, :3] = fitted.as_matrix()
        motion[:3, 3] = observed_centre - motion[:3, :3] @ source_centre
    return motion


# ---- hinge and angles ----
def _hinge(between: np.ndarray, canonical: np.ndarray,
           labels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(unit axis [3], point [3]) of the rotations `between` [F, 4, 4] of one jaw relative to
    the other (both turn about the hinge, so these do too, free of the shaft's own error)."""
    rotations = between[:, :3, :3]
    translations = between[:, :3, 3]
    rotvecs = Rotation.from_matrix(rotations).as_rotvec()  # [F*2, 3] phi * w
    scatter = rotvecs.T @ rotvecs
    _, eigenvectors = np.linalg.eigh(scatter)
    axis = eigenvectors[:, -1]
    if np.abs(rotvecs @ axis).max() < np.radians(MIN_TURN_DEG):
        raise ValueError(f"the jaws never turn relative to each other by more than "
                         f"{MIN_TURN_DEG:g} degrees: their hinge axis is undetermined")
    system = (np.eye(3)[None] - rotations).reshape(-1, 3)  # (I - R) p = t
    point, *_ = np.linalg.lstsq(system, translations.reshape(-1), rcond=None)
    jaws = canonical[labels != SHAFT].mean(axis=0)
    point = point + ((jaws - point) @ axis) * axis
    return axis, point


def _principal(points: np.ndarray, normal: np.ndarray, towards: np.ndarray | None = None,
               away: np.ndarray | None = None) -> np.ndarray:
    """Unit principal direction of points [N, 3] in the plane normal to `normal`, oriented
    towards `towards` or away from `away` (as seen from the points' centroid)."""
    flat = points - np.outer(points @ normal, normal)  # [N, 3] in the plane
    keep = np.ones(len(points), dtype=bool)
    for _ in range(3):  # trimmed: refit without the points farthest from the line
        centre = flat[keep].mean(axis=0)
        _, _, axes = np.linalg.svd(flat[keep] - centre, full_matrices=False)
        direction = axes[0]
        offset = flat - centre
        off_line = np.linalg.norm(offset - np.outer(offset @ direction, direction), axis=1)
        keep = off_line <= np.quantile(off_line, 0.8)
    target = towards - points.mean(axis=0) if towards is not None else points.mean(axis=0) - away
    return direction if direction @ target >= 0 else -direction


def _signed_angle(start: np.ndarray, end: np.ndarray, axis: np.ndarray) -> float:
    """Angle (degrees) of the rotation about `axis` from `start` to `end` (both normal to it)."""
    return float(np.degrees(np.arctan2(np.cross(start, end) @ axis, start @ end)))


def _rotation_about(axis: np.ndarray, point: np.ndarray, angle: float) -> np.ndarray:
    """[4, 4] rotation by `angle` (radians) about the line through `point` along `axis`."""
    motion = np.eye(4)
    motion[:3, :3] = Rotation.from_rotvec(angle * axis).as_matrix()
    motion[:3, 3] = point - motion[:3, :3] @ point
    return motion


def _constrained_angles(canonical: np.ndarray, labels: np.ndarray, motions: np.ndarray,
                        observations: list[Observation], axis: np.ndarray, point: np.ndarray,
                        options: ArticulationOptions) -> tuple[np.ndarray, np.ndarray]:
    """([F, 2] each jaw's rotation about the hinge relative to the canonical tool, radians;
    [F, 2] bool fitted) with the shaft's motion of each frame held."""
    turns = np.zeros((len(observations), 2))
    observed = np.zeros((len(observations), 2), dtype=bool)
    for f, observation in enumerate(observations):
        shaft = motions[f, SHAFT]
        back = _apply(np.linalg.inv(shaft), observation.points)  # into the shaft's frame
        current = np.tile(np.eye(4), (3, 1, 1))  # parts' motions in the shaft's frame
        for j, part in enumerate((JAW_A, JAW_B)):
            relative = np.linalg.inv(shaft) @ motions[f, part]
            rotvec = Rotation.from_matrix(relative[:3, :3]).as_rotvec()
            turns[f, j] = rotvec @ axis  # start from the free fit's turn about the axis
            current[part] = _rotation_about(axis, point, turns[f, j])
        owner = _assign_observed(canonical, labels, current, back)
        for j, part in enumerate((JAW_A, JAW_B)):
            model, target = canonical[labels == part], back[owner == part]
            if model.shape[0] < options.min_points or target.shape[0] < options.min_points:
                continue
            turns[f, j] = _fit_turn(model, target, axis, point, turns[f, j], options)
            observed[f, j] = True
    for j in range(2):  # unfitted frames carry the nearest fitted frame's angle
        fitted = np.nonzero(observed[:, j])[0]
        if fitted.size:
            for f in np.nonzero(~observed[:, j])[0]:
                turns[f, j] = turns[fitted[np.abs(fitted - f).argmin()], j]
    return turns, observed


def _fit_turn(model: np.ndarray, target: np.ndarray, axis: np.ndarray, point: np.ndarray,
              angle: float, options: ArticulationOptions) -> float:
    """The rotation (radians) about the hinge taking `model` [K, 3] onto `target` [M, 3]:
    ICP whose step is the closed-form planar rotation about the axis."""
    tree = cKDTree(model)
    target_arm = target - point
    target_arm = target_arm - np.outer(target_arm @ axis, axis)  # [M, 3] in the hinge plane
    for _ in range(options.icp_iterations):
        back = _apply(_rotation_about(axis, point, -angle), target)
        distance, nearest = tree.query(back, workers=-1)
        keep = distance <= options.trim_factor * max(float(np.median(distance)), 1e-9)
        if keep.sum() < 3:
            break
        source_arm = model[nearest[keep]] - point
        source_arm = source_arm - np.outer(source_arm @ axis, axis)
        sine = (np.cross(source_arm, target_arm[keep]) @ axis).sum()
        cosine = np.einsum("ij,ij->", source_arm, target_arm[keep])
        angle = float(np.arctan2(sine, cosine))
    return angle
