import numpy as np

from trackingworld.geometry import in_image


def test_in_image_edges_and_margin():
    W, H = 8, 6
    uv = np.array([[-0.5, 0.0], [-0.51, 0.0], [7.5, 5.5], [7.51, 2.0], [3.0, 5.6], [0.0, 0.0], [7.0, 5.0]])
    assert in_image(uv, W, H).tolist() == [True, False, True, False, False, True, True]
    # margin 0.5: the pixels that can be sampled bilinearly, 0 .. W-1 and 0 .. H-1
    assert in_image(uv, W, H, margin=0.5).tolist() == [False, False, False, False, False, True, True]
    assert not in_image(np.array([[0.4, 3.0]]), W, H, margin=1.0)[0]
    assert in_image(np.array([[0.5, 3.0]]), W, H, margin=1.0)[0]
