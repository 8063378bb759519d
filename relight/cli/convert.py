"""``relight convert SRC DST``: a capture folder to a capture store (Zarr v3,
``DST`` ending in ``.zarr``), a capture store back to a capture folder
(docs/relight_io.md, "Capture store"), or a photo capture resampled onto a
mesh's texel grid into a texel capture store, streamed in bounded memory
(``relight.io.photos_to_texel_store``), which ``relight fit`` then fits."""

from __future__ import annotations

from pathlib import Path

from ._common import (
    INDEX_FRAMES,
    INDEX_SIZE,
    CLIError,
    add_index_flag,
    add_photo_texel_flags,
    bar,
    finish_parser,
    photo_mesh_from_args,
    refuse_photo_flags,
    summary,
    write_index_page,
)

_SUFFIX = ".zarr"


def add_parser(sub) -> None:
    p = sub.add_parser("convert", help="capture folder <-> capture store (.zarr, chunked Zarr v3)",
                       description="Convert a capture folder (one EXR per view and light) to a chunked, compressed "
                                   "Zarr v3 capture store (DST ending in .zarr), or a store back to a folder; or "
                                   "resample a photo capture (with --mesh) onto the mesh's texel grid into a texel "
                                   "capture store, a light chunk of photographs at a time, for `relight fit DST`. The "
                                   "output is written under a temporary name and renamed into place.")
    p.add_argument("src", help="a capture folder (capture.json), a capture store (.zarr) or a photo capture")
    p.add_argument("dst", help="the store to write (.zarr) from a folder or photos, or the folder to write from a "
                               "store")
    add_photo_texel_flags(p, "photo captures")
    p.add_argument("--resume", action="store_true",
                   help="photo captures: keep what a killed conversion of the same photographs into DST with the "
                        "same settings finished (DST's partial store, .DST.partial beside it, checkpointed after "
                        "each light chunk of each camera); refused if the photographs, the mesh or a setting "
                        "changed. Without it an earlier partial store is cleared")
    add_index_flag(p)
    finish_parser(p, run)


def run(args) -> int:
    from ..io import (
        capture_folder_to_store,
        is_capture_store,
        is_photo_capture,
        open_capture_store,
        store_to_capture_folder,
    )

    src, dst = Path(args.src), Path(args.dst)
    if not src.exists():
        raise CLIError(f"{src}: no such capture folder or store")
    if src.resolve() == dst.resolve():
        raise CLIError(f"{dst}: the destination is the source")
    photos = (src / "capture.json").is_file() and is_photo_capture(src)
    if not photos:
        refuse_photo_flags(args, f"photo captures only; {src} is not one")
        if args.resume:
            raise CLIError(f"--resume: photo captures only; {src} is converted in one go")
    if photos:
        if dst.suffix != _SUFFIX:
            raise CLIError(f"{dst}: a photo capture converts to a texel capture store, whose name must end in "
                           f"{_SUFFIX}")
        _photos_to_store(args, src, dst)
        what = "store"
    elif (src / "capture.json").is_file():
        if dst.suffix != _SUFFIX:
            raise CLIError(f"{dst}: a capture folder converts to a store, whose name must end in {_SUFFIX}")
        with bar(None, "convert", args.quiet) as b:
            capture_folder_to_store(src, dst, progress=b)
        what = "store"
    elif is_capture_store(src):
        if dst.suffix == _SUFFIX:
            raise CLIError(f"{dst}: a store converts to a capture folder, whose name must not end in {_SUFFIX}")
        with bar(None, "convert", args.quiet) as b:
            store_to_capture_folder(src, dst, progress=b)
        what = "capture folder"
    else:
        raise CLIError(f"{src}: neither a capture folder (capture.json) nor a capture store (.zarr with "
                       "relight-store.json)")
    if not args.no_index:
        # The library's converters commit DST as a result set; the page goes in afterwards, the folder locked and
        # its manifest extended (as `relight view DST` does). A capture too large to read whole gets a page
        # without a slider that says so.
        def sweeps():
            from ..view import folder_sweeps

            return folder_sweeps(dst, None, INDEX_FRAMES, INDEX_SIZE)

        write_index_page(dst, sweeps, "convert", args.quiet, committed=True)
    if summary(args):
        store = open_capture_store(dst if what == "store" else src)
        V, L, P, C = store.shape
        on_disk = sum(f.stat().st_size for f in store.path.rglob("*") if f.is_file())
        print(f"wrote {what} {dst}: {V} view(s) x {L} lights x {P} samples x {C} channels, {store.dtype.name}; "
              f"store {on_disk / 2**20:.1f} MiB ({store.nbytes / max(on_disk, 1):.2f}x compression)")
    return 0


def _photos_to_store(args, src: Path, dst: Path) -> None:
    """``relight convert PHOTOS DST.zarr --mesh MESH``: :func:`relight.io.photos_to_texel_store`."""
    from ..io import PartialStoreMismatch, mesh_size_warning, photos_to_texel_store, read_photo_capture

    mesh = photo_mesh_from_args(args, src)
    photos = read_photo_capture(src, rig_units=args.rig_units, rig_up=args.rig_up)
    warning = mesh_size_warning(mesh["mesh"], photos.rig)
    if warning:
        import sys

        print(f"relight convert: warning: {warning}", file=sys.stderr)
    try:
        with bar(None, "convert", args.quiet) as b:
            _, report = photos_to_texel_store(photos, mesh["mesh"], args.resolution, dst,
                                              surface_info=mesh["mesh_info"], grazing_deg=args.grazing_deg,
                                              min_views=args.min_views, resume=args.resume, progress=b)
    except PartialStoreMismatch as err:
        raise CLIError(f"--resume: {err}") from None
    if summary(args) and report.n_unseen:
        print(f"{report.n_unseen} of the {report.texels} texels are unseen (no camera sees them): they hold no "
              "valid observation")
