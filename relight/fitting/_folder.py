"""A capture folder fitted and written whole, as ``relight fit`` does it: a
texel-space capture or store (read lazily, or whole for the subsurface step), a
photo capture (resampled onto a mesh's texel grid first) or a DiLiGenT object,
fitted and written with its report into a folder."""

from __future__ import annotations

import dataclasses
import os
import time
from pathlib import Path
from typing import Any, NamedTuple

from ._driver import DEFAULT_MODEL
from ._joint import SUBSURFACE_LOSS
from ._options import FitOptions, as_options


class FitFolderResult(NamedTuple):
    """What :func:`fit_folder` and :func:`fit_diligent_folder` did.

    **Attributes:**

    - ``report``: the report's dict (as written to report.json).
    - ``fit``: the :class:`relight.Fit`.
    - ``surface``: its ``stage.Surface`` (texels, or a DiLiGenT object's pixels).
    - ``capture``: what was fitted: a ``stage.Capture`` or a lazy capture reader / store (None for a
      DiLiGenT object).
    - ``mesh``: the ``stage.Mesh`` of the texel grid (None for a DiLiGenT object).
    - ``kind``: ``"texel"``, ``"photos"`` or ``"diligent"``.
    - ``surface_info``: the mesh spec of the texel grid (None for a DiLiGenT object).
    - ``fit_options``: the model choices recorded in the report's metadata.
    - ``scene``: the path of scene.xml in the folder, or None.
    - ``parts``: :func:`relight.fitting.fit_resumable`'s summary, or None (a DiLiGenT object).
    - ``subsurface``: the subsurface settings (:func:`relight.fitting.subsurface_step`'s), or None.
    - ``timings``: seconds per stage (``read_s``, ``fit_s``, ``subsurface_s``, ``write_s``).
    - ``streamed``: the capture was read block by block (not held whole).
    - ``warnings``: messages for the user (a mesh far from the rig's size, many flagged texels).
    """

    report: dict
    fit: Any
    surface: Any
    capture: Any
    mesh: Any
    kind: str
    surface_info: dict | None
    fit_options: dict
    scene: Path | None
    parts: dict | None
    subsurface: dict | None
    timings: dict
    streamed: bool
    warnings: tuple[str, ...]


# Share of flagged texels (unseen or failed) from which fit_folder warns.
FLAGGED_WARN = 0.5


def flagged_warning(report: dict) -> str:
    """The warning of a fit with many flagged texels (:func:`relight.fitting.fit_report`'s ``report``): the
    texels no camera saw apart from the failures among the seen, and what covers each."""
    r = report
    n, unseen, seen, failed = r["samples"], r["unseen_samples"], r["seen_samples"], r["failed_seen_samples"]
    parts = []
    if unseen:
        parts.append(f"{unseen} of the {n} texels are unseen: no camera sees them (coverage.exr 0; their maps hold "
                     "the map set's fill, the nearest seen texel's material, maps.json 'unseen'; more camera "
                     "views cover them)")
    if failed or not unseen:
        parts.append(f"{failed} of the {seen} seen texels failed (a solver failure, or fewer than 8 valid lights: a "
                     "rig with more lights covers them; their maps hold the defaults)")
    return f"{100 * r['failed_fraction']:.0f}% of the texels are flagged: " + "; ".join(parts)


def _model_choices(model, normals, solver) -> dict:
    return {"solver": solver, **({"model": model} if model else {}), **({"normals": True} if normals else {})}


def _read_capture(capture_dir: Path, *, whole: bool, mesh, mesh_info, resolution, grazing_deg, min_views,
                  rig_units, rig_up, progress):
    """(capture, surface, mesh, surface_info, metadata, coverage, kind, warnings) of a texel or photo capture."""
    from ..io import (
        is_photo_capture,
        load_texel_capture,
        mesh_size_warning,
        open_texel_capture,
        photos_to_texels,
        read_photo_capture,
    )

    if not is_photo_capture(capture_dir):
        read = load_texel_capture if whole else open_texel_capture
        capture, surface, mesh, metadata = read(capture_dir, progress=progress)
        return capture, surface, mesh, metadata["surface"], metadata, None, "texel", ()
    if mesh is None:
        raise ValueError(f"fit_folder: {capture_dir} is a photo capture (camera space): a mesh with UVs is needed to "
                         "resample it onto a texel grid")
    photos = read_photo_capture(capture_dir, rig_units=rig_units, rig_up=rig_up)
    warning = mesh_size_warning(mesh, photos.rig)
    capture, surface, coverage = photos_to_texels(photos, mesh, resolution, grazing_deg=grazing_deg,
                                                  min_views=min_views, progress=progress)
    return capture, surface, mesh, mesh_info, {}, coverage, "photos", (warning,) if warning else ()


def fit_folder(capture_dir: str | os.PathLike, folder: str | os.PathLike, *, parts: str | os.PathLike,
               model: str | None = None, normals: bool = False, solver: str = "lm", subsurface: str | None = None,
               regions: str | os.PathLike | None = None, eta: float | None = None, eta_from: str = "argument",
               passes: int = 1, resume: bool = False, options: FitOptions | None = None, mesh=None,
               mesh_info: dict | None = None, resolution: int = 256, grazing_deg: float = 80.0, min_views: int = 1,
               rig_units: str | None = None, rig_up: str | None = None, envmap: str | os.PathLike | None = None,
               source: str = "relight fit") -> FitFolderResult:
    """Fit a texel-space capture (folder or store) or a photo capture and write the map set, the Mitsuba
    scene, previews and the report into ``folder``.

    A texel capture is read lazily block by block (whole with ``subsurface``: the diffusion operator couples
    texels); a photo capture is first resampled onto ``mesh``'s texel grid (``relight.io.photos_to_texels``).
    The BRDF fit runs in resumable parts (:func:`relight.fitting.fit_resumable`), then with ``subsurface``
    :func:`relight.fitting.subsurface_step`; the output is :func:`relight.fitting.write_fit_folder`'s, scored
    against the capture's truth maps where it records them.

    Args:
        capture_dir: the capture folder or store (``relight simulate``'s, or a photo capture).
        folder: an existing folder to write the set into.
        parts: the parts folder of the resumable fit (kept between runs; ``relight fit``: ``OUT/.parts``).
        model, normals, solver: what is fitted (:func:`relight.fit`'s keywords; ``model`` None: its default).
        subsurface: None, or the subsurface step's ``per``: ``"region"``, ``"texel"`` or ``"auto"`` (texel
            captures only).
        regions: with ``subsurface``: a label map file (``relight.io.read_regions``), or None (one region).
        eta: with ``subsurface``: the relative index of refraction; None: the capture's, else skin's.
        eta_from: how an explicit ``eta`` is recorded in the settings' ``eta_from``.
        passes: with ``subsurface``: BRDF / subsurface alternations.
        resume: keep the finished parts of an earlier run of this fit in ``parts``.
        options: how the fits run (:class:`relight.fitting.FitOptions`: block, devices, ``progress``, which
            also reports the reading phases, and ``on_block``, called after each BRDF block).
        mesh: photo captures: the ``stage.Mesh`` with UVs in the cameras' frame.
        mesh_info: photo captures: its spec (``relight.io.mesh_spec``), recorded in maps.json.
        resolution, grazing_deg, min_views: photo captures: ``relight.io.photos_to_texels``'s.
        rig_units, rig_up: photo captures: ``relight.io.read_photo_capture``'s.
        envmap: the environment map of the Mitsuba scene, or None.
        source: the report metadata's ``source``.

    Returns:
        A :class:`FitFolderResult`.
    """
    import stage

    from ..io import read_regions
    from ._report import read_truth
    from ._resume import fit_resumable
    from ._run import subsurface_step
    from ._write import write_fit_folder

    capture_dir, folder, options = Path(capture_dir), Path(folder), as_options(options)
    progress = options.progress
    if subsurface is None and (regions is not None or eta is not None or passes != 1):
        raise ValueError("fit_folder: regions, eta and passes apply with subsurface only")
    kwargs = _model_choices(model, normals, solver)
    t0, times = time.perf_counter(), {}
    capture, surface, mesh, info, metadata, coverage, kind, warnings = _read_capture(
        capture_dir, whole=subsurface is not None, mesh=mesh, mesh_info=mesh_info, resolution=resolution,
        grazing_deg=grazing_deg, min_views=min_views, rig_units=rig_units, rig_up=rig_up, progress=progress)
    if subsurface is not None and kind != "texel":
        raise ValueError(f"fit_folder: {capture_dir} is a photo capture; subsurface fitting takes texel-space "
                         "captures only")
    times["read_s"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    # With subsurface, the BRDF stage takes fit_with_subsurface's loss (relight.fitting._joint.SUBSURFACE_LOSS).
    loss = {} if subsurface is None else {"loss": SUBSURFACE_LOSS}
    fitted, part_info = fit_resumable(capture, surface, parts, resume=resume, options=options, **kwargs, **loss)
    times["fit_s"] = time.perf_counter() - t0
    sss = None
    if subsurface is not None:
        t0 = time.perf_counter()
        labels = None if regions is None else read_regions(regions, surface)
        fitted, sss = subsurface_step(capture, surface, fitted, per=subsurface, regions=labels, eta=eta,
                                      metadata=metadata, passes=passes, model=model or DEFAULT_MODEL, normals=normals,
                                      solver=solver, options=dataclasses.replace(options, on_block=None))
        times["subsurface_s"] = time.perf_counter() - t0
        if sss["eta_from"] == "argument":
            sss["eta_from"] = eta_from
        if labels is not None:
            sss["regions"]["file"] = str(Path(regions).resolve())
    meta = {"capture": str(capture_dir.resolve()), "fit_options": kwargs, "source": source}
    report, scene = write_fit_folder(folder, fitted, surface, cameras=capture.cameras, rig=capture.rig, mesh=mesh,
                                     surface_info=info, metadata=meta, envmap=envmap, normals=normals,
                                     truth=read_truth(capture_dir, surface), subsurface=sss, coverage=coverage,
                                     timings=times, extra={"parts": part_info})
    if report["failed_fraction"] >= FLAGGED_WARN:
        warnings = (*warnings, flagged_warning(report))
    return FitFolderResult(report, fitted, surface, capture, mesh, kind, info, kwargs, scene, part_info, sss, times,
                           not isinstance(capture, stage.Capture), tuple(warnings))


def fit_diligent_folder(diligent_dir: str | os.PathLike, folder: str | os.PathLike, *, model: str | None = None,
                        normals: bool = False, solver: str = "lm", subsample: int = 1,
                        options: FitOptions | None = None) -> FitFolderResult:
    """Fit a DiLiGenT object (the model and the shading normal per pixel) and write normals, albedo and the
    report, scored against the benchmark's ground-truth normals, into ``folder``.

    Args:
        diligent_dir: the object's folder (``relight.io.read_diligent``).
        folder: an existing folder to write into.
        model, normals, solver: :func:`relight.fit`'s keywords (``model`` None:
            ``relight.fitting.DILIGENT_MODEL``; the normal is always fitted).
        subsample: fit every k-th pixel in x and y (1: all).
        options: how the fit runs (:class:`relight.fitting.FitOptions`).

    Returns:
        A :class:`FitFolderResult` (``capture``, ``mesh``, ``surface_info``, ``scene``, ``parts`` and
        ``subsurface`` None; ``report["diligent"]`` the object's entry, see
        :func:`relight.fitting.fit_diligent`).
    """
    from ..io import read_diligent
    from ._run import fit_diligent, write_diligent_folder

    diligent_dir = Path(diligent_dir)
    kwargs = _model_choices(model, normals, solver)
    t0, times = time.perf_counter(), {}
    d = read_diligent(diligent_dir)
    times["read_s"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    fitted, surface, entry = fit_diligent(d, name=diligent_dir.name, subsample=subsample,
                                          options=as_options(options), **kwargs)
    times["fit_s"] = time.perf_counter() - t0
    report = write_diligent_folder(folder, fitted, surface, d.mask, entry, times)
    return FitFolderResult(report, fitted, surface, None, None, "diligent", None, kwargs, None, None, None, times,
                           False, ())
