"""``make demo``: render a default synthetic scene, run the pipeline and the camera-centric baseline on it,
evaluate both against the exact ground truth and print the metrics side by side."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from trackingworld.config import InputConfig, RunConfig
from trackingworld.eval.evaluate import evaluate_to_file, format_table
from trackingworld.memory import reuse_freed_memory
from trackingworld.pipeline.run import DEFAULT_METHOD, METHODS, run
from trackingworld.synth import render_and_write
from trackingworld.viz.render import render as render_result


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--out", default="demo_out")
    ap.add_argument("--preset", default="default")
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args(argv)
    reuse_freed_memory()  # as the CLI (trackingworld.memory)
    out = Path(a.out)
    scene = out / "scene"
    t0 = time.perf_counter()
    print(f"[demo] rendering a '{a.preset}' synthetic scene into {scene}", file=sys.stderr)
    render_and_write(scene, a.preset, a.seed)
    inp = scene / "input"
    methods = [DEFAULT_METHOD] + [m for m in ("baseline",) if m != DEFAULT_METHOD and m in METHODS]
    table = {}
    for m in methods:
        cfg = RunConfig(method=m, inputs=InputConfig(input=str(inp / "frames"), depth=str(inp / "depth.npy"),
                                                     masks=str(inp / "masks"),
                                                     intrinsics=str(inp / "intrinsics.txt")))
        print(f"[demo] running --method {m}", file=sys.stderr)
        run(cfg, out / m)
        table[m] = evaluate_to_file(out / m, scene)
    print(f"[demo] rendering videos and the camera path of --method {DEFAULT_METHOD}", file=sys.stderr)
    renders = render_result(out / DEFAULT_METHOD, gt=scene, verbose=False)
    print()
    print(format_table(table))
    print(f"\n[demo] finished in {time.perf_counter() - t0:.0f} s")
    for m in methods:
        print(f"  {m}: {out / m / 'result.npz'} (metrics: {out / m / 'metrics.json'})")
    print(f"  scene and ground truth: {scene}")
    print(f"  renders: {', '.join(str(p) for p in renders.values())}")
    exe = Path(sys.executable).parent / "trackingworld"
    try:
        exe = exe.relative_to(Path.cwd())
    except ValueError:
        pass
    print(f"\nOpen the result in the 3D viewer (then browse to http://127.0.0.1:8080):\n"
          f"  {exe} view {out / DEFAULT_METHOD}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
