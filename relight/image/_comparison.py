"""Comparing a fit with its truth in pictures: the PSNR of two renders and the
truth | fit | error figure of the relit view, the diffuse albedo and the red
mean free path."""

from __future__ import annotations

import numpy as np

from ._exposure import subject_exposure
from ._figure import labelled_grid
from ._preview import dilate, texture_view
from ._tonemap import to_uint8, tonemap

# Error columns: the colour scale's top (relative error). Relit: 10% of the 90th-percentile pixel;
# albedo 10%; mean free path 50% (it is identified far more loosely than the albedo).
RELIT_ERROR_MAX = 0.1
ALBEDO_ERROR_MAX = 0.1
MFP_ERROR_MAX = 0.5


def psnr(est, ref, where) -> float:
    """Peak signal-to-noise ratio of an image against a reference over chosen pixels, in dB.

    Args:
        est: the image [H, W, C].
        ref: the reference [H, W, C].
        where: bool [H, W], the pixels compared.

    Returns:
        10 log10(peak^2 / MSE), the peak being the reference's maximum over the pixels; the MSE is
        floored at 1e-30 (a finite value for identical images) and no pixel gives MSE 0, peak 1.
    """
    where = np.asarray(where, bool)
    d = (np.asarray(est, np.float64) - np.asarray(ref, np.float64))[where]
    mse = float(np.mean(d * d)) if d.size else 0.0
    peak = float(np.max(np.asarray(ref, np.float64)[where])) if d.size else 1.0
    return float(10 * np.log10(peak * peak / max(mse, 1e-30)))


def _heat(x, vmax: float, where) -> np.ndarray:
    import matplotlib

    rgb = matplotlib.colormaps["magma"](np.clip(np.asarray(x) / vmax, 0.0, 1.0))[..., :3]
    return to_uint8(np.where(np.asarray(where)[..., None], rgb, 0.0).astype(np.float32))


def truth_fit_figure(mesh, surface, camera, truth, fitted, relit_truth, relit_fit, covered) -> np.ndarray:
    """The figure of a fit against its truth: columns truth | fit | error, as the camera sees them.

    Rows: the relit images (filmic, one exposure metered on the truth's subject; error |fit - truth| over the
    truth's 90th-percentile pixel, 0 to ``RELIT_ERROR_MAX``), the diffuse albedo (sRGB; relative error, 0 to
    ``ALBEDO_ERROR_MAX``) and the red mean free path (0 to the truth's largest; relative error, 0 to
    ``MFP_ERROR_MAX``), the maps seen through the camera (``texture_view``, gaps dilated).

    Args:
        mesh: the ``stage.Mesh`` the surface was sampled on.
        surface: the ``stage.Surface`` on a texel grid.
        camera: the ``stage.Camera`` of the relit images.
        truth: the true :class:`relight.MaterialMaps` at the surface's samples.
        fitted: the fitted :class:`relight.MaterialMaps` at the same samples.
        relit_truth: the truth rendered [H, W, 3] by ``camera``.
        relit_fit: the fit rendered the same way.
        covered: bool [H, W], the subject's pixels.

    Returns:
        uint8 [H', W', 3]: the 3 x 3 grid with its row and column titles and a colour bar under every heat map
        (:func:`relight.image._figure.labelled_grid`), each image at its own pixels.
    """
    covered = np.asarray(covered, bool)
    relit_truth, relit_fit = np.asarray(relit_truth), np.asarray(relit_fit)
    exposure = subject_exposure(relit_truth, covered)  # the one rule every render's preview uses
    tm = lambda img: to_uint8(tonemap(img, exposure=exposure, curve="filmic"))  # noqa: E731
    scale = max(float(np.percentile(relit_truth[covered], 90)), 1e-6) if covered.any() else 1.0
    err_relit = np.abs(relit_fit - relit_truth).mean(-1) / scale
    rows = [[tm(relit_truth), tm(relit_fit), _heat(err_relit, RELIT_ERROR_MAX, covered)]]
    valid = np.zeros(surface.resolution, bool)
    valid.reshape(-1)[np.asarray(surface.texel_index)] = True
    tex = lambda x: dilate(surface.to_texture(np.asarray(x, np.float32)), valid)  # noqa: E731
    rho_t, rho_f = np.asarray(truth.rho_d, np.float32), np.asarray(fitted.rho_d, np.float32)
    mfp_t, mfp_f = np.asarray(truth.mfp, np.float32)[:, :1], np.asarray(fitted.mfp, np.float32)[:, :1]
    views = texture_view(mesh, camera, {
        "on": tex(np.ones_like(mfp_t)), "albedo_t": tex(rho_t), "albedo_f": tex(rho_f),
        "albedo_e": tex(np.abs(rho_f - rho_t).mean(1, keepdims=True) / np.maximum(rho_t.mean(1, keepdims=True), 1e-6)),
        "mfp_t": tex(mfp_t), "mfp_f": tex(mfp_f), "mfp_e": tex(np.abs(mfp_f - mfp_t) / np.maximum(mfp_t, 1e-6)),
    })
    on = views["on"][..., 0] > 0.5
    srgb = lambda img: to_uint8(tonemap(np.clip(img, 0, 1), curve="none"))  # noqa: E731
    vmax = max(float(np.max(mfp_t)), 1e-12)
    rows.append([srgb(views["albedo_t"]), srgb(views["albedo_f"]),
                 _heat(views["albedo_e"][..., 0], ALBEDO_ERROR_MAX, on)])
    rows.append([_heat(views["mfp_t"][..., 0], vmax, on), _heat(views["mfp_f"][..., 0], vmax, on),
                 _heat(views["mfp_e"][..., 0], MFP_ERROR_MAX, on)])
    heat = lambda top, label: (0.0, top, label, "magma")  # noqa: E731
    scales = [[None, None, heat(100 * RELIT_ERROR_MAX, "% of p90 pixel")],
              [None, None, heat(100 * ALBEDO_ERROR_MAX, "rel. error, %")],
              [heat(vmax, "red, mm"), heat(vmax, "red, mm"), heat(100 * MFP_ERROR_MAX, "rel. error, %")]]
    return labelled_grid(rows, ["relit", "diffuse albedo", "mean free path"], ["truth", "fit", "error"], scales)
