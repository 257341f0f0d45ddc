"""Procedural synthetic scenes with exact ground truth (poses, depth, tracks, motion labels)."""

from trackingworld.synth.scene import PRESETS, Scene, SceneConfig, make_scene
from trackingworld.synth.write import render_and_write

__all__ = ["PRESETS", "Scene", "SceneConfig", "make_scene", "render_and_write"]
