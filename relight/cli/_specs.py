"""The command line's spellings of rigs, cameras and materials (``--rig lsx | dome:N | FILE``, ``--camera
front | FILE``, ``--subsurface NAME``) turned into library objects. Each function imports the library when it
is called: building a parser from this module imports no JAX."""

from __future__ import annotations

from pathlib import Path

from ._guard import CLIError


def parse_rig(spec: str, units: str | None = None, up: str | None = None) -> tuple:
    """``lsx`` (ICT Light Stage X, 346 near-field lights), ``dome:N`` (N distant
    lights: a geodesic dome when N = 10 * 4^s + 2, else a Fibonacci sphere) or a
    rig file: a rig.json (a capture folder's rig: positions/directions +
    intensities), or any file ``stage.load_rig_file`` reads (.npy / .txt
    tables, the Light Stage X table), with ``units`` / ``up`` as stated."""
    import stage

    s = spec.strip()
    if s.lower() in ("lsx", "light_stage_x", "lightstage"):
        return stage.light_stage_x(), "ICT Light Stage X (346 lights, near field)"
    if s.lower().startswith("dome:"):
        try:
            n = int(s[5:])
        except ValueError:
            raise CLIError(f"--rig {spec}: dome:N needs an integer light count N") from None
        if n < 4:
            raise CLIError(f"--rig {spec}: a dome needs at least 4 lights")
        if n > stage.MAX_LIGHTS:
            raise CLIError(f"--rig {spec}: a dome has at most {stage.MAX_LIGHTS} lights (stage.MAX_LIGHTS)")
        for sub in range(6):
            if 10 * 4**sub + 2 == n:
                return stage.geodesic_dome(sub), f"geodesic dome, {n} distant lights (subdivision {sub})"
        return stage.fibonacci_sphere(n), f"Fibonacci sphere, {n} distant lights"
    p = Path(s)
    if not p.exists():
        raise CLIError(f"--rig {spec}: not lsx, dome:N or an existing rig file")
    if p.is_dir():
        p = p / "rig.json"
    if units is not None or up is not None or p.suffix.lower() in (".npy", ".txt") or _is_lsx_table(p):
        stated = ", ".join(f"{k} {v}" for k, v in (("units", units), ("up", up)) if v is not None)
        return stage.load_rig_file(p, units=units, up=up), f"rig file {p}" + (f" ({stated})" if stated else "")
    return stage.load_rig(p), f"rig file {p}"


def _is_lsx_table(p: Path) -> bool:
    import stage

    if p.suffix.lower() != ".json" or not p.is_file():
        return False
    try:
        doc = stage.read_json(p)
    except ValueError:
        return False
    return isinstance(doc, dict) and "positions_cm" in doc


def parse_cameras(spec: str | None, mesh, size: int, default=None) -> tuple:
    """``front`` (``stage.front_camera``) or a camera file (``stage.load_cameras``:
    ``stage.save_cameras``'s, or a capture folder's ``cameras.json``, or a folder
    holding one); None: ``default`` if given, else ``front``."""
    import stage

    if spec is None:
        if default is not None:
            return tuple(default)
        spec = "front"
    if spec == "front":
        return (stage.front_camera(mesh, size),)
    p = Path(spec)
    if p.is_dir():
        p = p / "cameras.json"
    if not p.is_file():
        raise FileNotFoundError(f"--camera {spec}: not 'front' and no such cameras file")
    return stage.load_cameras(p)


def preset_mean_free_path(name: str):
    """``relight.materials.preset_mean_free_path`` of ``--subsurface NAME``; CLIError naming the flag."""
    from ..materials import preset_mean_free_path as preset

    try:
        return preset(name)
    except ValueError as err:
        raise CLIError(f"--subsurface {err}") from None


def __getattr__(name: str):
    # PEP 562: SUBSURFACE_PRESETS (relight.materials.subsurface_presets(), the names --subsurface takes) reads
    # skin_bssrdf, and so JAX, only when asked for.
    if name == "SUBSURFACE_PRESETS":
        from ..materials import subsurface_presets

        value = globals()["SUBSURFACE_PRESETS"] = subsurface_presets()
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
