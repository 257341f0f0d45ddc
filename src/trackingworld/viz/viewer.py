"""``trackingworld view DIR``: an interactive 4D viewer in the browser, served by viser on localhost.

The scene: the world-frame points of the current frame coloured by the video, the static map, fading trails
of dynamic tracks, every camera as a frustum with the current one highlighted and showing its frame, and the
camera path. The panel: a time slider with play, frame rate, colour mode, point size, density, trail length
and a checkbox per layer. Dense results stay smooth because only a nested random subset (up to
``--max-points`` per frame) is sent to the browser; the result itself is never changed.
"""

from __future__ import annotations

import sys
import threading
import time
from collections import OrderedDict
from pathlib import Path

import numpy as np

from trackingworld.errors import InputError
from trackingworld.geometry import quat_wxyz
from trackingworld.io.frames import frames_for_result
from trackingworld.io.result import Result, load_result
from trackingworld.viz import display as D

LAYERS = ("current points", "static map", "dynamic trails", "cameras", "camera path")
FRAME_CACHE = 64  # frames of point data kept ready for playback


def _import_viser():
    try:
        import viser
    except ImportError as e:  # pragma: no cover - viser is a dependency
        raise InputError("the viewer needs viser: pip install viser") from e
    return viser


class Viewer:
    """A viser server showing one result. ``set_frame(t)`` is what the slider and the play button call."""

    def __init__(self, result: Result, frames: np.ndarray | None, port: int = 8080, host: str = "127.0.0.1",
                 cfg: D.DisplayConfig | None = None, verbose: bool = True):
        viser = _import_viser()
        self.res, self.frames, self.cfg = result, frames, cfg or D.DisplayConfig()
        self.T = result.num_frames
        self.H, self.W = result.depth.shape[1:]
        self.order = D.display_order(result.num_tracks, self.cfg.seed)
        self.n_visible = result.visible.sum(0)  # [T] tracks visible in each frame
        self.n_dynamic = int(result.is_dynamic.sum())
        self.n_static = result.num_tracks - self.n_dynamic
        self.med_depth = D.median_depth(result.depth)
        self.extent = D.scene_extent(result.poses_c2w, self.med_depth)
        self.trail_idx = D.trail_indices(result.is_dynamic, result.visible, self.order, self.cfg.trail_tracks)
        self._cache: OrderedDict = OrderedDict()
        self._lock = threading.RLock()
        self._stop = threading.Event()
        self.t = 0
        self.server = viser.ViserServer(host=host, port=port, verbose=False)
        self.server.scene.set_up_direction(tuple(-result.poses_c2w[0, :3, 1].astype(float)))
        self._build_gui()
        self.server.on_client_connect(self._on_connect)
        self._draw_static()
        self._draw_cameras()
        self.set_frame(0)
        self._player = threading.Thread(target=self._play_loop, daemon=True)
        self._player.start()
        if verbose:
            print(f"[view] {result.num_tracks} tracks x {self.T} frames; open http://{host}:{self.port} "
                  "(Ctrl-C to stop)", file=sys.stderr)

    @property
    def port(self) -> int:
        return self.server.get_port()

    # ---- panel ---------------------------------------------------------------------------------------
    def _build_gui(self) -> None:
        gui = self.server.gui
        with gui.add_folder("Time"):
            self.slider = gui.add_slider("frame", min=0, max=max(self.T - 1, 1), step=1, initial_value=0,
                                         disabled=self.T < 2)
            self.playing = gui.add_checkbox("play", initial_value=False)
            self.fps = gui.add_slider("fps", min=1, max=30, step=1, initial_value=8)
        with gui.add_folder("Style"):
            self.color_mode = gui.add_dropdown("colour", D.COLOR_MODES, initial_value="video + dynamic tint")
            self.point_size = gui.add_slider("point size", min=0.1, max=5.0, step=0.05, initial_value=1.0)
            self.density = gui.add_slider("density", min=0.01, max=1.0, step=0.01, initial_value=1.0)
            self.trail_len = gui.add_slider("trail length", min=1, max=max(2, min(60, self.T - 1)), step=1,
                                            initial_value=min(self.cfg.trail_length, max(1, self.T - 1)))
        with gui.add_folder("Layers"):
            self.layers = {name: gui.add_checkbox(name, initial_value=True) for name in LAYERS}
        self.info = gui.add_markdown("")
        if self.frames is not None:
            self.image = gui.add_image(self._thumb(0), label="video frame")
        self.slider.on_update(lambda _: self.set_frame(int(self.slider.value)))
        for h in (self.color_mode, self.density, self.trail_len):
            h.on_update(lambda _: self._redraw())
        self.point_size.on_update(lambda _: self._resize_points())
        for name, h in self.layers.items():
            h.on_update(lambda _, n=name: self._toggle(n))

    def _thumb(self, t: int) -> np.ndarray:
        f = self.frames[t]
        step = max(1, int(np.ceil(max(f.shape[:2]) / 480)))
        return np.ascontiguousarray(f[::step, ::step])

    def _on_connect(self, client) -> None:
        """Start each browser behind and above the first camera, looking at the scene."""
        P = self.res.poses_c2w[0].astype(np.float64)
        target = P[:3, 3] + P[:3, 2] * self.extent
        eye = P[:3, 3] - P[:3, 2] * 0.6 * self.extent - P[:3, 1] * 0.4 * self.extent
        client.camera.position = tuple(eye)
        client.camera.look_at = tuple(target)
        client.camera.up_direction = tuple(-P[:3, 1])

    # ---- drawing ---------------------------------------------------------------------------------------
    def _k(self, cap: int, available: int) -> int:
        """Points to draw: the density slider's fraction of what the cap lets through."""
        return max(1, int(round(min(cap, available) * float(self.density.value))))

    def _size(self, drawn: int, total: int) -> float:
        return D.base_point_size(self.res.intrinsics[0, 0], self.med_depth, drawn, total) * float(self.point_size.value)

    def frame_data(self, t: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(track indices, points [M,3], colours [M,3]) drawn for frame ``t`` with the current settings."""
        key = (t, self.color_mode.value, float(self.density.value))
        if key in self._cache:
            self._cache.move_to_end(key)
            return self._cache[key]
        idx, pts, col = D.frame_points(self.res, t, self.order, self._k(self.cfg.max_points, int(self.n_visible[t])),
                                       self.color_mode.value, None if self.frames is None else self.frames[t])
        self._cache[key] = (idx, pts, col)
        while len(self._cache) > FRAME_CACHE:
            self._cache.popitem(last=False)
        return idx, pts, col

    def set_frame(self, t: int) -> None:
        with self._lock:
            t = int(np.clip(t, 0, self.T - 1))
            if int(self.slider.value) != t:
                self.slider.value = t  # its update callback comes back here and draws
                return
            self.t = t
            idx, pts, col = self.frame_data(self.t)
            n_vis = int(self.n_visible[self.t])
            self.points = self.server.scene.add_point_cloud(
                "/frame/points", pts, col, point_size=self._size(len(idx), n_vis), point_shape="rounded",
                visible=self.layers["current points"].value)
            self._draw_trails()
            self._highlight_camera()
            if self.frames is not None:
                self.image.image = self._thumb(self.t)
            legend = ""
            if self.color_mode.value == "label step":
                legend = ("\n\n" + D.step_legend() if self.res.label_step is not None
                          else "\n\n(no label_step in this result: label colours)")
            elif self.color_mode.value == "object":
                G = 0 if self.res.object_poses is None else len(self.res.object_poses)
                legend = (f"\n\n{G} rigid object{'' if G == 1 else 's'}, one colour each; the tracks of none in "
                          "the label colours" if self.res.object_id is not None
                          else "\n\n(no object_id in this result: label colours)")
            self.info.content = (f"frame **{self.t}** / {self.T - 1} &nbsp; drawn **{len(idx):,}** of "
                                 f"{n_vis:,} visible tracks ({self.res.num_tracks:,} in all, "
                                 f"{self.n_dynamic:,} dynamic)" + legend)

    def _redraw(self) -> None:
        with self._lock:
            self._cache.clear()
            self._draw_static()
            self.set_frame(self.t)

    def _resize_points(self) -> None:
        with self._lock:
            self._draw_static()
            self.set_frame(self.t)

    def _toggle(self, name: str) -> None:
        on = bool(self.layers[name].value)
        nodes = {"current points": ["points"], "static map": ["static"], "dynamic trails": ["trails"],
                 "cameras": ["frustums", "current_cam"], "camera path": ["path"]}[name]
        for n in nodes:
            handles = getattr(self, n, None)
            for h in handles if isinstance(handles, list) else [handles]:
                if h is not None:
                    h.visible = on

    def _draw_static(self) -> None:
        r = self.res
        idx, xyz = D.static_map(r.tracks_3d, r.query_frame, r.is_dynamic, self.order,
                                self._k(self.cfg.max_static_points, self.n_static))
        if self.color_mode.value == "label":
            col = np.broadcast_to(D.STATIC_COLOR, (len(idx), 3))
        else:
            col = D.query_colors(self.frames, r.tracks_2d, r.query_frame, r.colors, idx)
        col = D.fade_to(col, np.full(len(idx), 0.8, np.float32))  # a little paler than the current frame
        self.static = self.server.scene.add_point_cloud(
            "/static", xyz, np.ascontiguousarray(col),
            point_size=0.8 * self._size(len(idx), self.n_static), point_shape="rounded",
            visible=self.layers["static map"].value)

    def _draw_trails(self) -> None:
        seg, fade = D.trail_segments(self.res.tracks_3d, self.trail_idx, self.t, int(self.trail_len.value),
                                     self.res.visible)
        if seg.shape[0] == 0:
            seg, fade = np.zeros((1, 2, 3), np.float32), np.zeros(1, np.float32)
        col = D.trail_colors(fade)
        self.trails = self.server.scene.add_line_segments(
            "/trails", seg, np.repeat(col[:, None], 2, axis=1), thickness=2.0, thickness_units="screen",
            visible=self.layers["dynamic trails"].value and bool(fade.any()))

    def _draw_cameras(self) -> None:
        r = self.res
        fov = D.vertical_fov(r.intrinsics, self.H)
        step = max(1, self.T // 100)
        scale = 0.08 * self.extent
        self.frustums = []
        q = quat_wxyz(r.poses_c2w[:, :3, :3].astype(np.float64))
        for t in range(0, self.T, step):
            self.frustums.append(self.server.scene.add_camera_frustum(
                f"/cameras/{t:05d}", fov=fov, aspect=self.W / self.H, scale=scale, color=(150, 150, 150),
                wxyz=q[t], position=r.poses_c2w[t, :3, 3].astype(float), thickness=1.0, thickness_units="screen"))
        c = r.poses_c2w[:, :3, 3].astype(np.float32)
        seg = np.stack([c[:-1], c[1:]], axis=1) if self.T > 1 else np.zeros((1, 2, 3), np.float32)
        self.path = self.server.scene.add_line_segments("/camera_path", seg, (40, 40, 40), thickness=2.0,
                                                        thickness_units="screen")
        self._q = q

    def _highlight_camera(self) -> None:
        r, t = self.res, self.t
        img = None if self.frames is None else self._thumb(t)
        self.current_cam = self.server.scene.add_camera_frustum(
            "/current_camera", fov=D.vertical_fov(r.intrinsics, self.H), aspect=self.W / self.H,
            scale=0.1 * self.extent, color=tuple(int(v) for v in D.DYNAMIC_COLOR), image=img, format="jpeg",
            wxyz=self._q[t], position=r.poses_c2w[t, :3, 3].astype(float), thickness=3.0,
            thickness_units="screen", visible=self.layers["cameras"].value)

    # ---- playback --------------------------------------------------------------------------------------
    def _play_loop(self) -> None:
        while not self._stop.is_set():
            if self.playing.value and self.T > 1:
                t0 = time.perf_counter()
                self.set_frame((self.t + 1) % self.T)
                time.sleep(max(0.0, 1.0 / float(self.fps.value) - (time.perf_counter() - t0)))
            else:
                time.sleep(0.05)

    def stop(self) -> None:
        self._stop.set()
        self.server.stop()


def serve(result_dir: str | Path, port: int = 8080, host: str = "127.0.0.1", video: str | None = None,
          max_points: int | None = None, verbose: bool = True) -> None:
    """Open a result folder in the viewer and serve it until Ctrl-C."""
    res = load_result(result_dir)
    frames, why = frames_for_result(result_dir, res.depth.shape, video)
    if frames is None and verbose:
        print(f"[view] no video frames ({why}); colouring by the tracks' query-frame colours", file=sys.stderr)
    cfg = D.DisplayConfig()
    if max_points:
        cfg.max_points = cfg.max_static_points = int(max_points)
    v = Viewer(res, frames, port=port, host=host, cfg=cfg, verbose=verbose)
    try:
        while True:
            time.sleep(1.0)
    except KeyboardInterrupt:
        pass
    finally:
        v.stop()
