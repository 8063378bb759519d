"""``relight cameras FORMAT PATH --units U --out cameras.json``: a light stage's camera calibration from COLMAP,
OpenCV or Metashape as the project's camera file (``stage.read_colmap`` / ``stage.read_opencv_calibration`` /
``stage.read_metashape_xml``, then ``stage.save_cameras``; docs/stage.md, "Camera calibrations")."""

from __future__ import annotations

from pathlib import Path

from ._common import CLIError, add_out, finish_parser, summary

FORMATS = ("colmap", "opencv", "metashape")


def add_parser(sub) -> None:
    p = sub.add_parser("cameras", help="import a camera calibration (COLMAP, OpenCV, Metashape) as cameras.json",
                       description="Read a camera calibration and write it as the project's camera file "
                                   "(stage.save_cameras' JSON, the --camera files of the other commands), one "
                                   "line per camera printed. colmap: a sparse model folder (cameras + images, "
                                   "text or binary), one camera per registered image, named by the image; "
                                   "opencv: a FileStorage YAML or JSON file of one camera or several; metashape: "
                                   "Metashape's camera export (XML), its aligned cameras named by label. Pixel "
                                   "conventions and distortion coefficients are converted; lengths become mm.")
    p.add_argument("format", metavar="FORMAT", choices=FORMATS, help=f"one of {', '.join(FORMATS)}")
    p.add_argument("path", metavar="PATH", help="colmap: the model folder (e.g. sparse/0); opencv: the .yml / "
                                                ".yaml / .json file; metashape: the exported .xml file")
    p.add_argument("--units", required=True, metavar="U",
                   help="millimetres per unit of the calibration's lengths: a number (1000 for metres), or mm, "
                        "cm, m (structure from motion has no units of its own: say which)")
    add_out(p, "the camera file to write (JSON, e.g. cameras.json)")
    finish_parser(p, run)


def _units(text: str) -> float | str:
    """``--units`` as the readers take it: a number, else the unit's name (which the library checks)."""
    try:
        return float(text)
    except ValueError:
        return text


def run(args) -> int:
    import numpy as np

    import stage

    readers = {"colmap": stage.read_colmap, "opencv": stage.read_opencv_calibration,
               "metashape": stage.read_metashape_xml}
    out = Path(args.out)
    if out.is_dir():
        raise CLIError(f"{out}: a folder; --out names the camera file to write (e.g. {out / 'cameras.json'})")
    cameras = readers[args.format](args.path, _units(args.units))
    stage.save_cameras(out, list(cameras.values()), names=list(cameras))
    _warn_unusable_names(cameras, out, args)
    if summary(args):
        for name, cam in cameras.items():
            K, distorted = np.asarray(cam.K, np.float64), bool(np.any(np.asarray(cam.dist) != 0))
            print(f"{name}: {cam.width}x{cam.height} px, focal {K[0, 0]:.2f} x {K[1, 1]:.2f} px, "
                  f"{'distorted' if distorted else 'no distortion'}")
        print(f"wrote {len(cameras)} camera(s) to {out}")
    return 0


def _warn_unusable_names(cameras: dict, out: Path, args) -> None:
    """A warning (stderr, unless -qq) for each camera name that is not one plain file name (COLMAP keeps an
    image's subfolder in its name, "left/img0001"): a photo capture names each view's folder by its camera, and
    its reader refuses such a name (issue 29's rule: a name from a file never becomes a path), so it is said
    here, where the name is made, not when the capture is first read."""
    import sys

    from ..io import ImageFormatError, file_name

    for name in cameras:
        try:
            file_name(name, "camera name")
        except ImageFormatError as err:
            if summary(args):
                print(f"relight cameras: warning: {out}: {err}. A photo capture names its view folders by camera, "
                      f"and reading one refuses this name: rename the camera in {out.name} (its name only, "
                      "not its calibration)", file=sys.stderr)
