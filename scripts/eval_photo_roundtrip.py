"""The photo round trip, measured: simulated photographs -> texels -> fit -> truth.

    python scripts/eval_photo_roundtrip.py [--quick] [--normals] [--noise EXPOSURE] [--rig lsx|polarized]
                                           [--image-size N] [--resolution N] [--out docs/figures]

Per scene and camera count: `relight simulate --space image` (the CLI itself,
so the demo's skin material: rho_d varying over the UVs, F0 0.028, alpha
0.2-0.5, `relight.materials.demo_material`) writes a camera-space photo
capture; `relight.io.photos_to_texels` resamples it onto the mesh's texel
grid; `relight.fit(model="ggx")` fits it; the fitted maps are compared with
`demo_material` evaluated on the texel surface. Scenes:

* head: the bundled head scan (`stage.load_head`) under the ICT Light Stage X
  (all 346 lights, or its 85-light polarized ordering with `--rig polarized`);
* face: the MediaPipe canonical face (`../shared/data/meshes/
  mediapipe_canonical_face.obj`, cm, centred) under a 162-light geodesic dome.

Cameras: 1 = the CLI's `front` camera (+z, 11 degrees); 3 = three cameras at
the same distance over 80 degrees of azimuth around the front
(`stage.camera_ring`). Statistics over the texels seen by >= 1 camera and not
flagged by the fit: median and 90th percentile of the albedo relative error
(per texel, the mean over RGB of |rho - rho_true| / rho_true), of
|alpha - alpha_true|, and with `--normals` of the angle between the fitted and
the mesh's normal. Writes `photo_roundtrip[_normals][_quick].md` / `.json` / `.png`
under `--out` and prints the table.
"""

from __future__ import annotations

import json
import tempfile
import time
from pathlib import Path

import numpy as np
from _common import parser

ROOT = Path(__file__).resolve().parents[1]
FACE = ROOT.parent / "shared" / "data" / "meshes" / "mediapipe_canonical_face.obj"


def _cameras(mesh, n: int, size: int):
    """1: the CLI's front camera; n > 1: a ring at its distance over 80 degrees."""
    from stage import front_ring

    return front_ring(mesh, n, size)


def run_scene(name, mesh_args, mesh, rig_arg, n_cams, args, work: Path) -> dict:
    import relight
    import stage
    from relight.cli import main
    from relight.io import photos_to_texels, read_photo_capture
    from relight.materials import demo_material

    cams = _cameras(mesh, n_cams, args.image_size)
    photos = work / f"{name}_{n_cams}cam"
    if n_cams == 1:
        cam_arg = "front"
    else:
        cam_arg = str(stage.save_cameras(work / f"{name}_{n_cams}cam_cameras.json", cams))
    cmd = ["simulate", "--space", "image", *mesh_args, "--rig", rig_arg, "--camera", cam_arg,
           "--image-size", str(args.image_size), "--noise", args.noise, "--out", str(photos), "--quiet"]
    t0 = time.perf_counter()
    if main(cmd) != 0:
        raise RuntimeError(f"relight {' '.join(cmd)} failed")
    t_sim = time.perf_counter() - t0

    t0 = time.perf_counter()
    capture, surface, report = photos_to_texels(read_photo_capture(photos), mesh, args.resolution)
    t_ingest = time.perf_counter() - t0
    t0 = time.perf_counter()
    fitted = relight.fit(capture, surface, model="ggx", normals=args.normals)
    failed = np.asarray(fitted.failed)
    t_fit = time.perf_counter() - t0

    rho_t, _, alpha_t = (np.asarray(x, np.float64) for x in demo_material(surface))
    seen = ~report.unseen
    ok = seen & ~failed
    rel = np.mean(np.abs(np.asarray(fitted.rho_d, np.float64) - rho_t) / rho_t, axis=1)
    da = np.abs(np.asarray(fitted.alpha, np.float64)[:, 0] - alpha_t[:, 0])
    P = surface.num_samples

    def q(x):
        return [float(np.median(x[ok])), float(np.percentile(x[ok], 90))] if ok.any() else [float("nan")] * 2

    rig_name = {"lsx": "Light Stage X", "dome:162": "dome 162"}.get(rig_arg, "Light Stage X polarized")
    row = {"scene": name, "rig": rig_name, "lights": int(capture.shape[1]), "cameras": n_cams,
           "texels": P, "seen": int(seen.sum()), "unseen": int(report.n_unseen),
           "fitted": int(ok.sum()), "flagged_seen": int((seen & failed).sum()), "flagged_unseen": int(
               (report.unseen & failed).sum()),
           "albedo_rel": q(rel), "alpha_abs": q(da),
           "times_s": {"simulate": round(t_sim, 1), "ingest": round(t_ingest, 1), "fit": round(t_fit, 1)},
           "command": "relight " + " ".join(cmd).replace(str(work), "WORK")}
    if args.normals:
        n = np.asarray(fitted.normal, np.float64)
        g = np.asarray(surface.normal, np.float64)
        ang = np.degrees(np.arccos(np.clip(np.sum(n * g, 1) / np.linalg.norm(n, axis=1), -1.0, 1.0)))
        row["normal_deg"] = q(ang)
    maps = {"coverage": report.coverage, "albedo_rel": surface.to_texture(np.where(ok, rel, np.nan), np.nan)}
    return row, maps


def table(rows, normals: bool) -> str:
    head = ("| scene | lights | cameras | texels seen (fitted) | unseen | flagged (seen / unseen) | albedo rel. err. "
            "median / p90 | alpha abs. err. median / p90 |" + (" normal err. (deg) median / p90 |" if normals else "")
            + " simulate / ingest / fit (s) |")
    sep = "| " + " | ".join(["---"] * (head.count("|") - 1)) + " |"
    lines = [head, sep]
    for r in rows:
        t = r["times_s"]
        cells = [f"{r['scene']}, {r['rig']}", str(r["lights"]), str(r["cameras"]), f"{r['seen']} ({r['fitted']})",
                 f"{r['unseen']} ({100 * r['unseen'] / r['texels']:.0f}%)",
                 f"{r['flagged_seen']} / {r['flagged_unseen']}",
                 "{:.3f} / {:.3f}".format(*r["albedo_rel"]), "{:.3f} / {:.3f}".format(*r["alpha_abs"])]
        if normals:
            cells.append("{:.2f} / {:.2f}".format(*r["normal_deg"]))
        cells.append(f"{t['simulate']:.0f} / {t['ingest']:.0f} / {t['fit']:.0f}")
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def figure(rows, maps, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = len(rows)
    fig, ax = plt.subplots(2, n, figsize=(2.4 * n + 1.0, 5.4), squeeze=False, layout="constrained")
    vmax = max(r["cameras"] for r in rows)
    for j, (r, m) in enumerate(zip(rows, maps, strict=True)):
        cov = np.ma.masked_less(m["coverage"].astype(float), 0)
        cmap = matplotlib.colormaps["viridis"].copy()
        cmap.set_bad("black")
        cmap.set_under("red")
        ax[0, j].imshow(cov, cmap=cmap, vmin=0.5, vmax=vmax, interpolation="nearest")
        ax[0, j].set_title(f"{r['scene']}, {r['cameras']} cam\ncoverage: cameras per texel\n"
                           f"red: unseen ({r['unseen']})", fontsize=8)
        im = ax[1, j].imshow(np.ma.masked_invalid(m["albedo_rel"]), cmap="magma", vmin=0, vmax=0.1,
                             interpolation="nearest")
        ax[1, j].set_title(f"albedo rel. error\nmedian {r['albedo_rel'][0]:.3f}", fontsize=8)
        for a in ax[:, j]:
            a.set_xticks([])
            a.set_yticks([])
            a.set_facecolor("black")
    fig.colorbar(im, ax=ax[1, :].tolist(), shrink=0.8, label="albedo rel. error (clipped at 0.1)")
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv=None) -> int:
    p = parser(__doc__)
    p.add_argument("--quick", action="store_true", help="smoke run: 32 px images, 24 x 24 texels, polarized rig")
    p.add_argument("--normals", action="store_true", help="also fit the shading normal and report its error")
    p.add_argument("--noise", default="none", help="none | EXPOSURE (relight simulate --noise; default: none)")
    p.add_argument("--rig", default="lsx", choices=("lsx", "polarized"),
                   help="head scene: all 346 Light Stage X lights, or the 85-light polarized ordering")
    p.add_argument("--image-size", type=int, default=96)
    p.add_argument("--resolution", type=int, default=64)
    p.add_argument("--cameras", default="1,3", help="camera counts (default: 1,3)")
    p.add_argument("--scenes", default="head,face")
    p.add_argument("--out", default=str(ROOT / "docs" / "figures"))
    args = p.parse_args(argv)
    if args.quick:
        args.image_size, args.resolution, args.rig = 32, 24, "polarized"

    import stage
    from relight.io import mesh_spec, spec_mesh

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    rows, maps = [], []
    t_all = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="photo_roundtrip_") as tmp:
        work = Path(tmp)
        if args.rig == "polarized":
            lsx = str(stage.save_rig(work / "lsx_polarized.json", stage.light_stage_x("polarized")))
        else:
            lsx = "lsx"
        scenes = {"head": (["--mesh", "head"], lambda: stage.load_head(), lsx),
                  "face": (["--mesh", str(FACE), "--units", "cm", "--center"],
                           lambda: spec_mesh(mesh_spec(FACE, units="cm", center=True)), "dome:162")}
        for name in args.scenes.split(","):
            mesh_args, load, rig_arg = scenes[name]
            if name == "face" and not FACE.is_file():
                print(f"skipping face: {FACE} not found")
                continue
            mesh = load()
            for n_cams in (int(c) for c in args.cameras.split(",")):
                row, m = run_scene(name, mesh_args, mesh, rig_arg, n_cams, args, work)
                rows.append(row)
                maps.append(m)
                print(json.dumps({k: v for k, v in row.items() if k != "command"}), flush=True)
    total = time.perf_counter() - t_all
    md = table(rows, args.normals)
    settings = (f"images {args.image_size} x {args.image_size} px, texels {args.resolution} x {args.resolution}, "
                f"noise {args.noise}, GGX fit{' + normals' if args.normals else ''}; total {total:.0f} s")
    tag = "photo_roundtrip" + ("_normals" if args.normals else "") + ("_quick" if args.quick else "")
    (out / f"{tag}.md").write_text(f"{md}\n\n{settings}\n")
    (out / f"{tag}.json").write_text(json.dumps({"settings": vars(args), "total_s": round(total, 1), "rows": rows},
                                                indent=1) + "\n")
    figure(rows, maps, out / f"{tag}.png")
    print(md)
    print(settings)
    print(f"wrote {out / tag}.md/.json/.png")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
