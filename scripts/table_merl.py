"""Fit every rung of the model ladder to every measured MERL material (80 NBRDF
networks in ../shared/data/measured_brdf) under the Light Stage X, and table
the errors, sorted, after Ngan, Durand & Matusik 2005 ("Experimental analysis of
BRDF models", EGSR).

    .venv/bin/python scripts/table_merl.py                    # all 80, 512 texels: docs/figures/merl_*
    .venv/bin/python scripts/table_merl.py --materials gold-metallic-paint,chrome --texels 256
    .venv/bin/python scripts/table_merl.py --fits ggx,auto --loss cauchy --suffix _cauchy  # merl_table_cauchy.md
    .venv/bin/python scripts/table_merl.py --holdout-check --materials blue-acrylic,aventurnine

Scene (scripts/bench_fit.py's): a sphere of radius 50 mm at the centre of the
Light Stage X (346 near-field lights), one camera 1 m in front, ``--texels``
samples on the camera-facing part (cos >= 0.3; convex: no cast shadows).
Truth: ``stage.simulate`` with ``brdf.NBRDF`` as the material (geometric
frame), radiance x (1 + 0.01 N(0, 1)) as the data the fitter sees.

Per material and rung (``relight.fit(capture, surface, model=...)`` for
lambert, blinn_phong, ggx, ggx_aniso and auto; geometric normals, default
solver and loss, relight.fit's default unless --loss):

* reflectance error: relative RMS over the valid observations of the fitted
  model's OLAT radiance (``stage.simulate`` of ``Fit.material()`` in the fitted
  frame) against the noise-free NBRDF radiance, sqrt(sum (fit - true)^2 / sum true^2)
  over (light, sample, channel);
* relit error: the same over (sample, channel) of the sphere relit under the
  bundled environment map (Venice sunset): truth = image-based relighting of the
  noise-free NBRDF OLAT capture (``relight.envmap.light_weights`` +
  ``relight.render.relight_olat``, Debevec 2000), fit =
  ``relight.render.render_samples(fit.maps(surface), ..., method="rig")``, which
  is the same sum for the fitted maps (checked on the first material);
* for auto: the fraction of texels on each rung.

Also per material, the NBRDF's property checks (docs/measured_brdf.md):
the share of raw network outputs below 0 (clamped), reciprocity asymmetry
|f(wi, wo) - f(wo, wi)| (median and 99th percentile of log(1 + f) differences,
and relative where max(f) > 0.01 / sr), and the largest directional albedo over
8 view directions (half-vector quadrature, ``brdf.directional_albedo_half``).

Writes docs/figures/merl_table.md (sorted by the best rung's reflectance error),
docs/figures/merl_checks.md and docs/figures/merl_errors.png (``--suffix`` appended to
each name). ``--holdout-check`` fits nothing: it prints how often the held-out lights of
``model="auto"`` (every 5th) miss each texel's highlight (docs/measured_brdf.md, finding 7).
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

import brdf
import relight
import stage
from brdf import directional_albedo_half, load_nbrdf, nbrdf_names

ROOT = Path(__file__).resolve().parents[1]
from _common import front_camera, machine, parser, sphere_surface  # noqa: E402

FIG = ROOT / "docs" / "figures"
RUNGS = ("lambert", "blinn_phong", "ggx", "ggx_aniso")
FITS = RUNGS + ("auto",)
NOISE = 0.01
# Reciprocity: relative asymmetry is only meaningful where the network is above its own
# absolute accuracy (values near 0 are clamped ReLU/exp tails): above 0.01 / sr (albedo ~3%).
REL_FLOOR = 0.01


def _rel_rms(a, b, mask=None) -> float:
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    if mask is not None:
        m = np.broadcast_to(np.asarray(mask)[..., None], a.shape)
        a, b = a[m], b[m]
    return float(np.sqrt(np.sum((a - b) ** 2) / max(np.sum(b**2), 1e-300)))


def _simulate(surface, rig, cam, material):
    P, L = surface.num_samples, rig.num_lights
    return stage.simulate(surface, rig, [cam], material, np.ones((P, L), bool), np.ones((1, P), bool))


@eqx.filter_jit
def _pairs_eval(m, wi, wo):
    enc = brdf.nbrdf_encoding(wi, wo)
    return m(wi, wo), m(wo, wi), m.network(enc)


def property_checks(m, wi, wo, wo_alb):
    """(negative share, log-asym median, log-asym p99, rel-asym median, rel-asym p99, max albedo)."""
    a, b, raw = (np.asarray(x, np.float64) for x in _pairs_eval(m, wi, wo))
    lg = np.abs(np.log1p(a) - np.log1p(b))
    big = np.maximum(a, b) > REL_FLOOR
    rel = (np.abs(a - b) / np.maximum(np.maximum(a, b), 1e-300))[big]
    alb = np.asarray(_albedo(m, wo_alb))
    return (float(np.mean(raw < 0)), float(np.median(lg)), float(np.percentile(lg, 99)),
            float(np.median(rel)), float(np.percentile(rel, 99)), float(alb.max()))


_albedo = eqx.filter_jit(directional_albedo_half)


def main(argv=None):
    ap = parser(__doc__)
    ap.add_argument("--texels", type=int, default=512)
    ap.add_argument("--materials", default="", help="comma-separated names (default: every network in the folder)")
    ap.add_argument("--out", type=Path, default=FIG)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--fits", default=",".join(FITS), help=f"comma-separated subset of {','.join(FITS)}")
    ap.add_argument("--loss", default=relight.fitting.DEFAULT_LOSS, choices=relight.LOSSES,
                    help=f"relight.fit's loss (default: its own, {relight.fitting.DEFAULT_LOSS})")
    ap.add_argument("--suffix", default="", help="appended to the output names (merl_table<suffix>.md, ...)")
    ap.add_argument("--holdout-check", action="store_true",
                    help="no fits: per material, how often auto's held-out lights (every 5th) miss the highlight")
    args = ap.parse_args(argv)
    fits = tuple(k for k in FITS if k in args.fits.split(","))
    if not fits:
        sys.exit(f"--fits: none of {FITS}")
    names = [n for n in args.materials.split(",") if n] or nbrdf_names()
    if not names:
        sys.exit(f"no NBRDF networks found in {brdf.nbrdf_folder()}")
    rig = stage.light_stage_x()
    cam = front_camera()
    surface = sphere_surface(args.texels, seed=args.seed)
    wo_world = cam.view_directions(surface.position)
    env = relight.envmap.load_envmap(relight.envmap.bundled_envmap_path())
    dirs = np.asarray(rig.position, np.float64)
    dirs = jnp.asarray(dirs / np.linalg.norm(dirs, axis=1, keepdims=True), jnp.float32)
    weights = relight.envmap.light_weights(env, dirs, rig.center_irradiance)
    wi_p, wo_p = brdf.check.random_pairs(jax.random.PRNGKey(args.seed), 20000, jnp.float32)
    c = np.cos(np.linspace(0.02, 1.45, 8))
    wo_alb = jnp.asarray(np.stack([np.sqrt(1 - c * c), 0 * c, c], -1), jnp.float32)
    if args.holdout_check:
        for name in names:
            holdout_check(name, surface, rig, cam)
        return
    rng = np.random.default_rng(args.seed + 2)
    rows, checks = [], []
    t0 = time.time()
    for i, name in enumerate(names):
        t = time.time()
        m = load_nbrdf(name)
        checks.append((name, *property_checks(m, wi_p, wo_p, wo_alb)))
        true = _simulate(surface, rig, cam, m)
        rad = np.asarray(true.radiance, np.float32)
        noisy = rad * (1 + NOISE * rng.standard_normal(rad.shape)).astype(np.float32)
        cap = stage.Capture(jnp.asarray(noisy), true.mask, true.rig, true.cameras)
        relit_true = relight.render.relight_olat(true.radiance[0], weights)
        row = {"name": name}
        for model in fits:
            f = relight.fit(cap, surface, model=model, loss=args.loss)
            maps = f.maps(surface)
            pred = _simulate(maps.frame(surface), rig, cam, f.material())
            row[f"refl_{model}"] = _rel_rms(pred.radiance, true.radiance, true.mask)
            if model == "ggx":
                # the channel mean alone: the lobe's shape without its colour (the ladder's specular is grey)
                row["grey_ggx"] = _rel_rms(np.mean(pred.radiance, -1, keepdims=True),
                                           np.mean(true.radiance, -1, keepdims=True), true.mask)
            relit = relight.render.render_samples(maps, surface, env, wo_world, method="rig", rig=rig)
            row[f"relit_{model}"] = _rel_rms(relit, relit_true)
            if i == 0 and model == "ggx":
                # render_samples "rig" is relight_olat of the fitted maps' OLAT capture: check that identity here
                same = _rel_rms(relight.render.relight_olat(pred.radiance[0], weights), relit)
                print(f"check: render_samples(rig) vs relight_olat(simulate(fit)) relative RMS {same:.2e}", flush=True)
            if model == "auto":
                frac = np.bincount(np.asarray(f.model), minlength=len(relight.MODELS))[: len(RUNGS)] / f.model.shape[0]
                row["auto_frac"] = frac
        rows.append(row)
        errs = " ".join(f"{k} {row[f'refl_{k}']:.3f}/{row[f'relit_{k}']:.3f}" for k in fits)
        pick = f" auto picks {RUNGS[int(np.argmax(row['auto_frac']))]}" if "auto_frac" in row else ""
        print(f"[{i + 1}/{len(names)}] {name:26s} refl/relit {errs}{pick} "
              f"({time.time() - t:.1f} s, {time.time() - t0:.0f} s total)", flush=True)
    cmd = " ".join(["scripts/table_merl.py", *(argv if argv is not None else sys.argv[1:])])
    write_outputs(rows, checks, args.out, args.texels, cmd, time.time() - t0, fits, args.loss, args.suffix)


def holdout_check(name, surface, rig, cam, holdout: int = 5, excess: float = 3.0):
    """Print, for the noise-free capture of ``name``: the share of texels with a highlight
    (lights whose f_r cos-normalised radiance exceeds ``excess`` x the texel's 25th percentile),
    the median number of highlight lights, and the share of highlighted texels none of whose
    highlight lights is in ``relight.fit``'s held-out set (light % holdout == holdout // 2)."""
    true = _simulate(surface, rig, cam, load_nbrdf(name))
    rad = np.asarray(true.radiance[0], np.float64).mean(-1)
    mask = np.asarray(true.mask[0])
    wi_w, irr = rig.incident(surface.position)
    cos_i = np.asarray(surface.to_local(wi_w))[..., 2]
    f = np.where(mask, rad / np.maximum(cos_i * np.asarray(irr, np.float64).mean(-1), 1e-30), np.nan)  # [L, P]
    hi = mask & (f > excess * np.nanpercentile(f, 25, axis=0)[None])
    held = (np.arange(rig.num_lights) % holdout == holdout // 2)[:, None]
    n_hi, n_held = hi.sum(0), (hi & held).sum(0)
    lit = n_hi > 0
    print(f"{name:26s} texels with a highlight {np.mean(lit):.2f}, median highlight lights "
          f"{np.median(n_hi[lit]) if lit.any() else 0:.0f}, highlighted texels with none held out "
          f"{np.mean(n_held[lit] == 0) if lit.any() else 0:.2f}", flush=True)


def write_outputs(rows, checks, out: Path, texels: int, cmd: str, wall: float, fits=FITS,
                  loss=relight.fitting.DEFAULT_LOSS, suffix=""):
    out.mkdir(parents=True, exist_ok=True)
    rungs = [k for k in RUNGS if k in fits] or list(fits)
    best = lambda r: min(r[f"refl_{k}"] for k in rungs)  # noqa: E731
    rows = sorted(rows, key=best)
    short = {"lambert": "L", "blinn_phong": "BP", "ggx": "GGX", "ggx_aniso": "aniso", "auto": "auto"}
    has_auto, has_grey = "auto" in fits, "ggx" in fits
    head = ("| # | material | " + " | ".join(f"refl {short[k]}" for k in fits) + " | "
            + " | ".join(f"relit {short[k]}" for k in fits)
            + (" | refl GGX grey" if has_grey else "") + (" | auto picks (L/BP/GGX/aniso %)" if has_auto else "")
            + " |")
    lines = [head, "|" + "---|" * (2 + 2 * len(fits) + has_grey + has_auto)]
    for j, r in enumerate(rows, 1):
        cells = [str(j), r["name"], *(f"{r[f'refl_{k}']:.3f}" for k in fits), *(f"{r[f'relit_{k}']:.3f}" for k in fits)]
        if has_grey:
            cells.append(f"{r['grey_ggx']:.3f}")
        if has_auto:
            fr = r["auto_frac"]
            cells.append(f"**{short[RUNGS[int(np.argmax(fr))]]}** " + "/".join(f"{100 * x:.0f}" for x in fr))
        lines.append("| " + " | ".join(cells) + " |")
    med = {k: float(np.median([r[f"refl_{k}"] for r in rows])) for k in fits}
    medr = {k: float(np.median([r[f"relit_{k}"] for r in rows])) for k in fits}
    summary = ("| rung | median reflectance rel. RMS | median relit rel. RMS |\n|---|---|---|\n"
               + "\n".join(f"| {k} | {med[k]:.3f} | {medr[k]:.3f} |" for k in fits))
    (out / f"merl_table{suffix}.md").write_text(
        f"`.venv/bin/python {cmd}` ({len(rows)} materials, {texels} texels, Light Stage X, 1% noise, "
        f"{loss} loss; "
        f"{wall / 60:.1f} min on {machine()})\n\n"
        "Relative RMS against the noise-free NBRDF truth: *refl* over every valid (light, texel, channel) "
        "observation of the OLAT capture; *relit* of the sphere relit under the bundled Venice-sunset map "
        "(rig method vs the image-based relighting of the true OLAT capture). Sorted by the best rung's "
        "reflectance error. *auto picks*: the share of texels on each rung under `model=\"auto\"` "
        "(bold: the majority). *refl GGX grey*: the GGX rung's reflectance error on the channel mean "
        "(the lobe's shape without its colour: the ladder's specular albedo is grey).\n\n"
        + summary + "\n\n" + "\n".join(lines) + "\n")
    chk = ["| material | raw < 0 (clamped) | log-asym median | log-asym p99 | rel-asym median (f > 0.01) | "
           "rel-asym p99 (f > 0.01) | max albedo |", "|---|---|---|---|---|---|---|"]
    for c in sorted(checks, key=lambda c: c[2]):
        chk.append(f"| {c[0]} | {100 * c[1]:.2f}% | {c[2]:.2e} | {c[3]:.3f} | {c[4]:.3f} | {c[5]:.3f} | {c[6]:.3f} |")
    arr = np.asarray([c[1:] for c in checks])
    over = [c[0] for c in checks if c[6] > 1.0]
    (out / f"merl_checks{suffix}.md").write_text(
        f"`.venv/bin/python {cmd}`: NBRDF property checks on 20000 random direction pairs (float32) and "
        "8 view directions (albedo by half-vector quadrature).\n\n"
        f"Over all {len(checks)}: raw network output < 0 (clamped to 0) on at most {100 * arr[:, 0].max():.1f}% "
        f"of pairs (median {100 * np.median(arr[:, 0]):.2f}%); reciprocity |log(1+f(wi,wo)) - log(1+f(wo,wi))| "
        f"median of medians {np.median(arr[:, 1]):.1e}, worst median {arr[:, 1].max():.1e}, worst p99 "
        f"{arr[:, 2].max():.3f}; relative asymmetry where f > 0.01/sr: median of medians "
        f"{np.median(arr[:, 3]):.3f}, worst median {arr[:, 3].max():.3f}, worst p99 {arr[:, 4].max():.3f}; "
        f"max directional albedo {arr[:, 5].max():.3f} (materials above 1: {', '.join(over) or 'none'}).\n\n"
        + "\n".join(chk) + "\n")
    _chart(rows, out / f"merl_errors{suffix}.png", fits)
    print(f"wrote {out}/merl_table{suffix}.md, merl_checks{suffix}.md, merl_errors{suffix}.png")


def _chart(rows, path: Path, fits=FITS):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = len(rows)
    fig, axes = plt.subplots(2, 1, figsize=(max(12, 0.22 * n * 1.6), 8), sharex=True)
    x = np.arange(n)
    wdt = 0.8 / len(fits)
    colors = {"lambert": "#999999", "blinn_phong": "#e69f00", "ggx": "#0072b2", "ggx_aniso": "#009e73",
              "auto": "#d55e00"}
    for ax, kind, title in ((axes[0], "refl", "reflectance (OLAT observations)"),
                            (axes[1], "relit", "sphere relit under Venice sunset")):
        for j, k in enumerate(fits):
            ax.bar(x + (j - (len(fits) - 1) / 2) * wdt, [r[f"{kind}_{k}"] for r in rows], wdt, label=k,
                   color=colors[k])
        ax.set_yscale("log")
        ax.set_ylabel("relative RMS")
        ax.set_title(f"{title}: fit vs NBRDF truth, sorted by the best rung's reflectance error")
        ax.grid(axis="y", alpha=0.3, which="both")
    axes[0].legend(ncol=5, fontsize=8)
    axes[1].set_xticks(x)
    axes[1].set_xticklabels([r["name"] for r in rows], rotation=90, fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


if __name__ == "__main__":
    main()
