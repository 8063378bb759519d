"""Every reader against random and mutated files: a corrupt, truncated or
hostile file gives a valid result or the project's own error naming the file
(``relight.io.ImageFormatError`` or a subclass; a plain ``ValueError`` from the
``stage`` readers, which cannot import relight), never another exception type,
and never allocates beyond the stated limit.

Each read runs under lowered size limits (``MAX_IMAGE_PIXELS`` and
``stage.MAX_CAMERA_PIXELS`` set to ``SMALL_PIXELS``) and a tracemalloc peak
check: a reader that allocated what a header declares before checking it would
exceed ``_budget`` by orders of magnitude (a declared 200000 x 200000 image is
160 GB as RGBE; the budget is a few MB). Mutations are bit flips, byte sets,
insertions, deletions and truncations (biased toward the header), and
format-aware edits: declared sizes (HDR resolution line, PNG IHDR with its CRC
mended, PFM header, EXR dataWindow), header values (EXPOSURE, FORMAT), zlib
data behind a valid CRC, and JSON fields replaced by random JSON values.

Hypothesis runs derandomized with a fixed number of examples per reader, so the
file is deterministic and runs in well under a minute on one core
(``RELIGHT_FUZZ_SCALE=N`` multiplies the examples for a longer search).
"""

from __future__ import annotations

import json
import os
import re
import shutil
import struct
import tracemalloc
import warnings
import zlib
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import relight.io._errors as io_errors
import stage
import stage._camera as stage_camera
from relight.io import (
    ImageFormatError,
    open_capture,
    read_capture,
    read_diligent,
    read_exr,
    read_hdr,
    read_maps,
    read_pfm,
    read_photo_capture,
    read_png,
    read_texture,
    write_capture,
    write_exr,
    write_hdr,
    write_maps,
    write_pfm,
    write_photo_capture,
    write_png,
)

# The lowered pixel limit every fuzzed read runs under (64 x 64).
SMALL_PIXELS = 4096


# Multiplies every test's example count, for a longer exploratory run (RELIGHT_FUZZ_SCALE=20 pytest ...).
_SCALE = max(1, int(os.environ.get("RELIGHT_FUZZ_SCALE", "1")))


def _fuzz(examples: int):
    """The suite's one profile: derandomized, no example database, no deadline (a first read may import a
    parser), ``examples`` examples (times RELIGHT_FUZZ_SCALE)."""
    return settings(derandomize=True, database=None, deadline=None, max_examples=examples * _SCALE,
                    print_blob=False,
                    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow,
                                           HealthCheck.data_too_large])


def _budget(nbytes: int) -> int:
    """Peak bytes a read may allocate: decoded pixels under the lowered limit (4096 px x 4 channels x 8 bytes,
    with copies), 64 x the bytes on disk (parsers' working copies, pypng's row lists), and 8 MiB for the
    parsers' own state."""
    return 8 * 2**20 + 16 * SMALL_PIXELS * 4 * 8 + 64 * nbytes


@pytest.fixture
def small_limits(monkeypatch):
    monkeypatch.setattr(io_errors, "MAX_IMAGE_PIXELS", SMALL_PIXELS)
    monkeypatch.setattr(stage_camera, "MAX_CAMERA_PIXELS", SMALL_PIXELS)


def _size(target: Path) -> int:
    return sum(p.stat().st_size for p in target.rglob("*") if p.is_file()) if target.is_dir() else target.stat().st_size


def read_or_refuse(read, target: Path, stage_reader: bool = False):
    """Run ``read(target)`` under tracemalloc; return its result, or None after checking the refusal: an
    ImageFormatError (or, from a stage reader, exactly ValueError) whose message names ``target`` (a
    folder's errors name it or a file inside it)."""
    budget = _budget(_size(target))
    tracemalloc.start()
    try:
        with warnings.catch_warnings():
            # A parser's own warning before its refusal (numpy's "loadtxt: input contained no data") is not
            # a failure; a numeric RuntimeWarning (overflow, invalid value) is: it means NaN or Inf was made.
            warnings.simplefilter("ignore")
            warnings.simplefilter("error", RuntimeWarning)
            out = read(target)
    except ImageFormatError as err:
        assert str(target) in str(err), f"the error does not name {target}: {err}"
        out = None
    except ValueError as err:
        assert stage_reader and type(err) is ValueError, f"{type(err).__name__} (not the project's error): {err}"
        assert str(target) in str(err), f"the error does not name {target}: {err}"
        out = None
    finally:
        peak = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
    assert peak <= budget, f"reading {target} allocated {peak} bytes, beyond the budget of {budget}"
    return out


# ----------------------------------------------------------------- mutations

_POS = st.one_of(st.integers(0, 63), st.integers(0, 2**20))  # header bytes get half the edits
_OP = st.one_of(
    st.tuples(st.just("flip"), _POS, st.integers(0, 7)),
    st.tuples(st.just("set"), _POS, st.integers(0, 255)),
    st.tuples(st.just("insert"), _POS, st.binary(min_size=1, max_size=16)),
    st.tuples(st.just("delete"), _POS, st.integers(1, 64)),
    st.tuples(st.just("cut"), _POS, st.just(0)),
)
BYTE_EDITS = st.lists(_OP, min_size=1, max_size=4)


def _byte_edit(seed: bytes):
    return BYTE_EDITS.map(lambda ops: mutate(seed, ops))


def mutate(data: bytes, ops) -> bytes:
    """``data`` after the byte edits ``ops`` (positions taken modulo the current length)."""
    b = bytearray(data)
    for kind, pos, arg in ops:
        if not b:
            break
        i = pos % len(b)
        if kind == "flip":
            b[i] ^= 1 << arg
        elif kind == "set":
            b[i] = arg
        elif kind == "insert":
            b[i:i] = arg
        elif kind == "delete":
            del b[i:i + arg]
        else:
            del b[i:]
    return bytes(b)


HUGE = st.one_of(st.sampled_from([0, 1, 65, 4097, 100000, 200000, 2**31 - 1, 2**31, 2**32 + 1, 10**12]),
                 st.integers(0, 2**40))
JSON_LEAF = st.one_of(
    st.none(), st.booleans(), st.integers(-(2**70), 2**70), HUGE, st.floats(allow_nan=True, allow_infinity=True),
    st.text(max_size=12),
    st.sampled_from(["abc", "2", "1", "{light}", "{view.real}", "{light:s}", "{light:99999}", "../x.exr",
                     "/etc/passwd", "", "\x00", "views/v{view:03d}/l{light:03d}.exr", "mm", "+y", "pinhole"]),
)
JSON_VALUE = st.recursive(JSON_LEAF, lambda c: st.lists(c, max_size=4) | st.dictionaries(st.text(max_size=6), c,
                                                                                          max_size=3),
                          max_leaves=8)


def _paths(doc, prefix=()):
    """Every key / index path inside a JSON document."""
    out = [prefix]
    if isinstance(doc, dict):
        for k, v in doc.items():
            out += _paths(v, prefix + (k,))
    elif isinstance(doc, list):
        for i, v in enumerate(doc[:6]):
            out += _paths(v, prefix + (i,))
    return out


def _replace(doc, path, value, delete=False):
    if not path:
        return value
    doc = json.loads(json.dumps(doc))
    node = doc
    for k in path[:-1]:
        node = node[k]
    if delete and isinstance(node, dict):
        del node[path[-1]]
    else:
        node[path[-1]] = value
    return doc


@st.composite
def json_edit(draw, doc):
    """A JSON document's text after one of: a field (at any depth) replaced by a random value or deleted, an
    unknown field added, the whole document replaced, or byte edits of its text."""
    kind = draw(st.sampled_from(["replace", "replace", "delete", "add", "whole", "bytes"]))
    text = json.dumps(doc)
    if kind == "bytes":
        return mutate(text.encode(), draw(BYTE_EDITS))
    if kind == "whole":
        new = draw(JSON_VALUE)
    elif kind == "add":
        new = {**doc, draw(st.text(min_size=1, max_size=6)): draw(JSON_VALUE)} if isinstance(doc, dict) else doc
    else:
        path = draw(st.sampled_from(_paths(doc)[1:] or [()]))
        new = _replace(doc, path, draw(JSON_VALUE), delete=kind == "delete")
    return json.dumps(new).encode()


# --------------------------------------------------------------- image files

def _exr_bytes(tmp: Path) -> bytes:
    rng = np.random.default_rng(0)
    write_exr(tmp / "seed.exr", rng.uniform(0, 2, (6, 5, 3)).astype(np.float32), header={"note": [1, 2]})
    return (tmp / "seed.exr").read_bytes()


@st.composite
def exr_edit(draw, seed: bytes):
    """Byte edits, or the dataWindow's four int32s set to random (often huge) values."""
    if draw(st.booleans()):
        return mutate(seed, draw(BYTE_EDITS))
    i = seed.index(b"dataWindow\x00box2i\x00") + len(b"dataWindow\x00box2i\x00") + 4
    box = [draw(st.one_of(st.integers(-(2**31), 2**31 - 1), st.sampled_from([0, 5, 100000, 2**30])))
           for _ in range(4)]
    return seed[:i] + struct.pack("<4i", *box) + seed[i + 16:]


@_fuzz(150)
@given(data=st.data())
def test_exr_reader(tmp_path, small_limits, data):
    seed = _exr_bytes(tmp_path)
    path = tmp_path / "f.exr"
    path.write_bytes(data.draw(exr_edit(seed)))
    img = read_or_refuse(read_exr, path)
    if img is not None:
        assert img.ndim == 3 and img.shape[0] * img.shape[1] <= SMALL_PIXELS


def test_exr_declaring_a_huge_window_is_refused_before_reading(tmp_path):
    seed = _exr_bytes(tmp_path)
    i = seed.index(b"dataWindow\x00box2i\x00") + len(b"dataWindow\x00box2i\x00") + 4
    path = tmp_path / "huge.exr"
    path.write_bytes(seed[:i] + struct.pack("<4i", 0, 0, 199999, 199999) + seed[i + 16:])
    with pytest.raises(ImageFormatError, match=r"huge\.exr: part 0's dataWindow declares 200000x200000 pixels"):
        read_exr(path)


_HDR_HEAD = b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\nEXPOSURE=1.5\n\n-Y 6 +X 12\n"


def _hdr_bytes(tmp: Path, rle: bool) -> bytes:
    rng = np.random.default_rng(1)
    write_hdr(tmp / "seed.hdr", rng.uniform(0, 4, (6, 12, 3)), rle=rle, exposure=1.5)
    return (tmp / "seed.hdr").read_bytes()


@st.composite
def hdr_edit(draw, seed: bytes):
    """Byte edits, or a header line replaced (resolution with random sizes and signs, EXPOSURE, FORMAT)."""
    kind = draw(st.sampled_from(["bytes", "resolution", "exposure", "format"]))
    if kind == "bytes":
        return mutate(seed, draw(BYTE_EDITS))
    head_end = seed.index(b"\n\n") + 2
    res_end = seed.index(b"\n", head_end) + 1
    if kind == "resolution":
        a, b = draw(st.sampled_from(["-Y", "+Y", "-X", "+X"])), draw(st.sampled_from(["+X", "-X", "+Y", "-Y"]))
        line = f"{a} {draw(HUGE)} {b} {draw(HUGE)}\n".encode()
        return seed[:head_end] + line + seed[res_end:]
    key = "EXPOSURE" if kind == "exposure" else "FORMAT"
    value = draw(st.one_of(st.sampled_from(["abc", "nan", "inf", "-1", "0", "1e400", "32-bit_rle_xyze", ""]),
                           st.text(alphabet=st.characters(min_codepoint=32, max_codepoint=126), max_size=8)))
    line = b"\n" + f"{key}={value}".encode()
    head = re.sub(rb"\n" + key.encode() + rb"=[^\n]*", lambda _: line, seed[:head_end])
    return head + seed[head_end:]


@_fuzz(120)
@given(rle=st.booleans(), data=st.data())
def test_hdr_reader(tmp_path, small_limits, rle, data):
    seed = _hdr_bytes(tmp_path, rle)
    path = tmp_path / "f.hdr"
    path.write_bytes(data.draw(hdr_edit(seed)))
    img = read_or_refuse(read_hdr, path)
    if img is not None:
        assert img.dtype == np.float32 and np.all(np.isfinite(img)) and np.all(img >= 0)


def test_hdr_limits(tmp_path):
    """The three reported HDR failures: a 200000 x 200000 header, EXPOSURE=abc, and RGBE's largest pixel
    (finite, and refused by check_radiance as radiance); write_hdr refuses what its exponent cannot hold."""
    path = tmp_path / "a.hdr"
    path.write_bytes(b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 200000 +X 200000\n" + bytes(64))
    with pytest.raises(ImageFormatError, match=r"a\.hdr: the resolution line declares 200000x200000"):
        read_hdr(path)
    path.write_bytes(b"#?RADIANCE\nEXPOSURE=abc\n\n-Y 1 +X 1\n" + bytes([128, 128, 128, 129]))
    with pytest.raises(ImageFormatError, match=r"a\.hdr: header EXPOSURE='abc' is not a number"):
        read_hdr(path)
    path.write_bytes(b"#?RADIANCE\n\n-Y 1 +X 1\n" + bytes([255, 255, 255, 255]))
    img = read_hdr(path)
    np.testing.assert_allclose(img, 255.5 * 2.0**119, rtol=1e-7)  # RGBE's largest value, finite in float32
    with pytest.raises(ImageFormatError, match=r"a\.hdr: env has 3 values above 1e\+15 \(first at index \(0, 0, 0\)"):
        io_errors.check_radiance(img, path, "env")
    with pytest.raises(ValueError, match=r"argument 'image' has values up to 3e\+38, beyond RGBE's largest"):
        write_hdr(tmp_path / "b.hdr", np.full((1, 1, 3), 3e38))
    write_hdr(tmp_path / "c.hdr", np.full((1, 1, 3), 1.69e38))  # just inside: written and read back
    np.testing.assert_allclose(read_hdr(tmp_path / "c.hdr"), 1.69e38, rtol=2**-8)


@st.composite
def pfm_edit(draw, seed: bytes):
    if draw(st.booleans()):
        return mutate(seed, draw(BYTE_EDITS))
    magic = draw(st.sampled_from(["PF", "Pf", "PF", "P6"]))
    scale = draw(st.sampled_from(["-1.0", "1.0", "0", "nan", "-inf", "x"]))
    body = seed[seed.index(b"-1.0\n") + 5:]
    return f"{magic}\n{draw(HUGE)} {draw(HUGE)}\n{scale}\n".encode() + body


@_fuzz(100)
@given(data=st.data())
def test_pfm_reader(tmp_path, small_limits, data):
    write_pfm(tmp_path / "seed.pfm", np.random.default_rng(2).uniform(0, 1, (5, 7, 3)))
    path = tmp_path / "f.pfm"
    path.write_bytes(data.draw(pfm_edit((tmp_path / "seed.pfm").read_bytes())))
    img = read_or_refuse(read_pfm, path)
    if img is not None:
        assert img.dtype == np.float32 and img.shape[0] * img.shape[1] <= SMALL_PIXELS


def _chunks(data: bytes) -> list[tuple[int, bytes, bytes]]:
    """(offset, type, payload) of each PNG chunk of a valid file."""
    out, i = [], 8
    while i < len(data):
        n = struct.unpack(">I", data[i:i + 4])[0]
        out.append((i, data[i + 4:i + 8], data[i + 8:i + 8 + n]))
        i += 12 + n
    return out


def _chunk(kind: bytes, payload: bytes) -> bytes:
    return struct.pack(">I", len(payload)) + kind + payload + struct.pack(">I", zlib.crc32(kind + payload))


@st.composite
def png_edit(draw, seed: bytes):
    """Byte edits; or, behind a mended CRC (so the decoder reaches them): IHDR's size or depth edited, or the
    IDAT payload edited (corrupt zlib data)."""
    kind = draw(st.sampled_from(["bytes", "ihdr", "idat", "idat"]))
    if kind == "bytes":
        return mutate(seed, draw(BYTE_EDITS))
    chunks = _chunks(seed)
    out = seed[:8]
    for _, typ, payload in chunks:
        if typ == b"IHDR" and kind == "ihdr":
            w, h = draw(HUGE) % 2**32, draw(HUGE) % 2**32
            depth, colour = draw(st.sampled_from([1, 2, 4, 8, 16, 3])), draw(st.sampled_from([0, 2, 3, 4, 6, 7]))
            payload = struct.pack(">IIBB", w, h, depth, colour) + payload[10:]
        elif typ == b"IDAT" and kind == "idat":
            payload = mutate(payload, draw(BYTE_EDITS))
        out += _chunk(typ, payload)
    return out


@_fuzz(150)
@given(depth16=st.booleans(), data=st.data())
def test_png_reader(tmp_path, small_limits, depth16, data):
    rng = np.random.default_rng(3)
    top, dtype = (65535, np.uint16) if depth16 else (255, np.uint8)
    img = rng.integers(0, top, (6, 9, 3), endpoint=True).astype(dtype)
    write_png(tmp_path / "seed.png", img)
    path = tmp_path / "f.png"
    path.write_bytes(data.draw(png_edit((tmp_path / "seed.png").read_bytes())))
    out = read_or_refuse(read_png, path)
    if out is not None:
        assert out.ndim == 3 and out.shape[0] * out.shape[1] <= SMALL_PIXELS


def test_png_with_corrupt_zlib_data_is_named(tmp_path):
    write_png(tmp_path / "a.png", np.full((4, 4, 3), 7, np.uint8))
    data = (tmp_path / "a.png").read_bytes()
    out = data[:8]
    for _, typ, payload in _chunks(data):
        out += _chunk(typ, payload[:2] + bytes(b ^ 0xFF for b in payload[2:]) if typ == b"IDAT" else payload)
    (tmp_path / "a.png").write_bytes(out)
    with pytest.raises(ImageFormatError, match=r"a\.png: corrupt or truncated PNG \(error: Error -3"):
        read_png(tmp_path / "a.png")


@_fuzz(60)
@given(ops=BYTE_EDITS)
def test_texture_reader_jpeg(tmp_path, small_limits, ops):
    from PIL import Image

    rng = np.random.default_rng(4)
    Image.fromarray(rng.integers(0, 255, (8, 12, 3), endpoint=True).astype(np.uint8)).save(tmp_path / "seed.jpg")
    path = tmp_path / "f.jpg"
    path.write_bytes(mutate((tmp_path / "seed.jpg").read_bytes(), ops))
    out = read_or_refuse(read_texture, path)
    if out is not None:
        assert out.dtype == np.float32 and np.all(np.isfinite(out))


# ------------------------------------------------------------------- folders

def _copy_and_edit(pristine: Path, work: Path, name: str, content: bytes) -> Path:
    if work.exists():
        shutil.rmtree(work)
    shutil.copytree(pristine, work)
    (work / name).write_bytes(content)
    return work


@st.composite
def folder_edit(draw, pristine: Path, json_files: tuple[str, ...], binary_files: tuple[str, ...],
                binary_edit=None):
    """(file name, new bytes): a JSON file of the folder edited (json_edit) or a binary one (byte edits, or
    ``binary_edit`` if given)."""
    name = draw(st.sampled_from(json_files + binary_files))
    if name in json_files:
        return name, draw(json_edit(json.loads((pristine / name).read_text())))
    seed = (pristine / name).read_bytes()
    return name, draw(binary_edit(seed)) if binary_edit is not None else mutate(seed, draw(BYTE_EDITS))


@pytest.fixture(scope="module")
def capture_folder(tmp_path_factory):
    folder = tmp_path_factory.mktemp("capture") / "cap"
    rng = np.random.default_rng(5)
    cams = [stage.look_at((0.0, 0.0, 500.0), width=3, height=2), stage.look_at((500.0, 0.0, 0.0), width=3, height=2)]
    write_capture(folder, rng.uniform(0, 1, (2, 4, 6, 3)).astype(np.float32), stage.fibonacci_sphere(4), cams,
                  valid=rng.uniform(size=(2, 4, 6)) > 0.2, metadata={"units": "relative"}, sample_shape=(2, 3))
    return folder


@_fuzz(80)
@given(data=st.data())
def test_capture_folder_reader(tmp_path, small_limits, capture_folder, data):
    exrs = tuple(str(p.relative_to(capture_folder)) for p in sorted(capture_folder.rglob("*.exr"))[:3])
    name, content = data.draw(folder_edit(capture_folder, ("capture.json", "rig.json", "cameras.json"), exrs,
                                          exr_edit))
    folder = _copy_and_edit(capture_folder, tmp_path / "cap", name, content)

    def read(f):
        cap = read_capture(f)
        reader = open_capture(f)
        reader.stage_rig(), reader.stage_cameras()  # stage's readers of rig.json and cameras.json: ValueError
        return cap

    out = read_or_refuse(read, folder, stage_reader=True)
    if out is not None:
        assert np.all(np.isfinite(out.radiance)) and np.all(out.radiance >= 0)


def test_capture_json_reported_failures(tmp_path, capture_folder):
    """The reported capture.json failures, each now an ImageFormatError naming the file and the field."""
    info = json.loads((capture_folder / "capture.json").read_text())
    cases = [([1, 2], "must be a JSON object, got list"), ({**info, "version": "2"}, "field 'version'"),
             ({**info, "metadata": [1, 2]}, "field 'metadata' must be a JSON object"),
             ({**info, "files": "{view}/{light}/{foo}.exr"}, "field 'files'"),
             ({**info, "files": "{light:99999999}"}, "field 'files'.*width of 1000"),
             ({**info, "sample_shape": [100000, 100000]}, "field 'sample_shape' declares 100000x100000")]
    for doc, pattern in cases:
        folder = _copy_and_edit(capture_folder, tmp_path / "cap", "capture.json", json.dumps(doc).encode())
        with pytest.raises(ImageFormatError, match=r"capture\.json: " + pattern):
            read_capture(folder)


@pytest.fixture(scope="module")
def photo_folder(tmp_path_factory):
    folder = tmp_path_factory.mktemp("photos") / "ph"
    rng = np.random.default_rng(6)
    cams = [stage.look_at((0.0, 0.0, 500.0), width=4, height=3)]
    write_photo_capture(folder, [rng.uniform(0, 0.9, (4, 3, 4, 3))], stage.fibonacci_sphere(4), cams, fmt="png",
                        encoding="srgb", masks=[np.ones((3, 4), bool)], saturation=0.99)
    return folder


@_fuzz(60)
@given(data=st.data())
def test_photo_capture_reader(tmp_path, small_limits, photo_folder, data):
    pngs = ("cam000/l000.png", "cam000/mask.png")
    name, content = data.draw(folder_edit(photo_folder, ("capture.json", "rig.json", "cameras.json"), pngs,
                                          png_edit))
    folder = _copy_and_edit(photo_folder, tmp_path / "ph", name, content)
    out = read_or_refuse(lambda f: [read_photo_capture(f).read_view(0)], folder, stage_reader=True)
    if out is not None:
        assert np.all(np.isfinite(out[0].radiance))


@pytest.fixture(scope="module")
def map_set(tmp_path_factory):
    import relight
    from tests.scenes import plane

    surface = stage.texel_samples(plane(size=100.0, n=2), 4)
    maps = relight.material_maps(surface, rho_d=np.full((surface.num_samples, 3), 0.5),
                                 rho_s=np.full((surface.num_samples, 1), 0.04))
    return write_maps(tmp_path_factory.mktemp("maps") / "set", maps, surface)


@_fuzz(60)
@given(data=st.data())
def test_map_set_reader(tmp_path, small_limits, map_set, data):
    # Every field of maps.json is fuzzed (test_map_set_version_field below pins 'version' too).
    doc = json.loads((map_set / "maps.json").read_text())
    name = data.draw(st.sampled_from(["maps.json", "albedo.exr", "normal.exr", "coverage.exr"]))
    if name == "maps.json":
        path = data.draw(st.sampled_from(_paths(doc)[1:]))
        content = json.dumps(_replace(doc, path, data.draw(JSON_VALUE), data.draw(st.booleans()))).encode()
    else:
        content = data.draw(exr_edit((map_set / name).read_bytes()))
    folder = _copy_and_edit(map_set, tmp_path / "set", name, content)
    read_or_refuse(read_maps, folder)


@pytest.mark.parametrize("version", ["abc", [1]])
def test_map_set_version_field(tmp_path, map_set, version):
    doc = json.loads((map_set / "maps.json").read_text())
    folder = _copy_and_edit(map_set, tmp_path / "set", "maps.json", json.dumps({**doc, "version": version}).encode())
    with pytest.raises(ImageFormatError, match="maps.json"):
        read_maps(folder)


@pytest.fixture(scope="module")
def diligent_folder(tmp_path_factory):
    folder = tmp_path_factory.mktemp("diligent") / "objPNG"
    folder.mkdir()
    from scipy.io import savemat

    rng = np.random.default_rng(7)
    dirs = rng.normal(size=(3, 3))
    dirs[:, 2] = np.abs(dirs[:, 2]) + 1
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    np.savetxt(folder / "light_directions.txt", dirs, fmt="%.6f")
    np.savetxt(folder / "light_intensities.txt", rng.uniform(0.5, 2, (3, 3)), fmt="%.6f")
    names = [f"{i + 1:03d}.png" for i in range(3)]
    (folder / "filenames.txt").write_text("\n".join(names) + "\n")
    for n in names:
        write_png(folder / n, rng.integers(0, 65535, (5, 6, 3)).astype(np.uint16))
    write_png(folder / "mask.png", np.full((5, 6), 255, np.uint8))
    normals = rng.normal(size=(5, 6, 3))
    savemat(folder / "Normal_gt.mat", {"Normal_gt": normals / np.linalg.norm(normals, axis=-1, keepdims=True)})
    return folder


@pytest.mark.parametrize("compressed", [False, True])
def test_normal_gt_reader_agrees_with_scipy_and_bounds_declared_sizes(tmp_path, diligent_folder, compressed):
    """The bounded MAT v5 reader that replaced scipy.io.loadmat (whose C parser segfaulted on a mutated
    Normal_gt.mat in a longer fuzz run) returns what scipy wrote, bit for bit, past other variables (a
    large one skipped without being inflated); a declared size other than the images' is refused."""
    from scipy.io import savemat

    folder = _copy_and_edit(diligent_folder, tmp_path / "objPNG", "filenames.txt",
                            (diligent_folder / "filenames.txt").read_bytes())
    rng = np.random.default_rng(8)
    normals = rng.normal(size=(5, 6, 3))
    normals /= np.linalg.norm(normals, axis=-1, keepdims=True)
    savemat(folder / "Normal_gt.mat", {"big": rng.normal(size=(400, 400)), "note": "x", "Normal_gt": normals},
            do_compression=compressed)
    np.testing.assert_array_equal(read_diligent(folder).normals_gt, normals.astype(np.float32))
    savemat(folder / "Normal_gt.mat", {"Normal_gt": np.zeros((5, 7, 3))}, do_compression=compressed)
    with pytest.raises(ImageFormatError, match=r"Normal_gt\.mat: .*Normal_gt has shape \(5, 7, 3\), expected "
                                               r"\(5, 6, 3\)"):
        read_diligent(folder)
    data = bytearray((folder / "Normal_gt.mat").read_bytes())
    struct.pack_into("<I", data, 132, 2**31)  # the first element declares 2 GiB
    (folder / "Normal_gt.mat").write_bytes(bytes(data))
    with pytest.raises(ImageFormatError, match=r"Normal_gt\.mat: not a readable MAT-file .*overruns the file"):
        read_diligent(folder)


@st.composite
def text_edit(draw, seed: bytes):
    """Byte edits, or one value of a text table replaced by a token ('abc', 'nan', '1e400', '../x.png', ...)."""
    if draw(st.booleans()):
        return mutate(seed, draw(BYTE_EDITS))
    tokens = seed.split()
    i = draw(st.integers(0, len(tokens) - 1))
    tokens[i] = draw(st.sampled_from([b"abc", b"nan", b"inf", b"1e400", b"-1", b"0", b"../x.png", b"/etc/passwd",
                                      b"1 2", b"\xff\xfe"]))
    return b"\n".join(tokens)


@_fuzz(100)
@given(data=st.data())
def test_diligent_reader(tmp_path, small_limits, diligent_folder, data):
    name = data.draw(st.sampled_from(["light_directions.txt", "light_intensities.txt", "filenames.txt", "001.png",
                                      "mask.png", "Normal_gt.mat", "Normal_gt.mat"]))
    seed = (diligent_folder / name).read_bytes()
    edit = {".txt": text_edit, ".png": png_edit}.get(Path(name).suffix, _byte_edit)
    folder = _copy_and_edit(diligent_folder, tmp_path / "objPNG", name, data.draw(edit(seed)))
    out = read_or_refuse(read_diligent, folder)
    if out is not None:
        assert np.all(np.isfinite(out.images)) and (out.normals_gt is None or np.all(np.isfinite(out.normals_gt)))


# ------------------------------------------------------- stage's JSON readers

@_fuzz(120)
@given(data=st.data())
def test_rig_json_readers(tmp_path, small_limits, data):
    rig = stage.fibonacci_sphere(6, near_field=True)
    doc = {**stage.rig_to_dict(rig), "subsets": {"front": [0, 1, 2]}, "calibration": [1.0, 0.9, 1.1]}
    path = tmp_path / "rig.json"
    path.write_bytes(data.draw(json_edit(doc)))
    for read in (stage.load_rig, stage.load_rig_file, stage.rig_file_subsets):
        out = read_or_refuse(read, path, stage_reader=True)
        if isinstance(out, stage.Rig):
            assert np.all(np.isfinite(np.asarray(out.intensity))) and np.any(np.asarray(out.intensity) > 0)


@_fuzz(60)
@given(suffix=st.sampled_from([".npy", ".txt"]), data=st.data())
def test_rig_table_readers(tmp_path, small_limits, suffix, data):
    pos = np.asarray(stage.fibonacci_sphere(6).position, np.float64) / 10.0
    seed = tmp_path / f"seed{suffix}"
    np.save(seed, pos) if suffix == ".npy" else np.savetxt(seed, pos)
    path = tmp_path / f"rig{suffix}"
    edit = (_byte_edit if suffix == ".npy" else text_edit)(seed.read_bytes())
    path.write_bytes(data.draw(edit))
    read_or_refuse(lambda p: stage.load_rig_file(p, units="cm", up="+y"), path, stage_reader=True)


def test_npy_declaring_a_huge_table_is_refused(tmp_path):
    path = tmp_path / "big.npy"
    np.save(path, np.ones((4, 3)))
    data = path.read_bytes().replace(b"(4, 3)", b"(10000000000, 3)")
    path.write_bytes(data)
    tracemalloc.start()
    try:
        with pytest.raises(ValueError, match=r"big\.npy: not a readable \.npy array"):
            stage.load_rig_file(path, units="mm", up="+y")
        assert tracemalloc.get_traced_memory()[1] < 2**24
    finally:
        tracemalloc.stop()


@_fuzz(120)
@given(bare_list=st.booleans(), data=st.data())
def test_camera_json_reader(tmp_path, small_limits, bare_list, data):
    cams = [stage.look_at((0.0, 0.0, 500.0), width=8, height=6),
            stage.orthographic((0.0, 500.0, 1.0), width=8, height=8)]
    doc = {"convention": "opencv", "units": "mm", "cameras": [stage.camera_to_dict(c, f"c{i}") for i, c in
                                                              enumerate(cams)]}
    path = tmp_path / "cameras.json"
    path.write_bytes(data.draw(json_edit(doc["cameras"] if bare_list else doc)))
    out = read_or_refuse(stage.load_cameras, path, stage_reader=True)
    for cam in out or ():
        assert cam.width * cam.height <= SMALL_PIXELS and float(cam.K[0, 0]) > 0 and float(cam.K[1, 1]) > 0


# ------------------------------------------------------------------- meshes

_OBJ = b"""v 0 0 0
v 10 0 0
v 0 10 0
v 10 10 0
vt 0 0
vt 1 0
vt 0 1
vt 1 1
vn 0 0 1
f 1/1/1 2/2/1 3/3/1
f 2/2/1 4/4/1 3/3/1
"""


@st.composite
def obj_edit(draw):
    """Byte edits, or one number of the OBJ replaced by a token (nan, inf, 1e35, -1, 99, abc)."""
    if draw(st.booleans()):
        return mutate(_OBJ, draw(BYTE_EDITS))
    tokens = re.split(rb"([ /\n])", _OBJ)
    numbers = [i for i, t in enumerate(tokens) if re.fullmatch(rb"-?\d+", t)]
    i = draw(st.sampled_from(numbers))
    tokens[i] = draw(st.sampled_from([b"nan", b"inf", b"-inf", b"1e35", b"-1", b"0", b"99", b"abc", b"1e400"]))
    return b"".join(tokens)


def _ply_bytes(tmp: Path) -> bytes:
    import trimesh

    mesh = trimesh.Trimesh(np.array([[0, 0, 0], [10, 0, 0], [0, 10, 0], [10, 10, 0]], float), [[0, 1, 2], [1, 3, 2]],
                           process=False)
    mesh.export(tmp / "seed.ply")
    return (tmp / "seed.ply").read_bytes()


@st.composite
def ply_edit(draw, seed: bytes):
    """Byte edits, or an element count in the header set to a random (often huge) number."""
    if draw(st.booleans()):
        return mutate(seed, draw(BYTE_EDITS))
    which = draw(st.sampled_from([b"vertex", b"face"]))
    line = b"element " + which + b" " + str(draw(HUGE)).encode()
    return re.sub(rb"element " + which + rb" \d+", lambda _: line, seed)


@_fuzz(100)
@given(data=st.data())
def test_mesh_reader_obj(tmp_path, small_limits, data):
    path = tmp_path / "m.obj"
    path.write_bytes(data.draw(obj_edit()))
    out = read_or_refuse(stage.load_mesh, path, stage_reader=True)
    if out is not None:
        assert np.all(np.isfinite(out.vertices)) and np.all(np.abs(out.vertices) <= stage._mesh.MAX_COORDINATE_MM)
        assert out.uv is None or np.all(np.isfinite(out.uv))
        assert np.all(np.isfinite(out.normals)) and out.faces.max() < len(out.vertices)


@_fuzz(100)
@given(data=st.data())
def test_mesh_reader_ply(tmp_path, small_limits, data):
    path = tmp_path / "m.ply"
    path.write_bytes(data.draw(ply_edit(_ply_bytes(tmp_path))))
    out = read_or_refuse(stage.load_mesh, path, stage_reader=True)
    if out is not None:
        assert np.all(np.isfinite(out.vertices)) and out.faces.max() < len(out.vertices)


# ------------------------------------------------------------ random bytes

_READERS = {".exr": read_exr, ".hdr": read_hdr, ".pfm": read_pfm, ".png": read_png, ".jpg": read_texture}


@_fuzz(150)
@given(suffix=st.sampled_from(sorted(_READERS) + [".obj", ".ply", ".json"]),
       head=st.sampled_from([b"", b"v/1\x01", b"#?RADIANCE\n", b"PF\n", b"\x89PNG\r\n\x1a\n", b"\xff\xd8\xff",
                             b"ply\nformat binary_little_endian 1.0\n", b"v 1 2 3\n", b"{"]),
       body=st.binary(max_size=300))
def test_random_bytes(tmp_path, small_limits, suffix, head, body):
    path = tmp_path / f"f{suffix}"
    path.write_bytes(head + body)
    if suffix in _READERS:
        read_or_refuse(_READERS[suffix], path)
    elif suffix == ".json":
        for read in (stage.load_rig, stage.load_cameras, stage.load_rig_file):
            read_or_refuse(read, path, stage_reader=True)
    else:
        read_or_refuse(stage.load_mesh, path, stage_reader=True)
