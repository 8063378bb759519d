"""``relight reseal RESULT_DIR``: accept hand edits of a command's output folder (``relight.results.reseal``).

Readers refuse a result set whose files differ from its manifest (``relight-set.json``): an interrupted writer's
mix of old and new files and a deliberate edit look the same. After a deliberate edit (new rig intensities after
a recalibration, a retouched map), this rewrites the manifest over the files as they now are and lists what
changed."""

from __future__ import annotations

from pathlib import Path

from ._common import CLIError, finish_parser, summary


def add_parser(sub) -> None:
    p = sub.add_parser("reseal", help="accept hand edits of a result folder (rewrite its manifest)",
                       description="Rewrite RESULT_DIR/relight-set.json over the folder's files as they now are, "
                                   "after a deliberate edit: readers refuse a set whose files differ from its "
                                   "manifest, since an interrupted write looks the same. Lists the changed, added "
                                   "and removed files. Nothing checks that an edited file still makes sense: its "
                                   "reader does, when it is read.")
    p.add_argument("folder", metavar="RESULT_DIR", help="a command's output folder (with relight-set.json)")
    finish_parser(p, run)


def run(args) -> int:
    from ..results import reseal

    folder = Path(args.folder)
    if not folder.is_dir():
        raise CLIError(f"{folder}: no such result folder")
    diff = reseal(folder)
    if summary(args):
        parts = [f"{k}: {', '.join(v)}" for k, v in diff.items() if v]
        print(f"resealed {folder}/ ({'; '.join(parts) if parts else 'no file had changed'})")
    return 0
