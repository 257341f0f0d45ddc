"""Which step of the lifting decided each track's static / dynamic label (not in the paper).

The labels start from the coarse masks (``optim.labels``: a sure-dynamic track is dynamic, every other one static
until a test says otherwise) and are changed by the steps of ``pipeline.world`` in the order of
:data:`LABEL_STEPS`. :class:`LabelSteps` notes, per track, the last step that changed its label; 0 ("masks") means
no step did. Written as ``label_step`` in ``result.npz`` and counted in ``optim.json`` (``label_steps``), so a wrong
label can be traced to the rule that set it (``benchmarks/probe_label_steps.py`` does so against a synthetic
scene's ground truth).
"""

from __future__ import annotations

import numpy as np

# the steps in pipeline order; a track's code is its index here
LABEL_STEPS = (
    "masks",  # the masks' label, unchanged (an ambiguous track starts static)
    "stage2",  # its stage-2 offsets reached epsilon (the paper's as-static-as-possible test)
    "classify",  # the test of the masked and ambiguous tracks outside stage 2
    "rebuild_static",  # the test of the static tracks outside stage 2 (the appendix's vote, their own test)
    "depth_movers",  # the depth-discrepancy test (optim.depth_movers)
    "vote",  # the vote of the short tracks (pipeline.static_side.vote_short_tracks)
    "photo_static",  # a dynamic track found to be a static point by its colours (optim.photo_static)
    "occluded_static",  # a dynamic track found to be a static point a nearer surface hides (occluded_static)
    "photo_moving",  # a short static track whose point does not show its colour (pipeline.static_side.photo_moving)
)


class LabelSteps:
    """Per track ``[N]`` int8 (``step``): the index in :data:`LABEL_STEPS` of the last step that changed its label.

    ``start [N]`` bool: the masks' dynamic label. Call :meth:`after` with the labels once each step is done."""

    def __init__(self, start: np.ndarray):
        self.step = np.zeros(len(start), np.int8)
        self._last = np.array(start, bool)

    def after(self, name: str, dynamic: np.ndarray) -> None:
        """The step ``name`` is done and left the labels ``dynamic [N]`` bool."""
        changed = dynamic != self._last
        self.step[changed] = LABEL_STEPS.index(name)
        self._last = np.array(dynamic, bool)

    def counts(self, dynamic: np.ndarray) -> dict:
        """{step: {"dynamic": n, "static": m}}: the final labels ``dynamic [N]`` by the step that set them, the steps
        that set none left out."""
        out = {}
        for code, name in enumerate(LABEL_STEPS):
            mine = self.step == code
            if mine.any():
                n_dyn = int((mine & dynamic).sum())
                out[name] = {"dynamic": n_dyn, "static": int(mine.sum()) - n_dyn}
        return out
