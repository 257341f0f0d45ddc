"""Models kept loaded across the videos of one process (loaded_models): loaded once per key, one per kind, read
again when the checkpoint changes on disk."""

import os

import pytest

from trackingworld.loaded_models import kept_model, loaded, model_key, release


@pytest.fixture(autouse=True)
def _nothing_kept():
    release()
    yield
    release()


def test_a_model_is_loaded_once_per_key_and_one_per_kind_is_kept():
    loads = []

    def loader(name):
        def load():
            loads.append(name)
            return {"model": name}
        return load

    a = kept_model("depth", ("a", "cpu"), loader("a"))
    assert kept_model("depth", ("a", "cpu"), loader("a")) is a and loads == ["a"]
    m = kept_model("masks", ("a", "cpu"), loader("m"))  # another kind is kept beside it
    assert kept_model("depth", ("a", "cpu"), loader("a")) is a and loads == ["a", "m"]
    assert kept_model("depth", ("a", "cuda"), loader("a")) is not a  # another device: loaded again ...
    assert kept_model("depth", ("a", "cpu"), loader("a")) is not a and loads == ["a", "m", "a", "a"]  # ... one kept
    assert kept_model("masks", ("a", "cpu"), loader("m")) is m
    release("masks")
    kept_model("masks", ("a", "cpu"), loader("m"))
    assert loads == ["a", "m", "a", "a", "m"]


def test_a_failing_load_keeps_nothing():
    def broken():
        raise OSError("no weights")

    kept_model("depth", "k", lambda: 1)
    with pytest.raises(OSError):
        kept_model("depth", "other", broken)
    assert kept_model("depth", "k", lambda: 2) == 2  # the old one was dropped, the failed one not kept


def test_a_checkpoint_rewritten_on_disk_has_another_key(tmp_path):
    ckpt = tmp_path / "model.pth"
    ckpt.write_bytes(b"1234")
    key = model_key(str(ckpt), "cpu")
    assert model_key(str(ckpt), "cpu") == key and model_key(str(ckpt), "cuda") != key
    ckpt.write_bytes(b"123456")
    os.utime(ckpt, ns=(1, 1))
    assert model_key(str(ckpt), "cpu") != key
    assert model_key("hf:some/model", "cpu") == model_key("hf:some/model", "cpu")  # a hub name by its name


def test_loaded_keeps_one_model_per_spec_and_device():
    release()
    calls = []

    def load(spec, device):
        calls.append((spec, device))
        return object()

    a = loaded("depth", "hf:x", "cpu", load)
    assert loaded("depth", "hf:x", "cpu", load) is a and calls == [("hf:x", "cpu")]
    assert loaded("depth", "hf:x", "cuda", load) is not a and calls[-1] == ("hf:x", "cuda")
    release()
