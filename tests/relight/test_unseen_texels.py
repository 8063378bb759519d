"""Texels no camera sees (issue 28, item 2): coverage 0 in the map set, the documented fill in their maps,
counted apart from the solver's failures, warned about by ``relight render`` and labelled in the Mitsuba
export.

One photo capture of the bundled head (the 'front' camera, 48 px, a 162-light dome: ``relight simulate --space
image``; what is unseen depends on the camera, not on the rig, and the dome is half the Light Stage X's lights
to simulate and fit), fitted by ``relight fit`` on a 24 x 24 texel grid, shared by the tests; the unseen texels
are what ``relight.io.photos_to_texels`` (the projection's own seen mask) says."""

import contextlib
import io
import json

import numpy as np
import pytest
from scipy.spatial import cKDTree

import relight
import stage
from relight.io import UNSEEN_FILL, photos_to_texels, read_exr_channels, read_maps, read_photo_capture

SIZE = 48
RES = 24


@pytest.fixture(scope="module")
def fitted(tmp_path_factory):
    from relight.cli import main

    root = tmp_path_factory.mktemp("unseen")
    photos, maps = root / "photos", root / "maps"
    assert main(["simulate", "--space", "image", "--mesh", "head", "--rig", "dome:162", "--camera", "front",
                 "--image-size", str(SIZE), "--out", str(photos), "--quiet", "--no-index"]) == 0
    err = io.StringIO()
    with contextlib.redirect_stderr(err):
        assert main(["fit", str(photos), "--model", "ggx",
                     "--mesh", "head", "--resolution", str(RES), "--out", str(maps),
                     "--quiet", "--no-index"]) == 0
    mesh = stage.load_head()
    _, surface, report = photos_to_texels(read_photo_capture(photos), mesh, RES)
    return maps, surface, report, err.getvalue()


def test_coverage_is_zero_exactly_where_no_camera_sees(fitted):
    """coverage.exr's Y is 1 on the texels a camera sees and 0 on the unseen ones (and the gutter); its
    ``filled`` channel marks exactly the unseen texels; read_maps gives both back."""
    maps, surface, report, _ = fitted
    assert 0.2 * surface.num_samples < report.n_unseen < 0.9 * surface.num_samples
    idx = np.asarray(surface.texel_index)
    tex, _ = read_maps(maps)
    np.testing.assert_array_equal(tex.coverage.reshape(-1)[idx], ~report.unseen)
    np.testing.assert_array_equal(tex.filled.reshape(-1)[idx], report.unseen)
    atlas = np.zeros(RES * RES, bool)
    atlas[idx] = True
    assert not tex.coverage.reshape(-1)[~atlas].any() and not tex.filled.reshape(-1)[~atlas].any()
    ch, _ = read_exr_channels(maps / "coverage.exr")
    np.testing.assert_array_equal(ch["Y"], tex.coverage.astype(np.float32))
    np.testing.assert_array_equal(ch["filled"], tex.filled.astype(np.float32))


def test_unseen_texels_hold_the_documented_fill(fitted):
    """Each unseen texel's albedo, specular albedo, roughness and model are the nearest seen texel's (3D
    distance between texel centres); its tangent-space normal is (0, 0, 1); maps.json records the fill."""
    maps, surface, report, _ = fitted
    tex, _ = read_maps(maps)
    idx = np.asarray(surface.texel_index)
    pos = np.asarray(surface.position, np.float64)
    on, off = np.flatnonzero(~report.unseen), np.flatnonzero(report.unseen)
    src = on[cKDTree(pos[on]).query(pos[off])[1]]
    flat = lambda a: a.reshape((-1,) + a.shape[2:])[idx]  # noqa: E731
    for name in ("albedo", "specular", "alpha", "mfp", "model"):
        a = flat(getattr(tex, name))
        np.testing.assert_array_equal(a[off], a[src], err_msg=name)
    np.testing.assert_allclose(flat(tex.normal_ts)[off], np.broadcast_to([0.0, 0.0, 1.0], (len(off), 3)), atol=1e-5)
    np.testing.assert_allclose(flat(tex.normal)[off], np.asarray(surface.normal)[off], atol=1e-5)
    info = json.loads((maps / "maps.json").read_text())
    assert info["unseen"]["texels"] == report.n_unseen and info["unseen"]["fill"] == UNSEEN_FILL == "nearest_seen"


def test_report_counts_unseen_apart_from_failures(fitted):
    """report.json / report.md and the fit's warning count the unseen texels apart from the seen ones that
    failed."""
    maps, surface, report, err = fitted
    doc = json.loads((maps / "report.json").read_text())
    seen = ~report.unseen
    assert doc["unseen_samples"] == report.n_unseen and doc["seen_samples"] == int(seen.sum())
    assert doc["failed_seen_samples"] <= doc["seen_samples"]
    assert doc["failed_fraction"] == pytest.approx((report.n_unseen + doc["failed_seen_samples"]) / surface.num_samples)
    md = (maps / "report.md").read_text()
    assert (f"{report.n_unseen} unseen (no camera saw them" in md
            and f"{doc['failed_seen_samples']} of the {doc['seen_samples']} seen failed" in md)
    # More than half the texels are flagged (the back of the head): the warning splits them.
    assert f"{report.n_unseen} of the {surface.num_samples} texels are unseen" in err
    warning = relight.fitting._folder.flagged_warning({**doc, "unseen_samples": 0, "failed_seen_samples": 7})
    assert "7 of the" in warning and "unseen" not in warning


def test_render_warns_about_subject_pixels_on_unseen_texels(fitted, tmp_path):
    """relight render of the map set: the subject's pixels on unseen texels are counted (not 0.0) and a
    warning names how many and what to do; the truth-free threshold is UNSEEN_WARN."""
    from relight.render import UNSEEN_WARN, render_folder, unseen_warnings

    maps, *_ = fitted
    out = tmp_path / "render"
    out.mkdir()
    done = render_folder(maps, None, out)
    (gaps, subject), = done.resolved["unseen_pixels"]
    frac, = done.resolved["unseen_pixel_fraction"]
    assert gaps > 0 and frac == pytest.approx(gaps / subject) and frac > UNSEEN_WARN
    warning, = done.warnings
    assert f"({gaps} of {subject})" in warning and "fill" in warning and "capture views" in warning
    assert done.resolved["unseen_warn"] == UNSEEN_WARN == 1e-3
    assert unseen_warnings("maps", [0.5 * UNSEEN_WARN], 1, [[1, 2000]], filled=True) == []


def test_mitsuba_export_labels_the_fill(fitted):
    """The fit's Mitsuba scene carries the filled textures, a comment counting them and the coverage mask."""
    maps, surface, report, _ = fitted
    xml = (maps / "scene.xml").read_text()
    assert f"relight unseen texels: {report.n_unseen} of the {surface.num_samples} texels" in xml
    tex, _ = read_maps(maps)
    ch, _ = read_exr_channels(maps / "mitsuba" / "coverage.exr")
    np.testing.assert_array_equal(next(iter(ch.values())), tex.coverage.astype(np.float32))
    diffuse = next(iter(read_exr_channels(maps / "mitsuba" / "diffuse_x2.exr")[0].values()))
    # The filled texels hold the fill, not the fit's grey default (0.5, i.e. 1.0 doubled).
    assert not np.allclose(diffuse[tex.filled], 1.0)


def test_texture_set_in_memory_with_unseen_samples(fitted):
    """relight.io.texture_set(..., seen=): coverage is seen, filled the rest; no seen sample is refused;
    TextureSet.maps gives the filled maps back at every sample."""
    _, surface, report, _ = fitted
    maps = relight.material_maps(surface, np.full((surface.num_samples, 3), 0.5), 0.04, 0.3)
    tex = relight.io.texture_set(maps, surface, seen=~report.unseen)
    idx = np.asarray(surface.texel_index)
    np.testing.assert_array_equal(tex.coverage.reshape(-1)[idx], ~report.unseen)
    assert tex.info["unseen"]["texels"] == report.n_unseen
    assert tex.maps(surface).num_samples == surface.num_samples
    with pytest.raises(ValueError, match="no surface sample is seen"):
        relight.io.texture_set(maps, surface, seen=np.zeros(surface.num_samples, bool))
