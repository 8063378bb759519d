"""Pattern files (stage/_pattern_files.py, docs/pattern_files.md): round trip, PWM quantisation, the rig
check, and bad files refused naming the file and the field."""

import json

import numpy as np
import pytest

import stage


@pytest.fixture(scope="module")
def rig():
    return stage.light_stage_x()


def _weights(L, K=5, seed=0):
    W = np.random.default_rng(seed).uniform(0.0, 1.0, (K, L))
    W[0, :3] = [0.0, 1.0, 0.5]  # the ends of the range are allowed
    return W


def test_round_trip_keeps_weights_and_metadata(tmp_path, rig):
    W = _weights(rig.num_lights)
    meta = {"method": "learned", "training": {"steps": 2000, "noise": "shot, 1e4 e-", "loss": [0.5, 0.01]}}
    path = stage.save_patterns(tmp_path / "p.json", W, rig, metadata=meta)
    got, m = stage.load_patterns(path, rig)
    assert got.shape == W.shape and got.dtype == np.float32
    np.testing.assert_array_equal(np.asarray(got), W.astype(np.float32))
    assert m["method"] == "learned" and m["training"] == meta["training"]
    assert m["light_ids"] == list(range(rig.num_lights))
    # No rig: the file alone is read (and checked).
    got2, _ = stage.load_patterns(path)
    np.testing.assert_array_equal(np.asarray(got2), np.asarray(got))
    doc = json.loads(path.read_text())
    assert doc["format"] == stage.PATTERN_FORMAT and doc["version"] == stage.PATTERN_FORMAT_VERSION
    assert doc["num_lights"] == rig.num_lights and doc["num_patterns"] == 5
    # The weights as doubles: exactly the caller's values.
    np.testing.assert_array_equal(np.asarray(doc["weights"]), W)
    np.testing.assert_allclose(np.asarray([x["position_mm"] for x in doc["lights"]]), np.asarray(rig.position),
                               rtol=0, atol=0)
    # The gradient patterns play as they are.
    G = np.asarray(stage.gradient_patterns(rig), np.float64)
    stage.save_patterns(tmp_path / "g.json", G, rig, metadata={"method": "gradient"})
    np.testing.assert_array_equal(np.asarray(stage.load_patterns(tmp_path / "g.json", rig)[0]),
                                  G.astype(np.float32))


def test_quantised_file_holds_what_the_leds_play(tmp_path, rig):
    W = _weights(rig.num_lights, seed=1)
    path = stage.save_patterns(tmp_path / "q.json", W, rig, bits=8, light_ids=np.arange(rig.num_lights) + 1)
    got, meta = stage.load_patterns(path, rig)
    doc = json.loads(path.read_text())
    levels = np.asarray(doc["quantization"]["levels"])
    assert levels.dtype.kind == "i" and levels.min() >= 0 and levels.max() == 255
    np.testing.assert_array_equal(np.asarray(doc["weights"]), levels / 255)
    # Rounding to 255 levels moves a weight by at most half a level.
    assert np.max(np.abs(np.asarray(got, np.float64) - W)) <= 0.5 / 255 + 1e-7
    assert meta["bits"] == 8 and meta["light_ids"][0] == 1
    with pytest.raises(ValueError, match="bits"):
        stage.save_patterns(tmp_path / "x.json", W, rig, bits=7)


def test_a_file_for_another_rig_is_refused(tmp_path, rig):
    path = stage.save_patterns(tmp_path / "p.json", _weights(rig.num_lights), rig)
    with pytest.raises(ValueError, match="346 lights"):
        stage.load_patterns(path, stage.light_stage_x("polarized"))
    moved = stage.Rig(rig.position.at[10, 0].add(5.0), rig.intensity, rig.solid_angle, rig.near_field)
    with pytest.raises(ValueError, match="light 10 is 5.0 mm"):
        stage.load_patterns(path, moved)
    # Within the 1 mm tolerance it is the same rig (a re-measured calibration, float32 rounding).
    nudged = stage.Rig(rig.position.at[10, 0].add(0.3), rig.intensity, rig.solid_angle, rig.near_field)
    stage.load_patterns(path, nudged)
    dome = stage.geodesic_dome(1)
    path2 = stage.save_patterns(tmp_path / "d.json", _weights(dome.num_lights), dome)
    with pytest.raises(ValueError, match="distant"):
        stage.load_patterns(path2, stage.Rig(dome.position, dome.intensity, dome.solid_angle, True))


def _edit(path, fn):
    doc = json.loads(path.read_text())
    fn(doc)
    path.write_text(json.dumps(doc))
    return path


@pytest.mark.parametrize("edit, field", [
    (lambda d: d["weights"][2].__setitem__(7, 1.5), "weights"),
    (lambda d: d["weights"][2].__setitem__(7, -0.01), "weights"),
    (lambda d: d["weights"][0].__setitem__(0, "0.5"), "weights"),
    (lambda d: d["weights"][0].__setitem__(0, True), "weights"),
    (lambda d: d["weights"].pop(), "weights"),
    (lambda d: d["weights"][1].pop(), "weights"),
    (lambda d: d.__setitem__("format", "rig"), "format"),
    (lambda d: d.__setitem__("version", 2), "version"),
    (lambda d: d.__setitem__("version", "1"), "version"),
    (lambda d: d.__setitem__("num_lights", 0), "num_lights"),
    (lambda d: d["lights"].pop(), "lights"),
    (lambda d: d["lights"][3].__setitem__("position_mm", [0, 0]), "lights"),
    (lambda d: d["lights"][3].__setitem__("id", 0), "lights"),
    (lambda d: d.__setitem__("metadata", [1, 2]), "metadata"),
    (lambda d: d.__setitem__("near_field", "yes"), "near_field"),
])
def test_bad_files_are_refused_naming_the_file_and_the_field(tmp_path, rig, edit, field):
    path = stage.save_patterns(tmp_path / "p.json", _weights(rig.num_lights, K=3), rig)
    _edit(path, edit)
    with pytest.raises(ValueError, match=field) as err:
        stage.load_patterns(path, rig)
    assert str(path) in str(err.value)


def test_nan_in_a_file_is_refused(tmp_path, rig):
    path = stage.save_patterns(tmp_path / "p.json", _weights(rig.num_lights, K=2), rig)
    text = path.read_text()
    i = text.index('"weights"')
    path.write_text(text[:i] + text[i:].replace("0.5,", "NaN,", 1))  # Python's json reads the NaN token
    with pytest.raises(ValueError, match="weights") as err:
        stage.load_patterns(path, rig)
    assert str(path) in str(err.value)
    (tmp_path / "broken.json").write_text("{")
    with pytest.raises(ValueError, match="broken.json"):
        stage.load_patterns(tmp_path / "broken.json")
    with pytest.raises(FileNotFoundError, match="pattern file"):
        stage.load_patterns(tmp_path / "absent.json")


def test_bad_patterns_and_metadata_are_refused_on_saving(tmp_path, rig):
    L = rig.num_lights
    for bad in (np.full((2, L), 1.2), np.full((2, L - 1), 0.5), np.full((2, L), np.nan)):
        with pytest.raises(ValueError, match="patterns"):
            stage.save_patterns(tmp_path / "p.json", bad, rig)
    with pytest.raises(ValueError, match="metadata"):
        stage.save_patterns(tmp_path / "p.json", _weights(L), rig, metadata={"loss": float("nan")})
    with pytest.raises(ValueError, match="light_ids"):
        stage.save_patterns(tmp_path / "p.json", _weights(L), rig, light_ids=np.zeros(L, int))
    assert not (tmp_path / "p.json").exists()  # nothing half-written
