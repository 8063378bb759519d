"""``relight view RESULT_DIR``: write ``RESULT_DIR/index.html``, the results viewer (``relight.view``): one
self-contained page (no server, no network; images embedded) with the relit subject under an
environment-rotation slider, report.md, truth | fit | error where a truth is at hand, the maps, the charts and
previews, and settings.json.

The slider's sweep is made from what the folder records (``relight.view.folder_sweeps``): a capture is relit
image-based, a map set model-based through its rig, a render's turntable frames are shown as they are. A
folder that is a result set (a command's output) keeps a valid manifest: the folder is locked while the page
is written and ``relight-set.json`` then lists the new ``index.html``."""

from __future__ import annotations

from pathlib import Path

from ._common import CLIError, add_envmap, at_least, finish_parser, summary, write_index_page

# relight.view.DEFAULT_FRAMES / DEFAULT_SIZE, spelled here so that `relight view --help` imports no JAX
# (tests/relight/test_view.py checks them against the library's).
FRAMES = 24
SIZE = 160


def add_parser(sub) -> None:
    p = sub.add_parser("view", help="write index.html, the results viewer, into a result folder",
                       description="Write RESULT_DIR/index.html: a self-contained page (open it from file:// in any "
                                   "browser; no server, no network) showing the relit subject under an "
                                   "environment-rotation slider, report.md, truth | fit | error where a truth is at "
                                   "hand, the maps, the charts and previews, and settings.json. Works on the "
                                   "outputs of simulate, fit, render, convert and demo.")
    p.add_argument("folder", metavar="RESULT_DIR", help="a command's output folder (or any folder of results)")
    add_envmap(p, "environment map of the slider's sweep; default: the one the folder records, else the bundled")
    p.add_argument("--frames", type=int, default=FRAMES,
                   help=f"rotations of the slider's sweep over 360 degrees (default: {FRAMES}; 0: no slider)")
    p.add_argument("--size", type=int, default=SIZE, metavar="PX",
                   help=f"longer side of the sweep's frames in pixels (default: {SIZE}; never above the camera's)")
    finish_parser(p, run)


def run(args) -> int:
    folder = Path(args.folder)
    if not folder.is_dir():
        raise CLIError(f"{folder}: no such result folder")
    at_least("--frames", args.frames, 0)
    at_least("--size", args.size, 8)

    def sweeps():
        from ..view import folder_sweeps

        if args.frames == 0:
            return [], "no rotation slider (--frames 0)"
        return folder_sweeps(folder, args.envmap, frames=args.frames, size=args.size)

    path, sweeps_made = write_index_page(folder, sweeps, "view", quiet=args.quiet, committed=True,
                                         envmap=args.envmap)
    if summary(args):
        slider = f"{sweeps_made} sweep(s) of {args.frames} rotations" if sweeps_made else "no slider"
        print(f"wrote {path} ({slider}); open it in a browser: {path.resolve().as_uri()}")
    return 0
