"""Which folders a command may take as its output: what it wrote before result
sets had manifests (its ``settings.json`` names the command)."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import stage

__all__ = ["earlier_output"]

SETTINGS = "settings.json"


def earlier_output(command: str, legacy: Callable[[Path], bool] | None = None) -> Callable[[Path], bool]:
    """The test of a folder that ``relight <command>`` wrote before result-set manifests.

    Args:
        command: the command's name ("fit", "render", ...).
        legacy: a further test of such folders (a folder this command wrote in another older layout), or None.

    Returns:
        ``own(folder) -> bool``: True when the folder's settings.json names ``relight <command>``, or
        ``legacy(folder)`` holds; for ``result_set`` / ``check_output_folder``'s ``legacy``.
    """
    def own(folder: Path) -> bool:
        try:
            doc = stage.parse_json((Path(folder) / SETTINGS).read_bytes(), SETTINGS)
        except (OSError, ValueError):
            doc = None
        if isinstance(doc, dict) and doc.get("command") == f"relight {command}":
            return True
        return bool(legacy and legacy(folder))

    return own
