import json

import numpy as np

from trackingworld import load_result
from trackingworld.cli.main import main
from trackingworld.optim.label_steps import LABEL_STEPS, LabelSteps


def test_each_track_keeps_the_last_step_that_changed_it():
    start = np.array([True, False, False, True, False])
    steps = LabelSteps(start)
    dyn = start.copy()
    dyn[1] = True  # stage 2 finds a mover
    steps.after("stage2", dyn)
    steps.after("classify", dyn)  # no change: no track is the classification's
    dyn[[1, 3]] = False  # the vote turns one back and releases a masked one
    steps.after("vote", dyn)
    dyn[4] = True
    steps.after("photo_moving", dyn)
    names = [LABEL_STEPS[c] for c in steps.step]
    assert names == ["masks", "vote", "masks", "vote", "photo_moving"]
    assert steps.counts(dyn) == {"masks": {"dynamic": 1, "static": 1}, "vote": {"dynamic": 0, "static": 2},
                                 "photo_moving": {"dynamic": 1, "static": 0}}


def test_run_writes_the_steps_of_its_labels(tiny_scene, tmp_path):
    inp = tiny_scene / "input"
    out = tmp_path / "res"
    assert main(["run", str(inp / "frames"), "--out", str(out), "--depth", str(inp / "depth.npy"),
                 "--masks", str(inp / "masks"), "--intrinsics", str(inp / "intrinsics.txt"), "--quiet"]) == 0
    r = load_result(out)
    assert r.label_step is not None and r.label_step.shape == (r.num_tracks,)
    assert r.label_step.min() >= 0 and r.label_step.max() < len(LABEL_STEPS)
    name = np.array(LABEL_STEPS)[r.label_step]
    # the steps that only ever make a track dynamic, and those that only make it static
    assert r.is_dynamic[np.isin(name, ["stage2", "depth_movers", "photo_moving"])].all()
    assert not r.is_dynamic[np.isin(name, ["photo_static", "occluded_static"])].any()
    counts = json.loads((out / "optim.json").read_text())["label_steps"]
    assert sum(c["dynamic"] + c["static"] for c in counts.values()) == r.num_tracks
    assert sum(c["dynamic"] for c in counts.values()) == int(r.is_dynamic.sum())
    for step, c in counts.items():
        mine = name == step
        assert c == {"dynamic": int(r.is_dynamic[mine].sum()), "static": int((~r.is_dynamic[mine]).sum())}
    assert (r.label_step > 0).any()  # some step changed a label on this scene
