"""Rigid groups of one object joined across a gap in its tracks (not in the paper).

A 2D tracker loses every track of an object that is hidden for a few frames (it passes behind another one) or
that it cannot follow, and the tracks that start when the object comes back are new ones: no track crosses the
gap, or too few to carry :func:`trackingworld.optim.rigid.initial_motion`'s chain, so
:func:`~trackingworld.optim.rigid.rigid_movers` finds one group before it and another after it, each solved only in
its own frames. The tracks of the first then have nothing to follow them after the gap (``optim.hidden`` carries
them by donors on other objects, or holds them) and those of the second nothing before it. On `hard` scene 0 one
mover hidden in frames 29-30 would take the scene from 71.4 to 76.3 world 3D accuracy with its hidden observations
exact (docs/lifting.md item 6c).

Joining: each group's motion (object-to-world poses ``[T,4,4]``, NaN where unsolved) is extended over the gap at
constant velocity, fitted to the ``fit_frames`` solved frames at its end (a line through the world positions of
its points' centroid, the mean rotation step; the ends of a track are where the tracker is about to lose it, a
fit over several frames averages their noise). Where a group ends at most ``max_gap`` frames before another
starts, the two extensions meet in the middle frame of the gap, which gives the rigid transform between their
object frames; where ``min_cross`` or more tracks of one group are seen in the other's frames (found again by the
tracker after the gap), the transform is fitted to those instead (:func:`crossing_transform`). They are one object
when the first group's points, moved on by the second's motion through that transform, land on the second group's
tracks (within ``overlap_px`` of a track seen there, at a depth within ``depth_tol`` of that track's point on
the second group's motion) for at least ``min_overlap`` of those in the image in the second group's first
``test_frames`` solved frames. Groups are then merged, and a merged group may be joined
again. A merged group knows its motion in its groups' frames and the gap's (each half of the gap from the nearer
end's extension); a track takes it in its own group's frames and where it is hidden in the others.

Conventions: ``uv [N,T,2]`` px, ``vis [N,T]``, poses camera-to-world ``[T,4,4]`` (OpenCV axes), object-to-world
``[T,4,4]``, points ``[n,3]`` in the object frame, metres.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from trackingworld.geometry import in_image, invert_pose, project, rigid_transform, transform


@dataclass
class BridgeSettings:
    """When two rigid groups are one object (module docstring)."""

    max_gap: int = 6  # most frames strictly between one group's last solved frame and the other's first
    fit_frames: int = 8  # solved frames at a group's end its constant-velocity motion is fitted to
    test_frames: int = 3  # the later group's first solved frames the earlier group's points are tested in
    overlap_px: float = 3.0  # a moved point is on the other group within this distance of one of its seen tracks
    min_overlap: float = 0.5  # fraction of the moved points in the image that must be on the other group
    # ... and each such point's camera depth within this |log ratio| of the track's it lands on (its point on the
    # other group's motion; 0: not checked). A large dense group covers the image where a smaller one was lost
    # whatever its depth: on `default` 56 an object lost in frame 19 was joined to another one 2.4x as far that
    # came into view in frame 20 (91% of the moved points on its tracks, none within 0.1 in depth); the eight joins
    # of one object's groups on seven synthetic scenes had 92-99% of those points within 0.1 (docs/lifting.md 6c)
    depth_tol: float = 0.2
    # with at least this many tracks of one group seen in the other's frames (the tracker found them again after
    # the gap), the transform between the groups is fitted to those tracks' positions, not to the extensions
    min_cross: int = 10
    trim: float = 0.8  # ... the fraction of them kept (the nearest) in the fit's second round


@dataclass(eq=False)  # compared and hashed as itself (:func:`bridge` keeps the pairs it tried)
class RigidObject:
    """A rigid group, or groups merged into one: object-to-world ``motion [T,4,4]`` (NaN where unknown), its
    ``members`` (track indices), their ``points [n,3]`` in the object frame (metres) and ``own [n,T]``."""

    motion: np.ndarray
    members: np.ndarray
    points: np.ndarray
    own: np.ndarray  # [n,T] bool: the frames each member's own group was solved in

    def frames(self) -> np.ndarray:
        """The frames its motion is known in (sorted)."""
        return np.flatnonzero(np.isfinite(self.motion[:, 0, 0]))


def constant_velocity(motion: np.ndarray, centre: np.ndarray, frames: np.ndarray, at: np.ndarray) -> np.ndarray:
    """Object-to-world poses ``[len(at),4,4]`` at the frames ``at``, on the constant-velocity motion fitted to
    ``motion`` (object-to-world ``[T,4,4]``) in ``frames`` (solved, sorted, at least 2): the object point
    ``centre [3]`` on the least-squares line through its world positions, the rotation turning by the mean
    rotation step of consecutive frames about that at the window's middle frame."""
    O = motion[frames]
    x = transform(O, np.broadcast_to(centre, (len(frames), 3)))  # [n,3] world
    f = frames.astype(np.float64)
    fm = f.mean()
    A = np.stack([np.ones_like(f), f - fm], 1)
    coef, *_ = np.linalg.lstsq(A, x, rcond=None)  # [2,3]: position at fm, velocity per frame
    Rs = Rotation.from_matrix(O[:, :3, :3])
    steps = (Rs[1:] * Rs[:-1].inv()).as_rotvec() / np.diff(f)[:, None]  # world-frame rotation per frame
    w = steps.mean(0)
    mid = len(frames) // 2
    dt = at.astype(np.float64) - f[mid]
    R = (Rotation.from_rotvec(dt[:, None] * w) * Rs[mid]).as_matrix()
    pos = coef[0] + (at.astype(np.float64) - fm)[:, None] * coef[1]
    out = np.tile(np.eye(4), (len(at), 1, 1))
    out[:, :3, :3] = R
    out[:, :3, 3] = pos - R @ centre
    return out


def _end_fit(obj: RigidObject, last: bool, n: int, at: np.ndarray) -> np.ndarray:
    """:func:`constant_velocity` of ``obj`` fitted to its last (``last``) or first ``n`` known frames, at ``at``."""
    fr = obj.frames()
    fr = fr[-n:] if last else fr[:n]
    return constant_velocity(obj.motion, obj.points.mean(0), fr, at)


def overlap(points: np.ndarray, to_world: np.ndarray, uv: np.ndarray, vis: np.ndarray, poses: np.ndarray,
            K: np.ndarray, size: tuple[int, int], frames: np.ndarray, px: float,
            depth: np.ndarray | None = None, depth_tol: float = 0.0) -> float:
    """Fraction of the object points ``points [n,3]``, placed by object-to-world ``to_world [T,4,4]`` and projected
    into ``frames``, that land within ``px`` of one of the tracks ``uv [m,T,2]`` seen there (``vis [m,T]``), over
    those in front of the camera and in the image of size ``size`` (W, H). NaN when none is. With ``depth [m,T]``
    (the tracks' camera depths, metres) and ``depth_tol`` > 0, a point lands on its nearest track only where its own
    camera depth is within ``depth_tol`` of that track's in ``|log|`` ratio."""
    W, H = size
    hit = tot = 0
    w2c = invert_pose(poses)
    for t in frames:
        seen = np.flatnonzero(vis[:, t])
        if not len(seen):
            continue
        cam = transform(w2c[t] @ to_world[t], points)
        p, z = project(cam, K)
        ok = (z > 1e-3) & in_image(p, W, H)
        if not ok.any():
            continue
        d, j = cKDTree(uv[seen, t]).query(p[ok], k=1, distance_upper_bound=px)
        on = np.isfinite(d)
        if depth is not None and depth_tol > 0:
            zt = depth[seen[j[on]], t]
            on[on] = np.abs(np.log(np.maximum(z[ok][on], 1e-6) / np.maximum(zt, 1e-6))) <= depth_tol
        hit += int(on.sum())
        tot += int(ok.sum())
    return hit / tot if tot else float("nan")


def crossing_transform(a: RigidObject, b: RigidObject, xyz: np.ndarray, vis: np.ndarray, s: BridgeSettings):
    """The rigid transform ``[4,4]`` from ``a``'s object frame to ``b``'s fitted to the tracks of each group seen in
    the other's frames (``xyz [N,T,3]`` their world positions there, ``vis [N,T]``): a track of ``a`` is its point
    and, in ``b``'s frame, the median of its positions there; then the nearest ``trim`` of them again. None with
    fewer than ``min_cross`` such tracks."""
    src, dst = [], []
    for one, other, a_side in ((a, b, True), (b, a, False)):
        fr = other.frames()
        seen = vis[np.ix_(one.members, fr)]  # [n,F]
        cross = np.flatnonzero(seen.sum(1) > 0)
        if not len(cross):
            continue
        local = transform(invert_pose(other.motion[fr])[None], xyz[np.ix_(one.members[cross], fr)])  # [c,F,3]
        med = np.nanmedian(np.where(seen[cross][..., None], local, np.nan), axis=1)
        src.append(one.points[cross] if a_side else med)
        dst.append(med if a_side else one.points[cross])
    if not src or sum(len(x) for x in src) < s.min_cross:
        return None
    src, dst = np.concatenate(src), np.concatenate(dst)
    M = rigid_transform(src, dst)
    err = np.linalg.norm(transform(M, src) - dst, axis=1)
    near = err <= np.quantile(err, s.trim)
    return rigid_transform(src[near], dst[near])


def join(a: RigidObject, b: RigidObject, uv: np.ndarray, vis: np.ndarray, xyz: np.ndarray, poses: np.ndarray,
         K: np.ndarray, size: tuple[int, int], s: BridgeSettings) -> tuple[RigidObject | None, float]:
    """``a`` and ``b`` merged into one object when ``a`` ends before ``b`` starts, within the gap allowed, and
    ``a``'s points moved on by ``b``'s motion land on ``b``'s tracks (module docstring); else None. Also returns
    the overlap fraction (NaN where not tested). Merged: ``a``'s object frame, ``b``'s points moved into it.
    ``xyz [N,T,3]``: the tracks' world positions where seen (:func:`crossing_transform`)."""
    fa, fb = a.frames(), b.frames()
    if len(fa) < 2 or len(fb) < 2 or not 0 <= fb[0] - fa[-1] - 1 <= s.max_gap:
        return None, float("nan")
    c = (fa[-1] + fb[0]) // 2
    gap = np.arange(fa[-1] + 1, fb[0])
    oa = _end_fit(a, True, s.fit_frames, np.r_[c, gap])  # a's extension: at c, then over the gap
    ob = _end_fit(b, False, s.fit_frames, np.r_[c, gap])
    M = crossing_transform(a, b, xyz, vis, s)  # a's object frame -> b's
    if M is None:
        M = invert_pose(ob[0]) @ oa[0]
    moved = b.motion @ M  # a's points on b's motion
    test = fb[: s.test_frames]
    depth = np.zeros((len(b.members), vis.shape[1]))  # b's tracks' camera depths on b's motion, in the test frames
    depth[:, test] = transform((invert_pose(poses[test]) @ b.motion[test])[None], b.points[:, None, :])[..., 2]
    frac = overlap(a.points, moved, uv[b.members], vis[b.members], poses, K, size, test, s.overlap_px, depth,
                   s.depth_tol)
    if not frac >= s.min_overlap:
        return None, frac
    motion = a.motion.copy()
    motion[fb] = moved[fb]
    first = gap <= c
    motion[gap[first]] = oa[1:][first]
    motion[gap[~first]] = ob[1:][~first] @ M
    pts_b = transform(invert_pose(M), b.points)  # b's points in a's object frame
    return RigidObject(motion, np.r_[a.members, b.members], np.r_[a.points, pts_b], np.r_[a.own, b.own]), frac


def bridge(objects: list[RigidObject], uv: np.ndarray, vis: np.ndarray, xyz: np.ndarray, poses: np.ndarray,
           K: np.ndarray, size: tuple[int, int], s: BridgeSettings, log=None) -> list[RigidObject]:
    """``objects`` with every pair that :func:`join` merges merged, repeatedly (the earliest-ending first) until
    no pair joins."""
    objs = list(objects)
    tried = set()  # pairs that did not join: unchanged objects give the same answer, so they are not tested again
    while True:
        order = sorted(objs, key=lambda o: o.frames()[-1] if len(o.frames()) else -1)
        for a, b in ((a, b) for a in order for b in objs if a is not b and (a, b) not in tried):
            new, frac = join(a, b, uv, vis, xyz, poses, K, size, s)
            if log and np.isfinite(frac):
                fa, fb = a.frames(), b.frames()
                log(f"groups in frames {fa[0]}-{fa[-1]} and {fb[0]}-{fb[-1]}: {100 * frac:.0f}% of the first "
                    f"group's points on the second's tracks, {'joined' if new is not None else 'not joined'}")
            if new is not None:
                objs = [o for o in objs if o is not a and o is not b] + [new]
                break
            tried.add((a, b))
        else:
            return objs
