"""Scene description and random generation.

A scene is a textured room (seen from inside), static clutter and rigid movers, each a primitive
(box or sphere) with a local-to-world pose per frame, plus a camera path. World axes follow the camera
convention of the first frame roughly: x right, y down (the floor is at +y), z forward. Units: metres.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from scipy.spatial.transform import Rotation

from trackingworld.geometry import default_intrinsics, look_at, pose_from_rt, transform

ROOM, BOX, SPHERE = 0, 1, 2


@dataclass(frozen=True)
class SceneConfig:
    """Settings of one synthetic scene. Defaults are the ``default`` preset."""

    frames: int = 32
    width: int = 320
    height: int = 240
    fov_deg: float = 60.0
    cam_speed: float = 0.05  # metres per frame along the path
    cam_turn_deg: float = 0.6  # yaw change per frame, degrees
    n_clutter: int = 6
    n_masked_movers: int = 2  # plus one masked mover that enters mid-video
    n_bg_movers: int = 1  # movers the coarse masks miss
    mover_speed: float = 0.04  # metres per frame
    # depth-prior corruption (a monocular depth model's typical errors)
    prior_scale_std: float = 0.05  # per-frame scale error (relative)
    prior_distortion: float = 0.10  # amplitude of the smooth low-frequency multiplicative warp
    prior_noise: float = 0.02  # relative pixel noise
    prior_blur_px: float = 1.0  # edge blur of the prior
    mask_dilate_px: int = 6
    queries_per_frame: int = 200
    n_query_frames: int = 4
    # movers stand on the floor and slide / turn on it, as people and cars do, instead of floating: the scene the
    # weight-free depth's contact rule (``priors.sfm.fill_dynamic``) is made for. Off in the presets, whose
    # scenes every benchmark uses; the same seed draws the same numbers either way.
    grounded_movers: bool = False


PRESETS: dict[str, SceneConfig] = {
    "easy": SceneConfig(cam_speed=0.03, cam_turn_deg=0.3, n_masked_movers=1, prior_scale_std=0.02,
                        prior_distortion=0.05, prior_noise=0.01, prior_blur_px=0.5),
    "default": SceneConfig(),
    "hard": SceneConfig(frames=48, cam_speed=0.08, cam_turn_deg=1.0, n_masked_movers=3, n_bg_movers=2,
                        mover_speed=0.06, prior_scale_std=0.10, prior_distortion=0.20, prior_noise=0.03,
                        prior_blur_px=2.0),
}


@dataclass
class Primitive:
    kind: int  # ROOM, BOX or SPHERE
    size: np.ndarray  # box half-extents [3] or sphere radius [1]
    poses: np.ndarray  # [T,4,4] local -> world
    tex_seed: int
    tex_freq: float  # noise frequency, cycles per metre
    base_color: np.ndarray  # [3] in 0..1
    moving: bool = False
    masked: bool = True  # whether the coarse masks cover it (only meaningful for movers)
    name: str = ""


@dataclass
class Scene:
    config: SceneConfig
    K: np.ndarray  # [3,3]
    poses_c2w: np.ndarray  # [T,4,4]
    prims: list[Primitive] = field(default_factory=list)
    seed: int = 0

    @property
    def T(self) -> int:
        return self.config.frames


def _static(T: int, R: np.ndarray, c: np.ndarray) -> np.ndarray:
    return np.repeat(pose_from_rt(R, c)[None], T, axis=0)


def _bounce(c: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Centres ``c [T,3]`` of a straight path folded back into the box ``lo``..``hi`` [3], as a ball bounces off
    walls: a coordinate that would pass a bound is reflected at it (as often as it takes). Coordinates inside the
    box are returned exactly as given, so a path that never reaches a bound is unchanged."""
    span = hi - lo
    m = np.mod(c - lo, 2 * span)
    folded = lo + np.where(m <= span, m, 2 * span - m)
    return np.where((c >= lo) & (c <= hi), c, folded)


def _moving(T: int, c0: np.ndarray, vel: np.ndarray, spin_deg: float, axis: np.ndarray, rng,
            bounds: tuple[np.ndarray, np.ndarray] | None = None, upright: bool = False) -> np.ndarray:
    """Poses ``[T,4,4]`` of a rigid mover: its centre from ``c0`` at ``vel`` m/frame (bouncing off ``bounds``,
    the box its centre must stay in, when given), spinning at ``spin_deg`` per frame about ``axis`` (None: the
    vertical axis after a random initial rotation; with ``upright`` the random rotation is drawn but not used,
    so that a box keeps its faces level)."""
    R0 = Rotation.random(random_state=rng.integers(1 << 31)).as_matrix() if axis is None else np.eye(3)
    if upright:
        R0 = np.eye(3)
    t = np.arange(T, dtype=np.float64)
    ax = np.array([0.0, 1.0, 0.0]) if axis is None else axis
    Rs = Rotation.from_rotvec(np.outer(np.deg2rad(spin_deg) * t, ax)).as_matrix() @ R0
    c = c0[None] + vel[None] * t[:, None]
    return pose_from_rt(Rs, c if bounds is None else _bounce(c, *bounds))


def _camera_path(cfg: SceneConfig, rng: np.random.Generator) -> np.ndarray:
    T = cfg.frames
    t = np.arange(T, dtype=np.float64)
    heading = rng.uniform(-0.4, 0.4)
    direction = np.array([np.sin(heading), 0.0, np.cos(heading) * 0.5])
    direction /= np.linalg.norm(direction)
    eye = np.array([rng.uniform(-0.5, 0.5), -0.1, -1.0])[None] + cfg.cam_speed * t[:, None] * direction
    eye[:, 1] += 0.08 * np.sin(t / max(T, 1) * 2 * np.pi)  # a little bob
    yaw = np.deg2rad(cfg.cam_turn_deg) * (t - T / 2) * rng.choice([-1, 1])
    pitch = np.deg2rad(4.0) * np.sin(t / max(T, 1) * np.pi)
    poses = []
    for k in range(T):
        fwd = np.array([np.sin(yaw[k]), np.sin(pitch[k]), np.cos(yaw[k])])
        poses.append(look_at(eye[k], eye[k] + fwd))
    return np.stack(poses)


def make_scene(cfg: SceneConfig | str = "default", seed: int = 0, **overrides) -> Scene:
    """Generate a random scene. ``cfg`` is a :class:`SceneConfig` or a preset name."""
    if isinstance(cfg, str):
        if cfg not in PRESETS:
            raise ValueError(f"unknown preset {cfg!r}; choose from {', '.join(PRESETS)}")
        cfg = PRESETS[cfg]
    cfg = replace(cfg, **overrides)
    rng = np.random.default_rng(seed)
    T = cfg.frames
    K = default_intrinsics(cfg.width, cfg.height, cfg.fov_deg)
    cams = _camera_path(cfg, rng)
    I3 = np.eye(3)
    prims: list[Primitive] = []

    def color():
        return rng.uniform(0.15, 0.95, size=3)

    # Room: x in [-4.5, 4.5], y in [-2.2, 1.3] (floor at +1.3), z in [-3, 9]; local frame = world.
    room_lo, room_hi = np.array([-4.5, -2.2, -3.0]), np.array([4.5, 1.3, 9.0])
    prims.append(Primitive(ROOM, (room_hi - room_lo) / 2, _static(T, I3, (room_hi + room_lo) / 2),
                           int(rng.integers(1 << 30)), 2.2, color(), name="room"))
    eyes = cams[:, :3, 3]
    outside = np.flatnonzero(np.any((eyes <= room_lo) | (eyes >= room_hi), axis=1))
    if len(outside):  # it would render the room's outside: no texture, no ground truth worth the name
        raise ValueError(f"{T} frames at cam_speed {cfg.cam_speed} m/frame: the camera leaves the room at frame "
                         f"{outside[0]}; render fewer frames or lower cam_speed (and cam_turn_deg, mover_speed)")
    # Static clutter on the floor, spread in front of the camera path.

    def clear_of_camera(path: np.ndarray, radius: float) -> bool:
        """True when no point of ``path [M,3]`` comes within ``radius`` (x-z plane) of any camera centre."""
        d = np.linalg.norm((path[:, None, :] - eyes[None])[..., [0, 2]], axis=-1)
        return bool(d.min() > radius)

    for i in range(cfg.n_clutter):
        h = rng.uniform([0.2, 0.2, 0.2], [0.6, 0.9, 0.6])
        for _ in range(50):
            c = np.array([rng.uniform(-3.2, 3.2), room_hi[1] - h[1], rng.uniform(1.0, 8.0)])
            if clear_of_camera(c[None], 1.5 + h.max()):
                break
        yaw = Rotation.from_euler("y", float(rng.uniform(0, 90)), degrees=True).as_matrix()
        if rng.random() < 0.3:
            r = float(h[0])
            c[1] = room_hi[1] - r
            prims.append(Primitive(SPHERE, np.array([r]), _static(T, I3, c), int(rng.integers(1 << 30)),
                                   rng.uniform(3, 6), color(), name=f"clutter{i}"))
        else:
            prims.append(Primitive(BOX, h, _static(T, yaw, c), int(rng.integers(1 << 30)),
                                   rng.uniform(3, 6), color(), name=f"clutter{i}"))

    def mover(name: str, c0: np.ndarray, vel: np.ndarray, masked: bool, grow: float = 1.0) -> Primitive:
        """A sphere or box of a random size times ``grow``, its centre moving from ``c0`` at ``vel`` (with
        ``grounded_movers``: standing on the floor below ``c0``, moving at ``vel``'s horizontal part). It turns
        back where it would leave the room entirely (its centre ``reach`` past a wall, the floor or the ceiling),
        so a long video keeps its movers; the turn is not at the wall itself because the scenes of the benchmarks
        have movers that dip into the floor or start inside a wall, and they stay as they were rendered."""
        if rng.random() < 0.5:
            size = np.array([rng.uniform(0.25, 0.45)])
            kind = SPHERE
        else:
            size = rng.uniform([0.2, 0.2, 0.2], [0.45, 0.45, 0.45])
            kind = BOX
        size = size * grow
        reach = float(size.max())  # a sphere's radius, a box's largest half-extent
        if cfg.grounded_movers:  # on the floor (y down), sliding on it; an upright box's half-height is size[1]
            c0 = np.array([c0[0], room_hi[1] - float(size[0] if kind == SPHERE else size[1]), c0[2]])
            vel = np.array([vel[0], 0.0, vel[2]])
        poses = _moving(T, c0, vel, rng.uniform(-3, 3), None, rng, (room_lo - reach, room_hi + reach),
                        upright=cfg.grounded_movers)
        return Primitive(kind, size, poses, int(rng.integers(1 << 30)), rng.uniform(4, 8), color(), True,
                         masked, name)

    mid = cams[T // 2]
    # Masked movers: in front of the mid-video camera, moving laterally / in depth.
    t = np.arange(T)[:, None]
    for i in range(cfg.n_masked_movers):
        for _ in range(50):
            local = np.array([rng.uniform(-1.2, 1.2), rng.uniform(-0.3, 0.5), rng.uniform(2.5, 4.5)])
            c_mid = transform(mid, local)
            d = rng.normal(size=3) * np.array([1, 0.2, 1])
            vel = cfg.mover_speed * d / np.linalg.norm(d)
            if clear_of_camera(c_mid + vel * (t - T // 2), 1.2):
                break
        prims.append(mover(f"mover{i}", c_mid - vel * (T // 2), vel, True))
    # A masked mover that enters the view mid-video: off-screen left/right in the first frame,
    # reaching a visible spot at 60% of the video.
    side = rng.choice([-1.0, 1.0])
    zc = rng.uniform(2.5, 3.5)
    tan_half = (cfg.width / 2) / K[0, 0]
    start = transform(cams[0], np.array([side * (zc * tan_half + 1.0), 0.2, zc]))
    t_in = int(0.6 * T)
    target = transform(cams[t_in], np.array([side * 0.3, 0.2, zc]))
    vel = (target - start) / t_in
    prims.append(mover("entering", start, vel, True))
    # Background movers the masks miss: far, near the back wall, sliding slowly sideways.
    for i in range(cfg.n_bg_movers):
        local = np.array([rng.uniform(-1.5, 1.5), rng.uniform(-0.6, 0.4), rng.uniform(5.5, 7.0)])
        c_mid = transform(mid, local)
        vel = np.array([rng.choice([-1, 1]) * cfg.mover_speed * 0.8, 0.0, 0.0])
        prims.append(mover(f"bg_mover{i}", c_mid - vel * (T // 2), vel, False, grow=1.6))
    return Scene(cfg, K, cams, prims, seed)
