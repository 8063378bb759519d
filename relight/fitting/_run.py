"""Whole fits of one kind of input, as ``relight fit`` runs them: a DiLiGenT
object (per-pixel shading normals against the benchmark's ground truth) and the
subsurface step after a BRDF fit (per region, per texel or the held-out ladder,
one pass or several alternations)."""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path

import numpy as np

import skin_bssrdf

from ._driver import DEFAULT_MODEL
from ._joint import fit_with_subsurface
from ._report import angular_error_deg
from ._shadows import SHADOW_RATIO
from ._subsurface import fit_subsurface

# The model and loss a DiLiGenT object is fitted with unless told otherwise (scripts/eval_diligent.py's). Its
# product is the normal, which the robust loss recovers better past unmasked cast shadows and interreflections
# (docs/fit.md, "Defaults"); the cast shadows the loss still feels are censored before a second fit
# (``shadow_ratio=SHADOW_RATIO``: the cat's folds; docs/fit.md, "How", item 4).
DILIGENT_MODEL = "blinn_phong"
DILIGENT_LOSS = "cauchy"


def fit_diligent(data, *, name: str | None = None, subsample: int = 1, **fit_kw):
    """Fit the model and the shading normal per pixel of a DiLiGenT object, scored against its truth.

    Args:
        data: a ``relight.io.DiligentData`` (``relight.io.read_diligent``).
        name: the object's name for the report (its folder's name).
        subsample: fit every k-th pixel in x and y (1: all).
        **fit_kw: :func:`relight.fit`'s keywords (``model`` defaults to ``DILIGENT_MODEL``, ``loss`` to
            ``DILIGENT_LOSS``, ``shadow_ratio`` to ``relight.fitting.SHADOW_RATIO`` (None: no censoring);
            ``normals`` is always fitted; ``options``, a :class:`relight.fitting.FitOptions`, for blocks,
            devices and progress).

    Returns:
        ``(fit, surface, report)``: the :class:`relight.Fit`, the pixels' ``stage.Surface`` and the
        report's ``diligent`` entry (object, pixels, lights, subsample, loss, shadow_ratio and, where
        ``Normal_gt.mat`` is present, ``normal_error_deg``: mean, median and 95th percentile of the angular
        error, and the Lambertian least-squares baseline's mean and median).

    References:
        Shi et al. 2016, "A Benchmark Dataset and Evaluation for Non-Lambertian and Uncalibrated
        Photometric Stereo" (DiLiGenT; the mean angular error is its score).
    """
    from ..io import diligent_capture, lambert_normals
    from ._driver import fit

    if isinstance(subsample, bool) or int(subsample) != subsample or subsample < 1:
        raise ValueError(f"fit_diligent: subsample must be an integer >= 1, got {subsample!r}")
    if subsample > 1:
        keep = np.zeros_like(data.mask)
        keep[::subsample, ::subsample] = True
        data = dataclasses.replace(data, mask=data.mask & keep)
    capture, surface = diligent_capture(data)
    kw = {"model": DILIGENT_MODEL, "loss": DILIGENT_LOSS, "shadow_ratio": SHADOW_RATIO, **fit_kw, "normals": True}
    fitted = fit(capture, surface, **kw)
    report = {"object": name, "pixels": int(surface.num_samples),
              "lights": int(len(data.filenames)), "subsample": int(subsample),
              "loss": kw["loss"], "shadow_ratio": kw["shadow_ratio"]}
    if data.normals_gt is not None:
        gt = data.normals_gt[data.mask].astype(np.float64)
        err = angular_error_deg(np.asarray(fitted.normal, np.float64), gt)
        base = angular_error_deg(lambert_normals(data), gt)
        report["normal_error_deg"] = {
            "mean": float(err.mean()), "median": float(np.median(err)), "p95": float(np.percentile(err, 95)),
            "lambert_ls_baseline_mean": float(base.mean()), "lambert_ls_baseline_median": float(np.median(base))}
    return fitted, surface, report


def write_diligent_folder(folder: str | os.PathLike, fitted, surface, mask, diligent: dict,
                          timings: dict | None = None) -> dict:
    """Write a DiLiGenT fit's output: normals.exr / normals.png (0.5 + 0.5 n, camera frame), albedo.exr /
    albedo.png and the report (report.json, report.md).

    Args:
        folder: an existing folder to write into (atomic writes).
        fitted: the :class:`relight.Fit` of :func:`fit_diligent`.
        surface: its ``stage.Surface`` (one sample per mask pixel).
        mask: bool [H, W], the object's pixels (black elsewhere in normals.png).
        diligent: :func:`fit_diligent`'s report entry.
        timings: seconds per stage so far; the time of the map writes is added as ``"write_s"``.

    Returns:
        The report's dict (:func:`relight.fitting.fit_report` plus ``diligent``).
    """
    import time

    from ..image import to_uint8, tonemap
    from ..io import write_exr, write_png
    from ._report import fit_report
    from ._write import write_report

    folder, timings, t0 = Path(folder), dict(timings or {}), time.perf_counter()
    normals = surface.to_texture(np.asarray(fitted.normal, np.float32))
    write_exr(folder / "normals.exr", normals)
    rgb = np.where(np.asarray(mask)[..., None], np.round(255 * np.clip(0.5 + 0.5 * normals, 0, 1)), 0)
    write_png(folder / "normals.png", rgb.astype(np.uint8))
    albedo = surface.to_texture(np.asarray(fitted.rho_d, np.float32))
    write_exr(folder / "albedo.exr", albedo)
    write_png(folder / "albedo.png", to_uint8(tonemap(albedo, exposure=0.0, curve="none")))
    timings["write_s"] = time.perf_counter() - t0
    report = {**fit_report(fitted, surface, timings=timings), "diligent": diligent}
    write_report(folder, report)
    return report


def subsurface_step(capture, surface, fitted, *, per: str = "region", regions=None, eta: float | None = None,
                    metadata: dict | None = None, passes: int = 1, model: str = DEFAULT_MODEL, normals: bool = False,
                    solver="lm", options=None):
    """The subsurface fit after a BRDF fit: :func:`relight.fit_subsurface`, or with ``passes`` > 1
    :func:`relight.fit_with_subsurface`'s alternation started from ``fitted``.

    Args:
        capture: the whole ``stage.Capture`` (the diffusion operator couples samples).
        surface: its ``stage.Surface``.
        fitted: the BRDF :class:`relight.Fit`.
        per: ``"region"``, ``"texel"`` or ``"auto"`` (the held-out ladder none / region / texel).
        regions: int labels [P] 0..R-1 (``relight.io.read_regions``), or None (one region).
        eta: the relative index of the Fresnel transmittances; None: the capture's
            ``metadata["subsurface"]["eta"]``, else ``skin_bssrdf.SKIN_ETA``.
        metadata: the capture's metadata (capture.json), for its recorded eta.
        passes: BRDF / subsurface alternations (1: the plain sequence).
        model, normals, solver: the BRDF refits' model choices (``passes`` > 1).
        options: how the fits run (:class:`relight.fitting.FitOptions`; its ``progress`` reports every
            phase).

    Returns:
        ``(fit, settings)``: the new :class:`relight.Fit` and the settings to record: ``mode``, ``eta``,
        ``passes``, ``eta_from`` (``"argument"``, ``"capture"`` or ``"default"``) and ``regions`` (None, or
        ``{"count": R}``).

    References:
        Jensen et al. 2001, "A Practical Model for Subsurface Light Transport", eq. 5 (the Fresnel
        transmittances at ``eta``).
    """
    recorded = ((metadata or {}).get("subsurface") or {}).get("eta")
    chosen = eta if eta is not None else recorded if recorded is not None else skin_bssrdf.SKIN_ETA
    kw = {"eta": float(chosen)}
    if regions is not None:
        kw["regions"] = regions
    if passes > 1:
        fitted = fit_with_subsurface(capture, surface, model=model, normals=normals, per=per, passes=passes,
                                     first=fitted, fit_options={"solver": solver}, options=options, **kw)
    else:
        progress = None if options is None else options.progress
        fitted = fit_subsurface(capture, surface, fitted, per=per, progress=progress, **kw)
    settings = {"mode": per, "eta": float(chosen), "passes": int(passes),
                "eta_from": "argument" if eta is not None else "capture" if recorded is not None else "default",
                "regions": None if regions is None else {"count": int(np.max(regions)) + 1}}
    return fitted, settings
