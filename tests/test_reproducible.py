"""OpenCV without IPP (trackingworld.reproducible), in fresh interpreters: OpenCV reads the setting when it starts."""

import json
import os
import subprocess
import sys

import pytest

WARNING = "IPP was disabled"  # OpenCV's own start-up line that the module keeps quiet

PROBE = """
import json, os, threading
from trackingworld.reproducible import without_ipp
off = without_ipp()
import cv2
seen = {}
t = threading.Thread(target=lambda: seen.update(thread=cv2.ipp.useIPP()))
t.start(); t.join()
print(json.dumps({"off": off, "main": cv2.ipp.useIPP(), "thread": seen["thread"],
                  "level": cv2.utils.logging.getLogLevel(), "env": os.environ.get("OPENCV_LOG_LEVEL")}))
"""

# the edge-aware prior of the depth fields, called again and again on one input: IPP's blur gave other last bits
# from call to call on `default` 0 (module docstring); with IPP off every call must give the same map
REPEAT = """
import numpy as np
from trackingworld.reproducible import without_ipp
print(without_ipp())
from trackingworld.optim.edge_prior import inner_prior
rng = np.random.default_rng(0)
T, H, W = 12, 240, 320
y, x = np.mgrid[0:H, 0:W]
prior = np.stack([2 + np.sin(x / 40 + t) + 0.5 * (x > 150 + t) + 0.01 * rng.random((H, W)) for t in range(T)])
uv = np.stack([rng.random((20000, T)) * W, rng.random((20000, T)) * H], -1).astype(np.float32)
vis = rng.random((20000, T)) < 0.8
first = inner_prior(prior.astype(np.float32), uv, vis, 1.5)
print(max(int((inner_prior(prior.astype(np.float32), uv, vis, 1.5) != first).sum()) for _ in range(8)))
"""

# a batch's --jobs workers: started inside quiet_children with the run's set-up, they inherit IPP off and start
# without OpenCV's warning, their log level set back
WORKERS = """
import json, os
from concurrent.futures import ProcessPoolExecutor
from multiprocessing import get_context
from trackingworld.reproducible import without_ipp, quiet_children
without_ipp()
from trackingworld.pipeline.batch import _worker_start

def state(_):
    import cv2
    return cv2.ipp.useIPP(), cv2.utils.logging.getLogLevel()

if __name__ == "__main__":
    with quiet_children(), ProcessPoolExecutor(2, mp_context=get_context("spawn"), initializer=_worker_start,
                                               initargs=(1,)) as pool:
        print(json.dumps(list(pool.map(state, range(2)))))
    print(json.dumps(os.environ.get("OPENCV_LOG_LEVEL")))
"""


def _python(code: str, tmp_path=None, **env) -> subprocess.CompletedProcess:
    e = {k: v for k, v in os.environ.items() if k not in ("OPENCV_IPP", "OPENCV_LOG_LEVEL", "TRACKINGWORLD_IPP")}
    e.update(env)
    if tmp_path is not None:  # a script file: spawned workers import the main module by its path
        script = tmp_path / "probe.py"
        script.write_text(code)
        cmd = [sys.executable, str(script)]
    else:
        cmd = [sys.executable, "-c", code]
    return subprocess.run(cmd, env=e, capture_output=True, text=True, check=True, timeout=300)


def _ipp_built() -> bool:
    out = _python("import cv2; print(cv2.ipp.useIPP())")
    return out.stdout.strip() == "True"


def test_ipp_off_in_every_thread_without_opencvs_warning():
    if not _ipp_built():
        pytest.skip("this OpenCV has no IPP")
    out = _python(PROBE)
    got = json.loads(out.stdout)
    assert got["off"] and not got["main"] and not got["thread"]
    assert WARNING not in out.stderr
    assert got["level"] == 3 and got["env"] is None  # OpenCV's default level (warnings) back, the environment too


def test_the_log_level_asked_for_is_kept():
    got = json.loads(_python(PROBE, OPENCV_LOG_LEVEL="INFO").stdout)
    assert got["level"] == 4 and got["env"] == "INFO"


def test_the_opt_out_and_a_late_call_leave_opencv_as_it_is():
    if not _ipp_built():
        pytest.skip("this OpenCV has no IPP")
    got = json.loads(_python(PROBE, TRACKINGWORLD_IPP="1").stdout)
    assert not got["off"] and got["main"] and got["thread"]
    late = json.loads(_python("import cv2\n" + PROBE).stdout)  # cv2 first: too late for its worker threads,
    assert not late["off"] and late["main"] and late["thread"]  # so no thread is changed


def test_the_edge_aware_prior_is_the_same_map_from_call_to_call():
    out = _python(REPEAT).stdout.split()
    assert out[1] == "0"


def test_a_batchs_workers_inherit_ipp_off_quietly(tmp_path):
    if not _ipp_built():
        pytest.skip("this OpenCV has no IPP")
    out = _python(WORKERS, tmp_path)
    workers, env = out.stdout.strip().split("\n")
    assert json.loads(workers) == [[False, 3], [False, 3]]  # IPP off, warnings shown again
    assert WARNING not in out.stderr
    assert json.loads(env) is None  # the parent's environment as it was


# the command line's own path: main() turns IPP off before its parser imports cv2
CLI = """
import sys
import trackingworld.cli.main as cli

def probe(args):
    import cv2
    print(cv2.ipp.useIPP())
    return 0

cli.cmd_eval = probe
sys.exit(cli.main(["eval", "out", "--gt", "scene"]))
"""


def test_the_command_line_runs_without_ipp():
    if not _ipp_built():
        pytest.skip("this OpenCV has no IPP")
    assert _python(CLI).stdout.strip() == "False"
    assert _python(CLI, TRACKINGWORLD_IPP="1").stdout.strip() == "True"


def test_two_runs_write_the_same_result_to_the_bit(tiny_scene, tmp_path):
    import numpy as np

    inp = tiny_scene / "input"
    results = []
    for name in ("a", "b"):
        _python(f"""
import sys
from trackingworld.cli.main import main
sys.exit(main(["run", "{inp / 'frames'}", "--out", "{tmp_path / name}", "--depth", "{inp / 'depth.npy'}",
               "--masks", "{inp / 'masks'}", "--intrinsics", "{inp / 'intrinsics.txt'}", "--quiet"]))
""")
        results.append(np.load(tmp_path / name / "result.npz"))
    a, b = results
    assert a.files == b.files
    for key in a.files:
        assert np.array_equal(a[key], b[key], equal_nan=True), key
