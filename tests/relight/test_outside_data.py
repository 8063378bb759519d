"""Outside data: the Yale B reader (PGM, the strobes' directions, the face mask) and the held-out protocol
of relight.evaluation (closed forms on synthetic Lambertian captures; the azimuth sign on the real faces)."""

from __future__ import annotations

import dataclasses
import warnings
from pathlib import Path

import numpy as np
import pytest

import relight.evaluation as ev
from relight.io import DiligentData, ImageFormatError, read_pgm, read_yaleb, yaleb_direction

YALEB = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "yaleb"


def _write_pgm(path: Path, img: np.ndarray, maxval: int, comment: bool = False) -> None:
    head = b"P5\n" + (b"# made by a test\n" if comment else b"") + f"{img.shape[1]} {img.shape[0]}\n{maxval}\n".encode()
    body = img.astype(">u2" if maxval > 255 else np.uint8).tobytes()
    path.write_bytes(head + body)


@pytest.mark.parametrize("maxval", [255, 4095])
def test_pgm_round_trip_with_a_comment(tmp_path, maxval):
    img = np.random.default_rng(0).integers(0, maxval + 1, (7, 5))
    _write_pgm(tmp_path / "a.pgm", img, maxval, comment=True)
    got, m = read_pgm(tmp_path / "a.pgm")
    assert m == maxval and got.shape == (7, 5) and np.array_equal(got, img)


def test_pgm_damage_is_named(tmp_path):
    _write_pgm(tmp_path / "a.pgm", np.zeros((4, 4)), 255)
    (tmp_path / "short.pgm").write_bytes((tmp_path / "a.pgm").read_bytes()[:-3])
    with pytest.raises(ImageFormatError, match="short.pgm.*13 bytes of pixels, the header declares 16"):
        read_pgm(tmp_path / "short.pgm")
    (tmp_path / "p2.pgm").write_bytes(b"P2\n4 4\n255\n")
    with pytest.raises(ImageFormatError, match="p2.pgm: not a binary PGM"):
        read_pgm(tmp_path / "p2.pgm")
    (tmp_path / "huge.pgm").write_bytes(b"P5\n100000 100000\n255\n")
    with pytest.raises(ImageFormatError, match="huge.pgm: PGM size 100000 x 100000"):
        read_pgm(tmp_path / "huge.pgm")


def test_strobe_directions_follow_the_documented_frame():
    """Azimuth +90 is the subject's right = the image's left (-x); elevation +90 is up (+y); (0, 0) is the camera."""
    d = yaleb_direction([0, 90, 0, -35], [0, 0, 90, 40])
    a, e = np.radians(-35), np.radians(40)
    np.testing.assert_allclose(d, [[0, 0, 1], [-1, 0, 0], [0, 1, 0], [np.sin(-a) * np.cos(e), np.sin(e),
                                                                      np.cos(a) * np.cos(e)]], atol=1e-12)


def _lambert_data(tmp_path=None, L=24, H=6, W=5, seed=0):
    """A synthetic Lambertian capture in the DiLiGenT form: random normals and albedos, lights over the hemisphere."""
    rng = np.random.default_rng(seed)
    n = rng.normal(size=(H * W, 3))
    n[:, 2] = np.abs(n[:, 2]) + 1.0
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    lights = rng.normal(size=(L, 3))
    lights[:, 2] = np.abs(lights[:, 2]) + 0.3
    lights /= np.linalg.norm(lights, axis=1, keepdims=True)
    albedo = rng.uniform(0.2, 0.8, (H * W, 3))
    E = rng.uniform(0.5, 1.5, (L, 3))
    img = np.maximum(lights @ n.T, 0)[..., None] * albedo[None] * E[:, None, :]  # [L, P, 3]
    data = DiligentData(images=img.reshape(L, H, W, 3).astype(np.float32), light_directions=lights.astype(np.float32),
                        light_intensities=E.astype(np.float32), mask=np.ones((H, W), bool), normals_gt=None,
                        filenames=tuple(f"{i}.png" for i in range(L)))
    return data, n, albedo


def test_lambert_least_squares_is_exact_on_lambertian_data_and_ignores_what_it_is_told_to():
    data, n, albedo = _lambert_data()
    train, held = ev.heldout_split(len(data.filenames), 4, 1)
    assert len(held) == 6 and len(np.union1d(train, held)) == 24 and not np.intersect1d(train, held).size
    valid = ev.observation_validity(data, train, dark=1e-6, saturation=None)
    # Dark observations (attached shadows) break the linear model b . l; left out, the solve is exact.
    assert not valid.all()
    n_fit, a_fit = ev.lambert_least_squares(data, train, valid)
    np.testing.assert_allclose(n_fit, n, atol=1e-5)
    np.testing.assert_allclose(a_fit, albedo, rtol=1e-4)
    pred = ev.predict_lambert(n_fit, a_fit, data, held)
    observed = data.images[held][:, data.mask, :]
    assert ev.relative_rms(pred, observed, np.ones(pred.shape[:2], bool)) < 1e-4
    # A corrupted observation marked invalid changes nothing.
    bad = dataclasses.replace(data, images=data.images.copy())
    bad.images[train[0], 0, 0, :] = 0.999
    v = ev.observation_validity(bad, train, dark=1e-6, saturation=0.99)
    assert not v[0, 0]
    np.testing.assert_allclose(ev.lambert_least_squares(bad, train, v)[0][0], n[0], atol=1e-5)


def test_relative_rms_closed_forms():
    obs = np.ones((2, 3, 1))
    valid = np.ones((2, 3), bool)
    assert ev.relative_rms(np.zeros_like(obs), obs, valid) == 1.0
    assert ev.relative_rms(1.5 * obs, obs, valid) == pytest.approx(0.5)
    with pytest.raises(ValueError, match="no valid observation"):
        ev.relative_rms(obs, obs, ~valid)


def test_heldout_split_refuses_nonsense():
    with pytest.raises(ValueError, match="every >= 2"):
        ev.heldout_split(10, 1)


def test_yaleb_folder_round_trip(tmp_path):
    """Frames named by azimuth and elevation come back in name order with their directions, the
    documented intensity, and a mask of the pixels lit in most frames."""
    img = np.zeros((4, 3), np.uint8)
    img[1:3] = 200
    names = ["yaleB01_P00A+000E+00.pgm", "yaleB01_P00A+035E+40.pgm", "yaleB01_P00A-110E-20.pgm"]
    for name in names:
        _write_pgm(tmp_path / name, img, 255)
    (tmp_path / "yaleB01_P00.info").write_text("\n".join(names))
    d = read_yaleb(tmp_path)
    assert d.filenames == tuple(sorted(names)) and d.images.shape == (3, 4, 3, 3)
    np.testing.assert_allclose(d.light_directions, yaleb_direction([0, 35, -110], [0, 40, -20]), atol=1e-6)
    np.testing.assert_allclose(d.images[0, 1, 0], 200 / 255, rtol=1e-6)
    assert d.mask.sum() == 6 and d.mask[1:3].all()
    assert np.all(d.light_intensities == np.float32(np.pi))
    _write_pgm(tmp_path / "yaleB01_P00A+010E+00.pgm", np.zeros((5, 3)), 255)
    with pytest.raises(ImageFormatError, match=r"A\+010E\+00.pgm: size \(5, 3\)"):
        read_yaleb(tmp_path)


@pytest.mark.skipif(not (YALEB / "yaleB28").is_dir(), reason="../shared/data/yaleb is absent")
def test_real_faces_are_lit_from_the_side_the_directions_say():
    """On the real photographs, strobes whose direction points to the image's left (x < -0.3) light the
    left half of the face more than the right, by more than 2x, and the other way round."""
    d = read_yaleb(YALEB / "yaleB28")
    assert len(d.filenames) == 64 and 0.5 < d.mask.mean() < 0.98
    img, W = d.images[..., 0], d.images.shape[2]
    x = d.light_directions[:, 0]
    left = img[x < -0.3][:, :, : W // 2].mean() / img[x < -0.3][:, :, W // 2:].mean()
    right = img[x > 0.3][:, :, W // 2:].mean() / img[x > 0.3][:, :, : W // 2].mean()
    assert left > 2.0 and right > 2.0, (left, right)


def test_a_fit_in_the_wrong_units_says_so():
    """Radiance larger than the lights allow (intensities 100x too small: albedo 20-80 in the stated units)
    presses the diffuse albedo against its bound of 1; the fit warns, naming the likely cause. In the right
    units it is silent, and recovers the albedo."""
    import relight
    from relight.io import diligent_capture

    data, _, albedo = _lambert_data(L=16, H=4, W=4)
    # The images are albedo cos E; a Lambertian BRDF is rho_d / pi, so intensities pi E make rho_d the albedo.
    data = dataclasses.replace(data, light_intensities=data.light_intensities * np.float32(np.pi))
    capture, surface = diligent_capture(data)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        f = relight.fit(capture, surface, model="lambert", normals=True, loss="l2")
    np.testing.assert_allclose(np.asarray(f.rho_d), albedo, rtol=0.02)
    wrong = dataclasses.replace(data, light_intensities=data.light_intensities / 100)
    capture, surface = diligent_capture(wrong)
    with pytest.warns(UserWarning, match=r"100% of the 16 fitted samples reach diffuse albedo 1.*units"):
        relight.fit(capture, surface, model="lambert", normals=True, loss="l2")
