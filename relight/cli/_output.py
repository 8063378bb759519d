"""A command's output folder: the result set ``--out`` (``relight.results``), its settings.json, previews and
index.html. Each function imports the library when it is called: building a parser imports no JAX."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ._flags import PREVIEW_MIN_PX
from ._guard import CLIError


def writing(path):
    """``relight.results.writing``: a context in which a failed write names ``path`` (a full disk as
    NoSpaceError)."""
    from ..results import writing as named

    return named(path)


def write_json(path, obj, indent: int = 2) -> None:
    """Reports and settings: ``relight.io.write_json`` (atomic; NaN and Inf refused), a failed write
    naming the file (a full disk as NoSpaceError)."""
    from ..io import write_json as write

    with writing(path):
        write(path, obj, indent)


def write_settings(out: Path, command: str, args, **resolved) -> None:
    """settings.json: the command, every flag as given/defaulted, and the resolved values."""
    flags = {k: v for k, v in vars(args).items() if k not in ("func", "command")}
    write_json(Path(out) / "settings.json", {"command": f"relight {command}", "flags": flags, "resolved": resolved})


def output_set(out: str | os.PathLike, command: str, quiet: int | bool = 0, keep=(), create: bool = True,
               unhashed=(), legacy=None):
    """The result set ``--out`` of ``relight <command>`` (``relight.results.result_set``): the folder
    locked (a second writer fails naming it), refused unless it is absent, empty or an earlier output of this
    command (``relight.results.earlier_output``), built in a temporary sibling (the context's value) and
    swapped in whole with its manifest on success. Leftovers of killed runs are deleted (a warning on stderr
    says which). ``keep``, ``create``, ``unhashed`` and ``legacy`` are ``result_set``'s."""
    import sys

    from ..results import earlier_output, result_set

    out = Path(out)
    if out.exists() and not out.is_dir():
        raise CLIError(f"--out {out}: exists and is not a folder")

    def told(paths) -> None:
        if int(quiet or 0) < 2:
            print(f"relight {command}: warning: removed {len(paths)} leftover(s) of an interrupted run next to "
                  f"{out}: {', '.join(p.name for p in paths)}", file=sys.stderr)

    return result_set(out, command, command=f"relight {command}", keep=keep, create=create, unhashed=unhashed,
                      legacy=earlier_output(command, legacy), on_stale=told)


def check_out(out: str | os.PathLike, command: str, keep=(), legacy=None) -> Path:
    """Refuse ``--out`` early (before any work) unless a later :func:`output_set` would take it: CLIError
    naming the folder and what it holds."""
    from ..results import ForeignFolderError, check_output_folder, earlier_output

    out = Path(out)
    if out.exists() and not out.is_dir():
        raise CLIError(f"--out {out}: exists and is not a folder")
    try:
        check_output_folder(out, command, keep=keep, legacy=earlier_output(command, legacy))
    except ForeignFolderError as err:
        raise CLIError(f"--out {err}") from None
    return out


def upscale_nearest(img: np.ndarray, min_px: int = PREVIEW_MIN_PX) -> np.ndarray:
    """``relight.image.upscale_nearest``: ``img`` enlarged nearest-neighbour until its shorter side has at
    least ``min_px`` pixels."""
    from ..image import upscale_nearest as upscale

    return upscale(img, min_px)


def write_preview(path: Path, img: np.ndarray, exposure: float | None = None, curve: str = "filmic",
                  min_px: int = 0) -> None:
    """``relight.io.write_preview``: a tone-mapped PNG of the linear ``img``."""
    from ..io import write_preview as write

    write(path, img, exposure=exposure, curve=curve, min_px=min_px)


def write_map_previews(folder: Path, albedo, specular, roughness) -> None:
    """``relight.io.write_map_previews``: albedo.png, specular.png, roughness.png of texel-space maps."""
    from ..io import write_map_previews as write

    write(folder, albedo, specular, roughness)


def write_index_page(folder: Path, sweeps, command: str, quiet: int | bool = 0, committed: bool = False,
                     location: Path | None = None, envmap: Path | str | None = None) -> tuple[Path, int]:
    """``folder/index.html``: ``relight.view.write_index`` with the rows and note ``sweeps()`` returns. A sweep
    that fails (ValueError, RuntimeError, OSError: an input that moved, a map it cannot read) leaves a page
    without a slider, saying why, and a warning on stderr: the page never fails the command. ``folder`` is a
    result set being built (the command's ``tmp``; ``location``: the folder it becomes), or, ``committed``, a
    finished folder: then it is locked while the page is written and, if it is a result set, its manifest
    lists the new index.html (``relight.results.ResultSet.add``; ``relight view``). ``envmap``: the 3D view's
    environment map (None: the one the folder records, else the bundled one). Returns (the page's path, the
    number of sweeps)."""
    import sys

    from ..results import FolderLock, is_result_set, open_result_set

    folder = Path(folder)

    def make() -> tuple[Path, int]:
        from ..view import write_index

        try:
            rows, note = sweeps()
        except (ValueError, RuntimeError, OSError) as err:
            rows, note = [], f"no rotation slider: the sweep failed ({err})"
            if int(quiet or 0) < 2:
                print(f"relight {command}: warning: index.html: {note}", file=sys.stderr)
        return write_index(folder, rows, note, location=location, envmap=envmap), len(rows)

    if not committed or not is_result_set(folder):
        with writing(folder / "index.html"):
            return make()
    with FolderLock(folder, f"relight {command}"):
        with writing(folder / "index.html"):
            path, n = make()
        open_result_set(folder).add(path)
    return path, n
