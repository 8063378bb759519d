"""The demo as one library call: the bundled head with its skin textures and
spatially varying subsurface scattering, simulated under the Light Stage X with
shot noise, the full model ladder fitted, fit and truth relit by the same
renderer, and the fit's report against the truth (``relight demo``)."""

from __future__ import annotations

import dataclasses
import json
import os
import time
from pathlib import Path
from typing import Any

import numpy as np

# The demo's scene, described in report.md and settings.json.
TEXTURES = "Lee Perry-Smith head scan (Infinite Realities, CC-BY 3.0)"
RIG = "light_stage_x"


@dataclasses.dataclass
class Demo:
    """What :func:`run_demo` made: the report, the settings, and what :meth:`write` and :meth:`sweeps` need.

    **Attributes:**

    - ``report``: the fit's report (:func:`relight.fitting.fit_report` against the truth, ``against_truth``)
      plus the demo's entries (texels, lights, cameras, model and rung fractions, flagged fraction, relit PSNR,
      operator radius, seconds per stage).
    - ``settings``: the demo's settings (settings.json).
    - ``mesh``, ``surface``, ``truth``, ``maps``: the head, its seen texels, the true and the fitted
      :class:`relight.MaterialMaps`.
    - ``camera``, ``relit_truth``, ``relit_fit``, ``covered``: the relit view (the middle camera), the two
      renders [H, W, 3] and the head's pixels.
    - ``capture``, ``env``: the simulated ``stage.Capture`` and the environment map.
    """

    report: dict
    settings: dict
    mesh: Any
    surface: Any
    truth: Any
    maps: Any
    camera: Any
    relit_truth: np.ndarray
    relit_fit: np.ndarray
    covered: np.ndarray
    capture: Any
    env: Any

    def write(self, folder: str | os.PathLike, location: str | os.PathLike | None = None) -> None:
        """Write the demo's files into a folder: ``maps/`` and ``truth/`` (texture sets),
        relit_truth.exr, relit_fit.exr, preview.png (:func:`relight.image.truth_fit_figure`),
        settings.json, report.json and report.md.

        Args:
            folder: the folder (created if missing; a caller may build a result set around it).
            location: the folder it becomes (recorded in settings.json; default ``folder``).
        """
        import stage

        from ..fitting import write_report
        from ..image import truth_fit_figure
        from ..io import check_finite_output, mesh_spec, texture_set, write_exr, write_png, write_texture_set
        from ..results import atomic_write_text

        folder, t0 = Path(folder), time.perf_counter()
        folder.mkdir(parents=True, exist_ok=True)
        # The bundled head's spec and the relit camera, so that `relight view` (and `relight render`) can
        # rebuild the texel surface and render the sets as the demo did.
        info = mesh_spec(None, units=None, scale=None, center=None)
        meta = {"source": "relight demo", "cameras": [stage.camera_to_dict(self.camera, "relit")], "rig": None}
        write_texture_set(folder / "maps", texture_set(self.maps, self.surface, surface_info=info, metadata=meta))
        write_texture_set(folder / "truth", texture_set(self.truth, self.surface, surface_info=info, metadata=meta))
        for name, image in (("relit_truth.exr", self.relit_truth), ("relit_fit.exr", self.relit_fit)):
            check_finite_output(image, folder / name, "the relit image")
            write_exr(folder / name, image)
        write_png(folder / "preview.png", truth_fit_figure(self.mesh, self.surface, self.camera, self.truth,
                                                           self.maps, self.relit_truth, self.relit_fit,
                                                           self.covered))
        self.report["timings_s"]["write"] = round(time.perf_counter() - t0, 2)
        settings = {"command": "relight demo", "out": str(location or folder), **self.settings}
        atomic_write_text(folder / "settings.json", json.dumps(settings, indent=2))
        write_report(folder, self.report, "relight demo report", _preface(self.report))

    def sweeps(self, frames: int, size: int):
        """index.html's slider (``relight.view.write_index``'s rows and note): the simulated capture relit
        image-based (what the light stage measured, subsurface scattering and noise included).

        Args:
            frames: rotation frames.
            size: pixels of each frame.

        Returns:
            ``(rows, note)``: one :class:`relight.view.Sweep` and None.
        """
        from ..view import capture_sweep

        return [capture_sweep(self.capture, self.surface, self.mesh, self.camera, self.env, frames, size,
                              "the simulated capture relit image-based (`relight view` adds truth and fit, "
                              "model-based)")], None


def _preface(r: dict) -> list[str]:
    """report.md's description of the demo's scene and its relit comparison."""
    rungs = r["subsurface_rung_fraction"]
    lines = [
        f"The bundled head scan with its own skin textures (Lee Perry-Smith, Infinite Realities, CC-BY 3.0) and "
        f"spatially varying subsurface scattering, {r['lights']} lights (ICT Light Stage X), {r['cameras']} cameras, "
        f"texel grid {r['texel_resolution']}^2 ({r['texels_seen']} of {r['texels_on_atlas']} atlas texels seen by "
        f">= 1 camera), shot noise {100 * r['noise_relative_at_median']:.1f}% at the median radiance, "
        f"environment `{Path(r['envmap']).name}`.", "",
        "Model map: " + ", ".join(f"{k} {100 * v:.1f}%" for k, v in r["model_fraction"].items()) + "."]
    if rungs is not None:
        lines.append("Subsurface rungs: " + ", ".join(f"{k} {100 * v:.1f}%" for k, v in rungs.items())
                     + f"; mean free path identified on {100 * r['mfp_identified_fraction']:.1f}% of "
                       "texel-channels.")
    memory = {k: v for k, v in (r.get("peak_rss_mib") or {}).items() if v is not None}
    if memory:
        lines.append("Peak memory (the process's resident set, MiB, after each phase): "
                     + ", ".join(f"{k} {v:.0f}" for k, v in memory.items()) + ".")
    return lines + [f"Flagged texels: {100 * r['flagged_fraction']:.2f}%.",
                    f"Relit (fitted maps vs truth maps, same renderer, same map, view of the middle camera, "
                    f"{r['relit_pixels']} head pixels): PSNR {r['relit_psnr_db']:.1f} dB.", ""]


def _simulate(surface, truth, rig, cams, light_vis, cam_vis, noise: float, seed: int, progress):
    """The OLAT capture of the truth maps, then the sensor: (capture, the operator radius in mm)."""
    import jax.numpy as jnp

    import skin_bssrdf
    import stage

    from ..materials import SUBSURFACE

    profile = truth.profile()
    radius = skin_bssrdf.operator_radius(profile, where=np.asarray(truth.model) == SUBSURFACE)
    op = skin_bssrdf.DiffusionOperator.build(np.asarray(surface.position), np.asarray(surface.area), radius)
    sss = stage.Subsurface(profile, op, skin_bssrdf.SKIN_ETA)
    capture = stage.simulate(truth.frame(surface), rig, cams, truth.brdf(), light_vis, cam_vis, progress=progress,
                             subsurface=sss)
    if noise > 0:
        lit = np.asarray(capture.radiance)[np.asarray(capture.mask)]
        median = float(np.median(lit[lit > 0]))
        exposure = 1.0 / (noise * noise * median)  # Poisson: sigma / mean = 1 / sqrt(exposure x radiance)
        sensor = stage.Sensor(exposure=exposure, shot_noise=True)
        # The one seeding rule (stage.observation_key): the noise of (view, light, texel) is relight simulate's.
        views = [stage.sense_keyed(sensor, seed, capture.radiance[v], capture.mask[v], view=v, lights=0,
                                   samples=np.asarray(surface.texel_index)) for v in range(len(cams))]
        capture = stage.Capture(radiance=jnp.asarray(np.stack([r for r, _ in views])),
                                mask=jnp.asarray(np.stack([m for _, m in views])), rig=rig, cameras=capture.cameras,
                                sensor=sensor)
    return capture, radius


def run_demo(*, resolution: int = 96, envmap: str | os.PathLike | None = None, image_size: int = 320,
             cameras: int = 3, noise: float = 0.01, seed: int = 0, passes: int = 2, progress=None) -> Demo:
    """Simulate, fit and relight the bundled textured head, and report the fit against its truth.

    The head (``stage.load_head``) on a texel grid with its skin textures and spatially varying subsurface
    scattering (``relight.materials.skin_maps``), photographed under the Light Stage X by ``cameras``
    cameras (``stage.front_ring``) with Poisson shot noise; the diffusion operator's radius is
    ``skin_bssrdf.operator_radius`` of the truth's profile over its scattering texels. Fitted by
    :func:`relight.fit_with_subsurface` (the ladder with normals, then none / per-region / per-texel
    subsurface with the skin's regions); the truth and the fit relit by the same renderer
    (``relight.render.render_view``, rig method) from the middle camera.

    Args:
        resolution: the texel grid (N x N).
        envmap: the environment map's file; None: the bundled one.
        image_size: pixels (N x N) of each camera.
        cameras: cameras over 80 degrees around the front.
        noise: relative shot noise at the median observed radiance (0: noise-free).
        seed: the noise's seed.
        passes: BRDF / subsurface alternations.
        progress: ``stage.Progress`` for every phase (visibility, simulation, each fit).

    Returns:
        A :class:`Demo` (its ``report``; :meth:`Demo.write` writes the files).

    References:
        Jensen et al. 2001, "A Practical Model for Subsurface Light Transport", eq. 5 (the simulated
        subsurface term); Christensen & Burley 2015 (the profiles).
    """
    import stage

    from ..envmap import bundled_envmap_path, load_envmap
    from ..fitting import FitOptions, fit_report, fit_with_subsurface
    from ..image import psnr
    from ..io import head_skin_textures
    from ..materials import MODELS, skin_maps
    from ..render import render_view
    from ..simulation import peak_rss_mib

    envmap = Path(envmap) if envmap is not None else bundled_envmap_path()
    env = load_envmap(envmap)  # a missing or corrupt map fails before minutes of simulation and fitting
    times = {}
    t0 = time.perf_counter()
    mesh = stage.load_head()
    full = stage.texel_samples(mesh, resolution)
    rig = stage.light_stage_x()
    cams = stage.front_ring(mesh, cameras, image_size)
    times["geometry"] = time.perf_counter() - t0
    memory = {"geometry": peak_rss_mib()}  # the process's peak resident set after each phase, MiB

    t0 = time.perf_counter()
    light_vis = stage.light_visibility(mesh, full, rig, chunk=1 << 18, progress=progress)
    cam_vis = stage.camera_visibility(mesh, full, cams)
    seen = np.flatnonzero(cam_vis.any(axis=0))
    surface, light_vis, cam_vis = full.subset(seen), np.asarray(light_vis)[seen], cam_vis[:, seen]
    times["visibility"] = time.perf_counter() - t0
    memory["visibility"] = peak_rss_mib()

    t0 = time.perf_counter()
    skin = skin_maps(surface, head_skin_textures())
    truth = skin.maps(surface)
    capture, radius = _simulate(surface, truth, rig, cams, light_vis, cam_vis, noise, seed, progress)
    times["simulate"] = time.perf_counter() - t0
    memory["simulate"] = peak_rss_mib()

    t0 = time.perf_counter()
    fitted = fit_with_subsurface(capture, surface, model="auto", normals=True, per="auto", passes=passes,
                                 regions=skin.regions, radius_mm=radius, options=FitOptions(progress=progress))
    times["fit"] = time.perf_counter() - t0
    memory["fit"] = peak_rss_mib()

    t0 = time.perf_counter()
    maps = fitted.maps(surface)
    camera = cams[len(cams) // 2]
    relit_truth = render_view(truth, surface, mesh, camera, env, method="rig", rig=rig, background=False)
    relit_fit = render_view(maps, surface, mesh, camera, env, method="rig", rig=rig, background=False)
    times["relight"] = time.perf_counter() - t0
    memory["relight"] = peak_rss_mib()
    covered = np.asarray(stage.primary_hits(mesh, camera, 1)[0])

    model, rung, ident = np.asarray(fitted.model), fitted.mfp_rung, fitted.mfp_identified
    # The errors over every texel a camera sees (the demo's samples), with or without valid observations.
    report = fit_report(fitted, surface, truth, normals=True, timings={k: round(v, 2) for k, v in times.items()},
                        seen=np.ones(surface.num_samples, bool))
    report.update({
        "texels_seen": int(surface.num_samples), "texels_on_atlas": int(full.num_samples),
        "lights": int(rig.num_lights), "cameras": len(cams), "texel_resolution": int(resolution),
        "noise_relative_at_median": float(noise), "envmap": str(envmap),
        "model_fraction": {MODELS[m]: float(np.mean(model == m)) for m in range(len(MODELS))},
        "subsurface_rung_fraction": (None if rung is None else {k: float(np.mean(np.asarray(rung) == i))
                                                                for i, k in enumerate(("none", "region", "texel"))}),
        "mfp_identified_fraction": 0.0 if ident is None else float(np.mean(np.asarray(ident))),
        "flagged_fraction": float(np.mean(np.asarray(fitted.failed))),
        "relit_psnr_db": psnr(relit_fit, relit_truth, covered), "relit_pixels": int(covered.sum()),
        "operator_radius_mm": radius, "peak_rss_mib": memory})
    settings = {"resolution": resolution, "envmap": str(envmap), "image_size": image_size, "cameras": len(cams),
                "noise": noise, "seed": seed, "passes": passes, "rig": RIG, "textures": TEXTURES,
                "camera": stage.camera_to_dict(camera, "relit")}  # the relit images' camera (relight view's)
    return Demo(report, settings, mesh, surface, truth, maps, camera, relit_truth, relit_fit, covered, capture, env)
