"""Atomic writes (stage._atomic, the one implementation, public as
relight.results.atomic_* and used by every writer): a failure or a crash mid-write leaves the
old file intact and no partial file under the target name; the new file's
permissions are those of a plain open(): 0o666 less the umask, or the mode of
the file it replaces."""

import os
import stat
import subprocess
import sys
from pathlib import Path

import pytest

import relight.results
import stage._atomic
from relight.results._atomic import _umask, atomic_path, atomic_write_bytes, atomic_write_text

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture
def umask():
    """Set the process umask for one test and restore it afterwards."""
    old = os.umask(0o022)
    os.umask(old)

    def set_(mask):
        os.umask(mask)

    yield set_
    os.umask(old)


def _mode(path):
    return stat.S_IMODE(os.stat(path).st_mode)


@pytest.mark.skipif(os.name != "posix", reason="POSIX permissions")
@pytest.mark.parametrize("mask", [0o022, 0o027, 0o077, 0o002])
def test_new_file_respects_the_umask(tmp_path, umask, mask):
    umask(mask)
    assert _umask() == mask
    plain = tmp_path / "plain.bin"
    with open(plain, "wb") as fh:
        fh.write(b"x")
    atomic_write_bytes(tmp_path / "atomic.bin", lambda fh: fh.write(b"x"))
    with atomic_path(tmp_path / "by_name.exr") as tmp:  # encoders that write by name
        tmp.unlink()  # ... may recreate the file themselves
        tmp.write_bytes(b"x")
    assert _mode(tmp_path / "atomic.bin") == 0o666 & ~mask == _mode(plain)
    assert _mode(tmp_path / "by_name.exr") == 0o666 & ~mask


@pytest.mark.skipif(os.name != "posix", reason="POSIX permissions")
def test_replacing_keeps_the_old_files_mode(tmp_path, umask):
    umask(0o022)
    path = tmp_path / "image.hdr"
    path.write_bytes(b"old")
    os.chmod(path, 0o640)
    atomic_write_bytes(path, lambda fh: fh.write(b"new"))
    assert path.read_bytes() == b"new"
    assert _mode(path) == 0o640  # as open(path, "w") would leave it


def test_exception_mid_write_leaves_old_file_and_no_temporary(tmp_path):
    path = tmp_path / "image.pfm"
    path.write_bytes(b"old contents")

    def half_then_fail(fh):
        fh.write(b"partial")
        fh.flush()
        raise RuntimeError("encoder failed")

    with pytest.raises(RuntimeError, match="encoder failed"):
        atomic_write_bytes(path, half_then_fail)
    assert path.read_bytes() == b"old contents"
    assert sorted(os.listdir(tmp_path)) == ["image.pfm"]


def test_crash_mid_write_leaves_old_file_intact(tmp_path):
    # A process that dies without unwinding (os._exit: no finally, no cleanup)
    # in the middle of writing: the target still holds the old bytes; only a
    # hidden temporary file may remain, never a partial file under the name.
    path = tmp_path / "capture.exr"
    path.write_bytes(b"old contents")
    code = (
        "import os, sys\n"
        "from relight.results import atomic_write_bytes\n"
        "def w(fh):\n"
        "    fh.write(b'partial'); fh.flush(); os._exit(3)\n"
        "atomic_write_bytes(sys.argv[1], w)\n"
    )
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    r = subprocess.run([sys.executable, "-c", code, str(path)], env=env, cwd=ROOT)
    assert r.returncode == 3
    assert path.read_bytes() == b"old contents"
    left = sorted(set(os.listdir(tmp_path)) - {"capture.exr"})
    assert all(n.startswith(".capture.exr.") and n.endswith(".tmp.exr") for n in left), left


def test_missing_folder_is_a_clear_error(tmp_path):
    with pytest.raises(FileNotFoundError, match="does not exist"):
        atomic_write_bytes(tmp_path / "no" / "file.bin", lambda fh: fh.write(b"x"))


def test_one_implementation_everywhere():
    """relight.results exports stage's writer (stage writes its own rig, camera and pattern files with it)."""
    assert relight.results.atomic_path is stage._atomic.atomic_path is atomic_path
    assert relight.results.atomic_write_bytes is stage._atomic.atomic_write_bytes is atomic_write_bytes
    assert relight.results.atomic_write_text is stage._atomic.atomic_write_text is atomic_write_text


@pytest.mark.skipif(os.name != "posix", reason="POSIX permissions")
def test_every_layer_writes_with_the_umask(tmp_path, umask):
    """The writers that had their own temporary-file code (stage.save_cameras,
    stage.PackedMask.save, relight.io.write_merl) now give the permissions of a plain
    open() (mkstemp alone leaves 0o600), and leave no temporary file."""
    import numpy as np

    import stage
    from relight.io import write_merl

    umask(0o022)
    atomic_write_text(tmp_path / "note.txt", "h\u00e9llo\n")
    assert (tmp_path / "note.txt").read_text(encoding="utf-8") == "h\u00e9llo\n"
    stage.save_cameras(tmp_path / "cams.json", stage.look_at((0.0, 0.0, 1000.0)))
    stage.save_rig(tmp_path / "rig.json", stage.geodesic_dome(0))
    stage.PackedMask.pack(np.eye(9, dtype=bool)).save(tmp_path / "mask.npz")
    stage.PackedMask.pack(np.eye(3, dtype=bool)).save(tmp_path / "mask.bin")  # no .npz appended
    write_merl(tmp_path / "m.binary", np.full((3, 90, 90, 180), 0.1))
    names = sorted(os.listdir(tmp_path))
    assert names == ["cams.json", "m.binary", "mask.bin", "mask.npz", "note.txt", "rig.json"]
    for n in names:
        assert _mode(tmp_path / n) == 0o644, n
    np.testing.assert_array_equal(stage.PackedMask.load(tmp_path / "mask.bin").unpack(), np.eye(3, dtype=bool))
