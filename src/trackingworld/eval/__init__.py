"""Evaluation metrics (core maths on arrays) and the ``eval`` command's orchestration."""

from trackingworld.eval.depth import abs_rel_delta1, align_depth, depth_metrics
from trackingworld.eval.trajectory import camera_metrics, sim3_from_trajectories

__all__ = ["abs_rel_delta1", "align_depth", "camera_metrics", "depth_metrics", "sim3_from_trajectories"]
