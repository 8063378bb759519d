"""A fit's output folder: the texture set with its rig, cameras and Mitsuba 3
scene, the previews, and the report (report.json and report.md)."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ._report import report_markdown


def write_fit_maps(folder: str | os.PathLike, maps, surface, *, cameras, rig, mesh, surface_info: dict,
                   metadata: dict | None = None, envmap: str | os.PathLike | None = None,
                   mean_free_path: bool = False, seen=None) -> Path | None:
    """Write a fit's map set into a folder: the texture set, rig.json, scene.xml and the previews.

    The files are written into ``folder`` as it is (no manifest, no swap: a caller builds a result set
    around them): the texture set (``relight.io.write_texture_set_files``), rig.json (the capture's rig,
    which ``relight render --method rig`` uses), scene.xml (Mitsuba 3, for a pinhole first camera and an
    environment map), albedo / specular / roughness previews, optionally mean_free_path.png, and
    albedo_view / roughness_view (.exr, .png): the maps as the first camera sees them.

    Args:
        folder: an existing folder.
        maps: the fitted :class:`relight.MaterialMaps` (``Fit.maps(surface)``).
        surface: the ``stage.Surface`` on a texel grid.
        cameras: the capture's ``stage.Camera`` s (recorded in maps.json; the first renders the views).
        rig: the capture's ``stage.Rig``.
        mesh: the ``stage.Mesh`` the surface was sampled on.
        surface_info: the mesh spec recorded in maps.json (``relight.io.mesh_spec``).
        metadata: more of maps.json's metadata (source, fit options, subsurface settings, ...).
        envmap: the environment map the scene uses; None: no scene.
        mean_free_path: also write mean_free_path.png (the mean free path over the set's largest; after a
            subsurface fit).
        seen: bool [P], the samples some camera saw (``relight.io.texture_set``'s: the others are coverage 0
            and hold the set's documented fill, labelled in maps.json and the scene); None: every sample.

    Returns:
        The path of scene.xml, or None when none was written (an orthographic camera, no map).
    """
    import stage

    from ..export import write_mitsuba_scene
    from ..image import PREVIEW_MIN_PX, texture_view
    from ..io import (
        check_finite_output,
        texture_set,
        write_exr,
        write_map_previews,
        write_preview,
        write_texture_set_files,
    )
    from ..results import writing

    folder = Path(folder)
    cams = [stage.camera_to_dict(c, f"cam{i:03d}") for i, c in enumerate(cameras)]
    with writing(folder / "rig.json"):
        stage.save_rig(folder / "rig.json", rig)
    meta = {**(metadata or {}), "cameras": cams, "rig": "rig.json"}
    textures = texture_set(maps, surface, surface_info=surface_info, metadata=meta, seen=seen)
    write_texture_set_files(folder, textures)
    cam = cameras[0]
    scene = None
    if not cam.orthographic and envmap is not None:
        with writing(folder / "scene.xml"):
            scene = write_mitsuba_scene(folder, mesh, textures, cam, envmap)
    write_map_previews(folder, textures.albedo, textures.specular, textures.alpha[..., :1])
    if mean_free_path:
        # mean_free_path.png: mfp / the largest mfp of the set (one scale for R, G, B), linear.
        write_preview(folder / "mean_free_path.png", textures.mfp / max(float(np.max(textures.mfp)), 1e-12),
                      exposure=0.0, curve="none", min_px=PREVIEW_MIN_PX)
    views = texture_view(mesh, cam, {"albedo": textures.albedo, "roughness": textures.alpha[..., :1]})
    for name, img in views.items():
        check_finite_output(img, folder / f"{name}_view.exr", f"the {name} view")
        with writing(folder / f"{name}_view.exr"):
            write_exr(folder / f"{name}_view.exr", img)
        write_preview(folder / f"{name}_view.png", img, exposure=0.0, curve="none")
    return scene


def write_report(folder: str | os.PathLike, report: dict, title: str = "relight fit report", preface=()) -> None:
    """Write a fit's report into a folder as report.json and report.md, atomically.

    Args:
        folder: an existing folder.
        report: :func:`relight.fitting.fit_report`'s dict (with any added sections).
        title, preface: :func:`relight.fitting.report_markdown`'s.
    """
    from ..io import write_json
    from ..results import atomic_write_text, writing

    folder = Path(folder)
    with writing(folder / "report.json"):
        write_json(folder / "report.json", report)
    with writing(folder / "report.md"):
        atomic_write_text(folder / "report.md", report_markdown(report, title, preface))


def write_fit_folder(folder: str | os.PathLike, fitted, surface, *, cameras, rig, mesh, surface_info: dict,
                     metadata: dict | None = None, envmap: str | os.PathLike | None = None, truth=None,
                     normals: bool = False, subsurface: dict | None = None, coverage=None,
                     timings: dict | None = None, extra: dict | None = None) -> tuple[dict, Path | None]:
    """Write everything a fit's output folder holds: the map set (:func:`write_fit_maps`), coverage.png for a
    photo capture, and the report (:func:`relight.fitting.fit_report`, :func:`write_report`).

    Args:
        folder: an existing folder (a caller builds a result set around it).
        fitted: the :class:`relight.Fit`.
        surface: its ``stage.Surface`` on a texel grid.
        cameras, rig, mesh, surface_info, metadata, envmap: :func:`write_fit_maps`'s.
        truth: the true :class:`relight.MaterialMaps` (``relight.fitting.read_truth``), or None.
        normals: the fit fitted shading normals.
        subsurface: the subsurface settings of ``relight.fitting.subsurface_step`` (recorded in maps.json and
            reported), or None.
        coverage: a ``relight.io.PhotoTexelReport`` (coverage.png and the report's ``photos``; the texels it
            calls unseen are coverage 0 in the map set, hold its fill and are counted apart from the
            failures), or None.
        timings: seconds per stage so far (``"subsurface_s"`` is the subsurface section's time); the time of
            these writes is added as ``"write_s"``.
        extra: more top-level entries of the report (e.g. ``parts``).

    Returns:
        ``(report, scene)``: the report's dict and the path of scene.xml (None when none was written).
    """
    import time

    import jax

    from ..image import coverage_image
    from ..io import write_png
    from ..results import writing
    from ._report import fit_report, subsurface_report

    folder = Path(folder)
    timings = dict(timings or {})
    t0 = time.perf_counter()
    meta = {**(metadata or {}), **({"subsurface": subsurface} if subsurface is not None else {})}
    seen = None if coverage is None else ~np.asarray(coverage.unseen, bool)
    scene = write_fit_maps(folder, fitted.maps(surface), surface, cameras=cameras, rig=rig, mesh=mesh,
                           surface_info=surface_info, metadata=meta, envmap=envmap,
                           mean_free_path=subsurface is not None, seen=seen)
    if coverage is not None:
        with writing(folder / "coverage.png"):
            write_png(folder / "coverage.png", coverage_image(coverage.coverage))
    timings["write_s"] = time.perf_counter() - t0
    # The report reads the fit on the host: NumPy leaves, so its per-sample tests compile nothing.
    fitted = jax.tree_util.tree_map(np.asarray, fitted)
    report = {**fit_report(fitted, surface, truth, normals=normals, timings=timings, seen=seen), **(extra or {})}
    if subsurface is not None:
        report["subsurface"] = subsurface_report(fitted, subsurface, truth, timings.get("subsurface_s", 0.0))
    if coverage is not None:
        report["photos"] = coverage.to_dict()
    write_report(folder, report)
    return report, scene
