"""Result sets: a command's output folder (a fit's map set with its report and
previews, a render's images, a simulated capture folder or store) written as
one unit, locked while it is written, and checked by every reader.

Writing (:func:`result_set`): the set is built in a hidden temporary sibling
``.NAME.<random>.tmp``; the manifest ``relight-set.json`` is written last (the
completion marker); then the folder is swapped into place with one
``renameat2(RENAME_EXCHANGE)`` (Linux; elsewhere two renames, the old set moved
aside first, see :func:`swap_into`) and the old set is
deleted. ``NAME`` therefore holds the complete old set or the complete new one
at every instant (with the two-rename fallback: or, for a moment, nothing). A
process killed at any point leaves ``NAME`` as it was, plus a stale sibling
that the next writer of ``NAME`` deletes (holding the lock, it knows no live
process owns it); an old set moved aside by the fallback and never replaced is
put back.

Manifest (format ``relight-result-set``, version 1)::

    {"format": "relight-result-set", "version": 1, "kind": "fit",
     "generation": "<32 hex>", "created": "<UTC ISO time>", "writer": {"pid": ..., "host": ...},
     "files": {"albedo.exr": {"size": 1234, "sha256": "<64 hex>"}, ...},
     "unhashed": ["radiance/", ...]}

``files`` lists every regular file of the set (relative POSIX paths), except
hidden top-level entries (``.parts``: a fit's resumable blocks, not part of
the result) and the ``unhashed`` prefixes (a capture store's chunks, which
its own manifest and generation id protect). A reader (:func:`open_result_set`)
refuses a folder without the manifest, a file that is listed but missing or
whose size or SHA-256 differ (old and new files mixed, or an edit), and a
folder replaced while it was read (its inode changed).

Locking (:class:`FolderLock`): ``.NAME.lock`` next to the folder (it must
survive the swap), held with ``fcntl.flock`` for the whole command and
holding ``{"pid", "host", "command", "started"}``. The kernel drops a flock
when its process dies, even by SIGKILL, so a lock file left by a dead writer
is stale by construction and is taken over; a second live writer fails at
once with :class:`FolderLockedError` naming the folder and the holder's PID.

Disk full: an ``OSError`` with ``ENOSPC`` / ``EDQUOT`` raised while a set is
built becomes :class:`NoSpaceError`, naming the file (or the set) and saying
"no space left on device"; nothing of the set is committed.
"""

from __future__ import annotations

import contextlib
import ctypes
import datetime
import errno
import hashlib
import json
import os
import secrets
import shutil
import socket
from collections.abc import Callable, Iterable, Iterator, Sequence
from pathlib import Path

import stage

from ._atomic import _umask, atomic_write_text
from ._errors import ForeignFolderError, NoSpaceError, ResultSetError, _err, edited_hint, no_space_error
from ._format import format_version
from ._lock import FolderLock, _lock_path

__all__ = ["MANIFEST", "ResultSet", "check_output_folder", "clean_stale", "commit_point", "describe_folder",
           "file_digest", "folder_mode", "is_result_set", "open_result_set", "result_set", "swap_into",
           "write_manifest"]

FORMAT = "relight-result-set"
VERSION = 1
MANIFEST = "relight-set.json"
# Injection points for tests (none is set by the library; tests set them with monkeypatch, or in a subprocess
# before the command runs). ``_on_step(name)`` is called at each named commit point (:func:`commit_point`):
# "built" (files written, no manifest), "manifest" (manifest written, not swapped), "moved" (the two-rename
# swap's old set moved aside, the new one not yet in), "swapped" (swapped in, the old set not yet deleted), and
# the points a command names itself (relight fit's "block": its first block written to OUT/.parts). A test
# kills the process there to check what a crash at that instant leaves.
_on_step: Callable[[str], None] | None = None
# False: the two-rename swap even where the OS can exchange two folders atomically (to test the fallback).
_exchange_allowed = True
_HASH_BLOCK = 1 << 20


def commit_point(name: str) -> None:
    """Mark a named commit point of a write (module comment at ``_on_step``): a no-op unless a test injected
    ``_on_step``.

    Args:
        name: the point ("built", "manifest", "moved", "swapped", or a command's own, e.g. "block").

    Returns:
        None.
    """
    if _on_step is not None:
        _on_step(str(name))


def folder_mode() -> int:
    """The permission bits of a new folder.

    Returns:
        What a plain ``mkdir`` gives: 0o777 less the umask (``mkdtemp``'s 0o700 is not what a user expects).
    """
    return 0o777 & ~_umask()

# ------------------------------------------------------------------ the manifest


def file_digest(path: str | os.PathLike) -> str:
    """The SHA-256 of a file, as a manifest lists it.

    Args:
        path: the file (read in blocks of 1 MiB).

    Returns:
        64 lowercase hex digits.
    """
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        while block := fh.read(_HASH_BLOCK):
            h.update(block)
    return h.hexdigest()


def _set_files(folder: Path, unhashed: Sequence[str]) -> Iterator[str]:
    """Relative POSIX paths of the set's regular files: not the manifest, not hidden top-level entries, not
    under an ``unhashed`` prefix."""
    for root, dirs, files in os.walk(folder):
        rel_root = Path(root).relative_to(folder)
        if rel_root == Path("."):
            dirs[:] = [d for d in dirs if not d.startswith(".")]
            files = [f for f in files if not f.startswith(".") and f != MANIFEST]
        dirs.sort()
        for f in sorted(files):
            rel = (rel_root / f).as_posix()
            if any(rel == u.rstrip("/") or rel.startswith(u if u.endswith("/") else u + "/") for u in unhashed):
                continue
            if (Path(root) / f).is_file() and not (Path(root) / f).is_symlink():
                yield rel


def write_manifest(folder: str | os.PathLike, kind: str, unhashed: Sequence[str] = (), **extra) -> dict:
    """Hash every file of a set and write its manifest ``relight-set.json`` atomically.

    Args:
        folder: the set's folder.
        kind: the set's kind (the command that writes it: "fit", "render", ...).
        unhashed: path prefixes left out (a capture store's chunks, which their own manifest protects).
        **extra: JSON-able fields stored as they are.

    Returns:
        The manifest (module docstring), as written.
    """
    folder = Path(folder)
    files = {rel: {"size": (folder / rel).stat().st_size, "sha256": file_digest(folder / rel)}
             for rel in _set_files(folder, unhashed)}
    doc = {"format": FORMAT, "version": VERSION, "kind": str(kind), "generation": secrets.token_hex(16),
           "created": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
           "writer": {"pid": os.getpid(), "host": socket.gethostname()},
           "files": files, "unhashed": list(unhashed), **extra}
    atomic_write_text(folder / MANIFEST, json.dumps(doc, indent=1) + "\n")
    return doc


def is_result_set(folder: str | os.PathLike, kind: str | None = None) -> bool:
    """Whether a folder holds a result-set manifest; its files are not checked.

    Args:
        folder: the folder.
        kind: the kind the manifest must name, or None for any.

    Returns:
        True when ``folder/relight-set.json`` is a manifest (of ``kind``).
    """
    p = Path(folder) / MANIFEST
    try:
        doc = stage.parse_json(p.read_bytes(), p)
    except (OSError, ValueError):
        return False
    return isinstance(doc, dict) and doc.get("format") == FORMAT and (kind is None or doc.get("kind") == kind)


class ResultSet:
    """An opened result set (:func:`open_result_set`).

    Attributes:
        folder: the set's folder.
        manifest: the manifest as read.
        kind, generation: the manifest's fields.
        files: the manifest's table, relative POSIX path -> {"size", "sha256"}.

    :meth:`check` verifies files against the manifest, :meth:`unchanged` that the folder was not swapped
    since it was opened, and :meth:`add` lists new files in a finished set.
    """

    def __init__(self, folder: Path, doc: dict, ino: int):
        self.folder, self.manifest, self._ino = folder, doc, ino
        self.kind = str(doc.get("kind"))
        self.generation = str(doc.get("generation"))
        self.files: dict = dict(doc.get("files") or {})

    def check(self, names: Iterable[str | os.PathLike] | None = None) -> None:
        """Verify files against the manifest.

        Args:
            names: paths relative to the folder, or inside it; None: every listed file.

        Returns:
            None. Raises :class:`ResultSetError` naming the file when one is not listed, missing, or of
            another size or SHA-256, or when the folder was replaced.
        """
        rels = list(self.files) if names is None else [self._rel(n) for n in names]
        for rel in rels:
            path = self.folder / rel
            want = self.files.get(rel)
            if want is None:
                raise ResultSetError(f"{path}: not listed in {self.folder / MANIFEST}: written by another run than "
                                     f"the rest of the set (or added by hand); {edited_hint(self.folder)}")
            try:
                size = path.stat().st_size
            except FileNotFoundError:
                raise ResultSetError(f"{path}: listed in {self.folder / MANIFEST} but missing: an incomplete set"
                                     ) from None
            if size != want.get("size") or file_digest(path) != want.get("sha256"):
                raise ResultSetError(f"{path}: differs from the file {self.folder / MANIFEST} lists (size or "
                                     f"SHA-256): old and new files mixed, or an edit; {edited_hint(self.folder)}")
        self.unchanged()

    def unchanged(self) -> None:
        """Check that the folder was not replaced (swapped) since it was opened.

        Returns:
            None. Raises :class:`ResultSetError` if it was.
        """
        try:
            ino = os.stat(self.folder).st_ino
        except FileNotFoundError:
            ino = None
        if ino != self._ino:
            raise ResultSetError(f"{self.folder}: replaced while it was read; read it again")

    def add(self, *paths: str | os.PathLike) -> None:
        """List files just written into this finished set in its manifest.

        Each file gets its size and SHA-256; the other entries are kept as they are (not re-hashed: an
        addition never vouches for files it did not write), and the manifest is rewritten atomically. Call it
        holding the folder's lock (:class:`FolderLock`), with the files written under it, as ``relight view``
        adds its index.html to a finished output folder.

        Args:
            *paths: files inside the folder (absolute, or relative to it).

        Returns:
            None. Raises :class:`ResultSetError` if the folder was replaced since it was opened, or a path lies
            outside it or is not a regular file; FileNotFoundError for a missing file.
        """
        self.unchanged()
        path = self.folder / MANIFEST
        doc = stage.parse_json(path.read_bytes(), path, ResultSetError)
        files = doc.setdefault("files", {})
        for name in paths:
            rel = self._rel(name)
            file = self.folder / rel
            if Path(rel).is_absolute() or rel.startswith("../") or rel == MANIFEST:
                raise ResultSetError(f"{name}: not a file of the result set {self.folder}")
            if not file.is_file():
                if not file.exists():
                    raise FileNotFoundError(f"{file}: no such file (to add to {path})")
                raise ResultSetError(f"{file}: not a regular file (to add to {path})")
            files[rel] = {"size": file.stat().st_size, "sha256": file_digest(file)}
        atomic_write_text(path, json.dumps(doc, indent=1) + "\n")
        self.manifest, self.files = doc, dict(files)

    def _rel(self, name) -> str:
        p = Path(name)
        if p.is_absolute() or str(p).startswith(str(self.folder)):
            with contextlib.suppress(ValueError):
                p = p.relative_to(self.folder)
        return p.as_posix()


def open_result_set(folder: str | os.PathLike, kind: str | Sequence[str] | None = None) -> ResultSet:
    """Open the result set in a folder: its manifest read and checked.

    Args:
        folder: the set's folder.
        kind: the kind (or kinds) the set must be of; None: any.

    Returns:
        The :class:`ResultSet`; its files are verified on demand (:meth:`ResultSet.check`). Raises
        FileNotFoundError for a missing folder and :class:`ResultSetError` naming the folder for a missing
        or invalid manifest, a newer format version, or another kind.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise FileNotFoundError(f"{folder}: no such folder")
    ino = os.stat(folder).st_ino
    path = folder / MANIFEST
    if not path.is_file():
        raise ResultSetError(f"{folder}: no {MANIFEST}, so not a complete result set (an interrupted write, or not "
                             "written by this version of relight); rerun the command that made it")
    doc = stage.parse_json(path.read_bytes(), path, ResultSetError)
    if not isinstance(doc, dict) or doc.get("format") != FORMAT:
        raise ResultSetError(f"{path}: not a relight result-set manifest")
    format_version(doc, path, VERSION, error=ResultSetError)
    if not isinstance(doc.get("files"), dict):
        raise ResultSetError(f"{path}: field 'files' must be a table")
    kinds = (kind,) if isinstance(kind, str) else tuple(kind or ())
    if kinds and doc.get("kind") not in kinds:
        raise ResultSetError(f"{folder}: a {doc.get('kind')!r} result set, expected {' or '.join(kinds)}")
    return ResultSet(folder, doc, ino)


# ------------------------------------------------------------------ output folders

# What a foreign folder looks like, for the refusal message: a marker file -> its description.
_MARKERS = (("capture.json", "a capture folder"), ("relight-store.json", "a capture store"),
            ("maps.json", "a map set"), ("zarr.json", "a Zarr store"))


def describe_folder(folder: Path) -> str:
    """A short description of what a folder holds, for refusals.

    Args:
        folder: an existing folder.

    Returns:
        E.g. "a capture folder (capture.json, written by `relight simulate`)", or its first entries.
    """
    by = ""
    if is_result_set(folder):
        by = f", written by `relight {json.loads((folder / MANIFEST).read_text()).get('kind')}`"
    for name, what in _MARKERS:
        if (folder / name).is_file():
            return f"{what} ({name}{by})"
    if by:
        return f"a relight result set{by}"
    names = sorted(p.name for p in folder.iterdir())
    return f"{len(names)} entries: {', '.join(names[:5])}{', ...' if len(names) > 5 else ''}"


def check_output_folder(folder: str | os.PathLike, kind: str, accept: Sequence[str] = (),
                        keep: Sequence[str] = (), legacy=None) -> None:
    """Refuse a folder as the output of a command unless the command may replace it.

    Args:
        folder: the output folder.
        kind: the command's result-set kind.
        accept: further kinds it may replace.
        keep: hidden entries a folder may hold alone (a fit's ``.parts``).
        legacy: ``legacy(folder) -> bool``, a folder of this kind written before manifests
            (:func:`relight.results.earlier_output`).

    Returns:
        None when the folder is absent, empty, a result set of ``kind`` (or of a kind in ``accept``), holds
        only ``keep``, or passes ``legacy``. Raises :class:`ForeignFolderError` naming the folder and what
        it holds otherwise.
    """
    folder = Path(folder)
    if not (folder.exists() or folder.is_symlink()):
        return
    if not folder.is_dir() or folder.is_symlink():
        raise _err(ForeignFolderError, errno.EEXIST, f"{folder}: exists and is not a folder; refusing to replace it",
                   folder)
    entries = [p.name for p in folder.iterdir()]
    if all(e in keep for e in entries):
        return
    if is_result_set(folder, kind) or any(is_result_set(folder, k) for k in accept):
        return
    if legacy is not None and not is_result_set(folder) and legacy(folder):
        return
    raise _err(ForeignFolderError, errno.EEXIST,
               f"{folder}: exists and is {describe_folder(folder)}, not the output of an earlier `relight {kind}`; "
               "refusing to write into it (choose another --out, or move it away)", folder)


def _stale_names(folder: Path) -> list[Path]:
    """Siblings a killed writer of ``folder`` leaves: ``.NAME.*.tmp`` / ``.old`` / ``.building`` (and the
    ``..NAME.*`` of a nested folder writer)."""
    parent = folder.parent if str(folder.parent) else Path(".")
    out = []
    for p in parent.iterdir():
        n = p.name
        if not (n.startswith(f".{folder.name}.") or n.startswith(f"..{folder.name}.")) or n == _lock_path(folder).name:
            continue
        if ".tmp" in n or n.endswith((".old", ".building")):
            out.append(p)
    return sorted(out)


def clean_stale(folder: str | os.PathLike) -> list[Path]:
    """Delete what killed writers of a folder left next to it.

    Call it with the folder's lock held, so that no live writer owns them. If the folder is absent and a
    complete old set was moved aside by the two-rename swap, it is put back first.

    Args:
        folder: the output folder.

    Returns:
        The paths deleted (or restored).
    """
    folder = Path(folder)
    stale = _stale_names(folder)
    done = []
    if not folder.exists():
        for p in stale:
            if p.name.endswith(".old") and p.is_dir():
                cand = p / "set" if (p / "set").is_dir() else p
                if is_result_set(cand) or (cand / "relight-store.json").is_file() or (cand / "capture.json").is_file():
                    os.replace(cand, folder)
                    done.append(p)
                    break
    for p in stale:
        if p.is_dir() and not p.is_symlink():
            shutil.rmtree(p, ignore_errors=True)
        else:
            with contextlib.suppress(FileNotFoundError):
                p.unlink()
        if p not in done:
            done.append(p)
    return done


_RENAME_EXCHANGE = 2
_AT_FDCWD = -100


def _exchange(a: Path, b: Path) -> bool:
    """Swap ``a`` and ``b`` atomically (Linux renameat2 RENAME_EXCHANGE); False where unsupported (or when
    the injection point ``_exchange_allowed`` is False, to exercise the two-rename fallback)."""
    if not _exchange_allowed:
        return False
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        fn = libc.renameat2
    except (OSError, AttributeError):
        return False
    fn.argtypes = (ctypes.c_int, ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p, ctypes.c_uint)
    if fn(_AT_FDCWD, os.fsencode(a), _AT_FDCWD, os.fsencode(b), _RENAME_EXCHANGE) == 0:
        return True
    err = ctypes.get_errno()
    if err in (errno.EINVAL, errno.ENOSYS, errno.EOPNOTSUPP, errno.ENOTSUP):
        return False
    raise OSError(err, os.strerror(err), str(b))


def swap_into(tmp: Path, folder: Path) -> None:
    """Put a finished folder in place of another, whole.

    One atomic exchange where the OS has it (Linux ``renameat2``), else the old folder moved aside
    (``.NAME.<random>.old/set``), the new one renamed in, the old one deleted. The hidden entries of the old
    folder that the new one lacks are not carried over (see :func:`result_set`'s ``keep``).

    Args:
        tmp: the finished folder (a sibling of ``folder``, on the same file system).
        folder: where it goes (the caller has checked that it may replace what is there).

    Returns:
        None.
    """
    if not (folder.exists() or folder.is_symlink()):
        os.replace(tmp, folder)
        commit_point("swapped")
        return
    if _exchange(tmp, folder):
        commit_point("swapped")
        shutil.rmtree(tmp, ignore_errors=True)  # now the old set
        return
    aside = folder.parent / f".{folder.name}.{secrets.token_hex(6)}.old"
    aside.mkdir()
    os.replace(folder, aside / "set")
    commit_point("moved")
    try:
        os.replace(tmp, folder)
    except BaseException:
        os.replace(aside / "set", folder)
        raise
    commit_point("swapped")
    shutil.rmtree(aside, ignore_errors=True)


def _link_or_copy(src: str, dst: str) -> None:
    try:
        os.link(src, dst)
    except OSError:
        shutil.copy2(src, dst)


def _carry_over(folder: Path, tmp: Path, keep: Sequence[str]) -> None:
    """Hard-link (else copy) the entries of ``folder`` that ``tmp`` lacks into ``tmp`` (not the manifest, not
    ``keep``, which is moved later)."""
    if not folder.is_dir():
        return
    for src in folder.iterdir():
        dst = tmp / src.name
        if src.name == MANIFEST or src.name in keep or dst.exists() or dst.is_symlink():
            continue
        if src.is_symlink():
            os.symlink(os.readlink(src), dst)
        elif src.is_dir():
            shutil.copytree(src, dst, symlinks=True, copy_function=_link_or_copy)
        else:
            _link_or_copy(str(src), str(dst))


def _named_in(err: OSError, tmp: Path, folder: Path) -> OSError:
    """A full disk while the set at ``tmp`` was built, named where the file was going to be (in ``folder``)."""
    named = no_space_error(err, folder)
    if isinstance(named, NoSpaceError) and str(tmp) in str(named):
        named = _err(NoSpaceError, named.errno, str(named).replace(str(tmp), str(folder)),
                     str(named.filename).replace(str(tmp), str(folder)))
    return named


def _commit(tmp: Path, folder: Path, keep: Sequence[str]) -> None:
    """The finished set at ``tmp`` (manifest written): the umask's mode, ``keep`` moved over, swapped in."""
    os.chmod(tmp, folder_mode())
    commit_point("manifest")
    for name in keep:
        src = folder / name
        if src.exists() and not (tmp / name).exists():
            os.replace(src, tmp / name)
    swap_into(tmp, folder)


@contextlib.contextmanager
def result_set(folder: str | os.PathLike, kind: str, *, command: str | None = None, accept: Sequence[str] = (),
               keep: Sequence[str] = (), create: bool = True, unhashed: Sequence[str] = (),
               lock: bool = True, legacy=None, carry: bool = False, on_stale=None) -> Iterator[Path]:
    """Write a result set at a folder as a unit (module docstring); a context manager.

    Takes the folder's lock (:class:`FolderLock`), refuses a folder that is not of this kind
    (:func:`check_output_folder`), deletes what killed writers left (:func:`clean_stale`) and yields the
    temporary sibling to build the set in. On a normal exit the manifest is written (:func:`write_manifest`),
    the hidden entries ``keep`` of the old folder are moved into the new one, the folder mode set to 0o777
    less the umask, and the set swapped in (:func:`swap_into`); on an exception the temporary folder is
    deleted and the folder is left as it was (ENOSPC becomes :class:`NoSpaceError` naming the file).

    Args:
        folder: the output folder.
        kind: the set's kind (the manifest's "kind").
        command: recorded in the lock (default ``relight <kind>``).
        accept, keep, legacy: :func:`check_output_folder`'s.
        create: make the temporary folder (False: the body creates it, e.g. a folder writer that renames
            its own result to that name).
        unhashed: path prefixes the manifest does not hash.
        lock: take the folder's lock (False: the caller holds it).
        carry: a library writer adding its files to a user's folder (``write_maps`` into a folder holding a
            rig.json): any folder is taken, and the entries of the old folder that the new set does not
            write are hard-linked (copied where links fail) into it before the manifest, so they survive
            the swap and are listed; the originals stay in place until the swap, so a killed run loses
            nothing.
        on_stale: called with the paths :func:`clean_stale` deleted, if any.

    Returns:
        The context manager; its value is the temporary folder (a Path).
    """
    folder = Path(folder)
    parent = folder.parent if str(folder.parent) else Path(".")
    if not parent.is_dir():
        parent.mkdir(parents=True, exist_ok=True)
    holder = FolderLock(folder, command or f"relight {kind}") if lock else None
    if holder is not None:
        holder.acquire()
    try:
        if not carry:
            check_output_folder(folder, kind, accept, keep, legacy)
        elif folder.exists() and not folder.is_dir():
            raise _err(ForeignFolderError, errno.EEXIST, f"{folder}: exists and is not a folder", folder)
        stale = clean_stale(folder)
        if stale and on_stale is not None:
            on_stale(stale)
        tmp = parent / f".{folder.name}.{secrets.token_hex(6)}.tmp"
        if create:
            tmp.mkdir()
        try:
            try:
                yield tmp
                if not tmp.is_dir():
                    raise FileNotFoundError(f"{folder}: the result set was not built (no {tmp})")
                if carry:
                    _carry_over(folder, tmp, keep)
                commit_point("built")
                write_manifest(tmp, kind, unhashed)
            except OSError as err:
                named = _named_in(err, tmp, folder)
                if named is err:
                    raise
                raise named from err.__cause__ or err
            _commit(tmp, folder, keep)
        except BaseException:
            shutil.rmtree(tmp, ignore_errors=True)
            raise
    finally:
        if holder is not None:
            holder.release()
