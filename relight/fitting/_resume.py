"""A fit that survives being killed: its blocks written as parts
(:func:`relight.fitting.fit_parts`) into a folder kept between runs, and merged
back into a ``Fit`` (:func:`relight.fitting.merge_parts`)."""

from __future__ import annotations

import dataclasses
import shutil
from pathlib import Path

import jax

from ._driver import DEFAULT_BLOCK
from ._options import FitOptions, as_options
from ._parts import MANIFEST, finish_merged, fit_parts, merge_parts
from ._result import Fit


def _clear_parts(folder: Path) -> None:
    """Delete an earlier fit's parts at ``folder``: only what :func:`fit_parts` writes there (its manifest,
    its parts, hidden temporaries); FileExistsError if the folder holds anything else, so that a user's
    folder is never removed."""
    if not folder.exists():
        return
    own = folder.is_dir() and all(p.is_file() and (p.name == MANIFEST or p.name.startswith(("part_", ".")))
                                  for p in folder.iterdir())
    if not own:
        raise FileExistsError(f"{folder}: exists and is not a fit's parts folder; refusing to delete it (move it "
                              "away)")
    shutil.rmtree(folder)


def _device_count(devices) -> int:
    if devices is None:
        return len(jax.local_devices())
    return int(devices) if isinstance(devices, int) else len(devices)


def fit_resumable(capture, surface, folder, *, resume: bool = False, options: FitOptions | None = None,
                  **fit_kw) -> tuple[Fit, dict]:
    """Fit ``capture`` block by block into a parts folder and merge the parts into a ``Fit``.

    A killed fit resumes: with ``resume=True`` the parts that an earlier run of the same fit left in
    ``folder`` are kept and only the missing blocks are fitted (the parts of another fit raise
    :class:`relight.fitting.PartsFingerprintError`); without it the folder, if it is a parts folder, is
    cleared first and every block is fitted. The result is that of one :func:`relight.fit` call with the
    same settings, bit for bit.

    Args:
        capture: a ``stage.Capture``, a capture folder reader or store (read a block at a time).
        surface: the ``stage.Surface`` of the capture's samples.
        folder: the parts folder (created; ``relight fit`` keeps it hidden in its output, ``OUT/.parts``).
        resume: keep this fit's finished parts.
        options: how the fit runs (:class:`relight.fitting.FitOptions`: block, devices, progress,
            ``on_block``, called after each block fitted now).
        **fit_kw: what is fitted: :func:`relight.fit`'s keywords (model, normals, solver, ...).

    Returns:
        ``(fit, parts)``: the merged :class:`relight.Fit` and a JSON-able summary ``{"folder", "block",
        "blocks", "devices", "fitted_blocks", "resumed_blocks"}``.
    """
    folder = Path(folder)
    options = as_options(options)
    if not resume:
        _clear_parts(folder)
    fitted_now = []

    def each(s, e, arrays):
        fitted_now.append((s, e))
        if options.on_block is not None:
            options.on_block(s, e, arrays)

    block = DEFAULT_BLOCK if options.block is None else int(options.block)
    fit_parts(capture, surface, folder, block=block, process_index=0, process_count=1, on_block=each,
              options=dataclasses.replace(options, on_block=None), **fit_kw)
    fitted = finish_merged(merge_parts(folder, surface), capture, surface, block, dict(fit_kw, options=options))
    n_blocks = -(-surface.num_samples // block)
    return fitted, {"folder": folder.name, "block": block, "blocks": n_blocks,
                    "devices": _device_count(options.devices), "fitted_blocks": len(fitted_now),
                    "resumed_blocks": n_blocks - len(fitted_now)}
