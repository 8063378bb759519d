"""``relight info``: versions, devices, bundled data and the shared data folder."""

from __future__ import annotations

from pathlib import Path

from ._guard import guarded


def add_parser(sub) -> None:
    i = sub.add_parser("info", help="versions, devices, bundled data and the shared data folder")
    i.set_defaults(func=guarded(run))


def _version(dist: str) -> str:
    try:
        from importlib.metadata import version

        return version(dist)
    except Exception:
        return "not installed"


def run(args) -> int:
    import platform

    import jax

    import stage

    from ..envmap import bundled_envmap_path

    print(f"relight {_version('lightstage-relight')} (python {platform.python_version()})")
    print("libraries: " + ", ".join(f"{d} {_version(d)}" for d in ("jax", "equinox", "optimistix", "numpy", "OpenEXR",
                                                                    "trimesh", "embreex")))
    devices = jax.devices()
    print(f"jax {jax.__version__} on {jax.default_backend()} ({len(devices)} device(s): "
          f"{', '.join(str(d) for d in devices[:4])}{', ...' if len(devices) > 4 else ''})")
    rig = stage.light_stage_x()
    print(f"bundled rig: ICT Light Stage X, {rig.num_lights} lights")
    print(f"bundled mesh: {stage.head_mesh_path()}")
    print(f"bundled environment map: {bundled_envmap_path()}")
    shared = Path(__file__).resolve().parents[2] / "shared" / "data"
    if shared.is_dir():
        entries = sorted(p.name for p in shared.iterdir())
        print(f"shared data: {shared} ({', '.join(entries[:8])}{', ...' if len(entries) > 8 else ''})")
    else:
        print("shared data: none (../shared/data not found)")
    return 0
