"""Pretrained models kept loaded for the rest of the process, so that a batch of videos (``pipeline.batch``) loads
each model once rather than once per video: a depth model's weights are read and moved to the device in seconds
to tens of seconds, a cost a thousand videos would otherwise pay a thousand times.

One model of each kind is kept, the last one asked for: asking for another (another name or device) drops the
kept one first, so a process never holds two depth models. A local checkpoint (file or folder) is known by its
path, size and modification time (:func:`model_key`), so one rewritten while the process runs is read again.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Hashable
from typing import TypeVar

from trackingworld.io.cache import file_identity

M = TypeVar("M")

_KEPT: dict[str, tuple[Hashable, object]] = {}


def model_key(spec: str, device: str) -> tuple[str, str]:
    """What identifies a loaded model: its spec (a local checkpoint by path, size and mtime; a hub name as given)
    and the device it was moved to."""
    return json.dumps(file_identity(spec), sort_keys=True), str(device)


def kept_model(kind: str, key: Hashable, load: Callable[[], M]) -> M:
    """The model of ``kind`` (depth, masks, tracker) loaded for ``key`` (:func:`model_key`): the kept one when
    its key matches, else ``load()`` after the kept one of that kind is dropped. A failing ``load`` keeps
    nothing."""
    held = _KEPT.get(kind)
    if held is not None and held[0] == key:
        return held[1]  # type: ignore[return-value]
    _KEPT.pop(kind, None)  # let the old one go before the new one is read (memory)
    model = load()
    _KEPT[kind] = (key, model)
    return model


def loaded(kind: str, spec: str, device: str, load: Callable[[str, str], M]) -> M:
    """:func:`kept_model` of ``load(spec, device)``, known by :func:`model_key` of ``spec`` and ``device``: how the
    pipeline asks for a depth, mask or tracker model."""
    return kept_model(kind, model_key(spec, device), lambda: load(spec, device))


def release(kind: str | None = None) -> None:
    """Drop the kept model of ``kind`` (None: of every kind)."""
    if kind is None:
        _KEPT.clear()
    else:
        _KEPT.pop(kind, None)
