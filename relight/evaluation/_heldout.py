"""Held-out-light prediction: the protocol that scores a fit on real OLAT photographs without ground truth.

Fit on some lights, predict the photographs of the others, and compare with the classical baseline,
per-pixel Lambertian least squares (Woodham, "Photometric method for determining surface orientation from
multiple images", Opt. Eng. 1980) on the training observations that are neither dark (shadow) nor
saturated. A model that predicts held-out lights worse than that baseline is fitting something that is
not in the data (docs/RESULTS.md, "Outside data").
"""

from __future__ import annotations

import numpy as np

import stage

from ..io import DiligentData, grey_value

__all__ = ["heldout_split", "lambert_least_squares", "observation_validity", "predict_fit", "predict_lambert",
           "relative_rms"]

def heldout_split(num_lights: int, every: int, offset: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """(training lights, held-out lights): every ``every``-th light from ``offset`` is held out.

    Args:
        num_lights: the capture's light count L.
        every: the hold-out period (>= 2).
        offset: the first held-out light (0 <= offset < every).

    Returns:
        Two sorted int arrays that partition ``range(num_lights)``.
    """
    if not (isinstance(every, int) and every >= 2 and 0 <= offset < every and num_lights > every):
        raise ValueError(f"heldout_split: need every >= 2, 0 <= offset < every and more than `every` lights, "
                         f"got num_lights={num_lights}, every={every}, offset={offset}")
    held = np.arange(offset, num_lights, every)
    return np.setdiff1d(np.arange(num_lights), held), held


def observation_validity(data: DiligentData, lights, *, dark: float = 0.0, saturation: float | None = 0.995
                         ) -> np.ndarray:
    """Which observations of the mask's pixels a method may use or be scored on, bool [L', P].

    Args:
        data: the capture (:func:`relight.io.read_diligent` / :func:`relight.io.read_yaleb`), values as
            fractions of the sensor's full scale.
        lights: the light indices (L' of them).
        dark: an observation whose every channel is below this fraction of full scale is dark (shadow,
            or a light behind the surface) and invalid; 0 keeps every observation.
        saturation: an observation with any channel at or above this fraction is saturated and invalid;
            None keeps them.

    Returns:
        The validity of each (light, mask pixel), in the order of ``lights`` and of ``np.nonzero(data.mask)``.
    """
    obs = data.images[np.asarray(lights)][:, data.mask, :]
    valid = np.any(obs >= dark, axis=-1) if dark > 0 else np.ones(obs.shape[:2], bool)
    if saturation is not None:
        valid &= np.all(obs < saturation, axis=-1)
    return valid


def lambert_least_squares(data: DiligentData, lights, valid: np.ndarray | None = None
                          ) -> tuple[np.ndarray, np.ndarray]:
    """Per-pixel Lambertian least squares (Woodham 1980): the grey value of each pixel over ``lights`` is
    ``b . l`` with ``b`` its albedo-scaled normal, then an albedo per channel by least squares on the
    shading ``max(n . l, 0)``.

    Args:
        data: the capture (values divided by each light's intensity before fitting).
        lights: the light indices to fit on (L').
        valid: bool [L', P] observations to use (:func:`observation_validity`); None uses all. A pixel
            with fewer than three valid lights gets a zero normal (it predicts black).

    Returns:
        ``(normal, albedo)``: unit normals [P, 3] (camera frame) and RGB albedo [P, 3], float64, for the
        mask's pixels.
    """
    lights = np.asarray(lights)
    img = data.images[lights][:, data.mask, :] / data.light_intensities[lights][:, None, :]  # [L', P, 3]
    grey = grey_value(img)
    L = data.light_directions[lights].astype(np.float64)
    if valid is None:
        b = np.linalg.lstsq(L, grey, rcond=None)[0].T
        usable = np.ones(len(b), bool)
    else:
        w = valid.astype(np.float64)
        A = np.einsum("lp,li,lj->pij", w, L, L)  # per-pixel normal equations, [P, 3, 3]
        rhs = np.einsum("lp,lp,li->pi", w, grey, L)
        usable = (w.sum(0) >= 3) & (np.linalg.det(A) > 1e-9)
        b = np.zeros_like(rhs)
        b[usable] = np.linalg.solve(A[usable], rhs[usable][..., None])[..., 0]
    n = b / np.maximum(np.linalg.norm(b, axis=1, keepdims=True), 1e-12)
    n[~usable] = 0.0
    shade = np.maximum(L @ n.T, 0.0)  # [L', P]
    if valid is not None:
        shade = shade * valid
    albedo = np.sum(shade[..., None] * img, 0) / np.maximum(np.sum(shade**2, 0)[:, None], 1e-12)
    return n, albedo


def predict_lambert(normal: np.ndarray, albedo: np.ndarray, data: DiligentData, lights) -> np.ndarray:
    """The Lambertian prediction ``albedo max(n . l, 0) E_l`` of the mask's pixels under ``lights``,
    [L', P, 3] in the capture's units."""
    lights = np.asarray(lights)
    L = data.light_directions[lights].astype(np.float64)
    return np.maximum(L @ normal.T, 0.0)[..., None] * albedo[None] * data.light_intensities[lights][:, None, :]


def predict_fit(fit, capture: stage.Capture, surface: stage.Surface, view: int = 0) -> np.ndarray:
    """A fit's prediction of a capture's images: the fitted BRDF (diffuse included) at each sample, in its
    fitted shading frame, under the capture's rig, seen by camera ``view``, with no shadowing.

    Args:
        fit: a ``relight.fitting.Fit`` over the surface's samples.
        capture: supplies the rig (the lights to predict) and the cameras.
        surface: the samples.
        view: the camera.

    Returns:
        Radiance [L, P, 3], float64, in the capture's units.
    """
    maps = fit.maps(surface)
    P, L = surface.num_samples, capture.rig.num_lights
    cam = capture.cameras[view]
    out = stage.simulate(maps.frame(surface), capture.rig, [cam], maps.brdf(include_diffuse=True),
                         np.ones((P, L), bool), np.ones((1, P), bool))
    return np.asarray(out.radiance[0], np.float64)


def relative_rms(prediction: np.ndarray, observed: np.ndarray, valid: np.ndarray) -> float:
    """``sqrt(sum (prediction - observed)^2 / sum observed^2)`` over the valid observations.

    Args:
        prediction, observed: [L, P, C].
        valid: bool [L, P].

    Returns:
        The relative RMS error (0 is perfect; a prediction of zeros scores 1).
    """
    v = valid[..., None]
    den = float(np.sum(v * observed**2))
    if den <= 0:
        raise ValueError("relative_rms: no valid observation with a non-zero value")
    return float(np.sqrt(np.sum(v * (prediction - observed) ** 2) / den))
