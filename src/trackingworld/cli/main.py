"""``trackingworld`` command: synth, run, eval (and track2d once the dense tracker lands)."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from trackingworld.errors import InputError


def _size(text: str) -> tuple[int, int]:
    try:
        w, h = text.lower().split("x")
        return int(w), int(h)
    except ValueError as e:
        raise argparse.ArgumentTypeError(f"size must look like 320x240, got {text!r}") from e


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="trackingworld", description=__doc__.split("\n")[0] if __doc__ else None)
    p.add_argument("--version", action="store_true", help="print the version and exit")
    sub = p.add_subparsers(dest="cmd")

    s = sub.add_parser("synth", help="render a synthetic scene with exact ground truth")
    s.add_argument("out")
    s.add_argument("--preset", default="default", choices=["easy", "default", "hard"])
    s.add_argument("--seed", type=int, default=0)
    s.add_argument("--frames", type=int, default=None)
    s.add_argument("--size", type=_size, default=None, help="WxH, e.g. 320x240")

    r = sub.add_parser("run", help="world-centric dense 3D tracking of a video")
    r.add_argument("input", help="video file or folder of images")
    r.add_argument("--out", required=True, help="output folder")
    r.add_argument("--depth", help=".npy/.npz [T,H,W] metres, or folder of 16-bit PNG millimetres")
    r.add_argument("--masks", help="folder of PNGs (non-zero = dynamic) or .npy bool [T,H,W]")
    r.add_argument("--intrinsics", help="text file with a 3x3 matrix or fx,fy,cx,cy; or inline fx,fy,cx,cy")
    r.add_argument("--method", default="baseline", help="pipeline (baseline: camera-centric lifting)")
    r.add_argument("--device", default="cpu", help="cpu | cuda | cuda:N")
    r.add_argument("--max-frames", type=int, default=None)
    r.add_argument("--frame-stride", type=int, default=1)
    r.add_argument("--resize", type=int, default=None, help="long side of the processing resolution")
    r.add_argument("--grid-stride", type=int, default=4, help="stride of the tracked grid (px)")
    r.add_argument("--quiet", action="store_true")

    e = sub.add_parser("eval", help="evaluate a result folder against a synthetic scene")
    e.add_argument("dir", help="result folder (holding result.npz)")
    e.add_argument("--gt", required=True, help="scene folder written by `trackingworld synth`")
    e.add_argument("--json", action="store_true", help="print the full metrics as JSON")
    return p


def cmd_synth(a) -> int:
    from trackingworld.synth import render_and_write

    out = render_and_write(a.out, a.preset, a.seed, a.frames, a.size)
    print(f"scene written to {out} (inputs in {out / 'input'}, ground truth in {out / 'gt.npz'})")
    return 0


def cmd_run(a) -> int:
    from trackingworld.config import InputConfig, RunConfig, Track2DConfig
    from trackingworld.pipeline.run import run

    cfg = RunConfig(
        method=a.method, device=a.device,
        inputs=InputConfig(input=a.input, depth=a.depth, masks=a.masks, intrinsics=a.intrinsics,
                           max_frames=a.max_frames, frame_stride=a.frame_stride, resize=a.resize),
        track2d=Track2DConfig(grid_stride=a.grid_stride),
    )
    run(cfg, a.out, verbose=not a.quiet)
    print(f"result written to {Path(a.out) / 'result.npz'}")
    return 0


def cmd_eval(a) -> int:
    from trackingworld.eval.evaluate import evaluate_to_file, format_table

    m = evaluate_to_file(a.dir, a.gt)
    if a.json:
        print(json.dumps(m, indent=2))
    else:
        print(format_table({Path(a.dir).name or "result": m}))
    print(f"metrics written to {Path(a.dir) / 'metrics.json'}")
    return 0


def main(argv: list[str] | None = None) -> int:
    p = build_parser()
    a = p.parse_args(argv)
    if a.version:
        from trackingworld import __version__

        print(__version__)
        return 0
    if not a.cmd:
        p.print_help()
        return 2
    try:
        return {"synth": cmd_synth, "run": cmd_run, "eval": cmd_eval}[a.cmd](a)
    except InputError as e:
        print(f"trackingworld {a.cmd}: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
