"""``relight simulate --out NAME.zarr``: the capture streamed block by block into
a capture store. The store must hold what the folder form holds (same seed,
with and without sensor noise), whatever the block size; ``relight fit`` must
give the same maps from either; contradictory flags are refused by name."""

import json

import numpy as np
import pytest

from relight.cli import main
from relight.io import load_texel_capture, open_capture_store, read_capture, read_maps

from ._cli_runs import HEAD16_SIMULATE, head16, small_index

RES = 16
COMMON = ["simulate", "--rig", "dome:42", "--resolution", str(RES), "--image-size", "32", "--quiet"]
NOISE = ["--noise", "300", "--read-noise", "2", "--seed", "5"]
# The two forms run the same kernels on differently shaped chunks (the folder form 64 lights x every seen
# texel, the store 16 lights x one padded block), so XLA may round the last bit differently: 2 float32 ulps on one
# machine, up to 1.4e-6 relative (12 ulps) on another of the same kind whose CPU vectorises the sums differently.
RTOL, ATOL = 2e-6, 1e-7


@pytest.fixture(scope="module")
def captures(tmp_path_factory):
    """{name: path}; "folder" is the run's shared COMMON capture and "fit" its default fit
    (tests/relight/_cli_runs.py), the others are this module's own."""
    assert HEAD16_SIMULATE == COMMON
    root = tmp_path_factory.mktemp("simulate_store")
    folder, fit = head16(tmp_path_factory)
    got = {"folder": folder, "fit": fit}
    runs = {"folder_noisy": NOISE, "store.zarr": [], "store_b64.zarr": ["--block", "64"],
            "store_noisy.zarr": NOISE, "store_noisy_b64.zarr": [*NOISE, "--block", "64"]}
    with small_index():
        for name, extra in runs.items():
            got[name] = root / name
            assert main([*COMMON, *extra, "--out", str(got[name])]) == 0
    return got


def _folder(path):
    data = read_capture(path)
    return data.radiance, np.broadcast_to(data.valid, data.radiance.shape[:3])


def _store(path):
    return open_capture_store(path).read()


@pytest.mark.parametrize(("folder", "store"), [("folder", "store.zarr"), ("folder_noisy", "store_noisy_b64.zarr")])
def test_store_equals_the_folder_form(captures, folder, store):
    """Same seed, same capture: radiance to float32 rounding, the mask exactly,
    both on the full texel grid [V, L, H*W, C] (unseen texels 0 and invalid)."""
    rad_f, mask_f = _folder(captures[folder])
    rad_s, mask_s = _store(captures[store])
    assert rad_s.shape == rad_f.shape == (1, 42, RES * RES, 3)
    np.testing.assert_array_equal(mask_s, mask_f)
    assert mask_f.sum() > 1000
    np.testing.assert_allclose(rad_s, rad_f, rtol=RTOL, atol=ATOL)
    if folder == "folder":  # (with noise, read noise is drawn in shadow too)
        assert np.all(rad_s[~mask_s] == 0)
    assert open_capture_store(captures[store]).sample_shape == (RES, RES)


def test_noise_is_real_and_seeded(captures):
    """The noisy capture differs from the clean one by about the Poisson-Gaussian
    variance L / exposure + (read / exposure)^2 (Foi et al. 2008, eq. 1): within 20%."""
    clean, mask = _store(captures["store.zarr"])
    noisy, mask_n = _store(captures["store_noisy.zarr"])
    ok = mask & mask_n & (clean[..., 0] > 0.02)
    ratio = np.mean((noisy[ok] - clean[ok]) ** 2) / np.mean(clean[ok] / 300.0 + (2.0 / 300.0) ** 2)
    assert ok.sum() > 1000
    assert 0.8 < ratio < 1.2, ratio


@pytest.mark.parametrize(("a", "b"), [("store.zarr", "store_b64.zarr"), ("store_noisy.zarr", "store_noisy_b64.zarr")])
def test_block_size_does_not_change_the_capture(captures, a, b):
    """Blocks of 64 texels (4 blocks, store chunks of 64) and one block of the
    whole grid give the same store contents; with noise too, since every
    observation has its own key (seed, view, light, texel)."""
    sa, sb = open_capture_store(captures[a]), open_capture_store(captures[b])
    assert sa.chunks[2] != sb.chunks[2]
    (ra, ma), (rb, mb) = sa.read(), sb.read()
    np.testing.assert_array_equal(ma, mb)
    np.testing.assert_allclose(ra, rb, rtol=1e-6, atol=0)


def test_store_holds_truth_preview_and_settings(captures):
    """truth/, the preview and settings.json live inside the store folder (one
    rename puts them all in place), load_texel_capture reads the store, and no
    temporary folder is left beside it."""
    store = captures["store_b64.zarr"]
    truth, _ = read_maps(store / "truth")
    assert truth.resolution == (RES, RES)
    assert (store / "preview_all_lights.png").is_file() and (store / "preview_all_lights.exr").is_file()
    settings = json.loads((store / "settings.json").read_text())["resolved"]
    assert settings["form"] == "store" and settings["blocks"] == 4 and settings["block_texels"] == 64
    cap, surface, _, meta = load_texel_capture(store)
    ref, ref_surface, _, _ = load_texel_capture(captures["folder"])
    assert surface.num_samples == ref_surface.num_samples == settings["samples_seen"]
    np.testing.assert_allclose(np.asarray(cap.radiance), np.asarray(ref.radiance), rtol=RTOL, atol=ATOL)
    assert meta["space"] == "texel" and meta["writer"] == "relight simulate"
    assert not [p.name for p in store.parent.iterdir() if p.name.startswith(".")]


def test_fit_reads_the_store_as_the_folder(captures, tmp_path):
    """``relight fit`` on the store and on the folder (the shared run's `relight fit folder --quiet`) gives the
    same maps (the inputs agree to float32 rounding; the fit is deterministic)."""
    mf = captures["fit"]
    assert main(["fit", str(captures["store.zarr"]), "--model", "ggx", "--out", str(tmp_path / "ms"), "--quiet"]) == 0
    (tf, _), (ts, _) = read_maps(mf), read_maps(tmp_path / "ms")
    np.testing.assert_array_equal(tf.coverage, ts.coverage)
    for name in ("albedo", "specular", "alpha"):
        np.testing.assert_allclose(getattr(ts, name), getattr(tf, name), rtol=1e-4, atol=1e-5, err_msg=name)
    rf = json.loads((mf / "report.json").read_text())
    rs = json.loads((tmp_path / "ms" / "report.json").read_text())
    assert rs["samples"] == rf["samples"]
    # Noise-free: both errors are float32 rounding (~7e-8), equal to 1e-3 relative or 1e-6 absolute.
    median = lambda r: r["against_truth"]["errors"]["diffuse_albedo_rel"]["unflagged"]["median"]  # noqa: E731
    assert median(rs) == pytest.approx(median(rf), rel=1e-3, abs=1e-6)


def test_subsurface_store_equals_the_folder_form(tmp_path):
    """--subsurface in the store form: the operator couples every seen texel, so
    the store is written one light chunk of the whole surface at a time; it
    holds what the folder form holds."""
    sss = [*COMMON, "--rig", "dome:12", "--subsurface", "skin1"]
    assert main([*sss, "--out", str(tmp_path / "f")]) == 0
    assert main([*sss, "--out", str(tmp_path / "s.zarr")]) == 0
    rad_f, mask_f = _folder(tmp_path / "f")
    rad_s, mask_s = _store(tmp_path / "s.zarr")
    np.testing.assert_array_equal(mask_s, mask_f)
    np.testing.assert_allclose(rad_s, rad_f, rtol=1e-6, atol=ATOL)
    settings = json.loads((tmp_path / "s.zarr" / "settings.json").read_text())["resolved"]
    assert settings["blocks"] == 1 and settings["subsurface"]["source"] == "preset skin1"


def test_rerun_replaces_the_store(captures, tmp_path):
    out = tmp_path / "again.zarr"
    assert main([*COMMON, "--rig", "dome:12", "--out", str(out)]) == 0
    first = open_capture_store(out).generation
    assert main([*COMMON, "--rig", "dome:12", "--out", str(out), "--block", "128"]) == 0
    assert open_capture_store(out).generation != first
    assert json.loads((out / "settings.json").read_text())["resolved"]["block_texels"] == 128
    assert sorted(p.name for p in tmp_path.iterdir()) == ["again.zarr"]


@pytest.mark.parametrize(("extra", "needle"), [
    (["--space", "image"], "--space image"),
    (["--block", "64", "--subsurface", "skin1"], "--block 64: --subsurface"),
    (["--block", "10"], "--block 10"),
])
def test_bad_store_combinations_are_refused(tmp_path, capsys, extra, needle):
    assert main([*COMMON, *extra, "--out", str(tmp_path / "x.zarr")]) == 1
    assert needle in capsys.readouterr().err
    assert not (tmp_path / "x.zarr").exists()


def test_block_needs_a_store(tmp_path, capsys):
    assert main([*COMMON, "--block", "64", "--out", str(tmp_path / "folder")]) == 1
    err = capsys.readouterr().err
    assert "--block 64" in err and ".zarr" in err


def test_refuses_to_replace_a_folder_that_is_not_a_store(tmp_path, capsys):
    out = tmp_path / "precious.zarr"
    out.mkdir()
    (out / "thesis.tex").write_text("do not delete")
    assert main([*COMMON, "--out", str(out)]) == 1
    assert "precious.zarr" in capsys.readouterr().err
    assert (out / "thesis.tex").read_text() == "do not delete"


def test_half_store_equals_the_half_folder(tmp_path):
    """--half: a float16 store holding the folder's float16 values exactly."""
    half = [*COMMON, "--rig", "dome:12", "--half"]
    assert main([*half, "--out", str(tmp_path / "f")]) == 0
    assert main([*half, "--out", str(tmp_path / "s.zarr")]) == 0
    store = open_capture_store(tmp_path / "s.zarr")
    assert store.dtype == np.float16 and store.half
    rad_f, mask_f = _folder(tmp_path / "f")
    rad_s, mask_s = store.read()
    np.testing.assert_array_equal(mask_s, mask_f)
    # float16 rounding of values that agree to float32 rounding: at most one half-float ulp apart.
    np.testing.assert_allclose(rad_s.astype(np.float32), rad_f, rtol=2 ** -10, atol=2 ** -24)


@pytest.mark.parametrize(("n", "block", "want"), [(256, 100, (64, 64)), (1 << 20, 1 << 16, (1 << 16, 1 << 14)),
                                                  (1 << 20, 5000, (4096, 4096)), (1 << 20, 40000, (32768, 16384))])
def test_store_blocks_are_whole_store_chunks(n, block, want):
    """The block is rounded down to a multiple of the store's sample chunk (so
    every block writes whole chunks), the chunk is relight.io's default (16384
    samples of 8 RGB float32 lights) or the largest power of two in the block."""
    from relight.io import store_blocks

    got = store_blocks(n, block, 3, np.float32)
    assert got == want
    assert got[0] % got[1] == 0 and got[0] <= block


def test_the_help_texts_block_is_stages():
    """``relight simulate``'s DEFAULT_BLOCK (spelled there so that --help needs no JAX) is stage's."""
    import stage
    from relight.cli import simulate

    assert simulate.DEFAULT_BLOCK == stage.DEFAULT_BLOCK
