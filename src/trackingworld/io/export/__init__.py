"""``trackingworld export DIR --format F``: a result in the formats other tools read.

=============  ==========================================  ==============================================
format         written (default place, inside DIR/export)  read by
=============  ==========================================  ==============================================
tum            poses_tum.txt                               evo, TUM / ETH3D tools
colmap         colmap/{cameras,images,points3D}.txt,       COLMAP, pycolmap, gsplat, nerfstudio
               colmap/images/
nerfstudio     nerfstudio/transforms.json, images/,        nerfstudio (``ns-train ... --data``)
               depth/, static_points.ply
ply            ply/frame_00000.ply ..., ply/static.ply     trimesh, open3d, MeshLab, CloudCompare
tapvid3d       tapvid3d.npz                                TAPVid-3D evaluation code
rrd            result.rrd                                  ``rerun result.rrd``
objects        objects/object_000_tum.txt ...,             evo, TUM tools (each rigid object's
               objects/objects.json                        object-to-world trajectory)
=============  ==========================================  ==============================================

Every output is written under a temporary name and renamed, so a failed export leaves nothing half-written.
``max_points`` caps the tracks exported where files grow with them (colmap, ply, nerfstudio, rrd: a random
subset, the same for every frame); tum and tapvid3d keep every track.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

import numpy as np

from trackingworld.errors import InputError
from trackingworld.io.atomic import atomic_dir, atomic_path, check_writable, write_npz, write_text
from trackingworld.io.frames import frames_for_result
from trackingworld.io.result import Result, load_result, tum_lines
from trackingworld.progress import Progress
from trackingworld.viz import display as D

FORMATS = ("tum", "colmap", "nerfstudio", "ply", "tapvid3d", "rrd", "objects")
DEFAULT_NAMES = {"tum": "poses_tum.txt", "colmap": "colmap", "nerfstudio": "nerfstudio", "ply": "ply",
                 "tapvid3d": "tapvid3d.npz", "rrd": "result.rrd", "objects": "objects"}
DEFAULT_MAX_POINTS = {"colmap": 100_000, "nerfstudio": 300_000, "ply": 300_000, "rrd": 150_000}
EXPORT_DIR = "export"


def _write_images(frames: np.ndarray, folder: Path) -> list[str]:
    import imageio.v3 as iio

    from trackingworld.io.export.colmap import image_name

    folder.mkdir(parents=True, exist_ok=True)
    names = []
    for t, f in enumerate(frames):
        iio.imwrite(folder / image_name(t), f, quality=95)
        names.append(f"{folder.name}/{image_name(t)}")
    return names


def export(result_dir: str | os.PathLike, fmt: str, out: str | os.PathLike | None = None,
           max_points: int | None = None, video: str | None = None, images: bool = True,
           verbose: bool = True) -> Path:
    """Export a result folder; returns the written path (a file or a folder)."""
    if fmt not in FORMATS:
        raise InputError(f"--format {fmt}: unknown (one of {', '.join(FORMATS)})")
    result_dir = Path(result_dir)
    res = load_result(result_dir)
    out = Path(out) if out else result_dir / EXPORT_DIR / DEFAULT_NAMES[fmt]
    check_writable(out.parent, "export folder")  # before the frames are read and the points written
    cap = max_points if max_points is not None else DEFAULT_MAX_POINTS.get(fmt)
    order = D.display_order(res.num_tracks)
    frames = None
    if fmt in ("rrd", "ply") or (images and fmt in ("colmap", "nerfstudio")):  # colours, or images to write
        frames, why = frames_for_result(result_dir, res.depth.shape, video)
        if frames is None and verbose:
            print(f"[export] no input frames ({why}): colours from the tracks, no images", file=sys.stderr)
    info: dict
    if fmt == "tum":
        write_text(out, tum_lines(res.poses_c2w))
        info = {"frames": res.num_frames}
    elif fmt == "tapvid3d":
        from trackingworld.io.export.tapvid3d import tapvid3d_arrays

        write_npz(out, **tapvid3d_arrays(res, np.arange(res.num_tracks)))
        info = {"tracks": res.num_tracks}
    elif fmt == "colmap":
        from trackingworld.io.export.colmap import write_colmap

        with atomic_dir(out) as tmp:
            info = write_colmap(res, tmp, np.sort(D.first_k(order, ~res.is_dynamic, cap)))
            if frames is not None:
                _write_images(frames, tmp / "images")
    elif fmt == "nerfstudio":
        from trackingworld.io.export.nerfstudio import write_nerfstudio
        from trackingworld.io.export.ply import write_ply

        with atomic_dir(out) as tmp:
            names = _write_images(frames, tmp / "images") if frames is not None else None
            sidx, sxyz = D.static_map(res.tracks_3d, res.query_frame, res.is_dynamic, order, cap)
            write_ply(tmp / "static_points.ply", sxyz, res.colors[sidx])
            info = write_nerfstudio(res, tmp, names, "static_points.ply")
    elif fmt == "ply":
        info = _export_ply(res, out, frames, order, cap, verbose)
    elif fmt == "objects":
        info = _export_objects(res, out)
    else:  # rrd
        from trackingworld.io.export.rrd import write_rrd

        p = Progress("export: rrd", res.num_frames, verbose)
        with atomic_path(out) as tmp:
            info = write_rrd(res, tmp, frames, order, cap, p.update)
    if verbose:
        extra = ", ".join(f"{k} {v:,}" if isinstance(v, int) else f"{k} {v:.4g}" for k, v in info.items())
        print(f"[export] {fmt}: wrote {out} ({extra})", file=sys.stderr)
    return out


def _export_ply(res: Result, out: Path, frames, order, cap: int, verbose: bool) -> dict:
    from trackingworld.io.export.ply import write_ply

    p = Progress("export: ply", res.num_frames, verbose)
    n = 0
    with atomic_dir(out) as tmp:
        sidx, sxyz = D.static_map(res.tracks_3d, res.query_frame, res.is_dynamic, order, cap)
        write_ply(tmp / "static.ply", sxyz, res.colors[sidx])
        for t in range(res.num_frames):
            idx, pts, col = D.frame_points(res, t, order, cap, "video", None if frames is None else frames[t])
            write_ply(tmp / f"frame_{t:05d}.ply", pts, col, res.is_dynamic[idx])
            n += len(idx)
            p.update(t + 1)
    return {"frames": res.num_frames, "points": n, "static_points": len(sidx)}


def _export_objects(res: Result, out: Path) -> dict:
    """Each rigid object's object-to-world poses (``object_poses``) in the frames its motion is solved in, one TUM
    file per object (timestamp = frame index), and ``objects.json``: per object its file, track count and frames."""
    import json

    object_id = res.require("object_id", "--format objects")
    listing = []
    with atomic_dir(out) as tmp:
        for g, O in enumerate(res.object_poses):
            frames = np.flatnonzero(np.isfinite(O[:, 0, 0]))
            name = f"object_{g:03d}_tum.txt"
            (tmp / name).write_text(tum_lines(O[frames], frames))
            listing.append({"object": g, "file": name, "tracks": int((object_id == g).sum()),
                            "frames": [int(frames[0]), int(frames[-1])] if len(frames) else [],
                            "solved_frames": int(len(frames))})
        (tmp / "objects.json").write_text(json.dumps({"objects": listing, "pose": "object-to-world, world metres, "
                                                      "timestamp = frame index"}, indent=1) + "\n")
    return {"objects": len(listing), "tracks": int((object_id >= 0).sum())}
