"""Evaluate relight.fit on a DiLiGenT object folder (Shi et al. 2019): normal
accuracy against the ground truth and prediction of held-out lights, each
against the benchmark's Lambertian least-squares baseline.

    python scripts/eval_diligent.py ../shared/data/diligent/ballPNG [--model ggx] [--out docs/figures]

The fits use relight.fit_diligent's settings unless told otherwise: the Cauchy loss
(relight.fitting.DILIGENT_LOSS) and the cast-shadow censoring (relight.fitting.SHADOW_RATIO;
``--shadow-ratio 0`` turns it off).

Works on any DiLiGenT-layout folder (images, light_directions.txt,
light_intensities.txt, mask.png, Normal_gt.mat). Held-out protocol: every
sixth light (16 of 96) is held out; both methods fit the other 80 and predict
the 16; the error is the relative RMS over in-mask, unsaturated observations.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
from _common import parser, save_figure


def main(argv=None):
    ap = parser(__doc__)
    ap.add_argument("object_dir", type=Path)
    ap.add_argument("--model", default="blinn_phong", help="fit model rung or 'auto' (default: blinn_phong)")
    ap.add_argument("--solver", default="lm")
    ap.add_argument("--loss", default=None, help="'cauchy' or 'l2' (default: relight.fitting.DILIGENT_LOSS)")
    ap.add_argument("--shadow-ratio", type=float, default=None,
                    help="censor observations below this fraction of the first fit's prediction and refit "
                         "(default: relight.fitting.SHADOW_RATIO; 0: off)")
    ap.add_argument("--chunk", type=int, default=2048)
    ap.add_argument("--rounds", type=int, default=6, help="rounds of 20 solver steps (default: 6)")
    ap.add_argument("--subsample", type=int, default=1, help="fit every k-th pixel in x and y (quick looks)")
    ap.add_argument("--out", type=Path, default=None, help="write <name>.json and <name>_normals.png here")
    a = ap.parse_args(argv)

    import relight
    import relight.evaluation as ev
    from relight.fitting import angular_error_deg
    from relight.io import diligent_capture, read_diligent

    loss = relight.fitting.DILIGENT_LOSS if a.loss is None else a.loss
    ratio = relight.fitting.SHADOW_RATIO if a.shadow_ratio is None else a.shadow_ratio
    fit_kw = dict(model=a.model, normals=True, solver=a.solver, loss=loss, shadow_ratio=ratio or None,
                  options=relight.fitting.FitOptions(chunk=a.chunk, rounds=a.rounds))
    d = read_diligent(a.object_dir)
    if a.subsample > 1:
        import dataclasses

        keep = np.zeros_like(d.mask)
        keep[::a.subsample, ::a.subsample] = True
        d = dataclasses.replace(d, mask=d.mask & keep)
    if d.normals_gt is None:
        raise SystemExit(f"{a.object_dir}: no Normal_gt.mat, cannot score normals")
    name = a.object_dir.name
    gt = d.normals_gt[d.mask]
    n_lights = len(d.filenames)
    every = np.arange(n_lights)
    held = every[3::6]
    train = np.setdiff1d(every, held)

    n_base, _ = ev.lambert_least_squares(d, every)
    err_base = angular_error_deg(n_base, gt)
    capture, surface = diligent_capture(d)
    t0 = time.perf_counter()
    f = relight.fit(capture, surface, **fit_kw)
    t_fit = time.perf_counter() - t0
    err_fit = angular_error_deg(np.asarray(f.normal), gt)

    # Held-out lights: both fit on the 80 training lights, predict the 16.
    n_tr, alb_tr = ev.lambert_least_squares(d, train)
    obs = d.images[held][:, d.mask, :]
    valid = np.all(obs < 0.995, -1) & (d.light_directions[held, 2] > 0)[:, None]
    base_pred = ev.predict_lambert(n_tr, alb_tr, d, held)
    cap_tr, _ = diligent_capture(d, lights=train)
    f_tr = relight.fit(cap_tr, surface, **fit_kw)
    cap_h, _ = diligent_capture(d, lights=held)
    fit_pred = ev.predict_fit(f_tr, cap_h, surface)
    e_base, e_fit = ev.relative_rms(base_pred, obs, valid), ev.relative_rms(fit_pred, obs, valid)

    report = {
        "object": name, "pixels": int(d.mask.sum()), "lights": n_lights, "model": a.model, "solver": a.solver,
        "loss": loss, "shadow_ratio": ratio or None, "rounds": a.rounds,
        "normal_error_mean_deg": {"lambert_ls_baseline": float(err_base.mean()), "relight_fit": float(err_fit.mean())},
        "normal_error_median_deg": {"lambert_ls_baseline": float(np.median(err_base)),
                                    "relight_fit": float(np.median(err_fit))},
        "heldout_rel_rms": {"lambert_ls_baseline": e_base, "relight_fit": e_fit, "ratio": e_fit / e_base},
        "fit_failed_fraction": float(np.mean(np.asarray(f.failed))),
        "fit_seconds_all_lights": round(t_fit, 2),
    }
    print(f"{name}: {report['pixels']} pixels, {n_lights} lights, model {a.model} + normals ({a.solver}, "
          f"loss {loss}, shadow ratio {ratio or None})")
    print("| | Lambertian LS baseline | relight.fit |")
    print("|---|---|---|")
    print(f"| mean normal error (deg) | {err_base.mean():.2f} | {err_fit.mean():.2f} |")
    print(f"| median normal error (deg) | {np.median(err_base):.2f} | {np.median(err_fit):.2f} |")
    print(f"| held-out 16 lights, relative RMS | {e_base:.4f} | {e_fit:.4f} (x{e_fit / e_base:.2f}) |")
    print(f"fit time (96 lights): {t_fit:.1f} s; failed samples: {100 * report['fit_failed_fraction']:.2f}%")
    if a.out is not None:
        a.out.mkdir(parents=True, exist_ok=True)
        (a.out / f"diligent_{name}.json").write_text(json.dumps(report, indent=2))
        _figure(a.out / f"diligent_{name}_normals.png", d, err_base, err_fit, np.asarray(f.normal))
    return report


def _figure(path, d, err_base, err_fit, n_fit):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    def img(vals, fill=np.nan):
        out = np.full(d.mask.shape + vals.shape[1:], fill)
        out[d.mask] = vals
        return out

    fig, ax = plt.subplots(1, 4, figsize=(14, 3.6))
    ax[0].imshow(np.clip(img(0.5 + 0.5 * d.normals_gt[d.mask], 1.0), 0, 1))
    ax[0].set_title("ground-truth normals")
    ax[1].imshow(np.clip(img(0.5 + 0.5 * n_fit, 1.0), 0, 1))
    ax[1].set_title("relight.fit normals")
    vmax = float(np.percentile(err_base, 99))
    for k, (e, t) in enumerate(((err_base, "Lambertian LS"), (err_fit, "relight.fit"))):
        im = ax[2 + k].imshow(img(e), vmin=0, vmax=vmax, cmap="magma")
        ax[2 + k].set_title(f"{t}: mean {e.mean():.2f} deg")
        fig.colorbar(im, ax=ax[2 + k], fraction=0.046)
    for x in ax:
        x.set_axis_off()
    fig.tight_layout()
    save_figure(fig, path, dpi=90)


if __name__ == "__main__":
    main()
