"""``relight demo``: the main job end to end on built-in data, on the real
problem (``relight.demo.run_demo``): the bundled head scan with its own skin
textures and spatially varying subsurface scattering, photographed under the
bundled Light Stage X by several cameras with sensor noise; the full model
ladder fitted; the fitted maps and the truth maps relit by the same renderer
under the bundled environment map; the fit's report against the truth and the
time of each stage. docs/cli.md shows the same in Python."""

from __future__ import annotations

from pathlib import Path

from ._common import (
    INDEX_FRAMES,
    INDEX_SIZE,
    CLIError,
    add_envmap,
    add_image_size,
    add_index_flag,
    add_out,
    at_least,
    bar,
    check_out,
    finish_parser,
    output_set,
    summary,
    write_index_page,
)


def add_parser(sub) -> None:
    d = sub.add_parser("demo", help="simulate, fit and relight the bundled textured head (built-in defaults)",
                       description="Run the whole pipeline on built-in data: the bundled head scan with its skin "
                                   "textures and subsurface scattering, simulated under the bundled Light Stage X "
                                   "by --cameras cameras with shot noise (--noise), the full model ladder fitted "
                                   "(BRDF rungs, then none / per-region / per-texel subsurface), fit and truth "
                                   "relit under --envmap; writes OUT/maps/, OUT/truth/, relit EXRs, preview.png, "
                                   "report.md/report.json (every map's error over the seen texels) and "
                                   "settings.json. Takes minutes at the defaults; --resolution 32 --cameras 2 for "
                                   "a quick look.")
    add_out(d, "output folder (default: ./relight-demo)", default="relight-demo")
    d.add_argument("--resolution", type=int, default=96, help="texel grid size (default: 96)")
    d.add_argument("--cameras", type=int, default=3, help="cameras over 80 degrees around the front (default: 3)")
    d.add_argument("--noise", type=float, default=0.01,
                   help="relative shot noise at the median observed radiance (default: 0.01; 0 = noise-free)")
    d.add_argument("--seed", type=int, default=0, help="noise seed (default: 0)")
    d.add_argument("--passes", type=int, default=2,
                   help="BRDF / subsurface alternations (relight.fit_with_subsurface; default: 2)")
    add_envmap(d)
    add_image_size(d, 320, "preview image size in pixels")
    add_index_flag(d)
    finish_parser(d, run)


def run(args) -> int:
    at_least("--resolution", args.resolution, 16)
    at_least("--cameras", args.cameras, 1)
    at_least("--image-size", args.image_size, 16)
    at_least("--passes", args.passes, 1)
    if not 0 <= args.noise < 1:
        raise CLIError(f"--noise {args.noise}: must be in [0, 1)")
    report = run_demo(Path(args.out), resolution=args.resolution, envmap=args.envmap, image_size=args.image_size,
                      cameras=args.cameras, noise=args.noise, seed=args.seed, passes=args.passes, quiet=args.quiet,
                      index=not args.no_index)
    if not summary(args):
        return 0
    e = report["against_truth"]["errors"]
    print(f"wrote {args.out}/ (report.md, report.json, preview.png, maps/, truth/)")
    m = e["mfp_rel_identified"]["all_seen"]["median"]
    mfp = "n/a" if m is None else f"{100 * m:.1f}%"
    print(f"over {report['texels_seen']} seen texels, median: diffuse albedo "
          f"{100 * e['diffuse_albedo_rel']['all_seen']['median']:.2f}%, "
          f"mean free path {mfp} ({100 * report['mfp_identified_fraction']:.0f}% of texel-channels identified), "
          f"relit PSNR vs truth {report['relit_psnr_db']:.1f} dB")
    peak = max((v for v in (report.get("peak_rss_mib") or {}).values() if v is not None), default=None)
    if peak is not None:
        print(f"peak memory {peak / 1024:.1f} GiB (resident; report.md has it per phase)")
    return 0


def run_demo(out: Path, resolution: int = 96, envmap: str | Path | None = None, image_size: int = 320, cameras: int = 3,
             noise: float = 0.01, seed: int = 0, passes: int = 2, quiet: int | bool = 0, index: bool = True) -> dict:
    """``relight.demo.run_demo`` into the result set ``out`` (refused before the work unless it may be
    replaced), with progress bars and index.html; returns the report."""
    from ..demo import run_demo as demo

    out = check_out(out, "demo")  # output_set checks again, locked, before writing
    with bar(None, "demo", quiet, leave=True) as b:
        result = demo(resolution=resolution, envmap=envmap, image_size=image_size, cameras=cameras, noise=noise,
                      seed=seed, passes=passes, progress=b)
    # The whole demo folder is one result set: built beside out, swapped in with its manifest.
    with output_set(out, "demo", quiet) as tmp:
        result.write(tmp, location=out)
        if index:
            write_index_page(tmp, lambda: result.sweeps(INDEX_FRAMES, INDEX_SIZE), "demo", quiet, location=out)
    return result.report
