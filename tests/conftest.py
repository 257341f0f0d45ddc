import numpy as np
import pytest

from trackingworld.synth import render_and_write


@pytest.fixture(scope="session")
def tiny_scene(tmp_path_factory):
    """A small default-preset scene (10 frames, 128x96): renders in about a second."""
    out = tmp_path_factory.mktemp("scene")
    render_and_write(out, "default", seed=3, frames=10, size=(128, 96), verbose=False)
    return out


@pytest.fixture
def rng():
    return np.random.default_rng(0)
