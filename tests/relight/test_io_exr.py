"""OpenEXR IO: exact round trips (float and half, scanline and tiled, arbitrary
channels, multi-part, metadata), atomic writes, and errors that name the file."""

import os

import numpy as np
import pytest

from relight.io import (
    ExrPart,
    ImageFormatError,
    exr_header,
    read_exr,
    read_exr_channels,
    read_exr_parts,
    write_exr,
    write_exr_channels,
    write_exr_parts,
)
from relight.results import atomic_path


@pytest.fixture
def rgb():
    rng = np.random.default_rng(0)
    # Spans many octaves (HDR): 1e-4 .. 1e4.
    return (10.0 ** rng.uniform(-4, 4, size=(13, 17, 3))).astype(np.float32)


def test_float_roundtrip_is_exact(tmp_path, rgb):
    path = tmp_path / "a.exr"
    write_exr(path, rgb)
    back = read_exr(path)
    assert back.dtype == np.float32 and back.shape == rgb.shape
    np.testing.assert_array_equal(back, rgb)


@pytest.mark.parametrize("compression", ["none", "rle", "zips", "zip", "piz"])
def test_lossless_compressions_roundtrip_exactly(tmp_path, rgb, compression):
    path = tmp_path / f"{compression}.exr"
    write_exr(path, rgb, compression=compression)
    np.testing.assert_array_equal(read_exr(path), rgb)


def test_half_roundtrip(tmp_path, rgb):
    path = tmp_path / "h.exr"
    write_exr(path, rgb, half=True)
    chans, _ = read_exr_channels(path)
    assert all(c.dtype == np.float16 for c in chans.values())
    back = read_exr(path)
    # Half keeps 11 significant bits: round-to-nearest error <= 2^-11 relative
    # (values here stay inside half's normal range, 6.1e-5 .. 65504).
    normal = rgb >= np.finfo(np.float16).tiny
    np.testing.assert_allclose(back[normal], rgb[normal], rtol=2.0**-11)
    # Values already representable in half come back bit-exact.
    exact = rgb.astype(np.float16).astype(np.float32)
    write_exr(path, exact, half=True)
    np.testing.assert_array_equal(read_exr(path), exact)


def test_half_overflow_is_refused(tmp_path):
    with pytest.raises(ValueError, match="float16"):
        write_exr(tmp_path / "o.exr", np.full((2, 4, 3), 1e6, np.float32), half=True)
    assert not list(tmp_path.iterdir())


def test_tiled_roundtrip_and_type(tmp_path, rgb):
    path = tmp_path / "t.exr"
    write_exr(path, rgb, tile_size=(8, 4))
    np.testing.assert_array_equal(read_exr(path), rgb)
    header = exr_header(path)
    assert "tiles" in header and header["tiles"].xSize == 8 and header["tiles"].ySize == 4


def test_rgba_grey_and_arbitrary_channels(tmp_path, rgb):
    rgba = np.concatenate([rgb, rgb[..., :1] * 0.5], axis=-1)
    write_exr(tmp_path / "rgba.exr", rgba)
    np.testing.assert_array_equal(read_exr(tmp_path / "rgba.exr"), rgba)

    write_exr(tmp_path / "y.exr", rgb[..., 0])
    back = read_exr(tmp_path / "y.exr")
    assert back.shape == (13, 17, 1)
    np.testing.assert_array_equal(back[..., 0], rgb[..., 0])

    # Arbitrary names, mixed precision, and an order that is not alphabetical.
    names = ["normal.Z", "normal.X", "normal.Y", "mask"]
    chans = {n: rgb[..., i % 3] * (i + 1) for i, n in enumerate(names)}
    chans["id"] = np.arange(13 * 17, dtype=np.uint32).reshape(13, 17)
    write_exr_channels(tmp_path / "n.exr", chans)
    got, _ = read_exr_channels(tmp_path / "n.exr")
    assert set(got) == set(chans)
    assert got["id"].dtype == np.uint32
    np.testing.assert_array_equal(got["id"], chans["id"])
    stacked = read_exr(tmp_path / "n.exr", channels=names)
    np.testing.assert_array_equal(stacked, np.stack([chans[n] for n in names], axis=-1))


def test_multipart_roundtrip(tmp_path, rgb):
    parts = [
        ExrPart({"R": rgb[..., 0], "G": rgb[..., 1], "B": rgb[..., 2]}, {"light": 3}, "view0"),
        ExrPart({"Z": rgb[..., 2] * 2}, {"light": 4, "note": "depth"}, "view1"),
    ]
    path = tmp_path / "m.exr"
    write_exr_parts(path, parts)
    back = read_exr_parts(path)
    assert [p.name for p in back] == ["view0", "view1"]
    np.testing.assert_array_equal(back[1].channels["Z"], rgb[..., 2] * 2)
    assert back[0].header["light"] == 3 and back[1].header["note"] == "depth"
    np.testing.assert_array_equal(read_exr(path, part=0), rgb)
    np.testing.assert_array_equal(read_exr(path, channels=["Z"], part=1)[..., 0], rgb[..., 2] * 2)
    with pytest.raises(ImageFormatError, match=r"m\.exr.*part 2"):
        read_exr(path, part=2)


def test_metadata_roundtrip(tmp_path, rgb):
    meta = {
        "rig": {"name": "Light Stage X", "n_lights": 346, "radius_cm": 132.4, "ok": True},
        "exposure": 1.25,
        "iso": 100,
        "lights": [1, 2, 3],
        "nothing": None,
        "flag": False,
        "owner": "json:looks-like-json",  # a plain string with the marker survives
        "camera_position": np.array([0.0, 1.5, 3.0]),
        "camera_matrix": np.eye(4, dtype=np.float32),
        "long_vector": np.arange(5.0),
    }
    path = tmp_path / "meta.exr"
    write_exr(path, rgb, header=meta)
    h = exr_header(path)
    assert h["rig"] == meta["rig"]
    assert h["exposure"] == 1.25 and h["iso"] == 100
    assert h["lights"] == [1, 2, 3] and h["nothing"] is None and h["flag"] is False
    assert h["owner"] == "json:looks-like-json"
    np.testing.assert_array_equal(h["camera_position"], meta["camera_position"])
    np.testing.assert_array_equal(h["camera_matrix"], meta["camera_matrix"])
    assert h["long_vector"] == [0.0, 1.0, 2.0, 3.0, 4.0]
    # A header read back can be passed straight to the writer again.
    write_exr(tmp_path / "again.exr", rgb, header=h)
    assert exr_header(tmp_path / "again.exr")["rig"] == meta["rig"]


def test_not_an_exr_names_the_file(tmp_path):
    bad = tmp_path / "bad.exr"
    bad.write_bytes(b"this is not an EXR file")
    with pytest.raises(ImageFormatError, match=r"bad\.exr.*not an OpenEXR file"):
        read_exr(bad)
    with pytest.raises(FileNotFoundError, match=r"missing\.exr"):
        read_exr(tmp_path / "missing.exr")


@pytest.mark.parametrize("keep", [0.02, 0.5, 0.98])
def test_truncated_exr_names_the_file(tmp_path, rgb, keep):
    path = tmp_path / "full.exr"
    write_exr(path, np.tile(rgb, (8, 8, 1)))
    data = path.read_bytes()
    cut = tmp_path / "cut.exr"
    cut.write_bytes(data[: int(len(data) * keep)])
    with pytest.raises(ImageFormatError, match=r"cut\.exr"):
        read_exr(cut)


def test_missing_channel_names_file_and_channel(tmp_path, rgb):
    path = tmp_path / "rgb.exr"
    write_exr(path, rgb)
    with pytest.raises(ImageFormatError, match=r"rgb\.exr.*'A'.*\['B', 'G', 'R'\]"):
        read_exr(path, channels=["R", "G", "B", "A"])


def test_write_is_atomic(tmp_path, rgb):
    path = tmp_path / "keep.exr"
    write_exr(path, rgb)
    before = path.read_bytes()
    # A writer that dies half way leaves the old file and no temporary behind.
    with pytest.raises(RuntimeError, match="boom"):
        with atomic_path(path) as tmp:
            tmp.write_bytes(b"v/1\x01 half written")
            raise RuntimeError("boom")
    assert path.read_bytes() == before
    assert sorted(os.listdir(tmp_path)) == ["keep.exr"]
    # Overwriting goes through a temporary too and leaves only the target.
    write_exr(path, rgb * 2)
    np.testing.assert_array_equal(read_exr(path), rgb * 2)
    assert sorted(os.listdir(tmp_path)) == ["keep.exr"]


def test_bad_shapes_and_names_are_refused(tmp_path, rgb):
    with pytest.raises(ValueError, match="channel names"):
        write_exr(tmp_path / "x.exr", np.zeros((2, 2, 5), np.float32))
    with pytest.raises(ValueError, match="different shapes"):
        write_exr_channels(tmp_path / "x.exr", {"A": np.zeros((2, 2)), "B": np.zeros((2, 3))})
    with pytest.raises(FileNotFoundError, match="does not exist"):
        write_exr(tmp_path / "no" / "x.exr", rgb)


def test_half_refuses_nan_and_overflow_together_and_float_refuses_float32_overflow(tmp_path):
    """The reported write_exr(half=True) of [NaN, 1e6]: the NaN used to skip the overflow check and 1e6 was
    stored as Inf. NaN is refused under half, and so is anything beyond 65504 (Inf included), NaN or not;
    a float32 file refuses finite float64 values that would become Inf, and stores NaN / Inf as given."""
    path = tmp_path / "h.exr"
    with pytest.raises(ValueError, match=r"h\.exr: argument 'image', channel 'Y' has 1 NaN values; half=True"):
        write_exr(path, np.array([[np.nan, 1e6]], np.float32), half=True)
    for bad in (1e6, np.inf, -7e4):
        with pytest.raises(ValueError, match=r"argument 'image', channel 'Y' has values up to .*beyond float16"):
            write_exr(path, np.array([[bad, 1.0]], np.float32), half=True)
    with pytest.raises(ValueError, match=r"argument 'channels', channel 'R' has values up to 1e\+300, beyond "
                                         r"float32's"):
        write_exr_channels(path, {"R": np.array([[1e300, 1.0]])})
    write_exr(path, np.array([[np.inf, np.nan, 65504.0]]))  # float32 holds these as they are
    np.testing.assert_array_equal(read_exr(path)[0, :, 0], [np.inf, np.nan, 65504.0])
    write_exr(path, np.array([[65504.0, -65504.0]]), half=True)  # half's own maximum is accepted
    np.testing.assert_array_equal(read_exr(path)[0, :, 0], [65504.0, -65504.0])
