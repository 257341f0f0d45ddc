"""Dense 2D point tracking: tracker interface, flow-based tracker, query selection."""

from trackingworld.tracking2d.base import Tracker, TrackResult
from trackingworld.tracking2d.flow_tracker import FlowTracker, FlowTrackerConfig

__all__ = ["FlowTracker", "FlowTrackerConfig", "TrackResult", "Tracker"]
