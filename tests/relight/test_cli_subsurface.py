"""Subsurface scattering through the ``relight`` CLI: ``simulate --subsurface``
(preset and map), ``fit --subsurface region``, and ``render`` of map sets
whose model map is on the subsurface rung, on a 6 mm UV sphere at 24 x 24
texels under a 42-light dome (texels ~1 mm apart, finer than skin1's blue
mean free path of 0.68 mm is wide: the bundled head at this resolution has
texels ~11 mm apart, where only the red mean free path is identifiable)."""

import dataclasses
import json
import shutil

import jax.numpy as jnp
import numpy as np
import pytest

import brdf
from relight import MODELS
from relight.cli import main
from relight.cli._common import SUBSURFACE_PRESETS, preset_mean_free_path
from relight.io import read_capture, read_exr, read_maps, write_exr, write_texture_set

from ..scenes import write_sphere_obj

RES = 24
RADIUS = 6.0  # mm
PRESET = "skin1"
SSS, GGX = MODELS.index("subsurface"), MODELS.index("ggx")
# skin1 (Jensen et al. 2001): mfp = 1 / sqrt(3 sigma_a sigma_t'), in mm.
SKIN1_MFP = np.array([3.6733, 1.3665, 0.68269])


def _sim(mesh, out, *extra, res=RES):
    return main(["simulate", "--mesh", str(mesh), "--rig", "dome:42", "--resolution", str(res), "--image-size", "32",
                 "--out", str(out), "--quiet", "--no-index", *extra])


@pytest.fixture(scope="module")
def sss(tmp_path_factory):
    root = tmp_path_factory.mktemp("sss")
    mesh = write_sphere_obj(root / "sphere.obj", RADIUS, 24, 48)
    cap, maps = root / "capture", root / "maps"
    assert _sim(mesh, cap, "--subsurface", PRESET) == 0
    assert main(["fit", str(cap), "--model", "ggx",
                 "--subsurface", "region", "--out", str(maps), "--quiet", "--no-index"]) == 0
    white = root / "white.exr"
    write_exr(white, np.ones((16, 32, 3), np.float32))
    # The truth with the subsurface rung replaced by the local Lambert term (GGX rung): the control.
    tex, _ = read_maps(cap / "truth")
    ggx = root / "truth_ggx"
    shutil.copytree(cap / "truth", ggx)
    write_texture_set(ggx, dataclasses.replace(tex, model=np.where(tex.model == SSS, GGX, tex.model).astype(np.int32)))
    return root, mesh, cap, maps, white, ggx


def test_preset_mean_free_path_is_jensens():
    mfp, eta = preset_mean_free_path(PRESET)
    np.testing.assert_allclose(mfp, SKIN1_MFP, rtol=1e-4)
    assert eta == 1.3
    assert "spectralon" not in SUBSURFACE_PRESETS and "skin2" in SUBSURFACE_PRESETS


def test_simulate_writes_the_subsurface_truth(sss):
    _, _, cap, _, _, _ = sss
    meta = read_capture(cap).metadata["subsurface"]
    assert meta["source"] == f"preset {PRESET}" and meta["eta"] == 1.3 and meta["mfp_scale"] == 1.0
    np.testing.assert_allclose(meta["mfp_mm"], SKIN1_MFP, rtol=1e-4)
    tex, _ = read_maps(cap / "truth")
    cov = tex.coverage
    assert np.all(tex.model[cov] == SSS)
    np.testing.assert_allclose(tex.mfp[cov], np.broadcast_to(SKIN1_MFP, tex.mfp[cov].shape), rtol=1e-4)
    assert tex.info["metadata"]["subsurface"]["eta"] == 1.3
    settings = json.loads((cap / "settings.json").read_text())
    assert settings["flags"]["subsurface"] == PRESET and settings["resolved"]["subsurface"]["eta"] == 1.3


def test_fit_recovers_the_preset_mean_free_path(sss):
    """Measured: 3.42 / 1.19 / 0.54 mm against 3.67 / 1.37 / 0.68 (-7 / -13 / -21%).
    The bias is the BRDF fit's: Lambert + GGX fitted to blurred data puts part
    of the blur into the lobe (F0 0.021 against 0.028); the same search with the
    true lobe recovers all three channels within 1%. Hence 30%, and the order."""
    _, _, _, maps, _, _ = sss
    report = json.loads((maps / "report.json").read_text())
    ss = report["subsurface"]
    assert ss["mode"] == "region" and ss["eta"] == 1.3 and ss["eta_from"] == "capture"
    assert ss["subsurface_samples"] == ss["samples"] == report["samples"]
    med = np.array(ss["mfp_median_mm"])
    np.testing.assert_allclose(med, SKIN1_MFP, rtol=0.30)
    assert med[0] > med[1] > med[2]
    assert np.all(np.array(ss["against_truth"]["mfp_rel_error_median"]) < 0.30)
    assert ss["against_truth"]["model_agreement"] == 1.0
    # The profile albedo is the truth's total diffuse reflectance (measured 0.9%).
    assert report["against_truth"]["errors"]["diffuse_albedo_rel"]["unflagged"]["median"] < 0.03
    tex, _ = read_maps(maps)
    assert np.all(tex.model[tex.coverage] == SSS)
    np.testing.assert_allclose(np.median(tex.mfp[tex.coverage], axis=0), med, rtol=1e-5)
    assert tex.info["metadata"]["subsurface"]["eta"] == 1.3
    assert (maps / "mean_free_path.png").is_file() and "## Subsurface scattering" in (maps / "report.md").read_text()


def test_a_second_pass_removes_the_lobe_bias(sss, tmp_path):
    """`relight fit --subsurface region --passes 2` (relight.fit_with_subsurface):
    the lobe refitted against the predicted subsurface radiance no longer takes
    the blur, so the preset comes back closer than the one-pass fit's -7 / -13
    / -21% (test above): measured 3.3 / 8.7 / 13.1%. Bar: every channel within
    15% and better than one pass; the report records the passes."""
    _, _, cap, maps, _, _ = sss
    one = np.array(json.loads((maps / "report.json").read_text())["subsurface"]["mfp_median_mm"])
    out = tmp_path / "two"
    assert main(["fit", str(cap), "--model", "ggx",
                 "--subsurface", "region", "--passes", "2", "--out", str(out), "--quiet",
                 "--no-index"]) == 0
    ss = json.loads((out / "report.json").read_text())["subsurface"]
    two = np.array(ss["mfp_median_mm"])
    e1, e2 = np.abs(one - SKIN1_MFP) / SKIN1_MFP, np.abs(two - SKIN1_MFP) / SKIN1_MFP
    assert ss["passes"] == 2
    assert np.all(e2 < 0.15) and np.all(e2 < e1)


def _render(src, out, *extra):
    assert main(["render", str(src), "--out", str(out), "--quiet", "--no-index", *extra]) == 0
    return read_exr(out / "relit.exr")[..., :3], json.loads((out / "settings.json").read_text())


def test_render_agrees_with_image_based_relighting_of_the_capture(sss):
    """The truth map set rendered model-based (method rig, the capture's rig and
    camera) against the capture relit image-based, under the bundled map:
    measured median relative pixel difference 0.18% with the subsurface term,
    11% with the local Lambert term in its place (the control): the renderer
    applies the same diffusion as stage.simulate."""
    root, _, cap, _, _, ggx = sss
    view = ["--rig", str(cap / "rig.json"), "--camera", str(cap / "cameras.json")]
    ib, _ = _render(cap, root / "r_ib")
    img, settings = _render(cap / "truth", root / "r_sss", *view)
    ctl, _ = _render(ggx, root / "r_ggx", *view)
    assert settings["resolved"]["subsurface"]["eta"] == 1.3
    assert settings["resolved"]["subsurface"]["samples"] > 200
    m = (ib.mean(-1) > 0) & (img.mean(-1) > 0)
    rel = lambda a: np.median(np.abs(a[m] - ib[m]) / ib[m])  # noqa: E731
    assert m.sum() > 300
    assert rel(img) < 0.02
    assert rel(ctl) > 0.05


def test_subsurface_conserves_energy_under_a_white_environment(sss):
    """Uniform lighting on a convex surface: every texel receives the same
    irradiance, so the diffusion redistributes nothing and Jensen et al. 2001
    eq. 5 gives the Lambert radiance times its two Fresnel transmittances, the
    hemispherical T_in = 2 int F_t mu dmu and F_t(cos_o) (~1 at the centre).
    Measured ratio over the central 8 x 8 pixels, divided by T_in F_t(1):
    0.967 / 1.004 / 1.007: red loses ~3% (its 3.7 mm mean free path reaches the
    unseen half of the sphere, which the operator over the seen texels omits,
    and the 1% beyond the operator's radius)."""
    root, _, cap, _, white, ggx = sss
    view = ["--rig", str(cap / "rig.json"), "--camera", str(cap / "cameras.json"), "--envmap", str(white)]
    img, _ = _render(cap / "truth", root / "w_sss", *view)
    lam, _ = _render(ggx, root / "w_ggx", *view)
    eta = 1.3
    mu = np.linspace(0.0, 1.0, 20001)
    ft = np.asarray(brdf.fresnel_transmittance(jnp.asarray(mu)[:, None], eta))[:, 0]
    t_in = np.trapezoid(2 * ft * mu, mu)
    ft1 = float(np.asarray(brdf.fresnel_transmittance(jnp.ones((1, 1)), eta))[0, 0])
    c = img.shape[0] // 2
    box = (slice(c - 4, c + 4), slice(c - 4, c + 4))
    ratio = img[box].sum((0, 1)) / lam[box].sum((0, 1)) / (t_in * ft1)
    assert np.all((ratio > 0.95) & (ratio < 1.03)), ratio


def test_render_of_the_fitted_maps_uses_the_subsurface_term(sss):
    root, _, cap, maps, white, _ = sss
    img, settings = _render(maps, root / "r_fit", "--envmap", str(white))
    sub = settings["resolved"]["subsurface"]
    assert sub["eta"] == 1.3 and sub["eta_from"] == "maps.json" and sub["samples"] > 200
    assert np.all(np.isfinite(img)) and img.max() > 0


def test_simulate_from_a_mean_free_path_map(sss, tmp_path):
    """A map of another size (resampled bilinear), 0 on its left half: the
    truth has subsurface texels only where the map is > 0, with its values."""
    _, mesh, _, _, _, _ = sss
    mfp = np.zeros((12, 12, 3), np.float32)
    mfp[:, 6:] = (2.0, 1.0, 0.5)
    write_exr(tmp_path / "mfp.exr", mfp)
    out = tmp_path / "cap"
    assert _sim(mesh, out, "--subsurface", str(tmp_path / "mfp.exr"), "--mfp-scale", "2", res=16) == 0
    meta = read_capture(out).metadata["subsurface"]
    assert meta["eta"] == 1.4 and meta["mfp_scale"] == 2.0
    tex, _ = read_maps(out / "truth")
    cov = tex.coverage
    on = cov & (tex.model == SSS)
    assert on.any() and (cov & (tex.model == GGX)).any()
    u = (np.arange(16) + 0.5) / 16
    right = np.broadcast_to(u[None, :] > 0.55, cov.shape)  # well inside the map's non-zero half
    left = np.broadcast_to(u[None, :] < 0.45, cov.shape)
    assert np.all(tex.model[cov & right] == SSS) and np.all(tex.model[cov & left] == GGX)
    np.testing.assert_allclose(tex.mfp[cov & right & (u[None, :] > 0.6)], np.broadcast_to(
        (4.0, 2.0, 1.0), tex.mfp[cov & right & (u[None, :] > 0.6)].shape), rtol=1e-5)
    assert np.all(tex.mfp[cov & left] == 0)


@pytest.mark.parametrize("extra, message", [
    (["--subsurface", "skin9"], "--subsurface skin9: not a preset"),
    (["--subsurface", "spectralon"], "infinite"),
    (["--subsurface", "missing.exr"], "no such mean-free-path EXR"),
    (["--subsurface", "{nan}"], "NaN or Inf"),
    (["--subsurface", "{neg}"], "negative"),
    (["--subsurface", "{zero}"], "0 at every texel"),
    (["--subsurface", "{two}"], "3 channels"),
    (["--subsurface", "skin1", "--mfp-scale", "0"], "--mfp-scale 0.0"),
    (["--mfp-scale", "2"], "--mfp-scale: needs --subsurface"),
    (["--subsurface", "skin1", "--space", "image"], "texel space only"),
])
def test_bad_subsurface_is_refused(sss, tmp_path, capsys, extra, message):
    _, mesh, _, _, _, _ = sss
    maps = {"nan": np.full((4, 4, 3), np.nan), "neg": np.full((4, 4, 3), -1.0), "zero": np.zeros((4, 4, 3)),
            "two": np.ones((4, 4, 2))}
    for name, img in maps.items():
        if img.shape[-1] == 2:
            from relight.io import write_exr_channels

            write_exr_channels(tmp_path / f"{name}.exr", {"U": img[..., 0].astype(np.float32),
                                                         "V": img[..., 1].astype(np.float32)})
        else:
            write_exr(tmp_path / f"{name}.exr", img.astype(np.float32))
    extra = [e.format(**{k: str(tmp_path / f"{k}.exr") for k in maps}) for e in extra]
    assert _sim(mesh, tmp_path / "out", *extra, res=8) == 1
    err = capsys.readouterr().err
    assert "relight simulate: error:" in err and message in err, err


@pytest.mark.parametrize("extra, message", [
    (["--regions", "labels.png"], "--regions: needs --subsurface"),
    (["--subsurface", "texel", "--regions", "labels.png"], "regions apply to region|auto"),
    (["--subsurface", "region", "--regions", "missing.png"], "no such label map"),
    (["--subsurface", "region", "--eta", "0.9"], "--eta 0.9"),
    (["--passes", "2"], "--passes: needs --subsurface"),
    (["--subsurface", "region", "--passes", "0"], "--passes 0"),
])
def test_bad_fit_subsurface_flags_are_refused(sss, tmp_path, capsys, extra, message):
    _, _, cap, _, _, _ = sss
    (tmp_path / "labels.png").write_bytes(b"")
    extra = [str(tmp_path / e) if e.endswith(".png") else e for e in extra]
    assert main(["fit", str(cap), "--model", "ggx", "--out", str(tmp_path / "out"), "--quiet", *extra]) == 1
    err = capsys.readouterr().err
    assert "relight fit: error:" in err and message in err, err


def test_regions_label_map_is_read_per_texel(sss, tmp_path):
    """--regions: a PNG's distinct colours become labels 0..R-1 at the fitted
    texels, at the texel itself on the grid's size and the nearest texel else."""
    from relight.io import load_texel_capture, read_regions, write_png

    _, _, cap, _, _, _ = sss
    _, surface, _, _ = load_texel_capture(cap)
    right = np.asarray(surface.uv)[:, 0] > 0.5
    for size in (RES, 2 * RES):
        img = np.zeros((size, size, 3), np.uint8)
        img[:, size // 2:] = (255, 0, 0)
        write_png(tmp_path / f"labels{size}.png", img)
        labels = read_regions(str(tmp_path / f"labels{size}.png"), surface)
        assert labels.shape == (surface.num_samples,) and set(np.unique(labels)) == {0, 1}
        np.testing.assert_array_equal(labels, right.astype(int))
