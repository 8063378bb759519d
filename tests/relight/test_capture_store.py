"""Capture stores (relight.io._store, _store_reader): Zarr v3 on disk, chunked for the fitter.

Round trips folder -> store -> folder bit for bit (float32 and half), the
streaming writer against stage.simulate, chunked reads that cover every sample
once in O(chunk) memory, atomic commits and replacement, the refusals (no
marker, wrong shape, a path out of the store, a missing or damaged chunk),
load_texel_capture on a store and `relight convert` both ways."""

import json
import os
import tracemalloc

import jax.numpy as jnp
import numpy as np
import pytest

import brdf
import stage
from relight.cli import main
from relight.io import (
    CaptureStoreError,
    CaptureStoreWriter,
    ImageFormatError,
    StoreChangedError,
    capture_folder_to_store,
    load_texel_capture,
    mesh_spec,
    open_capture_store,
    read_capture,
    store_to_capture_folder,
    texel_surface,
    write_capture,
    write_capture_store,
)
from relight.io._store import MARKER
from tests.scenes import uv_sphere

V, L, H, W, C = 2, 12, 20, 50, 3
P = H * W


def _folder(tmp_path, name="cap", half=False, valid=True, seed=0):
    rng = np.random.default_rng(seed)
    rad = rng.uniform(0.0, 4.0, (V, L, P, C)).astype(np.float16 if half else np.float32)
    rad[0, 3, :100] = 0.0  # shadowed samples: exact zeros survive
    mask = rng.uniform(size=(V, L, P)) > 0.3 if valid else None
    rig = stage.geodesic_dome(0)  # 12 distant lights
    cams = stage.camera_ring(V, 1300.0, fov_deg=11.0, width=24, height=24)
    meta = {"space": "texel", "exposure": 0.5, "surface": {"bundled": "head", "path": "/x/head.glb", "scale": 25.0,
                                                            "center": True, "resolution": [H, W]}}
    write_capture(tmp_path / name, rad, rig, cams, valid=mask, metadata=meta, sample_shape=(H, W), half=half)
    return tmp_path / name, rad, mask


def _files(folder):
    return {p.relative_to(folder).as_posix() for p in folder.rglob("*") if p.is_file()}


@pytest.mark.parametrize("half,valid,chunks", [(False, True, None), (True, True, (1, 5, 300, 3)),
                                               (False, False, (1, 12, 128, 3))])
def test_folder_store_folder_round_trip_is_bit_exact(tmp_path, half, valid, chunks):
    folder, rad, mask = _folder(tmp_path, half=half, valid=valid)
    store_path = capture_folder_to_store(folder, tmp_path / "cap.zarr", chunks=chunks)
    store = open_capture_store(store_path)
    assert store.shape == (V, L, P, C) and store.dtype == rad.dtype and store.sample_shape == (H, W)
    r, m = store.read()
    assert r.dtype == rad.dtype and r.tobytes() == rad.tobytes()  # bit for bit, not merely close
    np.testing.assert_array_equal(m, mask if valid else np.ones((V, L, P), bool))
    back = store_to_capture_folder(store_path, tmp_path / "back")
    assert _files(back) == _files(folder)
    for name in ("rig.json", "cameras.json", "capture.json"):  # metadata carried over exactly
        assert json.loads((back / name).read_text()) == json.loads((folder / name).read_text()), name
    a, b = read_capture(folder, dtype=None), read_capture(back, dtype=None)
    assert b.radiance.dtype == rad.dtype and b.radiance.tobytes() == a.radiance.tobytes()
    assert (b.valid is None) == (not valid)
    if valid:
        np.testing.assert_array_equal(b.valid, a.valid)


@pytest.fixture(scope="module")
def sphere_scene():
    mesh = uv_sphere(radius=50.0, n_lat=16, n_lon=32)
    surf = stage.texel_samples(mesh, 24)
    rig = stage.geodesic_dome(1)  # 42 distant lights
    cam = stage.look_at((0.0, 0.0, 1000.0), fov_deg=8, width=32, height=32)
    lv = stage.light_visibility(mesh, surf, rig, packed=True)
    cv = stage.camera_visibility(mesh, surf, [cam])
    f = lambda v, c: jnp.full((surf.num_samples, c), v, jnp.float32)  # noqa: E731
    mat = brdf.lambert_ggx(f(0.6, 3), f(0.04, 1), f(0.3, 1))
    return surf, rig, cam, mat, lv, cv


def test_streaming_writer_from_simulate_chunks_equals_simulate(tmp_path, sphere_scene):
    surf, rig, cam, mat, lv, cv = sphere_scene
    ref = stage.simulate(surf, rig, [cam], mat, lv, cv, light_chunk=16)
    shape = (1, rig.num_lights, surf.num_samples, 3)
    # Store chunks (5 lights x 100 samples) cut across the simulation's blocks (16 lights x all samples).
    with CaptureStoreWriter(tmp_path / "sim.zarr", shape, np.float32, rig, [cam], {"source": "test"},
                            chunks=(1, 5, 100, 3)) as w:
        for chunk in stage.simulate_chunks(surf, rig, [cam], mat, lv, cv, light_chunk=16):
            w.write(*chunk)
    r, m = open_capture_store(tmp_path / "sim.zarr").read()
    np.testing.assert_array_equal(r, np.asarray(ref.radiance))  # exactly: the writer only copies
    np.testing.assert_array_equal(m, np.asarray(ref.mask))
    assert np.asarray(ref.mask).mean() > 0.2  # a real capture, not all shadow
    # Blocks chunked over samples too (37 samples, not a divisor of anything): the same numbers as the stream.
    stream_r, stream_m = np.zeros(shape, np.float32), np.zeros(shape[:3], bool)
    with CaptureStoreWriter(tmp_path / "sim2.zarr", shape, np.float32, rig, [cam], chunks=(1, 8, 64, 3)) as w:
        for v, ls, ps, rad, msk in stage.simulate_chunks(surf, rig, [cam], mat, lv, cv, light_chunk=10,
                                                         sample_chunk=37):
            stream_r[v, ls, ps], stream_m[v, ls, ps] = np.asarray(rad), msk
            w.write(v, ls, ps, rad, msk)
    store = open_capture_store(tmp_path / "sim2.zarr")
    r2, m2 = store.read()
    np.testing.assert_array_equal(r2, stream_r)
    np.testing.assert_array_equal(m2, stream_m)
    cap = store.to_capture()
    assert cap.rig.num_lights == rig.num_lights and len(cap.cameras) == 1
    np.testing.assert_allclose(np.asarray(cap.cameras[0].R), np.asarray(cam.R), rtol=0, atol=1e-12)


def _random_store(path, shape, chunks, seed=1):
    rng = np.random.default_rng(seed)
    rad = rng.uniform(0.0, 1.0, shape).astype(np.float32)
    mask = rng.uniform(size=shape[:3]) > 0.5
    cap = stage.Capture(radiance=jnp.asarray(rad), mask=jnp.asarray(mask), rig=stage.fibonacci_sphere(shape[1]),
                        cameras=tuple(stage.camera_ring(shape[0], 1300.0, fov_deg=11.0, width=8, height=8)))
    write_capture_store(path, cap, chunks=chunks, metadata={"seed": seed})
    return rad, mask


@pytest.mark.parametrize("n", [64, 100, 1000, 1500])
def test_iter_sample_chunks_covers_every_sample_once(tmp_path, n):
    rad, mask = _random_store(tmp_path / "s.zarr", (2, 9, 1000, 3), (1, 4, 64, 3))
    store = open_capture_store(tmp_path / "s.zarr")
    seen = np.zeros(1000, int)
    parts = []
    for sl, r, m in store.iter_sample_chunks(n):
        assert r.shape == (2, 9, sl.stop - sl.start, 3) and m.shape == r.shape[:3] and sl.stop - sl.start <= n
        seen[sl] += 1
        parts.append((r, m))
    assert np.all(seen == 1)
    np.testing.assert_array_equal(np.concatenate([p[0] for p in parts], axis=2), rad)
    np.testing.assert_array_equal(np.concatenate([p[1] for p in parts], axis=2), mask)
    # Any selection: lists, ints and strided slices on each axis.
    r, m = store.read(views=1, lights=[7, 2], samples=slice(5, 900, 7))
    np.testing.assert_array_equal(r, rad[1:2][:, [7, 2]][:, :, 5:900:7])
    np.testing.assert_array_equal(m, mask[1:2][:, [7, 2]][:, :, 5:900:7])


def test_reading_a_chunk_allocates_o_chunk(tmp_path):
    shape, block = (2, 8, 10 * 4096, 3), 4096  # the store is 10 sample blocks
    rad, _ = _random_store(tmp_path / "big.zarr", shape, (1, 8, block, 3))
    store = open_capture_store(tmp_path / "big.zarr")
    block_bytes = 2 * 8 * block * (3 * 4 + 1)
    total = store.nbytes
    assert total == 10 * block_bytes

    def peak(fn):
        tracemalloc.start()
        try:
            out = fn()
            return out, tracemalloc.get_traced_memory()[1]
        finally:
            tracemalloc.stop()

    (r, m), p_block = peak(lambda: store.read(samples=slice(3 * block, 4 * block)))
    assert r.shape == (2, 8, block, 3) and r.nbytes + m.nbytes == block_bytes
    np.testing.assert_array_equal(r, rad[:, :, 3 * block: 4 * block])
    # The result, the chunks in flight (two, one per view) and their compressed bytes: well under 3 blocks,
    # against the 10 the whole store would take.
    assert p_block < 3 * block_bytes, (p_block, block_bytes)

    def consume():  # a consumer that drops each block before asking for the next (as the fitter does)
        it, seen = store.iter_sample_chunks(block), 0
        for _ in range(10):
            sl, r, m = next(it)
            seen += sl.stop - sl.start
            del r, m
        return seen

    n_seen, p_iter = peak(consume)
    assert n_seen == shape[2] and p_iter < 3 * block_bytes, (p_iter, block_bytes)
    _, p_all = peak(store.read)  # the measure sees the allocations: the whole store is >= its size
    assert p_all >= total


def test_an_interrupted_write_leaves_nothing(tmp_path):
    rig = stage.fibonacci_sphere(4)
    dst = tmp_path / "cap.zarr"
    with pytest.raises(RuntimeError, match="boom"):
        with CaptureStoreWriter(dst, (1, 4, 100, 3), np.float32, rig, chunks=(1, 2, 50, 3)) as w:
            w.write(0, slice(0, 2), slice(None), np.ones((2, 100, 3), np.float32))  # two chunks committed to tmp
            raise RuntimeError("boom")
    assert os.listdir(tmp_path) == []  # no store, no partial store, no temporary folder
    # An incomplete capture is not committed either (close() says what is missing).
    with pytest.raises(ValueError, match="incomplete, 2 of 4 chunks"):
        with CaptureStoreWriter(dst, (1, 4, 100, 3), np.float32, rig, chunks=(1, 2, 50, 3)) as w:
            w.write(0, slice(0, 2), slice(None), np.ones((2, 100, 3), np.float32))
    assert os.listdir(tmp_path) == []
    w = CaptureStoreWriter(dst, (1, 4, 100, 3), np.float32, rig)  # dropped without close(): cleaned up too
    assert len(os.listdir(tmp_path)) == 1
    del w
    assert os.listdir(tmp_path) == []
    # Writing an element twice, or NaN, is refused naming what.
    with CaptureStoreWriter(dst, (1, 4, 100, 3), np.float32, rig, chunks=(1, 2, 50, 3)) as w:
        w.write(0, slice(0, 4), slice(0, 60), np.ones((4, 60, 3), np.float32))
        with pytest.raises(ValueError, match="written twice"):
            w.write(0, 1, slice(55, 100), np.ones((1, 45, 3), np.float32))
        with pytest.raises(ImageFormatError, match="NaN"):
            w.write(0, slice(0, 4), slice(60, 100), np.full((4, 40, 3), np.nan, np.float32))
        w.write(0, slice(0, 4), slice(60, 100), np.zeros((4, 40, 3), np.float32))
    r, m = open_capture_store(dst).read()
    assert r[..., :60, :].min() == 1.0 and r[..., 60:, :].max() == 0.0 and m.all()
    # A folder that is not a store is never replaced.
    (tmp_path / "other.zarr").mkdir()
    with pytest.raises(FileExistsError, match="not a capture store"):
        CaptureStoreWriter(tmp_path / "other.zarr", (1, 4, 100, 3), np.float32, rig)


def test_an_existing_store_is_replaced_atomically(tmp_path):
    dst = tmp_path / "s.zarr"
    old_rad, _ = _random_store(dst, (1, 6, 300, 3), (1, 3, 100, 3), seed=1)
    reader = open_capture_store(dst)
    rng = np.random.default_rng(2)
    new_rad = rng.uniform(0.0, 1.0, (1, 6, 300, 3)).astype(np.float32)
    with CaptureStoreWriter(dst, (1, 6, 300, 3), np.float32, stage.fibonacci_sphere(6), chunks=(1, 3, 100, 3)) as w:
        w.write(0, slice(0, 6), slice(None), new_rad[0])  # every chunk written, not yet committed
        np.testing.assert_array_equal(open_capture_store(dst).read()[0], old_rad)  # still the old store, whole
    # The reader opened before the swap refuses to read rather than mix old metadata with new chunks.
    with pytest.raises(StoreChangedError, match="replaced or removed"):
        reader.read(samples=slice(0, 10))
    np.testing.assert_array_equal(open_capture_store(dst).read()[0], new_rad)
    assert sorted(os.listdir(tmp_path)) == ["s.zarr"]  # the old store and the temporary are gone
    # The marker ties the manifest to the arrays: a manifest from another write is refused ...
    _random_store(tmp_path / "t.zarr", (1, 6, 300, 3), (1, 3, 100, 3), seed=3)
    (dst / MARKER).write_bytes((tmp_path / "t.zarr" / MARKER).read_bytes())
    with pytest.raises(CaptureStoreError, match="generation"):
        open_capture_store(dst)
    # ... and a store without its marker (an unfinished write) is not a store.
    (dst / MARKER).unlink()
    with pytest.raises(CaptureStoreError, match=f"{dst}: no {MARKER}"):
        open_capture_store(dst)


def _edit_manifest(path, fn):
    doc = json.loads((path / MARKER).read_text())
    fn(doc)
    (path / MARKER).write_text(json.dumps(doc))


@pytest.mark.parametrize("edit,match", [
    (lambda d: d.update(shape=[1, 6, 301, 3], sample_shape=[1, 301]),
     r"array 'radiance' has shape \(1, 6, 300, 3\), relight-store.json declares \(1, 6, 301, 3\)"),
    (lambda d: d["arrays"].update(radiance="mask"), r"array 'radiance' has shape \(1, 6, 300\)"),
    (lambda d: d.update(shape=[2, 6, 300, 3]), "1 cameras but .* declares 2 views"),
    (lambda d: d.update(shape=[1, 6, 300]), "field 'shape'"),
    (lambda d: d.update(dtype="float64"), "missing or bad field"),
    (lambda d: d["arrays"].update(radiance="../t.zarr/radiance"), "'arrays.radiance': path '../t.zarr/radiance' "
                                                                  "leaves the store"),
    (lambda d: d["files"].update(rig="/etc/passwd"), "'files.rig': path '/etc/passwd' leaves the store"),
    (lambda d: d.update(format="something-else"), "not a relight capture store"),
])
def test_a_bad_store_is_refused_naming_why(tmp_path, edit, match):
    _random_store(tmp_path / "s.zarr", (1, 6, 300, 3), (1, 3, 100, 3))
    _random_store(tmp_path / "t.zarr", (1, 6, 300, 3), (1, 3, 100, 3))
    _edit_manifest(tmp_path / "s.zarr", edit)
    with pytest.raises(CaptureStoreError, match=match):
        open_capture_store(tmp_path / "s.zarr")


def test_a_folder_whose_files_leave_it_is_refused(tmp_path):
    folder, _, _ = _folder(tmp_path)
    info = json.loads((folder / "capture.json").read_text())
    (tmp_path / "elsewhere").mkdir()
    for v in range(V):
        for light in range(L):
            src = folder / f"views/v{v:03d}/l{light:03d}.exr"
            src.rename(tmp_path / "elsewhere" / f"{v}_{light}.exr")
    info["files"] = "../elsewhere/{view}_{light}.exr"
    (folder / "capture.json").write_text(json.dumps(info))
    with pytest.raises(ImageFormatError, match="field 'files'.*leaves the capture folder"):
        capture_folder_to_store(folder, tmp_path / "cap.zarr")
    assert not (tmp_path / "cap.zarr").exists()


def test_load_texel_capture_reads_a_store(tmp_path):
    res = 8
    spec = {**mesh_spec(None), "resolution": [res, res]}
    _, full = texel_surface(spec, res)
    rig = stage.geodesic_dome(0)
    cams = stage.camera_ring(2, 1300.0, fov_deg=11.0, width=24, height=24)
    rng = np.random.default_rng(3)
    rad = rng.uniform(0.1, 1.0, (2, 12, res * res, 3)).astype(np.float32)
    valid = np.zeros((2, 12, res * res), bool)
    valid[..., np.asarray(full.texel_index)[::2]] = True  # half the texels observed
    write_capture(tmp_path / "cap", rad, rig, cams, valid=valid, sample_shape=(res, res),
                  metadata={"space": "texel", "surface": spec})
    capture_folder_to_store(tmp_path / "cap", tmp_path / "cap.zarr", chunks=(1, 5, 16, 3))
    a = load_texel_capture(tmp_path / "cap")
    seen = []
    b = load_texel_capture(tmp_path / "cap.zarr", progress=lambda *x: seen.append(x))
    np.testing.assert_array_equal(np.asarray(b.capture.radiance), np.asarray(a.capture.radiance))
    np.testing.assert_array_equal(np.asarray(b.capture.mask), np.asarray(a.capture.mask))
    np.testing.assert_array_equal(np.asarray(b.surface.texel_index), np.asarray(a.surface.texel_index))
    assert b.metadata == a.metadata and b.capture.rig.num_lights == 12
    assert seen[0] == ("read capture", 0, 4) and seen[-1] == ("read capture", 4, 4)


def test_cli_convert_both_ways(tmp_path, capsys):
    folder, rad, mask = _folder(tmp_path, half=True)
    assert main(["convert", str(folder), str(tmp_path / "c.zarr"), "--quiet"]) == 0
    assert main(["convert", str(tmp_path / "c.zarr"), str(tmp_path / "back")]) == 0
    assert "wrote capture folder" in capsys.readouterr().out
    back = read_capture(tmp_path / "back", dtype=None)
    assert back.radiance.tobytes() == rad.tobytes()
    np.testing.assert_array_equal(back.valid, mask)
    for argv, match in ((["convert", str(tmp_path / "nope"), str(tmp_path / "x.zarr")], "no such capture"),
                        (["convert", str(folder), str(tmp_path / "x")], "must end in .zarr"),
                        (["convert", str(tmp_path / "c.zarr"), str(tmp_path / "y.zarr")], "must not end in .zarr"),
                        (["convert", str(tmp_path / "back" / "views"), str(tmp_path / "z.zarr")],
                         "neither a capture folder")):
        assert main([*argv, "--quiet"]) == 1
        err = capsys.readouterr().err
        assert "relight convert: error: " in err and match in err, err
    assert not any((tmp_path / n).exists() for n in ("x.zarr", "x", "y.zarr", "z.zarr"))


def _damage(kind):
    """Edits of one chunk file of a store (issue 29, item 5): what a partial copy, a full disk or bit rot leaves."""
    def gone(p):
        p.unlink()

    def truncated(p):
        p.write_bytes(p.read_bytes()[: len(p.read_bytes()) // 2])

    def flipped(p):
        b = bytearray(p.read_bytes())
        b[-1] ^= 0x01
        p.write_bytes(bytes(b))

    return {"gone": gone, "truncated": truncated, "flipped": flipped}[kind]


@pytest.mark.parametrize("version", [2, 1])
@pytest.mark.parametrize("array,key,kind", [("radiance", "c/0/1/1/0", "gone"), ("radiance", "c/0/0/2/0", "truncated"),
                                            ("mask", "c/0/1/0", "flipped")])
def test_a_missing_or_damaged_chunk_is_refused_by_name(tmp_path, array, key, kind, version):
    """Zarr reads a missing chunk file as its fill value: a store that lost one chunk would be fitted as black,
    masked-out pixels (the reported case: `relight fit` exited 0 on zero-filled data). Every read that touches a
    missing, truncated or changed chunk raises CaptureStoreError naming the store and the chunk; reads that do not
    touch it are exact. A version 1 store (no digests) is read with a warning that it cannot be verified, and
    still refuses a missing or undecodable chunk; a flipped bit that still decodes is what only version 2's
    digests can catch."""
    rad, mask = _random_store(tmp_path / "s.zarr", (1, 6, 300, 3), (1, 3, 100, 3))
    if version == 1:
        _edit_manifest(tmp_path / "s.zarr", lambda d: (d.pop("chunk_digests"), d.update(version=1)))
    _damage(kind)(tmp_path / "s.zarr" / array / key)
    if version == 1:  # read, and said that it cannot be verified
        with pytest.warns(UserWarning, match="version 1 capture store, written before chunk digests"):
            store = open_capture_store(tmp_path / "s.zarr")
    else:
        store = open_capture_store(tmp_path / "s.zarr")
    sample_block = int(key.split("/")[3]) * 100
    # The untouched chunks read exactly.
    r, m = store.read(samples=slice((sample_block + 100) % 300, (sample_block + 100) % 300 + 100))
    lo = (sample_block + 100) % 300
    np.testing.assert_array_equal(r, rad[:, :, lo:lo + 100])
    np.testing.assert_array_equal(m, mask[:, :, lo:lo + 100])
    if version == 1 and kind == "flipped":
        return
    message = f"{tmp_path / 's.zarr'}: damaged store: " + ("a chunk cannot be decoded" if version == 1 and kind ==
                                                           "truncated" else f"chunk file {array}/{key}")
    with pytest.raises(CaptureStoreError, match=message):
        store.read()
    with pytest.raises(CaptureStoreError, match="damaged store"):
        list(store.iter_sample_chunks())
    if array == "mask":
        with pytest.raises(CaptureStoreError, match="damaged store"):
            store.read_mask()


def test_fit_and_convert_refuse_a_store_with_a_missing_chunk(tmp_path, capsys):
    """The reported commands: `relight fit` and `relight convert` of a store missing a radiance chunk end with the
    one-line error naming the chunk (exit 1), and write nothing."""
    folder, _, _ = _folder(tmp_path)
    assert main(["convert", str(folder), str(tmp_path / "c.zarr"), "--quiet"]) == 0
    chunk = sorted((tmp_path / "c.zarr" / "radiance").rglob("c/*/*/*/*"))[1]
    chunk.unlink()
    name = chunk.relative_to(tmp_path / "c.zarr").as_posix()
    for argv in (["convert", str(tmp_path / "c.zarr"), str(tmp_path / "back")],
                 ["fit", str(tmp_path / "c.zarr"), "--model", "lambert", "--out", str(tmp_path / "maps"),
                  "--no-index"]):
        assert main([*argv, "--quiet"]) == 1
        err = capsys.readouterr().err
        assert f"relight {argv[0]}: error: " in err and f"chunk file {name} is missing" in err, err
        assert "Traceback" not in err
    assert not (tmp_path / "back").exists() and not (tmp_path / "maps" / "albedo.exr").exists()
