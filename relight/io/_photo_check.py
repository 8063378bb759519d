"""A photo capture summarised before any fitting (``relight info PHOTOS_DIR``): per camera its size, formats,
how its values become radiance, per-image saturated and dark fractions, the radiance range and how many
lights light the subject, and warnings for the likely mistakes of a delivery: sensor counts read as radiance,
images all saturated or all black, a rig in the wrong units or turned the wrong way, cameras that see nothing.
One image is in memory at a time."""

from __future__ import annotations

import dataclasses

import numpy as np

from ._photos import PhotoCapture

# A stored value at or below this fraction of full scale (PNG), or of the view's brightest value (EXR), is dark.
DARK_FRACTION = 0.01
# A PNG value at or above this fraction of full scale counts as saturated when capture.json states no
# 'saturation' (the sensor's clip, less rounding).
SATURATED_FRACTION = 0.999
# A light lights the subject in a view when more than this fraction of its sampled subject pixels is not dark.
LIT_PIXELS = 0.01
# Near-field lights closer to the rig centre than this (mm) are taken for positions in the wrong units.
NEAR_LIGHT_MM = 100.0


@dataclasses.dataclass
class PhotoCheck:
    """What :func:`check_photo_capture` found: ``views`` (one dict per camera), ``rig`` (a dict) and
    ``warnings`` (strings, each naming the file or camera and what to do); ``pixels`` says over which pixels
    the fractions are computed."""

    views: list[dict]
    rig: dict
    warnings: list[str]
    pixels: str


def _view_stats(cap: PhotoCapture, view: int, stride: int) -> dict:
    """One view's row: stored-value statistics over every ``stride``-th subject pixel of each light's image."""
    v = cap._views[view]
    mask = cap.read_mask(view)[::stride, ::stride]
    n = max(int(mask.sum()), 1)
    png = [f.suffix.lower() == ".png" for f in v["files"]]
    sat_level = v["saturation"] if v["saturation"] is not None else SATURATED_FRACTION
    saturated, peaks, lows, highs, imgs = [], [], [], [], []
    for light, path in enumerate(v["files"]):
        img, sat = cap._read_image(path, v["encoding"], v["size"], v["saturation"])
        img = np.asarray(img[::stride, ::stride], np.float64)[mask]
        stored_max = img.max(axis=-1) if img.size else np.zeros(0)
        if v["saturation"] is None and png[light]:
            sat = stored_max >= sat_level
        else:
            sat = sat[::stride, ::stride][mask]
        saturated.append(float(np.count_nonzero(sat)) / n)
        peaks.append(float(stored_max.max()) if stored_max.size else 0.0)
        radiance = img * float(v["scale"][light])
        positive = radiance[radiance > 0]
        lows.append(float(positive.min()) if positive.size else np.inf)
        highs.append(float(radiance.max()) if radiance.size else 0.0)
        imgs.append(stored_max)
    full = 1.0 if all(png) else max(max(peaks), np.finfo(np.float64).tiny)
    dark = [float(np.count_nonzero(m <= DARK_FRACTION * full)) / n for m in imgs]
    lit = sum(1 for d in dark if 1.0 - d > LIT_PIXELS)
    return {"camera": cap.names[view], "size": [cap.cameras[view].width, cap.cameras[view].height],
            "format": "png" if all(png) else "exr" if not any(png) else "mixed",
            "scale_stated": bool(v["scale_stated"]), "subject_pixels_sampled": int(mask.sum()),
            "saturated_fraction": {"median": float(np.median(saturated)), "max": float(np.max(saturated))},
            "dark_fraction": {"median": float(np.median(dark)), "min": float(np.min(dark))},
            "radiance_range": [min(lows) if np.isfinite(min(lows)) else 0.0, max(highs)],
            "lights_lit": lit, "peak_of_full_scale": max(peaks) if all(png) else None}


def _rig_warnings(cap: PhotoCapture, mesh) -> tuple[dict, list[str]]:
    """The rig's row and its warnings: near-field lights too close to the centre or inside the mesh's
    bounds, and cameras with no light on their side of the subject or not looking at it."""
    rig, where = cap.rig, cap.rig_file
    pos = np.asarray(rig.position, np.float64)
    r = np.linalg.norm(pos, axis=1)
    out, warns = {"lights": int(rig.num_lights), "near_field": bool(rig.near_field),
                  "radius_mm": [float(r.min()), float(r.max())]}, []
    if rig.near_field and r.min() < NEAR_LIGHT_MM:
        warns.append(f"{where}: {int(np.sum(r < NEAR_LIGHT_MM))} lights lie within {NEAR_LIGHT_MM:g} mm of the rig "
                     f"centre (closest {r.min():.3g} mm): positions in metres or centimetres read as mm? State "
                     "the rig's 'units'")
    if mesh is not None and rig.near_field:
        lo, hi = (np.asarray(a, np.float64) for a in (mesh.vertices.min(0), mesh.vertices.max(0)))
        inside = np.all((pos >= lo) & (pos <= hi), axis=1)
        if inside.any():
            warns.append(f"{where}: {int(inside.sum())} lights sit inside the mesh's bounding box (mm): the rig's "
                         "units or the mesh's scale are wrong")
    dirs = pos / np.maximum(r[:, None], 1e-12)
    for name, cam in zip(cap.names, cap.cameras, strict=True):
        c = np.asarray(cam.center, np.float64)
        if np.linalg.norm(c) > 0 and not np.any(dirs @ (c / np.linalg.norm(c)) > 0):
            warns.append(f"camera {name!r}: no light is on its side of the subject: is the rig's 'up' axis (or "
                         "its sign) right?")
        pix, z = cam.project(np.zeros((1, 3)))
        u, v = (float(x) for x in np.asarray(pix)[0])
        if not (float(np.asarray(z)[0]) > 0 and 0 <= u < cam.width and 0 <= v < cam.height):
            warns.append(f"camera {name!r}: the rig centre is not in its image (behind it or outside the frame): "
                         "check R and t in cameras.json (world to camera, mm)")
    return out, warns


def check_photo_capture(cap: PhotoCapture, *, stride: int = 4, mesh=None) -> PhotoCheck:
    """Summarise a photo capture and say what looks wrong, before any fitting.

    Args:
        cap: an opened capture (:func:`relight.io.read_photo_capture`).
        stride: every ``stride``-th row and column of each camera's mask is sampled (>= 1).
        mesh: an optional ``stage.Mesh`` in the cameras' frame (mm): lights inside its bounds are reported.

    Returns:
        A :class:`PhotoCheck`. Warnings: PNG images with no stated exposure or gain (counts read as
        radiance: ``PhotoCapture.unscaled_png``); a view whose images are all saturated (median saturated
        fraction above half) or all dark (no light lights the subject); a view where at most one light does;
        near-field lights within NEAR_LIGHT_MM of the centre or inside the mesh; a camera with no light on its
        side of the subject, or whose image does not contain the rig centre.
    """
    if isinstance(stride, bool) or not isinstance(stride, (int, np.integer)) or stride < 1:
        raise ValueError(f"stride must be an integer >= 1, got {stride!r}")
    views, warns = [], []
    for i in range(cap.n_views):
        row = _view_stats(cap, i, int(stride))
        views.append(row)
        name = row["camera"]
        if cap.unscaled_png(i):
            warns.append(f"camera {name!r}: PNG values with no 'exposure' or 'gain' in capture.json are read as "
                         f"fractions of full scale (peak {row['peak_of_full_scale']:.3g}); if they are sensor "
                         "counts, state 'gain' (docs/capture_layout.md, 'From sensor counts to radiance')")
        if row["saturated_fraction"]["median"] > 0.5:
            warns.append(f"camera {name!r}: most of the subject is saturated in most images (median "
                         f"{100 * row['saturated_fraction']['median']:.0f}%): shorter exposure, or a wrong "
                         "'saturation' level")
        if row["lights_lit"] == 0:
            warns.append(f"camera {name!r}: every image is dark on the subject (<= {100 * DARK_FRACTION:g}% of "
                         "full scale): wrong exposure, wrong mask, or a camera that sees nothing")
        elif row["lights_lit"] == 1 and cap.n_lights > 1:
            warns.append(f"camera {name!r}: only one of {cap.n_lights} lights lights the subject")
    rig, rig_warns = _rig_warnings(cap, mesh)
    return PhotoCheck(views, rig, warns + rig_warns,
                      f"every {stride}th row and column of each camera's mask (all pixels without a mask)")
