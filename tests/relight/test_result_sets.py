"""Result sets written as a unit (relight.results): manifests checked by
the readers, mixed sets refused, output folders locked and refused when they
are not the command's own kind, the umask respected, a full disk named, and
the CLI's input checks (a 12-light dome fit, --rotate nan, a missing JAX
platform). The SIGKILL tests are in test_kill.py."""

import errno
import hashlib
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import textwrap
from pathlib import Path

import jax.numpy as jnp
import numpy as np
import pytest

import relight
import stage
from relight.cli import main
from relight.io import (
    CaptureStoreError,
    ImageFormatError,
    open_capture,
    open_capture_store,
    read_maps,
    write_capture,
    write_capture_store,
    write_maps,
)
from relight.results import (
    MANIFEST,
    FolderLock,
    FolderLockedError,
    ForeignFolderError,
    NoSpaceError,
    ResultSetError,
    WriteError,
    clean_stale,
    open_result_set,
    result_set,
    write_manifest,
    writing,
)
from relight.results import _resultset as rsm
from tests.helpers import xla_flags

from ._cli_runs import small_index

RES = 8
ENV = os.environ | {"XLA_FLAGS": xla_flags(), "RELIGHT_CACHE_DIR": "off", "JAX_PLATFORMS": "cpu"}


@pytest.fixture(scope="module")
def surface():
    return stage.texel_samples(stage.load_head(), RES)


def _maps(surface, value: float):
    return relight.material_maps(surface, rho_d=np.full((surface.num_samples, 3), value), rho_s=0.04, alpha=0.3)


def test_manifest_lists_every_file_with_its_sha256(tmp_path):
    (tmp_path / "a.txt").write_text("alpha")
    (tmp_path / "sub").mkdir()
    (tmp_path / "sub" / "b.bin").write_bytes(b"\x00\x01")
    (tmp_path / ".parts").mkdir()
    (tmp_path / ".parts" / "part_0.npz").write_bytes(b"resumable, not part of the set")
    (tmp_path / "chunks").mkdir()
    (tmp_path / "chunks" / "c0").write_bytes(b"zz")
    doc = write_manifest(tmp_path, "test", unhashed=("chunks/",))
    assert set(doc["files"]) == {"a.txt", "sub/b.bin"}  # hidden top-level entries and unhashed prefixes left out
    assert doc["files"]["a.txt"] == {"size": 5, "sha256": hashlib.sha256(b"alpha").hexdigest()}
    assert json.loads((tmp_path / MANIFEST).read_text()) == doc
    rs = open_result_set(tmp_path, "test")
    rs.check()  # every listed file as listed
    (tmp_path / "sub" / "b.bin").write_bytes(b"\x00\x02")  # same size, other bytes
    with pytest.raises(ResultSetError, match=r"b\.bin: differs"):
        rs.check(["sub/b.bin"])
    (tmp_path / "a.txt").unlink()
    with pytest.raises(ResultSetError, match=r"a\.txt: listed .* but missing"):
        rs.check(["a.txt"])
    with pytest.raises(ResultSetError, match="not listed"):
        rs.check(["new.txt"])
    with pytest.raises(ResultSetError, match="expected fit"):
        open_result_set(tmp_path, "fit")


def test_a_folder_swapped_while_read_is_refused(tmp_path):
    with result_set(tmp_path / "set", "test") as tmp:
        (tmp / "x.txt").write_text("old")
    rs = open_result_set(tmp_path / "set")
    with result_set(tmp_path / "set", "test") as tmp:
        (tmp / "x.txt").write_text("new")
    with pytest.raises(ResultSetError, match="replaced while it was read"):
        rs.unchanged()
    assert (tmp_path / "set" / "x.txt").read_text() == "new"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["set"]  # no temporary, old or lock file left


def test_a_file_added_to_a_finished_set_is_listed(tmp_path):
    """ResultSet.add: a file written into a finished set (under its lock) joins the manifest, which keeps the
    other entries as they were; the set then verifies whole."""
    with result_set(tmp_path / "set", "test") as tmp:
        (tmp / "x.txt").write_text("x")
    folder = tmp_path / "set"
    with FolderLock(folder, "relight view"):
        (folder / "index.html").write_text("<html></html>")
        rs = open_result_set(folder, "test")
        rs.add(folder / "index.html")
    assert rs.files["index.html"] == {"size": 13, "sha256": hashlib.sha256(b"<html></html>").hexdigest()}
    again = open_result_set(folder, "test")
    assert set(again.files) == {"x.txt", "index.html"} and again.generation == rs.generation
    again.check()
    with pytest.raises(FileNotFoundError, match="missing.txt"):
        again.add("missing.txt")
    with pytest.raises(ResultSetError, match="not a file of the result set"):
        again.add("../elsewhere.txt")


def test_mixed_map_set_is_refused(surface, tmp_path):
    """The reported failure: a new albedo.exr beside the old maps.json and the other maps (what an in-place
    writer killed mid-set leaves). Every file is a valid map; only the manifest tells the mix apart."""
    old, new = tmp_path / "old", tmp_path / "new"
    write_maps(old, _maps(surface, 0.2), surface)
    write_maps(new, _maps(surface, 0.7), surface)
    tex, _ = read_maps(old)
    np.testing.assert_allclose(tex.albedo[tex.coverage], 0.2, rtol=1e-6)
    shutil.copy(new / "albedo.exr", old / "albedo.exr")
    # The reader's own file-format error, chained from the result set's refusal.
    with pytest.raises(ImageFormatError, match=r"albedo\.exr: differs .* mixed") as err:
        read_maps(old)
    assert isinstance(err.value.__cause__, ResultSetError)
    assert isinstance(ResultSetError("x"), ValueError)  # the CLI reports it like any bad input file
    (new / MANIFEST).unlink()  # a set without a manifest (interrupted before its last file) is no set
    with pytest.raises(ImageFormatError, match="no relight-set.json") as err:
        read_maps(new)
    assert isinstance(err.value.__cause__, ResultSetError)
    assert str(new) in str(err.value)


def test_a_mixed_capture_folder_or_store_is_refused_as_a_format_error(tmp_path):
    """A capture folder or store inside a result set whose rig.json is not the set's own: the reader's
    format error (CaptureStoreError for a store), naming the file, chained from the ResultSetError."""
    rig = stage.geodesic_dome(0)  # 12 distant lights
    radiance = np.full((1, rig.num_lights, 4, 3), 0.5, np.float32)
    cameras = stage.camera_ring(1, 1300.0, fov_deg=11.0, width=8, height=8)
    folder, store = tmp_path / "cap", tmp_path / "cap.zarr"
    write_capture(folder, radiance, rig, cameras)
    capture = stage.Capture(radiance=jnp.asarray(radiance), mask=jnp.ones(radiance.shape[:3], bool), rig=rig,
                            cameras=tuple(cameras))
    write_capture_store(store, capture)
    for path, open_it, error in ((folder, open_capture, ImageFormatError),
                                 (store, open_capture_store, CaptureStoreError)):
        write_manifest(path, "simulate")
        open_it(path)
        rig_json = next(p for p in path.rglob("rig.json"))
        rig_json.write_text(rig_json.read_text().replace("\n", "\n\n", 1))  # the same rig, other bytes
        with pytest.raises(error, match=r"rig\.json: differs") as err:
            open_it(path)
        assert isinstance(err.value.__cause__, ResultSetError)


def test_a_failed_write_leaves_the_old_set_and_nothing_else(surface, tmp_path, monkeypatch):
    out = tmp_path / "maps"
    write_maps(out, _maps(surface, 0.2), surface)
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    calls = []

    def full_disk(path, *a, **k):
        calls.append(path)
        if len(calls) == 3:  # the third map: two new files already written
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        return real(path, *a, **k)

    real = relight.io._texture_set.write_exr_channels
    monkeypatch.setattr(relight.io._texture_set, "write_exr_channels", full_disk)
    with pytest.raises(NoSpaceError) as exc:
        write_maps(out, _maps(surface, 0.7), surface)
    msg = str(exc.value)
    # Named where the file was going to be (not its temporary folder), with the reason in words.
    assert msg.startswith(f"{out / 'roughness.exr'}: no space left on device"), msg
    assert exc.value.errno == errno.ENOSPC and isinstance(exc.value, OSError)
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["maps"]


def test_an_encoder_runtime_error_on_a_full_disk_is_named(tmp_path, monkeypatch):
    """OpenEXR's bindings raise RuntimeError when the disk fills: with no free block left it is reported as
    no space, else as a write failure, both naming the file."""
    path = tmp_path / "a.exr"

    class Full:
        f_bavail = 0

    with pytest.raises(WriteError, match=r"a\.exr: cannot write \(boom\)"):
        with writing(path):
            raise RuntimeError("boom")
    monkeypatch.setattr(rsm.os, "statvfs", lambda _: Full())
    with pytest.raises(NoSpaceError, match=r"a\.exr: no space left on device"):
        with writing(path):
            raise RuntimeError("Unable to write")


def test_second_writer_is_refused_and_a_dead_writers_lock_is_taken_over(tmp_path):
    out = tmp_path / "out"
    with FolderLock(out, "relight fit"):
        with pytest.raises(FolderLockedError, match=rf"{out}: being written by another relight process \(pid "
                                                    rf"{os.getpid()} .*relight fit"):
            FolderLock(out).acquire()
        with pytest.raises(FolderLockedError):
            with result_set(out, "fit"):
                pass
    assert not (tmp_path / ".out.lock").exists()  # released and removed
    # A holder killed outright (SIGKILL) leaves its lock file; the kernel has dropped its flock.
    code = f"""
        import os, sys
        from relight.results import FolderLock
        FolderLock({str(out)!r}, "relight simulate").acquire()
        print(os.getpid(), flush=True)
        sys.stdin.read()
    """
    with subprocess.Popen([sys.executable, "-c", textwrap.dedent(code)], stdin=subprocess.PIPE,
                          stdout=subprocess.PIPE, text=True, env=ENV) as p:
        pid = int(p.stdout.readline())
        with pytest.raises(FolderLockedError, match=rf"pid {pid} .*relight simulate"):
            FolderLock(out).acquire()
        os.kill(pid, signal.SIGKILL)
        p.wait()
    assert json.loads((tmp_path / ".out.lock").read_text())["pid"] == pid  # stale lock left behind
    with result_set(out, "fit") as tmp:  # taken over
        (tmp / "x").write_text("1")
    assert (out / "x").read_text() == "1"


def test_foreign_folders_are_refused(tmp_path, capsys):
    cap = tmp_path / "cap"
    cap.mkdir()
    (cap / "capture.json").write_text("{}")
    with pytest.raises(ForeignFolderError, match=r"cap: exists and is a capture folder \(capture.json\)"):
        with result_set(cap, "render"):
            pass
    assert sorted(p.name for p in cap.iterdir()) == ["capture.json"]
    # Each command refuses another's result set, before any work.
    with result_set(tmp_path / "r", "render") as tmp:
        (tmp / "relit.exr").write_bytes(b"")
    for argv, folder, what in (
            (["render", str(tmp_path / "nowhere"), "--out", str(cap)], cap, "capture folder"),
            (["fit", str(tmp_path / "nowhere"), "--model", "ggx", "--out", str(cap)], cap, "capture folder"),
            (["fit", str(tmp_path / "nowhere"), "--model", "ggx",
              "--out", str(tmp_path / "r")], tmp_path / "r", "relight render")):
        if argv[0] == "render":
            argv = ["render", str(tmp_path / "r2src"), *argv[2:]]
            (tmp_path / "r2src").mkdir(exist_ok=True)
            (tmp_path / "r2src" / "capture.json").write_text("{}")
        assert main([*argv, "--quiet"]) == 1
        err = capsys.readouterr().err
        assert f"--out {folder}: exists and is" in err and what in err and "refusing" in err, err
    # An empty folder and one holding only a fit's resumable parts are a fit's own.
    (tmp_path / "e" / ".parts").mkdir(parents=True)
    with result_set(tmp_path / "e", "fit", keep=(".parts",)) as tmp:
        (tmp / "maps.json").write_text("{}")
    assert sorted(p.name for p in (tmp_path / "e").iterdir()) == [".parts", "maps.json", MANIFEST]


def test_leftovers_of_killed_runs_are_cleaned_and_an_old_set_put_back(tmp_path):
    out = tmp_path / "out"
    with result_set(out, "fit") as tmp:
        (tmp / "v").write_text("old")
    # What a run killed during the two-rename swap leaves: the old set aside, the new one half made.
    aside = tmp_path / ".out.abc123.old"
    aside.mkdir()
    os.replace(out, aside / "set")
    (tmp_path / ".out.def456.tmp").mkdir()
    (tmp_path / "..out.ghi.tmp.xyz.tmp").mkdir()  # a nested folder writer's own temporary
    (tmp_path / ".other.abc.tmp").mkdir()  # another folder's: not ours to touch
    done = clean_stale(out)
    assert (out / "v").read_text() == "old"  # put back
    assert len(done) == 3
    assert sorted(p.name for p in tmp_path.iterdir()) == [".other.abc.tmp", "out"]
    seen = []
    (tmp_path / ".out.x.tmp").mkdir()
    with result_set(out, "fit", on_stale=seen.append) as tmp:
        (tmp / "v").write_text("new")
    assert [p.name for p in seen[0]] == [".out.x.tmp"] and (out / "v").read_text() == "new"


def test_the_two_rename_swap_when_there_is_no_exchange(tmp_path, monkeypatch):
    monkeypatch.setattr(rsm, "_exchange", lambda a, b: False)
    for value in ("old", "new"):
        with result_set(tmp_path / "out", "fit") as tmp:
            (tmp / "v").write_text(value)
    assert (tmp_path / "out" / "v").read_text() == "new"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]


@pytest.mark.parametrize("umask", [0o022, 0o027])
def test_folders_get_the_umask_mode(tmp_path, umask):
    """A set built by a folder writer that makes its folder with mkdtemp (0o700 whatever the umask), as
    write_capture does, ends up with the mode a plain mkdir gives."""
    old = os.umask(umask)
    try:
        with result_set(tmp_path / "cap", "simulate", create=False) as tmp:
            made = tempfile.mkdtemp(dir=tmp_path)
            os.replace(made, tmp)
            (tmp / "views").mkdir()
            rsm.atomic_write_text(tmp / "capture.json", "{}")
        with result_set(tmp_path / "fit", "fit") as tmp:
            (tmp / "a").write_text("")
    finally:
        os.umask(old)
    for name in ("cap", "fit"):
        assert (tmp_path / name).stat().st_mode & 0o777 == 0o777 & ~umask, name
    assert (tmp_path / "cap" / "views").stat().st_mode & 0o777 == 0o777 & ~umask
    assert (tmp_path / "cap" / "capture.json").stat().st_mode & 0o777 == 0o666 & ~umask


# ------------------------------------------------------------------ the CLI on a 12-light dome


def test_a_deliberate_edit_is_accepted_with_relight_reseal(tmp_path, capsys):
    """A capture folder whose rig.json was edited by hand (new intensities after a recalibration): the reader's
    refusal says how to accept the edit, `relight reseal` rewrites the manifest (listing the changed file and
    recording the previous generation) and the capture then reads with the new intensities. A folder with no
    manifest is refused by reseal too, naming it."""
    rig = stage.geodesic_dome(0)
    radiance = np.full((1, rig.num_lights, 4, 3), 0.5, np.float32)
    folder = tmp_path / "cap"
    write_capture(folder, radiance, rig, stage.camera_ring(1, 1300.0, fov_deg=11.0, width=8, height=8))
    old = write_manifest(folder, "simulate", stage="test")
    rig_json = folder / "rig.json"
    doc = json.loads(rig_json.read_text())
    doc["intensities"] = (2.0 * np.asarray(doc["intensities"])).tolist()
    rig_json.write_text(json.dumps(doc))
    with pytest.raises(ImageFormatError, match=rf"rig\.json: differs.*relight reseal {folder}"):
        open_capture(folder)
    assert main(["reseal", str(folder)]) == 0
    assert capsys.readouterr().out.strip() == f"resealed {folder}/ (changed: rig.json)"
    manifest = json.loads((folder / MANIFEST).read_text())
    assert manifest["resealed"]["previous_generation"] == old["generation"] != manifest["generation"]
    assert manifest["kind"] == "simulate" and manifest["stage"] == "test"
    np.testing.assert_allclose(np.asarray(open_capture(folder).rig["intensities"]), 2.0 * np.asarray(rig.intensity),
                               rtol=1e-6)
    (tmp_path / "plain").mkdir()
    assert main(["reseal", str(tmp_path / "plain"), "--quiet"]) == 1
    assert f"{tmp_path / 'plain'}: no relight-set.json" in capsys.readouterr().err


@pytest.fixture(scope="module")
def dome12(tmp_path_factory):
    """A capture of the head under a 12-light dome: at most 6 lights see a texel, fewer than the 8 the fit
    needs, so every texel is flagged."""
    root = tmp_path_factory.mktemp("dome12")
    with small_index():
        assert main(["simulate", "--rig", "dome:12", "--resolution", str(RES), "--image-size", "16", "--out",
                     str(root / "cap"), "--quiet"]) == 0
    return root


def test_fit_of_a_12_light_dome_completes(dome12, capsys):
    out = dome12 / "maps"
    assert main(["fit", str(dome12 / "cap"), "--model", "ggx", "--out", str(out), "--quiet"]) == 0
    assert "100% of the texels are flagged" in capsys.readouterr().err
    report = json.loads((out / "report.json").read_text())
    assert report["failed_fraction"] == 1.0 and report["against_truth"] is None
    assert "no comparison against the simulated truth" in (out / "report.md").read_text()
    tex, _ = read_maps(out)  # a complete, consistent set
    assert tex.resolution == (RES, RES) and np.all(np.isfinite(tex.albedo))
    open_result_set(out, "fit").check()


@pytest.mark.parametrize("value", ["nan", "inf", "-inf"])
def test_render_refuses_a_non_finite_rotation_before_writing(dome12, capsys, value):
    out = dome12 / f"r_{value}"
    assert main(["render", str(dome12 / "cap"), f"--rotate={value}", "--out", str(out), "--quiet"]) == 1
    assert f"--rotate {float(value)}: must be a finite number" in capsys.readouterr().err
    assert not out.exists()


def test_render_full_disk_names_the_file(dome12, capsys, monkeypatch):
    import relight.io

    def full(path, *a, **k):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    # render_folder looks relight.io.write_exr up at each call, so a full disk there reaches the command.
    monkeypatch.setattr(relight.io, "write_exr", full)
    out = dome12 / "r_full"
    assert main(["render", str(dome12 / "cap"), "--out", str(out), "--image-size", "16", "--quiet"]) == 1
    err = capsys.readouterr().err
    assert f"{out / 'relit.exr'}: no space left on device" in err and "Errno" not in err, err
    assert not out.exists() and not list(dome12.glob(".r_full*"))


def test_missing_jax_platform_is_one_line_and_exit_2(tmp_path):
    r = subprocess.run([str(Path(sys.executable).parent / "relight"), "info"], env={**ENV, "JAX_PLATFORMS": "cuda"},
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 2, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "JAX_PLATFORMS=cuda" in lines[0] and "not available" in lines[0], r.stderr
    assert "Traceback" not in r.stderr


def test_missing_jax_platform_for_every_command(monkeypatch, capsys, tmp_path):
    import jax

    def broken():
        raise AssertionError

    monkeypatch.setattr(jax, "devices", broken)
    monkeypatch.setenv("JAX_PLATFORMS", "cuda")
    for argv in (["info"], ["simulate", "--out", str(tmp_path / "s")], ["fit", "x", "--out", str(tmp_path / "f")],
                 ["render", "x", "--out", str(tmp_path / "r")], ["demo", "--out", str(tmp_path / "d")]):
        assert main(argv) == 2, argv
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and f"relight {argv[0]}: error: JAX_PLATFORMS=cuda" in err[0], err
    assert not list(tmp_path.iterdir())


def test_a_commands_own_output_from_before_manifests_is_replaceable(tmp_path):
    """A folder an earlier version of the same command wrote (its settings.json names the command, no manifest)
    is still that command's to replace; another command refuses it."""
    from relight.cli._guard import CLIError
    from relight.cli._output import check_out

    old = tmp_path / "old"
    old.mkdir()
    (old / "settings.json").write_text(json.dumps({"command": "relight fit"}))
    (old / "albedo.exr").write_bytes(b"")
    assert check_out(old, "fit") == old
    with pytest.raises(CLIError, match=r"--out .*old: exists and is 2 entries: albedo.exr, settings.json, not the "
                                       r"output of an earlier `relight render`"):
        check_out(old, "render")
