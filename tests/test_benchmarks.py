"""The benchmark scripts refuse a preset the synthetic generator does not know on one line, before any work (they
run on demand, never in the tests; only their command lines are checked here)."""

import importlib
import sys
from pathlib import Path

import pytest

BENCH = Path(__file__).resolve().parents[1] / "benchmarks"


@pytest.fixture(scope="module", autouse=True)
def _benchmarks_importable():
    sys.path.insert(0, str(BENCH))  # the scripts import their sibling _common
    yield
    sys.path.remove(str(BENCH))


@pytest.mark.parametrize("script", ["bench_device", "bench_focal", "bench_optim", "bench_priors", "bench_scaling",
                                    "bench_solver"])
def test_an_unknown_preset_is_refused_by_argparse(script, capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit) as e:
        importlib.import_module(script).main(["--preset", "nope"])
    assert e.value.code == 2
    assert "invalid choice: 'nope'" in capsys.readouterr().err
    assert not any(tmp_path.iterdir())  # no scratch folder, no scene


def test_bench_scenes_refuses_an_unknown_preset(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit, match="unknown preset 'nope'; choose from easy, default, hard"):
        importlib.import_module("bench_scenes").main(["--scenes", "nope:0", "--cache", str(tmp_path / "c")])
    assert not any(tmp_path.iterdir())


@pytest.mark.parametrize("scene, says", [("nope=1", "'nope' is not a SceneConfig field"),
                                         ("cam_speed=fast", "'fast' is not of type float"),
                                         ("n_clutter=2.5", "'2.5' is not of type int")])
def test_bench_scaling_refuses_a_bad_scene_field(scene, says, capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit) as e:
        importlib.import_module("bench_scaling").main(["--scene", scene])
    assert e.value.code == 2 and says in capsys.readouterr().err
