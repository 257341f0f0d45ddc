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
