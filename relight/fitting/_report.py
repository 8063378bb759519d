"""The report of a fit: what the solver did, and, against an optional truth (a
simulated capture's ``truth/`` maps), every map's error over the seen texels
and over the unflagged ones, with the counts. ``relight fit`` and ``relight
demo`` write it as report.json (:func:`fit_report`) and report.md
(:func:`report_markdown`)."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ..materials import LAMBERT, MODELS, SUBSURFACE

# against_truth["errors"]: name -> what it is and the samples it is over (beyond "seen" / "unflagged").
ERROR_ROWS = {
    "diffuse_albedo_rel": "diffuse albedo relative error, abs(fit - truth) / truth (mean over R, G, B per texel)",
    "specular_albedo_rel": "specular albedo relative error (texels whose true rung has a lobe and rho_s > 0)",
    "roughness_rel": "roughness relative error (texels whose fitted and true rung both have a lobe)",
    "normal_deg": "shading normal angle to the truth's, degrees (normals fitted)",
    "mfp_rel": "mean free path relative error (texel-channels with a true mean free path > 0)",
    "mfp_rel_identified": "mean free path relative error (texel-channels the fit identifies)",
    "mfp_rel_identified_r": "mean free path relative error, red (texels whose red channel the fit identifies)",
    "mfp_rel_identified_g": "mean free path relative error, green (texels whose green channel the fit identifies)",
    "mfp_rel_identified_b": "mean free path relative error, blue (texels whose blue channel the fit identifies)",
}
# Relative errors divide by the truth floored here: a zero true value gives a large, finite error.
_REL_FLOOR = 1e-12


def angular_error_deg(n, gt) -> np.ndarray:
    """The angle between two fields of directions, in degrees.

    Args:
        n: directions [P, 3] (any length > 0; normalised here).
        gt: reference directions [P, 3] (normalised here).

    Returns:
        Angles [P] in degrees, in [0, 180]; 90 where either direction has zero length.
    """
    a, b = np.asarray(n, np.float64), np.asarray(gt, np.float64)
    c = np.sum(a * b, -1) / np.maximum(np.linalg.norm(a, axis=-1) * np.linalg.norm(b, axis=-1), 1e-30)
    return np.degrees(np.arccos(np.clip(c, -1.0, 1.0)))


def _rel(a, b) -> np.ndarray:
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    return np.abs(a - b) / np.maximum(np.abs(b), _REL_FLOOR)


def _stats(values, where) -> dict:
    """{"samples", "median", "p95"} of ``values`` [P] or [P, C] at ``where`` ([P]: texels, channels pooled;
    [P, C]: texel-channels); ``samples`` counts ``where``; None statistics over no sample (JSON has no NaN)."""
    where = np.asarray(where, bool)
    v = np.asarray(values, np.float64)[where].reshape(-1)
    v = v[np.isfinite(v)]
    n = int(np.count_nonzero(where))
    if v.size == 0:
        return {"samples": n, "median": None, "p95": None}
    return {"samples": n, "median": float(np.median(v)), "p95": float(np.percentile(v, 95))}


def truth_errors(fitted, truth, normals: bool = False, seen=None) -> dict:
    """Every map's error of a fit against the true maps, over the seen and over the unflagged samples.

    Args:
        fitted: a :class:`relight.Fit` (or its fields as NumPy arrays) with per-sample ``observed`` and
            ``failed``.
        truth: the true :class:`relight.MaterialMaps` at the same samples.
        normals: also compare the shading normals (fitted with ``normals=True``).
        seen: bool [P], the samples counted as seen; None: those with observations (``observed > 0``).

    Returns:
        ``{"seen_samples", "unflagged_samples", "errors": {name: {"what", "all_seen", "unflagged"}}}``:
        each row (``ERROR_ROWS``) over the seen samples (flagged ones included: their maps are what the
        fit wrote) and over the seen unflagged ones, each ``{"samples", "median", "p95"}``.
        Roughness is over the samples whose fitted and true rung both have a lobe (a Lambert sample's
        roughness is a placeholder), specular albedo where the truth has one, the mean free path rows
        only when the truth scatters somewhere (per texel-channel).
    """
    seen = np.asarray(fitted.observed) > 0 if seen is None else np.asarray(seen, bool).reshape(-1)
    ok = seen & ~np.asarray(fitted.failed, bool)
    f_model, t_model = np.asarray(fitted.model).reshape(-1), np.asarray(truth.model).reshape(-1)
    every = np.ones_like(seen)
    t_rho_s = np.asarray(truth.rho_s, np.float64)[:, 0]
    rows = {"diffuse_albedo_rel": (_rel(fitted.rho_d, truth.rho_d).mean(-1), every),
            "specular_albedo_rel": (_rel(fitted.rho_s, truth.rho_s), (t_model != LAMBERT) & (t_rho_s > 0)),
            "roughness_rel": (_rel(np.asarray(fitted.alpha)[:, :1], np.asarray(truth.alpha)[:, :1]),
                              (f_model != LAMBERT) & (t_model != LAMBERT))}
    if normals:
        rows["normal_deg"] = (angular_error_deg(fitted.normal, truth.normal), every)
    if np.any(t_model == SUBSURFACE):
        t_mfp = np.asarray(truth.mfp, np.float64)
        f_mfp = np.zeros_like(t_mfp) if getattr(fitted, "mfp", None) is None else np.asarray(fitted.mfp, np.float64)
        ident = getattr(fitted, "mfp_identified", None)
        ident = np.zeros_like(t_mfp, bool) if ident is None else np.asarray(ident, bool)
        e = _rel(f_mfp, t_mfp)
        rows["mfp_rel"] = (e, t_mfp > 0)
        rows["mfp_rel_identified"] = (e, ident)
        for c, name in enumerate("rgb"):
            rows[f"mfp_rel_identified_{name}"] = (e[:, c], ident[:, c])

    def at(mask, m):
        m = np.asarray(m, bool)
        return (mask[:, None] if m.ndim == 2 else mask) & m

    errors = {name: {"what": ERROR_ROWS[name], "all_seen": _stats(v, at(seen, m)), "unflagged": _stats(v, at(ok, m))}
              for name, (v, m) in rows.items()}
    return {"seen_samples": int(seen.sum()), "unflagged_samples": int(ok.sum()), "errors": errors}


def read_truth(capture_dir: str | os.PathLike, surface):
    """The true maps of a simulated capture (its ``truth/`` texture set) at the surface's samples.

    Args:
        capture_dir: a capture folder or store written by ``relight simulate``.
        surface: the fitted ``stage.Surface``.

    Returns:
        The truth's :class:`relight.MaterialMaps`, or None when the capture has no ``truth/`` set.
    """
    from ..io import is_map_set, read_maps

    truth_dir = Path(capture_dir) / "truth"
    if not is_map_set(truth_dir):
        return None
    textures, _ = read_maps(truth_dir)
    return textures.maps(surface)


def fit_report(fitted, surface, truth=None, *, normals: bool = False, timings: dict | None = None,
               seen=None) -> dict:
    """The report of a fit: flagged fraction, residuals, steps, rungs and, with a truth, every map's error.

    Args:
        fitted: a :class:`relight.Fit` (NumPy leaves keep the statistics free of compilation).
        surface: the fitted ``stage.Surface``.
        truth: the true :class:`relight.MaterialMaps` at the same samples (a simulation's), or None.
        normals: the fit fitted shading normals (their angle to the truth's is reported).
        timings: seconds per stage (``{"fit_s": ...}``), reported rounded to the millisecond.
        seen: bool [P], the samples some camera saw (a photo capture's ``~PhotoTexelReport.unseen``): the
            others are counted as unseen, apart from the failures, and the truth errors count these as seen
            (:func:`truth_errors`); None: those with observations.

    Returns:
        A JSON-able dict: ``samples``, ``failed_fraction`` (every flagged sample, unseen ones included),
        ``unseen_samples`` (no camera saw them: no observation, their maps the map set's fill),
        ``seen_samples``, ``failed_seen_samples`` / ``failed_seen_fraction`` (flagged among the seen: a
        solver failure or fewer valid observations than the fit needs), ``residual_rms_median`` (unflagged samples),
        ``observed_samples``, ``steps_median`` and ``observed_median`` (over the samples with
        observations), ``timings_s``, ``model_counts`` / ``unresolved_fraction`` / ``ambiguous_fraction`` /
        ``collapsed_fraction`` / ``lobe_unmeasured_fraction``
        where the fit has them, and with a truth ``against_truth`` (:func:`truth_errors`; None when every
        sample is flagged).
    """
    failed = np.asarray(fitted.failed, bool)
    observed = np.asarray(fitted.observed)
    has_obs = observed > 0
    seen_ = has_obs if seen is None else np.asarray(seen, bool)
    n_seen = int(seen_.sum())
    r = {
        "samples": int(surface.num_samples),
        "failed_fraction": float(np.mean(failed)),
        "unseen_samples": int(surface.num_samples) - n_seen,
        "seen_samples": n_seen,
        "failed_seen_samples": int(np.sum(failed & seen_)),
        "failed_seen_fraction": float(np.sum(failed & seen_) / n_seen) if n_seen else None,
        "residual_rms_median": float(np.median(np.asarray(fitted.residual)[~failed])) if (~failed).any() else None,
        "observed_samples": int(np.sum(has_obs)),
        "steps_median": float(np.median(np.asarray(fitted.steps)[has_obs])) if has_obs.any() else 0.0,
        "observed_median": float(np.median(observed[has_obs])) if has_obs.any() else 0.0,
        "timings_s": {k: round(float(v), 3) for k, v in (timings or {}).items()},
    }
    if getattr(fitted, "model", None) is not None:
        counts = np.bincount(np.asarray(fitted.model).reshape(-1), minlength=len(MODELS))
        r["model_counts"] = {m: int(c) for m, c in zip(MODELS, counts, strict=False)}
    for name in ("unresolved", "ambiguous", "collapsed", "lobe_unmeasured"):
        if getattr(fitted, name, None) is not None:
            r[f"{name}_fraction"] = float(np.mean(np.asarray(getattr(fitted, name))))
    if truth is not None:
        # Every sample flagged (e.g. a 12-light dome leaves fewer than 8 valid lights a texel): nothing to compare.
        r["against_truth"] = truth_errors(fitted, truth, normals=normals, seen=seen) if (~failed).any() else None
    return r


def subsurface_report(fitted, settings: dict, truth=None, seconds: float = 0.0) -> dict:
    """The subsurface part of a fit's report: where the subsurface rung was chosen and its mean free paths.

    Args:
        fitted: a :class:`relight.Fit` after :func:`relight.fit_subsurface`.
        settings: the subsurface settings to record (mode, eta, regions, ...), copied into the result.
        truth: the true :class:`relight.MaterialMaps`, or None.
        seconds: the subsurface fit's time.

    Returns:
        ``settings`` plus ``subsurface_samples``, ``samples``, ``mfp_median_mm`` (per channel, over the
        subsurface samples), ``seconds``, ``rung_counts`` and ``identified_fraction`` /
        ``identified_sigma`` where the fit has them, and with a truth ``against_truth``: the truth's
        subsurface samples and median mean free path, the median relative error per channel over the
        samples subsurface in both (``mfp_rel_error_median``) and the fraction where the choice agrees.
    """
    model = np.asarray(fitted.model)
    on = model == SUBSURFACE
    mfp = np.asarray(fitted.mfp, np.float64) if fitted.mfp is not None else np.zeros((len(model), 3))
    r = {**settings, "subsurface_samples": int(on.sum()), "samples": int(len(model)),
         "mfp_median_mm": np.median(mfp[on], axis=0).tolist() if on.any() else None, "seconds": round(seconds, 3)}
    rung = getattr(fitted, "mfp_rung", None)
    if rung is not None:
        counts = np.bincount(np.asarray(rung).reshape(-1), minlength=3)
        r["rung_counts"] = {"none": int(counts[0]), "region": int(counts[1]), "texel": int(counts[2])}
    ident = getattr(fitted, "mfp_identified", None)
    if ident is not None:
        ident = np.asarray(ident, bool)
        # Over the subsurface samples, per channel: the 1-sigma of ln mfp below Fit.IDENTIFIED_SIGMA.
        r["identified_fraction"] = ident[on].mean(axis=0).tolist() if on.any() else None
        r["identified_sigma"] = float(getattr(type(fitted), "IDENTIFIED_SIGMA", float("nan")))
    if truth is not None:
        t_on = np.asarray(truth.model) == SUBSURFACE
        t_mfp = np.asarray(truth.mfp, np.float64)
        both = on & t_on
        r["against_truth"] = {
            "truth_subsurface_samples": int(t_on.sum()),
            "truth_mfp_median_mm": np.median(t_mfp[t_on], axis=0).tolist() if t_on.any() else None,
            "mfp_rel_error_median": (np.median(_rel(mfp[both], t_mfp[both]), axis=0).tolist()
                                     if both.any() else None),
            "model_agreement": float(np.mean(on == t_on)),
        }
    return r


def _g(x, unit: str = "") -> str:
    """A report number to 3 significant figures ("-" for None)."""
    return "-" if x is None else f"{x:.3g}{unit}"


def _truth_md(a: dict) -> list[str]:
    lines = [f"Against the simulated truth, over the {a['seen_samples']} seen texels (flagged ones included: their "
             f"maps are what the fit wrote) and over the {a['unflagged_samples']} unflagged ones (samples: texels, "
             "texel-channels for the mean free path):", "",
             "| error | seen texels: median / 95th pct (samples) | unflagged: median / 95th pct (samples) |",
             "| --- | --- | --- |"]
    for row in a["errors"].values():
        cells = [f"{_g(c['median'])} / {_g(c['p95'])} ({c['samples']})" for c in (row["all_seen"], row["unflagged"])]
        lines.append(f"| {row['what']} | {cells[0]} | {cells[1]} |")
    return lines + [""]


def _subsurface_md(ss: dict) -> list[str]:
    fmt = lambda v: "-" if v is None else " / ".join(f"{x:.3g}" for x in v)  # noqa: E731
    regions = "" if ss.get("regions") is None else f", {ss['regions']['count']} regions of {ss['regions']['file']}"
    lines = ["## Subsurface scattering", "",
             f"Mode {ss['mode']}{regions}, eta {ss['eta']:g} ({ss['eta_from']}): {ss['subsurface_samples']} of "
             f"{ss['samples']} texels on the subsurface rung (the others keep the BRDF's local Lambert term); "
             f"{ss['seconds']:.2f} s.", "",
             "| mean free path (mm) | R / G / B |", "| --- | --- |",
             f"| median over subsurface texels | {fmt(ss['mfp_median_mm'])} |"]
    if "identified_fraction" in ss:
        lines.append(f"| identified fraction (1-sigma of ln mfp < {ss['identified_sigma']:g}) | "
                     f"{fmt(ss['identified_fraction'])} |")
    if "against_truth" in ss:
        a = ss["against_truth"]
        lines += [f"| simulated truth, median | {fmt(a['truth_mfp_median_mm'])} |",
                  f"| relative error vs truth, median | {fmt(a['mfp_rel_error_median'])} |"]
    lines.append("")
    if "rung_counts" in ss:
        c = ss["rung_counts"]
        lines += [f"Texels per rung: none {c['none']}, region {c['region']}, texel {c['texel']}.", ""]
    if "against_truth" in ss:
        lines += [f"Subsurface / local choice agrees with the truth on "
                  f"{100 * ss['against_truth']['model_agreement']:.1f}% of the texels.", ""]
    return lines


def _photos_md(ph: dict) -> list[str]:
    return [f"Photo capture resampled onto the texel grid ({ph['sampling']}; views beyond {ph['grazing_deg']:g} "
            f"degrees, outside a mask, occluded or saturated dropped): **{ph['unseen']} of {ph['texels']} texels "
            f"({100 * ph['unseen_fraction']:.1f}%) unseen** (seen by fewer than {ph['min_views']} camera(s); "
            "flagged, red in coverage.png, 0 in coverage.exr; their maps hold the map set's fill, maps.json "
            "`unseen`: the nearest seen texel's material and the mesh's normal, not measurements).", "",
            "| camera | texels seen | valid observations |", "| --- | --- | --- |",
            *[f"| {v['camera']} | {v['seen']} | {100 * v['valid_fraction']:.1f}% |" for v in ph["views"]], ""]


def _diligent_md(dg: dict) -> list[str]:
    lines = [f"DiLiGenT object {dg['object']}: {dg['pixels']} pixels (every {dg['subsample']}-th in x and y), "
             f"{dg['lights']} lights; shading normals fitted (normals.png: 0.5 + 0.5 n, camera frame).", ""]
    if "normal_error_deg" in dg:
        e = dg["normal_error_deg"]
        lines += ["| angular error vs Normal_gt (deg) | mean | median |", "| --- | --- | --- |",
                  f"| relight fit | {e['mean']:.2f} | {e['median']:.2f} |",
                  f"| Lambertian least squares (baseline) | {e['lambert_ls_baseline_mean']:.2f} | "
                  f"{e['lambert_ls_baseline_median']:.2f} |", ""]
    return lines


def flagged_summary(report: dict) -> str:
    """How a fit's flagged samples split (:func:`fit_report`'s counts): those no camera saw apart from the
    failures among the seen, e.g. "2493 unseen (no camera saw them; coverage 0, maps.json's fill) and 12 of
    the 1289 seen failed (a solver failure or fewer than 8 valid lights)"."""
    r = report
    if "unseen_samples" not in r:  # a report written before the split
        return "solver failure, fewer than 8 valid lights or unseen"
    return (f"{r['unseen_samples']} unseen (no camera saw them; coverage 0, their maps maps.json's fill) and "
            f"{r['failed_seen_samples']} of the {r['seen_samples']} seen failed (a solver failure or fewer than 8 "
            "valid lights)")


def report_markdown(report: dict, title: str = "relight fit report", preface=()) -> str:
    """A fit's report (:func:`fit_report`, with its optional sections) as Markdown.

    Args:
        report: the dict of :func:`fit_report`, optionally with ``subsurface`` (:func:`subsurface_report`),
            ``photos`` (``relight.io.PhotoTexelReport.to_dict()``) and ``diligent``
            (:func:`relight.fitting.fit_diligent`'s) entries.
        title: the page's heading.
        preface: lines placed after the heading (a caller's description of its run).

    Returns:
        The Markdown text: every number to 3 significant figures, each error row saying over which samples.
    """
    r = report
    lines = [f"# {title}", "", *preface,
             f"{r['samples']} texels fitted; {100 * r['failed_fraction']:.2f}% flagged: {flagged_summary(r)}. "
             f"Median RMS residual {_g(r['residual_rms_median'])} (unflagged texels); over the "
             f"{r['observed_samples']} texels with observations, median steps {r['steps_median']:.0f} and median "
             f"valid observations {r['observed_median']:.0f}.", ""]
    if r.get("ambiguous_fraction"):
        lines += [f"{100 * r['ambiguous_fraction']:.2f}% of the texels are ambiguous (`Fit.ambiguous`: a diffuse "
                  "albedo 1-sigma above 10%; at low signal to noise a broad grey lobe can take part of the diffuse "
                  "term, so their albedo may read dark).", ""]
    if r.get("collapsed_fraction"):
        lines += [f"{100 * r['collapsed_fraction']:.2f}% of the texels have a collapsed lobe (`Fit.collapsed`: F0 "
                  "below 1% or roughness at 0.95 or above on a lobed rung; the lights do not constrain that lobe, "
                  "so its F0 and roughness are not measurements).", ""]
    if r.get("lobe_unmeasured_fraction"):
        lines += [f"{100 * r['lobe_unmeasured_fraction']:.2f}% of the texels have a lobe no light of theirs sampled "
                  "(`Fit.lobe_unmeasured`: F0 and roughness taken from their neighbours, sigma inf; a prior, not a "
                  "measurement).", ""]
    if "against_truth" in r and r["against_truth"] is None:
        lines += ["Every texel is flagged, so there is no comparison against the simulated truth.", ""]
    elif "against_truth" in r:
        lines += _truth_md(r["against_truth"])
    if "photos" in r:
        lines += _photos_md(r["photos"])
    if "diligent" in r:
        lines += _diligent_md(r["diligent"])
    if "subsurface" in r:
        lines += _subsurface_md(r["subsurface"])
    if "model_counts" in r:
        lines += ["Texels per model: " + ", ".join(f"{k} {v}" for k, v in r["model_counts"].items() if v) + ".", ""]
    lines += ["| stage | seconds |", "| --- | --- |",
              *[f"| {k.removesuffix('_s')} | {v:.2f} |" for k, v in r["timings_s"].items()], ""]
    return "\n".join(lines)
