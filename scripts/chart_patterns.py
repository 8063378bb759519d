"""Chart learned lighting patterns (Kang et al. 2018) against OLAT and spherical
gradient illumination (Ma et al. 2007) on the Light Stage X: parameter and relit
error against capture time.

    .venv/bin/python scripts/train_patterns.py          # first: build/patterns/lsx_K*.{eqx,json,patterns.json}
    .venv/bin/python scripts/train_patterns.py --no-grid --steps 4000 --out build/patterns_plain   # the ablation
    .venv/bin/python scripts/chart_patterns.py --compare build/patterns_plain   # docs/figures/patterns_*
    .venv/bin/python scripts/chart_patterns.py --samples 200 --patterns 32
    .venv/bin/python scripts/chart_patterns.py --replot  # redraw from docs/figures/patterns_results.json

Test set (held out: its own seed, never seen in training, narrower ranges than
training's): ``--samples`` Lambert + GGX samples from
``relight.patterns.TEST_RANGES`` (rho_d ~ U(0.1, 0.8)^3, F0 ~ U(0.02, 0.08),
alpha log-uniform in [0.1, 0.6]), positions uniform in a 100 mm ball about the
rig centre, normals within 75 degrees of the view direction, one camera 1 m in
front, no cast shadows (the hemisphere cut only). Every method sees the same
samples through the same sensor (``train_patterns.SENSOR``: 2000
photo-electrons per unit radiance per frame, shot noise, 5 e- read noise; no
saturation) with its own noise draw, one exposure per frame; capture time =
frames x ``FRAME_S`` (1/60 s).

Methods: learned K patterns (decoder start, then
``relight.fitting.fit_patterns``; also the decoder alone and fit_patterns from
its default start), with ``--compare`` the plain decoder's patterns (no
closed-form specular features; decoder alone and decoder start), random K
patterns (the untrained pattern layer, sigmoid of N(0, 2^2) logits,
fit_patterns from its default start: what training adds),
spherical gradients (``stage.gradient_patterns``: 4 = full + x, y, z; 6 = x,
y, z and complements; fit_patterns, default start),
OLAT (every light, ``relight.fit``). All fit Lambert + GGX with the geometric
normal (``normals=False``). Errors per sample: relative albedo (mean over
RGB), relative roughness, relative F0; relit: the lumitexel relit under the
bundled Venice sunset (``relight.envmap.light_weights``, Debevec 2000) from
the fitted parameters (``relight.patterns.lumitexels``) against the truth's,
relative RMS over every (sample, channel). Also Ma et al.'s closed-form
diffuse normal (``stage.diffuse_normals``) from the 4 gradient frames.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from _common import FIG, ROOT, machine, parser
from _common import PATTERN_CAMERA_EYE as CAMERA_EYE
from _common import PATTERN_SENSOR as SENSOR

import relight
import relight.patterns as rp
import stage

FRAME_S = 1.0 / 60.0
# A roughness off by more than this is counted as "not identified" in the table.
ALPHA_FAIL = 0.25
# Bins of the true roughness and F0 for the breakdown of the roughness error.
ALPHA_BINS = (0.1, 0.18, 0.3, 0.61)
F0_BINS = (0.02, 0.04, 0.06, 0.081)


def errors(lumi, rig, w_env, relit_true, rho_d, rho_s, alpha, seconds, frames, extra=None):
    """Per-method summary: medians and 90th percentiles of the per-sample errors, the relit relative RMS."""
    rho_d = np.asarray(rho_d, np.float32).reshape(-1, 3)
    rho_s = np.asarray(rho_s, np.float32).reshape(-1)
    alpha = np.asarray(alpha, np.float32).reshape(-1)
    t_rho, t_s, t_a = (np.asarray(x, np.float64) for x in (lumi.rho_d, lumi.rho_s, lumi.alpha))
    e_rho = np.mean(np.abs(rho_d - t_rho) / t_rho, axis=1)
    e_a = np.abs(alpha - t_a) / t_a
    e_s = np.abs(rho_s - t_s) / t_s
    rad, _, _ = rp.lumitexels(rig, lumi.position, lumi.normal, lumi.tangent, lumi.bitangent, lumi.wo,
                              jnp.asarray(np.clip(rho_d, 0, 1)), jnp.asarray(np.clip(rho_s, 0, 1)),
                              jnp.asarray(np.clip(alpha, 1e-3, 1)))
    relit = np.einsum("lc,nlc->nc", w_env, np.asarray(rad, np.float64))
    rel = float(np.sqrt(np.sum((relit - relit_true) ** 2) / np.sum(relit_true ** 2)))
    per = np.sqrt(np.sum((relit - relit_true) ** 2, 1) / np.sum(relit_true ** 2, 1))
    q = lambda x, p: float(np.percentile(x, p))  # noqa: E731
    out = {"frames": frames, "seconds": seconds, "albedo_median": q(e_rho, 50), "albedo_p90": q(e_rho, 90),
           "alpha_median": q(e_a, 50), "alpha_p90": q(e_a, 90), "f0_median": q(e_s, 50), "f0_p90": q(e_s, 90),
           "alpha_fail": float(np.mean(e_a > ALPHA_FAIL)), "relit_rms": rel, "relit_sample_median": q(per, 50),
           "relit_sample_p90": q(per, 90)}
    # Where roughness fails: by the true roughness and by the true F0 (a weak or a sharp lobe).
    for name, t, edges in (("alpha", t_a, ALPHA_BINS), ("f0", t_s, F0_BINS)):
        out[f"alpha_median_by_{name}"] = [q(e_a[(t >= lo) & (t < hi)], 50) if np.any((t >= lo) & (t < hi))
                                         else None for lo, hi in zip(edges[:-1], edges[1:], strict=True)]
    out.update(extra or {})
    return out


def run(args) -> dict:
    rig = stage.light_stage_x()
    cam = stage.look_at(CAMERA_EYE, fov_deg=20, width=64, height=64)
    sensor = stage.Sensor(**SENSOR)
    env = relight.envmap.load_envmap(relight.envmap.bundled_envmap_path())
    w_env = np.asarray(relight.envmap.light_weights(env, rig.directions, rig.center_irradiance), np.float64)
    N = args.samples
    lumi = rp.simulate_lumitexels(jax.random.PRNGKey(args.seed), rig, cam.center, N, rp.TEST_RANGES)
    relit_true = np.einsum("lc,nlc->nc", w_env, np.asarray(lumi.radiance, np.float64))
    capture = rp.as_capture(lumi, rig, cam)
    surface = rp.as_surface(lumi)
    vis = np.ones((N, rig.num_lights), bool)
    key = jax.random.PRNGKey(args.seed + 1)
    rows = {}

    def note(name, row, t0):
        row["fit_wall_s"] = time.time() - t0
        rows[name] = row
        r = {k: 100 * v for k, v in row.items() if isinstance(v, float)}
        print(f"{name:28s} {row['frames']:4d} frames {row['seconds']:6.3f} s | albedo {r['albedo_median']:6.2f}%"
              f" (p90 {r['albedo_p90']:6.2f}%) | alpha {r['alpha_median']:6.2f}% (p90 {r['alpha_p90']:6.1f}%)"
              f" | F0 {r['f0_median']:6.1f}% | relit {r['relit_rms']:5.2f}% | {row['fit_wall_s']:.0f} s", flush=True)

    def patterns_fit(name, W, k, model=None, extra=None, default_start=True):
        t0 = time.time()
        pc = stage.sense_patterns(stage.capture_patterns(capture, W), sensor, jax.random.fold_in(key, k))
        if model is not None:
            dec = rp.decoder_start(pc, surface, vis, model)
            note(name + " decoder only", errors(lumi, rig, w_env, relit_true, dec["rho_d"], dec["rho_s"],
                                                dec["alpha"], W.shape[0] * FRAME_S, W.shape[0]), t0)
            t0 = time.time()
            if args.default_start and default_start:
                f = relight.fitting.fit_patterns(pc, surface, vis, model="ggx")
                note(name + " default start", errors(lumi, rig, w_env, relit_true, f.rho_d, f.rho_s, f.alpha[:, 0],
                                                     W.shape[0] * FRAME_S, W.shape[0]), t0)
                t0 = time.time()
            f = rp.fit_learned(pc, surface, vis, model)
        else:
            f = relight.fitting.fit_patterns(pc, surface, vis, model="ggx")
        row = errors(lumi, rig, w_env, relit_true, f.rho_d, f.rho_s, f.alpha[:, 0], W.shape[0] * FRAME_S,
                     W.shape[0], dict(extra or {}, failed=int(np.sum(np.asarray(f.failed)))))
        note(name, row, t0)
        return pc

    for k in args.patterns:
        model, meta = rp.load_model(args.models / f"lsx_K{k}")
        patterns_fit(f"learned {k}", np.asarray(model.patterns), 100 + k, model=model,
                     extra={"train_steps": meta.get("steps")})
    for k in args.patterns if args.compare else ():
        # The plain decoder (no closed-form specular features), trained by --no-grid into --compare.
        path = args.compare / f"lsx_K{k}"
        if path.with_suffix(".eqx").is_file():
            model, meta = rp.load_model(path)
            patterns_fit(f"plain {k}", np.asarray(model.patterns), 300 + k, model=model, default_start=False,
                         extra={"train_steps": meta.get("steps")})
    for k in args.patterns:
        # The untrained pattern layer (the training's initialisation, seed 0 + K): what learning adds.
        init = rp.PatternAutoencoder(jax.random.split(jax.random.PRNGKey(k))[0], k, rig.num_lights, width=8, depth=1)
        patterns_fit(f"random {k}", np.asarray(init.patterns), 200 + k)
    for comp, n in ((False, 4), (True, 6)):
        W = np.asarray(stage.gradient_patterns(rig, complement=comp))
        pc = patterns_fit(f"gradient {n}", W, n, extra={})
        if not comp:
            # Ma et al. 2007 eq. 4 needs the patterns in gradient_weights' units; the [0, 1] set is one scale of them.
            nrm = np.asarray(stage.diffuse_normals(pc.radiance))[0]
            c = np.clip(np.sum(nrm * np.asarray(lumi.normal), 1), -1, 1)
            ang = np.rad2deg(np.arccos(c))
            rows["gradient 4"]["normal_closed_form_median_deg"] = float(np.median(ang))
            rows["gradient 4"]["normal_closed_form_p90_deg"] = float(np.percentile(ang, 90))
    t0 = time.time()
    olat = stage.sense(capture, sensor, jax.random.fold_in(key, 999))
    f = relight.fit(olat, surface, model="ggx")
    note("OLAT 346", errors(lumi, rig, w_env, relit_true, f.rho_d, f.rho_s, f.alpha[:, 0], rig.num_lights * FRAME_S,
                            rig.num_lights, {"failed": int(np.sum(np.asarray(f.failed)))}), t0)
    return {"machine": machine(), "samples": N, "seed": args.seed, "sensor": SENSOR, "frame_s": FRAME_S,
            "test_ranges": {"rho_d": rp.TEST_RANGES.rho_d, "rho_s": rp.TEST_RANGES.rho_s,
                            "alpha": rp.TEST_RANGES.alpha, "radius_mm": rp.TEST_RANGES.radius_mm,
                            "max_view_deg": rp.TEST_RANGES.max_view_deg}, "rows": rows}


def table(res) -> str:
    lines = [f"Learned patterns against OLAT and gradient illumination, Light Stage X, {res['samples']} held-out "
             f"samples (seed {res['seed']}), sensor {res['sensor']}, frame {res['frame_s']:.4f} s. "
             f"Errors per sample, relative; 'alpha > {int(ALPHA_FAIL * 100)}%': share of samples whose roughness is "
             "off by more than that; relit: relative RMS of the Venice-sunset relit lumitexels over all "
             "(sample, channel).", "",
             "| method | frames | capture time | albedo median | albedo p90 | roughness median | roughness p90 | "
             f"alpha > {int(ALPHA_FAIL * 100)}% | F0 median | relit RMS | fit time |",
             "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    for name, r in res["rows"].items():
        lines.append(f"| {name} | {r['frames']} | {r['seconds']:.3f} s | {100 * r['albedo_median']:.2f}% | "
                     f"{100 * r['albedo_p90']:.2f}% | {100 * r['alpha_median']:.2f}% | {100 * r['alpha_p90']:.1f}% | "
                     f"{100 * r['alpha_fail']:.1f}% | {100 * r['f0_median']:.1f}% | {100 * r['relit_rms']:.2f}% | "
                     f"{r['fit_wall_s']:.0f} s |")
    lines += ["", "Median roughness error by true roughness (" + ", ".join(
        f"[{a:g}, {b:g})" for a, b in zip(ALPHA_BINS[:-1], ALPHA_BINS[1:], strict=True)) + ") and by true F0 (" +
        ", ".join(f"[{a:g}, {b:g})" for a, b in zip(F0_BINS[:-1], F0_BINS[1:], strict=True)) + "):", "",
        "| method | by alpha | by F0 |", "| --- | --- | --- |"]
    fmt = lambda v: " / ".join("-" if x is None else f"{100 * x:.1f}%" for x in v)  # noqa: E731
    for name, r in res["rows"].items():
        lines.append(f"| {name} | {fmt(r['alpha_median_by_alpha'])} | {fmt(r['alpha_median_by_f0'])} |")
    g = res["rows"].get("gradient 4", {})
    if "normal_closed_form_median_deg" in g:
        lines += ["", "Ma et al. 2007's closed-form diffuse normal from the 4 gradient frames (specular included): "
                  f"median {g['normal_closed_form_median_deg']:.2f} deg, "
                  f"p90 {g['normal_closed_form_p90_deg']:.2f} deg."]
    lines += ["", f"Machine: {res['machine']}."]
    return "\n".join(lines) + "\n"


def plot(res, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = res["rows"]
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.6))
    panels = (("albedo", "diffuse albedo error (relative)"), ("alpha", "roughness error (relative)"),
              ("relit", "relit error (relative RMS)"))
    groups = {"learned": ("C0", "o", "learned + fit_patterns"), "decoder": ("C0", "x", "learned, decoder only"),
              "default": ("C2", "s", "learned, default start"),
              "plain": ("C4", "^", "learned, plain decoder + fit_patterns"), "random": ("C7", "v", "random patterns"),
              "gradient": ("C1", "D", "gradient (Ma 2007)"),
              "OLAT": ("C3", "*", "OLAT (346)")}

    def group(name):
        if name.startswith("plain"):
            return "plain decoder" if name.endswith("decoder only") else "plain"
        if name.endswith("decoder only"):
            return "decoder"
        if name.endswith("default start"):
            return "default"
        return name.split(" ")[0]

    for ax, (what, title) in zip(axes, panels, strict=True):
        for g, (col, mk, label) in groups.items():
            pts = sorted(((r["seconds"], r, n) for n, r in rows.items() if group(n) == g), key=lambda p: p[0])
            if not pts:
                continue
            t = [p[0] for p in pts]
            if what == "relit":
                ax.plot(t, [p[1]["relit_rms"] for p in pts], marker=mk, color=col, label=label,
                        ls="-" if g == "learned" else ":")
            else:
                ax.plot(t, [p[1][f"{what}_median"] for p in pts], marker=mk, color=col, label=label + " (median)",
                        ls="-" if g == "learned" else ":")
                if g in ("learned", "gradient", "OLAT"):
                    ax.plot(t, [p[1][f"{what}_p90"] for p in pts], marker=mk, color=col, alpha=0.4, ls="--",
                            label=label + " (p90)")
            for s, r, _ in pts:
                if g in ("learned", "gradient", "OLAT"):
                    ax.annotate(str(r["frames"]), (s, r["relit_rms"] if what == "relit" else r[f"{what}_median"]),
                                textcoords="offset points", xytext=(4, 4), fontsize=7, color=col)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel(f"capture time [s] (frames x {res['frame_s'] * 1000:.1f} ms)")
        ax.set_title(title)
        ax.grid(True, which="both", alpha=0.3)
        if what == "albedo":
            ax.axhline(0.02, color="k", lw=0.8, ls="-.")
            ax.text(ax.get_xlim()[0], 0.02, " 2% bar", fontsize=7, va="bottom")
        if what == "alpha":
            ax.axhline(0.10, color="k", lw=0.8, ls="-.")
            ax.text(ax.get_xlim()[0], 0.10, " 10% bar", fontsize=7, va="bottom")
    axes[0].legend(fontsize=7, loc="best")
    fig.suptitle(f"Learned patterns (Kang et al. 2018) vs OLAT and gradients, Light Stage X, {res['samples']} "
                 "held-out samples, same per-frame sensor", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main(argv=None) -> int:
    ap = parser(__doc__)
    ap.add_argument("--samples", type=int, default=1000)
    ap.add_argument("--patterns", default="4,8,16,32,64")
    ap.add_argument("--models", type=Path, default=ROOT / "build" / "patterns")
    ap.add_argument("--seed", type=int, default=2026)
    ap.add_argument("--out", type=Path, default=FIG)
    ap.add_argument("--no-default-start", dest="default_start", action="store_false",
                    help="skip fit_patterns from its own default start for the learned patterns")
    ap.add_argument("--compare", type=Path, default=None,
                    help="also the plain-decoder models in this folder (train_patterns.py --no-grid --out ...)")
    ap.add_argument("--replot", action="store_true")
    args = ap.parse_args(argv)
    args.patterns = [int(k) for k in args.patterns.split(",")]
    res_path = args.out / "patterns_results.json"
    if args.replot:
        res = json.loads(res_path.read_text())
    else:
        t0 = time.time()
        res = run(args)
        res["wall_s"] = time.time() - t0
        args.out.mkdir(parents=True, exist_ok=True)
        res_path.write_text(json.dumps(res, indent=1) + "\n")
    (args.out / "patterns_table.md").write_text(table(res))
    plot(res, args.out / "patterns_chart.png")
    print(table(res))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
