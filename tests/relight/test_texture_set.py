"""The fitted-map texture set: round trip, gutter padding, tangent-space
normals and the refusals (missing file, corrupt EXR, wrong resolution)."""

import json
import shutil

import numpy as np
import pytest

import relight
import stage
from relight.io import ImageFormatError, read_maps, texture_set, write_exr, write_maps, write_texture_set

RES = 16


@pytest.fixture(scope="module")
def head_surface():
    return stage.texel_samples(stage.load_head(), RES)


def _random_maps(surface, seed=0):
    rng = np.random.default_rng(seed)
    P = surface.num_samples
    n = np.asarray(surface.normal, np.float64)
    t = np.asarray(surface.tangent, np.float64)
    # Tilt the fitted normal away from the mesh normal so the tangent-space map is not trivial.
    tilt = n + 0.3 * rng.normal(size=(P, 3))
    tilt /= np.linalg.norm(tilt, axis=1, keepdims=True)
    return relight.material_maps(
        surface,
        rho_d=rng.uniform(0.05, 0.9, (P, 3)),
        rho_s=rng.uniform(0.0, 0.1, (P, 1)),
        alpha=rng.uniform(0.05, 0.8, (P, 2)),
        normal=tilt,
        tangent=t,
        mfp=rng.uniform(0.0, 3.0, (P, 3)),
        model=rng.integers(0, len(relight.MODELS), P),
    )


@pytest.fixture(scope="module")
def written(head_surface, tmp_path_factory):
    folder = tmp_path_factory.mktemp("maps")
    maps = _random_maps(head_surface)
    info = {"bundled": "head", "path": str(stage.head_mesh_path()), "scale": stage.HEAD_SCALE_MM, "center": True}
    write_maps(folder, maps, head_surface, metadata={"note": "test"}, surface_info=info)
    return folder, maps


def test_round_trip(written, head_surface):
    folder, maps = written
    tex, info = read_maps(folder)
    assert tex.resolution == (RES, RES)
    assert info["resolution"] == [RES, RES] and info["bundled"] == "head"
    assert tex.info["metadata"]["note"] == "test"
    assert tex.info["models"] == {str(i): m for i, m in enumerate(relight.MODELS)}
    back = tex.maps(head_surface)
    # Stored as float32: exact for float32 inputs up to the cast (1e-6 relative).
    for name in ("rho_d", "rho_s", "alpha", "mfp"):
        np.testing.assert_allclose(np.asarray(getattr(back, name)), np.asarray(getattr(maps, name)), rtol=1e-6,
                                   atol=1e-7, err_msg=name)
    np.testing.assert_array_equal(np.asarray(back.model), np.asarray(maps.model))
    n_in = np.asarray(maps.normal, np.float64)
    n_in /= np.linalg.norm(n_in, axis=1, keepdims=True)
    np.testing.assert_allclose(np.asarray(back.normal), n_in, atol=1e-6)
    # The tangent is stored made orthogonal to the normal; it stays a unit vector perpendicular to n.
    t = np.asarray(back.tangent)
    np.testing.assert_allclose(np.linalg.norm(t, axis=1), 1.0, atol=1e-6)
    np.testing.assert_allclose(np.sum(t * np.asarray(back.normal), axis=1), 0.0, atol=1e-6)
    assert not list(folder.glob(".*tmp*")), "a temporary file survived"


def test_tangent_space_normal_is_in_the_surface_frame(written, head_surface):
    folder, maps = written
    tex, _ = read_maps(folder)
    idx = np.asarray(head_surface.texel_index)
    n_ts = tex.normal_ts.reshape(-1, 3)[idx].astype(np.float64)
    t, b, n = (np.asarray(x, np.float64) for x in (head_surface.tangent, head_surface.bitangent, head_surface.normal))
    world = n_ts[:, :1] * t + n_ts[:, 1:2] * b + n_ts[:, 2:3] * n
    np.testing.assert_allclose(world, np.asarray(tex.maps(head_surface).normal), atol=1e-5)
    # Encoded 0.5 n + 0.5 in the default R, G, B channels: all in [0, 1].
    from relight.io import read_exr

    enc = read_exr(folder / "normal.exr")
    assert enc.min() >= 0.0 and enc.max() <= 1.0


def test_gutter_is_filled_from_the_charts(written, head_surface):
    folder, maps = written
    tex, _ = read_maps(folder)
    cov = tex.coverage
    assert cov.sum() == head_surface.num_samples
    # One ring around the charts: every such texel holds a value inside the range of the
    # valid texels (a bilinear lookup near a seam blends only chart values), not the 0 background.
    ring = ~cov & (np.roll(cov, 1, 0) | np.roll(cov, -1, 0) | np.roll(cov, 1, 1) | np.roll(cov, -1, 1))
    assert ring.any()
    alb = tex.albedo
    lo, hi = alb[cov].min(0), alb[cov].max(0)
    assert np.all(alb[ring] >= lo - 1e-6) and np.all(alb[ring] <= hi + 1e-6)
    assert np.all(tex.alpha[ring] > 0)
    np.testing.assert_allclose(np.linalg.norm(tex.normal[ring], axis=-1), 1.0, atol=1e-5)
    # The model index is categorical: padding copies a neighbour, never averages.
    assert set(np.unique(tex.model[ring])) <= set(np.unique(np.asarray(maps.model)))


@pytest.fixture
def broken(written, tmp_path):
    """A copy of the written map set, for the tests that damage it."""
    folder, _ = written
    copy = tmp_path / "set"
    shutil.copytree(folder, copy)
    return copy


def test_missing_folder_and_files(broken, tmp_path):
    with pytest.raises(FileNotFoundError, match="nowhere"):
        read_maps(tmp_path / "nowhere")
    (broken / "albedo.exr").unlink()
    with pytest.raises(FileNotFoundError, match="albedo.exr"):
        read_maps(broken)
    (broken / "maps.json").unlink()
    with pytest.raises(FileNotFoundError, match="maps.json"):
        read_maps(broken)


def test_corrupt_exr_names_the_file(broken):
    data = (broken / "roughness.exr").read_bytes()
    (broken / "roughness.exr").write_bytes(data[: len(data) // 2])
    with pytest.raises(ImageFormatError, match="roughness.exr"):
        read_maps(broken)


def test_wrong_resolution_names_the_file(broken):
    write_exr(broken / "specular.exr", np.zeros((RES // 2, RES // 2), np.float32))
    with pytest.raises(ImageFormatError, match=r"specular.exr.*8x8.*16x16"):
        read_maps(broken)


def test_bad_maps_json(broken):
    info = json.loads((broken / "maps.json").read_text())
    (broken / "maps.json").write_text(json.dumps({**info, "format": "something-else"}))
    with pytest.raises(ImageFormatError, match="maps.json.*not a relight map set"):
        read_maps(broken)
    (broken / "maps.json").write_text("{not json")
    # The message of stage.read_json, the one JSON reader (relight.io raises it as its ImageFormatError).
    with pytest.raises(ImageFormatError, match="maps.json.*not valid JSON"):
        read_maps(broken)


def test_surface_mismatch_is_refused(written):
    folder, _ = written
    tex, _ = read_maps(folder)
    other = stage.texel_samples(stage.load_head(), RES * 2)
    with pytest.raises(ValueError, match="16x16"):
        tex.maps(other)


def test_write_refuses_wrong_sample_count(head_surface, tmp_path):
    maps = _random_maps(head_surface)
    with pytest.raises(ValueError, match="samples"):
        write_maps(tmp_path / "x", maps, head_surface.subset(np.arange(10)))


def test_in_memory_set_is_what_reading_the_files_gives(written, head_surface, tmp_path):
    """``texture_set`` (what ``relight fit`` now uses instead of writing the maps
    and reading them back) equals ``read_maps`` of the written set, to the
    float32 rounding of the tangent-space normal's 0.5 n + 0.5 encoding."""
    folder, maps = written
    info = {"bundled": "head", "path": str(stage.head_mesh_path()), "scale": stage.HEAD_SCALE_MM, "center": True}
    mem = texture_set(maps, head_surface, metadata={"note": "test"}, surface_info=info)
    disk, _ = read_maps(folder)
    for name in ("albedo", "specular", "alpha", "normal", "tangent", "mfp", "model", "coverage"):
        a, b = getattr(mem, name), getattr(disk, name)
        assert a.shape == b.shape and a.dtype == b.dtype, name
        np.testing.assert_array_equal(a, b, err_msg=name)
    np.testing.assert_allclose(mem.normal_ts, disk.normal_ts, atol=2e-7)  # 2 ulp of the encoding at 1
    assert mem.info == {**disk.info, "writer": mem.info["writer"]}
    # Writing the in-memory set gives the same files.
    write_texture_set(tmp_path / "again", mem)
    again, _ = read_maps(tmp_path / "again")
    for name in ("albedo", "alpha", "model", "coverage"):
        np.testing.assert_array_equal(getattr(again, name), getattr(disk, name), err_msg=name)
    assert json.loads((tmp_path / "again" / "maps.json").read_text()) == disk.info
