"""trackingworld: world-centric dense 3D tracking of almost all pixels from a monocular video.

Conventions (stated once, used everywhere):

* Camera axes are OpenCV's: x right, y down, z forward (metres).
* Poses are camera-to-world 4x4 matrices ``c2w`` (``X_world = c2w @ X_cam``), last row ``0 0 0 1``.
* Pixel coordinates are x right / y down, with (0, 0) the centre of the top-left pixel, so a pixel
  ``(x, y)`` unprojects to ``K^-1 [x, y, 1]^T``.
* Depth is the camera-frame z coordinate (not the ray length), in metres.
"""

from trackingworld.io.result import Result, load_result, save_result

__version__ = "0.1.0"
__all__ = ["Result", "load_result", "save_result", "__version__"]
