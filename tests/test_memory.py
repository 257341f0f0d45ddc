"""The CLI's allocator setting (trackingworld.memory), in subprocesses: it is process-wide."""

import os
import subprocess
import sys

import pytest

# a 128 MB array made, dropped and made again: the page faults of the second one
PROBE = """
import resource, sys
import numpy as np
from trackingworld.memory import reuse_freed_memory
print(reuse_freed_memory())
a = np.ones(1 << 24); del a
before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
a = np.ones(1 << 24)
print(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)
"""


def _probe(setting: str) -> tuple[str, int]:
    env = dict(os.environ, TRACKINGWORLD_MALLOC=setting)
    out = subprocess.run([sys.executable, "-c", PROBE], env=env, capture_output=True, text=True, check=True)
    was_set, faults = out.stdout.split()
    return was_set, int(faults)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's mallopt")
def test_freed_large_arrays_are_reused_without_new_page_faults():
    assert _probe("0")[0] == "False"  # the opt-out leaves malloc as it is
    was_set, faults = _probe("1")
    _, faults_default = _probe("0")
    if was_set == "False":
        pytest.skip("not glibc")
    assert faults_default > 0  # glibc maps a block this large afresh each time
    assert faults < faults_default / 2


# 32 arrays of 8 MB with a small one kept between each, the large ones dropped: free holes the heap keeps
HOLES = """
import numpy as np
from trackingworld.memory import release_freed_memory, reuse_freed_memory

def rss():
    return int([l for l in open("/proc/self/status") if l.startswith("VmRSS")][0].split()[1]) * 1024

print(reuse_freed_memory())
big, small = [], []
for _ in range(32):
    big.append(np.ones(1 << 20))
    small.append(np.ones(16))
del big
before = rss()
print(release_freed_memory(), before - rss())
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's malloc_trim")
def test_released_memory_leaves_the_resident_set_where_the_heap_keeps_it():
    out = subprocess.run([sys.executable, "-c", HOLES], capture_output=True, text=True, check=True).stdout.split()
    if out[0] == "False":
        pytest.skip("not glibc")
    assert out[1] == "True" and int(out[2]) > 200e6  # of the 268 MB dropped


def test_the_peak_estimate_warns_only_past_the_available_memory():
    from trackingworld.memory import available_bytes, estimate_peak_bytes, guess_tracks, memory_warning

    # the run measured at 120 frames (257,283 tracks, 2.44 GB peak RSS) is not underestimated
    assert 2.44e9 <= estimate_peak_bytes(257_283, 120) <= 1.4 * 2.44e9
    assert estimate_peak_bytes(2 * 257_283, 120) > estimate_peak_bytes(257_283, 120)
    assert memory_warning(257_283, 120, available=8e9) is None
    msg = memory_warning(257_283, 120, available=1e9)
    assert "257,283 tracks x 120 frames" in msg and "1.0 GB is available" in msg and "--resize" in msg
    assert "\n" not in msg
    assert memory_warning(guess_tracks(480, 854, 300), 300, available=24e9, guessed=True).startswith("about ")
    if sys.platform.startswith("linux"):
        assert available_bytes() > 0


def test_a_run_too_large_for_the_memory_says_so_and_still_runs(tiny_scene, tmp_path, capsys, monkeypatch):
    from trackingworld import load_result, memory
    from trackingworld.cli.main import main

    monkeypatch.setattr(memory, "available_bytes", lambda: 1e6)  # a machine with 1 MB left
    inp = tiny_scene / "input"
    out = tmp_path / "res"
    assert main(["run", str(inp / "frames"), "--out", str(out), "--depth", str(inp / "depth.npy"),
                 "--masks", str(inp / "masks"), "--intrinsics", str(inp / "intrinsics.txt"),
                 "--method", "baseline"]) == 0
    warned = [line for line in capsys.readouterr().err.splitlines() if line.startswith("[run] warning:")]
    assert len(warned) == 2 and warned[0].startswith("[run] warning: about ")  # before and after the 2D tracks
    n = load_result(out).tracks_2d.shape[0]
    assert f"{n:,} tracks x 10 frames" in warned[1]
    with pytest.warns(RuntimeWarning, match="tracks x 10 frames need about"):  # quiet: through warnings
        assert main(["run", str(inp / "frames"), "--out", str(tmp_path / "quiet"), "--depth", str(inp / "depth.npy"),
                     "--masks", str(inp / "masks"), "--intrinsics", str(inp / "intrinsics.txt"),
                     "--method", "baseline", "--quiet"]) == 0
    assert "[run] warning" not in capsys.readouterr().err


def test_the_available_memory_is_the_smaller_of_the_kernel_and_a_container_limit(tmp_path):
    from trackingworld.memory import available_bytes

    meminfo = tmp_path / "meminfo"
    meminfo.write_text("MemTotal: 32000000 kB\nMemAvailable: 20000000 kB\n")
    none = tmp_path / "none"
    assert available_bytes(meminfo, none) == 20000000 * 1024
    v2 = tmp_path / "v2"
    v2.mkdir()
    (v2 / "memory.max").write_text("8000000000\n")
    (v2 / "memory.current").write_text("3000000000\n")
    assert available_bytes(meminfo, v2) == 5e9
    (v2 / "memory.max").write_text("max\n")
    assert available_bytes(meminfo, v2) == 20000000 * 1024
    v1 = tmp_path / "v1" / "memory"
    v1.mkdir(parents=True)
    (v1 / "memory.limit_in_bytes").write_text("4000000000\n")
    (v1 / "memory.usage_in_bytes").write_text("1000000000\n")
    assert available_bytes(meminfo, v1.parent) == 3e9
    (v1 / "memory.limit_in_bytes").write_text("9223372036854771712\n")  # v1's "no limit"
    assert available_bytes(meminfo, v1.parent) == 20000000 * 1024
    assert available_bytes(tmp_path / "missing", none) is None


def test_a_run_hands_back_freed_memory_before_the_stages_of_its_peak(tiny_scene, tmp_path, monkeypatch):
    # after the 2D tracks and the priors (pipeline.run), and as stage 3 and the rigid step start (pipeline.world)
    import trackingworld.pipeline.run as run_mod
    import trackingworld.pipeline.world as world
    from trackingworld.cli.main import main

    calls = []
    monkeypatch.setattr(run_mod, "release_freed_memory", lambda: calls.append("run"))
    real_timed = world.timed

    def timed(timings, name, verbose):
        calls.append(name)
        return real_timed(timings, name, verbose)

    monkeypatch.setattr(world, "timed", timed)
    monkeypatch.setattr(world, "release_freed_memory", lambda: calls.append("released"))
    inp = tiny_scene / "input"
    assert main(["run", str(inp / "frames"), "--out", str(tmp_path / "o"), "--depth", str(inp / "depth.npy"),
                 "--masks", str(inp / "masks"), "--intrinsics", str(inp / "intrinsics.txt"), "--quiet"]) == 0
    assert calls[:2] == ["run", "run"]  # before the first stage
    assert [calls[i + 1] for i, c in enumerate(calls) if c == "released"] == ["stage3", "rigid_movers"]
