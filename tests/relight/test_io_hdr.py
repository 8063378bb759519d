"""Radiance HDR (flat, old and new RLE), PFM and PNG: round trips against the
formats' own precision, real files, and errors naming the file."""

import numpy as np
import pytest

from relight.io import ImageFormatError, read_hdr, read_hdr_header, read_pfm, read_png, write_hdr, write_pfm, write_png

ENVMAPS = ["grace", "uffizi", "pisa", "ennis", "venice_sunset_1k", "royal_esplanade_1k"]


def _hdr_image(h=9, w=40, seed=1):
    rng = np.random.default_rng(seed)
    img = (10.0 ** rng.uniform(-3, 3, size=(h, w, 3))).astype(np.float32)
    img[2, 5:30] = [1.0, 2.0, 3.0]  # long runs exercise the run-length codes
    img[4] = 0.0
    return img


@pytest.mark.parametrize("rle", [True, False])
def test_hdr_roundtrip_within_rgbe_precision(tmp_path, rle):
    img = _hdr_image()
    path = tmp_path / "x.hdr"
    write_hdr(path, img, rle=rle)
    back = read_hdr(path)
    assert back.shape == img.shape and back.dtype == np.float32
    # RGBE keeps 8 mantissa bits of the pixel's largest component; with
    # mid-point decoding the error is <= 2^-8 of that component.
    peak = img.max(axis=-1, keepdims=True)
    assert np.all(np.abs(back - img) <= peak * 2.0**-8)
    # Decoded values are fixed points of encode/decode: a second round trip is exact.
    write_hdr(path, back, rle=rle)
    np.testing.assert_array_equal(read_hdr(path), back)


def test_rle_and_flat_agree_and_rle_is_smaller(tmp_path):
    img = np.ones((16, 64, 3), np.float32) * [0.5, 1.0, 2.0]
    write_hdr(tmp_path / "r.hdr", img, rle=True)
    write_hdr(tmp_path / "f.hdr", img, rle=False)
    np.testing.assert_array_equal(read_hdr(tmp_path / "r.hdr"), read_hdr(tmp_path / "f.hdr"))
    assert (tmp_path / "r.hdr").stat().st_size < (tmp_path / "f.hdr").stat().st_size / 4


def test_old_style_rle_and_orientations(tmp_path):
    # Hand-made file: 1 row of 6 pixels in old-style RLE: p, repeat x3, q, q.
    p, q = bytes([128, 64, 32, 129]), bytes([10, 20, 30, 128])
    body = p + bytes([1, 1, 1, 3]) + q + q
    (tmp_path / "old.hdr").write_bytes(b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 1 +X 6\n" + body)
    img = read_hdr(tmp_path / "old.hdr")
    v = lambda b: (np.array(list(b[:3]), np.float64) + 0.5) * 2.0 ** (b[3] - 136)  # noqa: E731
    np.testing.assert_allclose(img[0, :4], np.tile(v(p), (4, 1)), rtol=1e-7)
    np.testing.assert_allclose(img[0, 4:], np.tile(v(q), (2, 1)), rtol=1e-7)
    # '+Y' stores rows bottom-up, '-X' columns right-to-left, 'X' first is transposed.
    rows = [bytes([1 + 10 * i + j, 0, 0, 129]) for i in range(2) for j in range(3)]  # 2 scanlines x 3
    data = b"".join(rows)
    ref = np.array([[1, 2, 3], [11, 12, 13]], np.float64)
    for res, expect in [
        ("-Y 2 +X 3", ref),
        ("+Y 2 +X 3", ref[::-1]),
        ("-Y 2 -X 3", ref[:, ::-1]),
        ("+X 2 -Y 3", ref.T),
    ]:
        (tmp_path / "o.hdr").write_bytes(b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n" + res.encode() + b"\n" + data)
        got = read_hdr(tmp_path / "o.hdr")[..., 0]
        np.testing.assert_allclose(got, (expect + 0.5) * 2.0**-7, rtol=1e-7, err_msg=res)


@pytest.mark.parametrize("name", ENVMAPS)
def test_real_envmaps_read_and_rewrite_exactly(shared_data, tmp_path, name):
    path = shared_data / "envmaps" / f"{name}.hdr"
    img = read_hdr(path)
    h, w = read_hdr_header(path)["shape"]
    assert img.shape == (h, w, 3) and w == 2 * h
    assert np.isfinite(img).all() and img.min() >= 0 and img.max() > 1
    write_hdr(tmp_path / "copy.hdr", img)  # decoded values re-encode to the same bytes' values
    np.testing.assert_array_equal(read_hdr(tmp_path / "copy.hdr"), img)


def test_hdr_errors_name_the_file(tmp_path):
    (tmp_path / "magic.hdr").write_bytes(b"P6\n2 2\n255\n" + bytes(12))
    with pytest.raises(ImageFormatError, match=r"magic\.hdr.*not a Radiance"):
        read_hdr(tmp_path / "magic.hdr")
    (tmp_path / "res.hdr").write_bytes(b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\nY 2 X 3\n")
    with pytest.raises(ImageFormatError, match=r"res\.hdr.*resolution"):
        read_hdr(tmp_path / "res.hdr")
    (tmp_path / "xyz.hdr").write_bytes(b"#?RADIANCE\nFORMAT=32-bit_rle_xyze\n\n-Y 1 +X 1\n" + bytes(4))
    with pytest.raises(ImageFormatError, match=r"xyz\.hdr.*xyze"):
        read_hdr(tmp_path / "xyz.hdr")
    for rle in (True, False):
        write_hdr(tmp_path / "full.hdr", _hdr_image(), rle=rle)
        data = (tmp_path / "full.hdr").read_bytes()
        (tmp_path / "cut.hdr").write_bytes(data[: len(data) * 2 // 3])
        with pytest.raises(ImageFormatError, match=r"cut\.hdr.*truncated"):
            read_hdr(tmp_path / "cut.hdr")
    with pytest.raises(ValueError, match=r"neg\.hdr.*non-negative"):
        write_hdr(tmp_path / "neg.hdr", -np.ones((2, 4, 3), np.float32))


def test_pfm_roundtrip_and_byte_order(tmp_path):
    img = _hdr_image(5, 7)
    write_pfm(tmp_path / "a.pfm", img)
    np.testing.assert_array_equal(read_pfm(tmp_path / "a.pfm"), img)
    write_pfm(tmp_path / "g.pfm", img[..., 0])
    np.testing.assert_array_equal(read_pfm(tmp_path / "g.pfm")[..., 0], img[..., 0])
    # Big-endian (positive scale), rows bottom to top, written by hand.
    big = b"PF\n7 5\n1.0\n" + img[::-1].astype(">f4").tobytes()
    (tmp_path / "be.pfm").write_bytes(big)
    np.testing.assert_array_equal(read_pfm(tmp_path / "be.pfm"), img)
    (tmp_path / "cut.pfm").write_bytes(big[:-10])
    with pytest.raises(ImageFormatError, match=r"cut\.pfm.*truncated"):
        read_pfm(tmp_path / "cut.pfm")


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
@pytest.mark.parametrize("channels", [1, 2, 3, 4])
def test_png_roundtrip_exact(tmp_path, dtype, channels):
    rng = np.random.default_rng(channels)
    img = rng.integers(0, np.iinfo(dtype).max, size=(6, 5, channels), endpoint=True).astype(dtype)
    write_png(tmp_path / "a.png", img)
    back = read_png(tmp_path / "a.png")
    assert back.dtype == dtype
    np.testing.assert_array_equal(back, img)


def test_png_keeps_16_bits_of_diligent(shared_data):
    img = read_png(shared_data / "diligent" / "ballPNG" / "001.png")
    assert img.dtype == np.uint16 and img.shape[-1] == 3
    # Pillow would give at most 255; the real data uses the low byte too.
    assert img.max() > 255 and np.any(img % 256 != 0)


def test_png_errors(tmp_path):
    with pytest.raises(TypeError, match="uint8 or uint16"):
        write_png(tmp_path / "f.png", np.zeros((2, 2, 3), np.float32))
    (tmp_path / "bad.png").write_bytes(b"\x89PNG\r\n\x1a\n garbage")
    with pytest.raises(ImageFormatError, match=r"bad\.png"):
        read_png(tmp_path / "bad.png")


def test_rgbe_extremes_never_reach_the_renderer_as_inf(tmp_path):
    """RGBE's largest pixel (255.5 * 2^119 = 1.7e38) decodes finite, but a sum of three is Inf in float32:
    read_hdr returns it as stored and load_envmap refuses it (check_radiance's MAX_RADIANCE, 1e15), naming
    the file and the pixel. write_hdr refuses a value past RGBE's range rather than wrapping its exponent
    byte to 0 (the reported 3e38 that read back as black)."""
    from relight.envmap import load_envmap

    img = np.full((4, 8, 3), 0.5, np.float32)
    path = tmp_path / "sun.hdr"
    write_hdr(path, img, rle=False)
    data = bytearray(path.read_bytes())
    data[-4 * 8 * 4 + 4 * 3:-4 * 8 * 4 + 4 * 4] = bytes([255, 255, 255, 255])  # row 0, column 3
    path.write_bytes(bytes(data))
    pixels = read_hdr(path)
    assert np.all(np.isfinite(pixels)) and float(pixels.max()) == np.float32(255.5 * 2.0**119)
    with np.errstate(over="ignore"):
        assert not np.isfinite(pixels[0, 3].sum())  # why it must not go further
    with pytest.raises(ImageFormatError, match=r"sun\.hdr: environment radiance has 3 values above 1e\+15 "
                                               r"\(first at index \(0, 3, 0\)"):
        load_envmap(path)
    with pytest.raises(ValueError, match=r"argument 'image' has values up to 3e\+38, beyond RGBE's largest"):
        write_hdr(tmp_path / "big.hdr", np.full((1, 1, 3), 3e38))
