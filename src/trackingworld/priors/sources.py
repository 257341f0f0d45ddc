"""Where each prior comes from, read off its flag: a file, a model, the weight-free default, or none."""

from __future__ import annotations

from collections.abc import Callable

from trackingworld.priors.depth_models import is_model_spec
from trackingworld.priors.mask_models import is_mask_model_spec


def _source(spec: str | None, default: str, is_model: Callable[[str], bool]) -> str:
    if spec is None or spec == default:
        return default
    if spec == "none":
        return "none"
    return "model" if is_model(spec) else "file"


def depth_source(spec: str | None) -> str:
    """file | model | sfm (the default) | none."""
    return _source(spec, "sfm", is_model_spec)


def mask_source(spec: str | None) -> str:
    """file | model | motion (the default) | none."""
    return _source(spec, "motion", is_mask_model_spec)


def intrinsics_given(spec: str | None) -> bool:
    """True when ``--intrinsics`` names a file or values (not ``auto``, the default)."""
    return spec not in (None, "", "auto")
