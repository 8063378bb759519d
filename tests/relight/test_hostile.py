"""The hostile-input suite (issue 29): inputs a careless user or an attacker makes, each class held by at least one
case, run by the installed command line in one process under a 3 GiB address-space limit (``resource.setrlimit``),
so that a regression that allocates what a size asks for fails its case instead of taking the machine down.

Classes held here: sizes and counts from flags and files checked against stated limits before any allocation
(docs/reliability.md, "Sizes and counts"); JSON nested past the parser's recursion limit, in a manifest of --out and
in a viewed folder; a file name that is not UTF-8 in a viewed folder; something that is not a regular file (a FIFO)
where a file is read; a finite but absurd angle; a non-finite output image; an out-of-memory failure reported as
one line. Held elsewhere: names from files as path
components (test_cli_photos.py), the viewer's escaping and embed rule (test_view_escaping.py), store chunks
(test_capture_store.py), photo exposure overflow (test_cli_photos.py)."""

import json
import os
import subprocess
import sys

import numpy as np
import pytest

from relight.cli import main

LIMIT_BYTES = 3 << 30

# One process for every case: the limit is set first, then each argv runs through relight.cli.main with its
# stderr captured; one JSON line per case (exit code, stderr).
_RUNNER = """
import contextlib, io, json, resource, sys
resource.setrlimit(resource.RLIMIT_AS, ({limit}, {limit}))
from relight.cli import main
for argv in json.loads(sys.argv[1]):
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        try:
            rc = main(argv)
        except BaseException as exc:  # a raw exception is a failure of the case, reported as such
            rc, err = 99, io.StringIO(f"RAW {{type(exc).__name__}}: {{exc}}")
    print(json.dumps({{"argv": argv, "rc": rc, "err": err.getvalue()}}), flush=True)
"""


@pytest.fixture(scope="module")
def hostile(tmp_path_factory):
    root = tmp_path_factory.mktemp("hostile")
    # A rig table of 70000 directions (beyond stage.MAX_LIGHTS): the Voronoi partition of 2 million asked for
    # 29 TiB; this one must be refused by its count.
    rng = np.random.default_rng(0)
    d = rng.normal(size=(70000, 3))
    np.save(root / "big_rig.npy", d / np.linalg.norm(d, axis=1, keepdims=True))
    # An --out holding a relight-set.json nested 100000 deep (json raised RecursionError, a raw traceback).
    (root / "deep_out").mkdir()
    (root / "deep_out" / "relight-set.json").write_text("[" * 100000 + "]" * 100000)
    # A viewed folder whose settings.json nests past the parser, beside a report.md holding NUL bytes.
    (root / "view").mkdir()
    (root / "view" / "settings.json").write_text('{"a":' * 100000 + "1" + "}" * 100000)
    (root / "view" / "report.md").write_text("# report\n\x00\x00 | a\n|---|\n")
    # ... and a file whose name is not UTF-8 (the page failed with "surrogates not allowed", naming no file).
    (root / "view" / os.fsdecode(b"bad\xff\xfe.png")).write_bytes(b"\x89PNG\r\n\x1a\n")
    # A FIFO given as an environment map (it said "no such HDR file"; reading it would hang).
    os.mkfifo(root / "env.hdr")
    sim = ["simulate", "--resolution", "8", "--image-size", "16", "--quiet", "--no-index"]
    render = ["render", str(root / "cap"), "--image-size", "16", "--quiet", "--no-index"]
    cases = {
        "capture": [*sim, "--rig", "dome:12", "--out", str(root / "cap")],
        "fifo_env": [*render, "--envmap", str(root / "env.hdr"), "--out", str(root / "r0")],
        "rotate_huge": [*render, "--rotate", "1e308", "--out", str(root / "r1")],
        "rotate_same": [*render, "--rotate", str(1e308 % 360.0), "--out", str(root / "r2")],
        "dome": [*sim, "--rig", "dome:1000000000", "--out", str(root / "s1")],
        "resolution": ["simulate", "--rig", "dome:12", "--resolution", "100000", "--quiet", "--out", str(root / "s2")],
        "image_size": [*sim, "--rig", "dome:12", "--image-size", "1000000", "--out", str(root / "s3")],
        "rig_file": [*sim, "--rig", str(root / "big_rig.npy"), "--rig-units", "directions", "--out",
                     str(root / "s4")],
        "cameras": ["demo", "--cameras", "100000", "--quiet", "--out", str(root / "d")],
        "frames": ["view", str(root / "view"), "--frames", "100000"],
        "deep_out": [*sim, "--rig", "dome:12", "--out", str(root / "deep_out")],
        "deep_view": ["view", str(root / "view"), "--frames", "2", "--size", "32"],
    }
    code = _RUNNER.format(limit=LIMIT_BYTES)
    run = subprocess.run([sys.executable, "-c", code, json.dumps(list(cases.values()))], capture_output=True,
                         text=True, timeout=300)
    assert run.returncode == 0, run.stderr[-3000:]
    results = [json.loads(line) for line in run.stdout.splitlines() if line.startswith("{")]
    assert [r["argv"] for r in results] == list(cases.values()), run.stderr[-3000:]
    return root, dict(zip(cases, results, strict=True))


@pytest.mark.parametrize("case, message", [
    ("dome", "--rig dome:1000000000: a dome has at most 65536 lights"),
    ("resolution", "--resolution 100000: must be at most 8192"),
    ("image_size", "--image-size 1000000: must be at most 16384"),
    ("rig_file", "70000 lights; a rig has 1 to 65536 (stage.MAX_LIGHTS)"),
    ("cameras", "--cameras 100000: must be at most 64"),
    ("frames", "--frames 100000: must be at most 720"),
    ("deep_out", "not the output of an earlier `relight simulate`"),
    ("fifo_env", "env.hdr: is a FIFO (named pipe), not a regular file (HDR file expected)"),
])
def test_a_size_or_file_beyond_its_limit_is_one_named_error(hostile, case, message):
    """Each ends with exit 1 and the command's one-line error naming the flag or file and the limit, under the
    memory limit, having written nothing."""
    root, results = hostile
    r = results[case]
    assert r["rc"] == 1, r
    assert r["err"].startswith(f"relight {r['argv'][0]}: error: ") and message in r["err"], r["err"]
    assert "Traceback" not in r["err"] and len(r["err"].strip().splitlines()) == 1, r["err"]
    assert not any((root / n).exists() for n in ("s1", "s2", "s3", "s4", "d", "r0"))


def test_a_huge_rotation_is_the_rotation_it_names(hostile):
    """--rotate 1e308 (a finite float) is 1e308 mod 360 = 296 degrees, exactly: the same frame as --rotate 296,
    no overflow in the float32 trigonometry (it used to warn of one, or blame "setting 'rotation'")."""
    from relight.io import read_exr

    root, results = hostile
    assert results["capture"]["rc"] == results["rotate_huge"]["rc"] == results["rotate_same"]["rc"] == 0, results
    assert "Warning" not in results["rotate_huge"]["err"]
    huge, same = read_exr(root / "r1" / "relit.exr"), read_exr(root / "r2" / "relit.exr")
    assert np.all(np.isfinite(huge)) and np.array_equal(huge, same)


def test_a_viewed_folder_of_hostile_files_still_gets_its_page(hostile):
    """settings.json nested past the parser is read as no settings, report.md's NUL bytes are text: the page is
    written (exit 0), not an error blaming index.html."""
    root, results = hostile
    assert results["deep_view"]["rc"] == 0, results["deep_view"]
    assert (root / "view" / "index.html").is_file()


def test_running_out_of_memory_is_one_line(monkeypatch, capsys):
    """An allocation beyond the machine (numpy's MemoryError, which says how much it asked for) ends the command
    with one line and exit 1, not a traceback."""
    from relight.cli import info

    def boom(args):
        raise MemoryError("Unable to allocate 7.45 GiB for an array with shape (1000000000,) and data type float64")

    monkeypatch.setattr(info, "run", boom)
    assert main(["info", "."]) == 1
    err = capsys.readouterr().err
    assert err.startswith("relight info: error: out of memory (Unable to allocate 7.45 GiB") and "--resolution" in err


def test_a_non_finite_relit_image_is_not_written(tmp_path, monkeypatch, capsys):
    """The finite-output rule (issue 29, item 6, the class): a relit frame holding a NaN (here injected after the
    renderer, standing for any input or bug that makes one) ends `relight render` with one line naming relit.exr
    and the count, exit 1, and no relit.exr or relit.png is written."""
    from relight.render import _folder

    cap = tmp_path / "cap"
    assert main(["simulate", "--rig", "dome:12", "--resolution", "8", "--image-size", "16", "--quiet", "--no-index",
                 "--out", str(cap)]) == 0
    original = _folder._capture_views

    def poisoned(*a, **k):
        views, *rest = original(*a, **k)
        frames = views[0][0]
        frames[0] = np.array(frames[0], np.float32)
        frames[0][3, 4, 1] = np.nan
        return (views, *rest)

    monkeypatch.setattr(_folder, "_capture_views", poisoned)
    capsys.readouterr()
    assert main(["render", str(cap), "--out", str(tmp_path / "relit"), "--image-size", "16", "--no-index",
                 "--quiet"]) == 1
    err = capsys.readouterr().err
    assert "relit.exr: the relit image has 1 NaN/Inf values (first at index (3, 4, 1)); not written" in err, err
    assert not list(tmp_path.glob("relit/relit.*"))


def _declared_png(path, side: int) -> None:
    """A valid 8-bit grey PNG of side x side zero pixels, a few hundred KB: its rows compressed as a stream,
    never held whole."""
    import struct
    import zlib

    from tests.relight.test_fuzz_readers import _chunk as chunk

    z, row, parts = zlib.compressobj(9), bytes(side + 1), []
    for _ in range(side):
        parts.append(z.compress(row))
    parts.append(z.flush())
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", side, side, 8, 0, 0, 0, 0))
                     + chunk(b"IDAT", b"".join(parts)) + chunk(b"IEND", b""))


def test_a_small_png_declaring_a_huge_image_is_refused_from_its_header(tmp_path):
    """The reported case: a 261 KB PNG declaring 16384^2 pixels, given as --regions (over 90 s, 3.3 GB) or as a
    camera's mask (2.9 GB), was decoded before its size was compared with the texel grid or the camera. Now the
    header is compared first: refused within a few MB (a decode would allocate 268 MB at least)."""
    import tracemalloc

    import stage
    from relight.io import ImageFormatError, read_png, read_regions
    from tests.scenes import uv_sphere

    path = tmp_path / "huge.png"
    _declared_png(path, 16384)
    assert path.stat().st_size < 1 << 20
    surface = stage.texel_samples(uv_sphere(), 8)
    tracemalloc.start()
    with pytest.raises(ImageFormatError, match=r"huge\.png: the PNG header says 16384x16384 pixels, more than"):
        read_regions(path, surface)
    with pytest.raises(ImageFormatError, match=r"huge\.png: the PNG header says 16384x16384 pixels, expected 8x8"):
        read_png(path, shape=(8, 8))
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert peak < 16 << 20, peak
