"""relight.io.photos_to_texel_store: photographs to a texel capture store, streamed a light chunk at a time.
The same observations as the in-memory relight.io.photos_to_texels (test_photo_texels.py's scene: the head,
three 56 px cameras, 162 lights), a store that relight.io.open_texel_capture and relight.fit read back, and
memory set by the light chunk, not by the number of lights."""

import tracemalloc

import numpy as np
import pytest

import relight
from relight.io import (
    mesh_spec,
    open_capture_store,
    open_texel_capture,
    photos_to_texel_store,
    photos_to_texels,
    read_photo_capture,
)

from .test_photo_texels import RES, scene  # noqa: F401  (the module's fixture, built once here)


def test_the_store_holds_what_photos_to_texels_gives(scene, tmp_path, monkeypatch):  # noqa: F811
    """Every texel's observations, validity and the report are those of the in-memory resampling, exactly
    (the same taps and weights; light chunks of 5, which do not divide the 162 lights; min_views 2, so the
    geometry pre-pass decides which texels count as seen); texels off the atlas hold nothing valid; the store's
    metadata rebuilds the surface, and a fit of the store equals the fit of the in-memory capture. (min_views
    1 and the CLI: test_cli_convert_then_fit.) The photographs are read two at a time (the read budget
    forced down to two 56 px RGB images), which does not divide the chunk of 5 either."""
    import relight.io._photo_store as photo_store

    monkeypatch.setattr(photo_store, "_READ_VALUES", 2 * 56 * 56 * 3)
    min_views = 2
    mesh, _, _, _, masked, _ = scene
    photos = read_photo_capture(masked)
    cap, surface, ref = photos_to_texels(photos, mesh, RES, min_views=min_views)
    path = tmp_path / "texels.zarr"
    surf, report = photos_to_texel_store(photos, mesh, RES, path, surface_info=mesh_spec(None), min_views=min_views,
                                         light_chunk=5)
    idx = np.asarray(surf.texel_index)
    np.testing.assert_array_equal(idx, np.asarray(surface.texel_index))
    store = open_capture_store(path)
    assert (store.n_views, store.n_lights, store.n_samples) == (3, 162, RES * RES)
    rad, valid = store.gather_samples(idx)
    np.testing.assert_array_equal(valid, np.asarray(cap.mask))
    np.testing.assert_allclose(rad, np.asarray(cap.radiance), rtol=1e-6, atol=0)
    off = np.setdiff1d(np.arange(RES * RES), idx)
    assert not store.gather_samples(off)[1].any()
    for k in ("views_per_texel", "unseen", "coverage", "weight"):
        np.testing.assert_array_equal(getattr(report, k), getattr(ref, k), err_msg=k)
    assert report.rejected == ref.rejected and np.allclose(report.valid_fraction, ref.valid_fraction)
    assert store.metadata["photos"] == ref.to_dict() and store.metadata["space"] == "texel"
    streamed, s2, _, _ = open_texel_capture(path)  # the texels with an observation
    f_store = relight.fit(streamed, s2, model="lambert")
    keep = np.searchsorted(idx, np.asarray(s2.texel_index))
    f_mem = relight.fit(type(cap)(cap.radiance[:, :, keep], cap.mask[:, :, keep], cap.rig, cap.cameras),
                        surface.subset(keep), model="lambert")
    np.testing.assert_allclose(np.asarray(f_store.rho_d), np.asarray(f_mem.rho_d), rtol=1e-5)


def test_memory_is_set_by_the_light_chunk(scene, tmp_path):  # noqa: F811
    """Peak traced memory (numpy's allocations) of the in-memory resampling against the streamed one with 6
    lights per read: the in-memory path holds a camera's whole stack of 162 photographs (and the whole texel
    capture), the streamed one never does, so its peak is lower by at least half a stack. (The rest of both
    peaks is the mesh, its BVH and the per-texel geometry, the same in both.)"""
    mesh, _, _, images, masked, _ = scene
    photos = read_photo_capture(masked)
    peaks = {}
    for name, run in (("memory", lambda: photos_to_texels(photos, mesh, RES)),
                      ("stream", lambda: photos_to_texel_store(photos, mesh, RES, tmp_path / "s.zarr",
                                                               surface_info=mesh_spec(None), light_chunk=6))):
        tracemalloc.start()
        run()
        peaks[name] = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
    stack = images[0].nbytes  # one camera's 162 photographs as float32 (6.1 MB)
    assert peaks["stream"] < peaks["memory"] - 0.5 * stack, (peaks, stack)


def test_bad_arguments_are_named(scene, tmp_path):  # noqa: F811
    mesh, _, _, _, masked, _ = scene
    photos = read_photo_capture(masked)
    for kw, match in (({"light_chunk": 0}, "light_chunk"), ({"grazing_deg": 95}, "grazing_deg"),
                      ({"min_views": 0}, "min_views")):
        with pytest.raises(ValueError, match=match):
            photos_to_texel_store(photos, mesh, RES, tmp_path / "x.zarr", surface_info=mesh_spec(None), **kw)
    assert not (tmp_path / "x.zarr").exists()


def test_cli_convert_then_fit(scene, tmp_path, capsys):  # noqa: F811
    """`relight convert PHOTOS DST.zarr --mesh head --resolution N` writes the texel store (the library's, with
    the unseen count said), `relight fit DST.zarr` fits it like any texel store and gives the albedo of `relight
    fit PHOTOS --mesh head` on the same texels; --mesh is refused for what is not a photo capture, and a photo
    capture needs it and a .zarr destination."""
    import json

    from relight.cli import main

    _, _, _, _, masked, _ = scene
    dst = tmp_path / "texels.zarr"
    assert main(["convert", str(masked), str(dst), "--mesh", "head", "--resolution", "16", "--no-index"]) == 0
    said = capsys.readouterr().out
    assert "texels are unseen" in said and "wrote store" in said
    assert open_capture_store(dst).metadata["surface"]["resolution"] == [16, 16]
    for argv, match in (([str(masked), str(tmp_path / "x.zarr")], "--mesh"),
                        ([str(masked), str(tmp_path / "x"), "--mesh", "head"], ".zarr"),
                        ([str(dst), str(tmp_path / "y"), "--mesh", "head"], "photo captures only")):
        assert main(["convert", *argv, "--no-index"]) != 0
        assert match in capsys.readouterr().err, argv
    kw = ["--model", "lambert", "--quiet", "--no-index"]
    assert main(["fit", str(dst), "--out", str(tmp_path / "a"), *kw]) == 0
    assert main(["fit", str(masked), "--mesh", "head", "--resolution", "16", "--out", str(tmp_path / "b"), *kw]) == 0
    a, b = (json.loads((tmp_path / k / "report.json").read_text()) for k in "ab")
    assert a["seen_samples"] == b["seen_samples"] > 50 and a["failed_seen_samples"] == b["failed_seen_samples"]
    from relight.io import read_exr

    A, B = (read_exr(tmp_path / k / "albedo.exr") for k in "ab")
    seen = photos_to_texels(read_photo_capture(masked), scene[0], 16)[2].coverage > 0  # texels a camera sees
    assert seen.sum() == a["seen_samples"]
    np.testing.assert_allclose(A[seen], B[seen], rtol=1e-4, atol=1e-6)


def test_a_killed_conversion_resumes_where_it_stopped(scene, tmp_path, monkeypatch):  # noqa: F811
    """A conversion stopped after 7 of its 15 light chunks (an exception from the progress callback, standing in
    for a kill: nothing after it runs) leaves no store but a partial one; run again with resume=True it reads
    only the 8 chunks of photographs the first run did not finish and gives the store of one uninterrupted run,
    chunk for chunk, and its report. Other settings refuse to resume; without resume the partial store is
    cleared and everything is read again."""
    from relight.io import PartialStoreMismatch, PhotoCapture

    mesh, _, _, _, masked, _ = scene
    photos = read_photo_capture(masked)
    # 5 chunks a camera, 15 in all; no cast shadows (their ray casting is most of a conversion and the same bits
    # either way: test_the_store_holds_what_photos_to_texels_gives checks them)
    kw = {"surface_info": mesh_spec(None), "light_chunk": 40, "min_views": 2, "shadows": False}
    _, ref = photos_to_texel_store(photos, mesh, RES, tmp_path / "whole.zarr", **kw)
    path = tmp_path / "texels.zarr"

    class Killed(Exception):
        pass

    def kill_after(n):
        calls = []

        def progress(phase, done, total):
            if phase == "photos to texels" and done > 0:
                calls.append(done)
                if len(calls) == n:
                    raise Killed
        return progress

    with pytest.raises(Killed):
        photos_to_texel_store(photos, mesh, RES, path, progress=kill_after(7), **kw)
    partial = tmp_path / ".texels.zarr.partial"
    assert not path.exists() and len((partial / "journal.jsonl").read_text().splitlines()) == 7

    reads = []
    real = PhotoCapture.read_view

    def counted(self, v, lights=None):
        reads.append(v)
        return real(self, v, lights=lights)

    monkeypatch.setattr(PhotoCapture, "read_view", counted)
    with pytest.raises(PartialStoreMismatch, match="another conversion"):
        photos_to_texel_store(photos, mesh, RES, path, resume=True, **{**kw, "min_views": 1})
    reads.clear()
    _, report = photos_to_texel_store(photos, mesh, RES, path, resume=True, **kw)
    assert not partial.exists() and len(reads) == 1 + 15 - 7  # the channel count's one photograph, then 8 chunks
    a, b = open_capture_store(path), open_capture_store(tmp_path / "whole.zarr")
    idx = np.arange(RES * RES)
    for x, y in zip(a.gather_samples(idx), b.gather_samples(idx), strict=True):
        np.testing.assert_array_equal(x, y)
    assert a.metadata == b.metadata and report.to_dict() == ref.to_dict()
    with pytest.raises(Killed):
        photos_to_texel_store(photos, mesh, RES, path, progress=kill_after(2), **kw)
    reads.clear()
    photos_to_texel_store(photos, mesh, RES, path, **kw)
    assert len(reads) == 1 + 15 and open_capture_store(path).metadata == b.metadata
