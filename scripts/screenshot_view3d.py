"""Screenshots of a results page's 3D view (relight/view/_page3d.py) in headless Chromium, the browser the test
suite runs the page's self-test in (WebGL2 on SwiftShader): one picture per source (fit, truth, error), side by
side with a caption, written as one PNG (default docs/figures/view3d.png).

    python scripts/screenshot_view3d.py RESULT_DIR [--out docs/figures/view3d.png] [--sources fit,truth,error]
        [--map shaded] [--rotation 0] [--gain G] [--zoom 1]

RESULT_DIR is a ``relight demo`` or ``relight fit`` output whose index.html has a 3D view (``relight view
RESULT_DIR`` rewrites an older page). Each shot opens ``index.html#view3d=source:S,map:M,rot:R,shot:1``: the page
starts in that state and pins its canvas to the window's corner, so a 640 x 480 window holds exactly the canvas.
docs/figures/view3d.png is of the default ``relight demo`` (96^2 texels, 3 cameras): ``--rotation 60 --zoom 1.2``.
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import tempfile
from pathlib import Path

import _common

# As tests/relight/test_view.py runs it: WebGL2 on SwiftShader, opted in (no deprecation note on the console).
FLAGS = ("--headless", "--no-sandbox", "--disable-gpu", "--enable-unsafe-swiftshader", "--no-first-run",
         "--hide-scrollbars")
MAPS = ("shaded", "albedo", "f0", "roughness", "normal", "mfp")
WIDTH, HEIGHT = 640, 480


def shot(chromium: str, page: Path, state: str, out: Path, profile: Path) -> None:
    """One screenshot of ``page`` opened in the 3D view's ``state`` (the address's ``#view3d=`` part)."""
    url = page.resolve().as_uri() + "#view3d=" + state + ",shot:1"
    subprocess.run([chromium, *FLAGS, f"--user-data-dir={profile}", f"--window-size={WIDTH},{HEIGHT}",
                    "--virtual-time-budget=30000", f"--screenshot={out}", url], check=True, capture_output=True,
                   timeout=300)


def main() -> None:
    import numpy as np
    from PIL import Image, ImageDraw

    from relight.view import view3d_data

    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("folder", type=Path, help="a relight demo or relight fit output with index.html")
    p.add_argument("--out", type=Path, default=_common.FIG / "view3d.png")
    p.add_argument("--sources", default="fit,truth,error", help="comma-separated: fit, truth, error")
    p.add_argument("--map", default="shaded", choices=MAPS)
    p.add_argument("--rotation", type=float, default=0.0, help="environment rotation about +y, degrees")
    p.add_argument("--gain", type=float, default=None, help="the error's gain (default: the page's)")
    p.add_argument("--zoom", type=float, default=1.0, help="closer than the page's first view by this factor")
    args = p.parse_args()
    chromium = shutil.which("chromium") or shutil.which("chromium-browser") or shutil.which("google-chrome")
    if chromium is None:
        raise SystemExit("headless Chromium is not installed (Debian: apt-get install chromium)")
    page = args.folder / "index.html"
    data = view3d_data(page.read_text(encoding="utf-8")) if page.is_file() else None
    if data is None:
        raise SystemExit(f"{page}: no 3D view (run `relight view {args.folder}` to rewrite the page)")
    sources = [s for s in args.sources.split(",") if s]
    if any(s not in ("fit", "truth", "error") for s in sources) or ("truth" not in data["sets"] and sources != ["fit"]):
        raise SystemExit(f"--sources: fit, truth, error (truth and error need a truth map set); got {args.sources}")
    gain = args.gain if args.gain is not None else data["error_gain"]
    tiles = []
    with tempfile.TemporaryDirectory() as tmp:
        for s in sources:
            png = Path(tmp) / f"{s}.png"
            state = f"source:{s},map:{MAPS.index(args.map)},rot:{args.rotation:g},gain:{gain:g},zoom:{args.zoom:g}"
            shot(chromium, page, state, png, Path(tmp) / f"profile-{s}")
            img = np.asarray(Image.open(png).convert("RGB"))[:HEIGHT, :WIDTH]
            if np.mean(np.any(img != img[0, 0], axis=-1)) < 0.02:
                raise SystemExit(f"{s}: the screenshot shows no subject (did the page's WebGL start?)")
            tiles.append((s, img))
    cap = 26
    sheet = Image.new("RGB", (WIDTH * len(tiles), HEIGHT + cap), (250, 250, 250))
    draw = ImageDraw.Draw(sheet)
    for i, (s, img) in enumerate(tiles):
        sheet.paste(Image.fromarray(img), (i * WIDTH, cap))
        label = {"fit": "fit", "truth": "truth", "error": f"error |fit - truth| x{gain:g}"}[s]
        draw.text((i * WIDTH + 8, 6), f"{label} ({args.map}, environment turned {args.rotation:g} deg, "
                  f"{data['exposure']:+.2f} EV)", fill=(30, 30, 30))
    args.out.parent.mkdir(parents=True, exist_ok=True)
    sheet.save(args.out, optimize=True)
    print(f"wrote {args.out} ({len(tiles)} view(s) of {args.folder})")


if __name__ == "__main__":
    main()
