"""relight.io.photos_to_texel_store's geometry taken a block of texels at a time (issue 30: memory bounded by
the block, not by the grid): the blocks give the whole grid's projections, taps, weights, rejections and cast
shadows. A small capture: the bundled head on a 24 x 24 texel grid, two 24 x 20 px cameras, random
photographs and masks, a 42-light dome."""

import numpy as np
import pytest

import stage
from relight.io import mesh_spec, open_capture_store, photos_to_texel_store, read_photo_capture, write_photo_capture


@pytest.fixture(scope="module")
def small(tmp_path_factory):
    mesh = stage.load_head()
    rig = stage.geodesic_dome(1)
    v = np.asarray(mesh.vertices, np.float64)
    cams = stage.camera_ring(2, 1300.0, target=tuple(0.5 * (v.min(0) + v.max(0))), fov_deg=20.0, width=24,
                             height=20, start_deg=-30, arc_deg=60)
    rng = np.random.default_rng(0)
    images = [rng.uniform(0, 1, (rig.num_lights, 20, 24, 3)).astype(np.float32) for _ in cams]
    masks = [rng.uniform(0, 1, (20, 24)) > 0.05 for _ in cams]
    folder = write_photo_capture(tmp_path_factory.mktemp("blocks") / "p", images, rig, cams, masks=masks)
    return mesh, rig, cams, masks, read_photo_capture(folder)


def test_geometry_in_blocks_is_the_whole_grids(small, monkeypatch):
    import relight.io._photo_store as ps

    mesh, rig, cams, masks, photos = small
    surface = stage.texel_samples(mesh, 24)
    P, L = surface.num_samples, rig.num_lights
    fields = {k: np.asarray(getattr(surface, k)) for k in ps._GEOMETRY_FIELDS}
    block = ps._block_surface(fields, surface.resolution, 5, 9)
    for k in ps._GEOMETRY_FIELDS:
        np.testing.assert_array_equal(np.asarray(getattr(block, k)), fields[k][5:9], err_msg=k)
    views, weight, lit = ps._geometry(mesh, fields, surface.resolution, photos, 80.0, True, None)  # one block
    monkeypatch.setattr(ps, "_GEOMETRY_BLOCK", 37)  # blocks of 37 texels, the last one shorter
    calls = []
    b_views, b_weight, b_lit = ps._geometry(mesh, fields, surface.resolution, photos, 80.0, True,
                                            lambda *a: calls.append(a))
    assert P > 5 * 37
    np.testing.assert_array_equal(b_lit[0].bits, lit[0].bits)
    np.testing.assert_array_equal(b_lit[1], lit[1])
    # The cast shadows of the texels some camera sees (the only ones read), as the whole grid's.
    np.testing.assert_array_equal(lit[1], np.flatnonzero(np.any(weight > 0, axis=0)))
    np.testing.assert_array_equal(np.asarray(lit[0]), stage.light_visibility(mesh, surface, rig)[lit[1]])
    assert 0 < int(np.asarray(lit[0]).sum()) < lit[0].bits.shape[0] * L  # some texels see some lights
    # The projection is compiled per block length: the same arithmetic, vectorised differently (last bits).
    np.testing.assert_allclose(b_weight, weight, rtol=1e-6, atol=0)
    grid = np.asarray(surface.texel_index)
    occ = stage.Occluder(mesh, surface)
    for v, (a, b) in enumerate(zip(views, b_views, strict=True)):
        ref = stage.project_texels(mesh, surface, cams[v], mask=masks[v], occluder=occ)
        assert 0 < len(a.idx) < P and a.rejected == b.rejected == ref.rejected
        for k in ("idx", "cells", "tap"):
            np.testing.assert_array_equal(getattr(b, k), getattr(a, k), err_msg=k)
        np.testing.assert_allclose(b.weights, a.weights, rtol=0, atol=1e-6)
        # The texels each camera sees, in grid order, with their four taps and weights.
        np.testing.assert_array_equal(np.sort(a.idx), np.flatnonzero(ref.seen))
        assert np.all(np.diff(a.cells) > 0) and np.array_equal(a.cells, grid[a.idx])
        np.testing.assert_array_equal(a.taps(), ref.taps[a.idx])
        np.testing.assert_allclose(a.weights, ref.weights[a.idx], rtol=0, atol=1e-6)
        np.testing.assert_allclose(weight[v], np.where(ref.seen, ref.cos_o, 0.0), rtol=1e-6, atol=0)
    # One "light visibility" count over the blocks: from 0, never back, to every (texel, light) pair of the grid.
    done = [d for phase, d, total in calls if phase == "light visibility" and total == P * L]
    assert len(done) == len(calls) and done[0] == 0 and done[-1] == P * L and np.all(np.diff(done) >= 0)


def test_a_store_converted_in_small_blocks_is_the_same(small, tmp_path, monkeypatch):
    """The whole conversion with the geometry in blocks of 37 texels, the photographs sampled 7 texels at a
    time and written in runs of 100 grid cells writes the store of the default blocks (one of each here), bit for
    bit, and returns the same surface."""
    import relight.io._photo_store as ps

    mesh, _, _, _, photos = small
    kw = {"surface_info": mesh_spec(None), "light_chunk": 16}
    surf, report = photos_to_texel_store(photos, mesh, 24, tmp_path / "a.zarr", **kw)
    monkeypatch.setattr(ps, "_GEOMETRY_BLOCK", 37)
    monkeypatch.setattr(ps, "_TAP_TEXELS", 7)
    monkeypatch.setattr(ps, "_WRITE_TEXELS", 100)
    b_surf, b_report = photos_to_texel_store(photos, mesh, 24, tmp_path / "b.zarr", **kw)
    a, b = open_capture_store(tmp_path / "a.zarr"), open_capture_store(tmp_path / "b.zarr")
    ra, va = a.gather_samples(np.arange(24 * 24))
    rb, vb = b.gather_samples(np.arange(24 * 24))
    assert 0 < int(va.sum()) < va.size
    np.testing.assert_array_equal(vb, va)
    np.testing.assert_array_equal(rb, ra)
    assert b_report.to_dict() == report.to_dict() and a.metadata["photos"] == b.metadata["photos"]
    for k in ("position", "normal", "tangent", "uv", "area", "texel_index", "face"):
        np.testing.assert_array_equal(np.asarray(getattr(b_surf, k)), np.asarray(getattr(surf, k)), err_msg=k)
