"""Resumable and multi-process fits: :func:`relight.fit`'s sample blocks written
as parts of one result set, and merged back into a ``Fit``.

A result set is a folder: ``manifest.json`` (the fingerprint of the inputs and
settings, the block size and the blocks) and one ``part_<start>_<stop>.npz``
per finished block, each written atomically (``relight.results.atomic_write_bytes``) the
moment its block is fitted and stamped with the fingerprint. A reader accepts a
part only under the manifest's fingerprint, so a set never mixes results of two
different fits. Blocks go round-robin to processes (block b to process
``b % process_count``, by default ``jax.process_index()`` of
``jax.process_count()`` after ``jax.distributed.initialize``); nothing is
exchanged between processes, each writes its own parts.

Every block is fitted by the same code and with the same padded solver shapes
(the observation count and the chunk size are fixed by the whole capture, as in
:func:`relight.fit`), so a set fitted in any order, by any number of
processes, interrupted and resumed, merges to exactly the ``Fit`` of one
``relight.fit`` call with the same ``block`` (bit-identical; tested).
"""

from __future__ import annotations

import hashlib
import inspect
import io
import json
import re
import zipfile
from pathlib import Path

import jax
import numpy as np

import stage

from ..results import atomic_write_bytes, atomic_write_text
from . import _driver as _d
from ._neighbours import lobes_from_neighbours
from ._options import as_options
from ._result import FIELDS, Fit, fit_from_arrays

MANIFEST = "manifest.json"
# Bumped when the layout of a part or of the manifest changes: an old set is then refused, not misread.
_FORMAT = 1


class PartsFingerprintError(ValueError):
    """A result-set folder (or one of its parts) belongs to another fit: other data, surface or settings."""


class PartsIncompleteError(ValueError):
    """A result set lacks parts for some blocks (the fit has not finished on every process)."""


def _part_name(s: int, e: int) -> str:
    return f"part_{s}_{e}.npz"


def _hash_leaves(h, tree) -> None:
    """Feed every leaf of a pytree (arrays: dtype, shape and bytes; others: repr) into the hash ``h``."""
    for leaf in jax.tree_util.tree_leaves(tree):
        if isinstance(leaf, (np.ndarray, jax.Array, np.generic)):
            a = np.ascontiguousarray(np.asarray(leaf))
            h.update(f"{a.dtype.str}{a.shape}".encode())
            h.update(a.tobytes())
        else:
            h.update(repr(leaf).encode())


def _fit_keywords(fit_kw: dict) -> dict:
    """relight.fit's keywords with ``fit_kw`` over its defaults, read from its signature (one home for
    them); TypeError naming an unknown keyword."""
    kw = {k: p.default for k, p in inspect.signature(_d.fit).parameters.items() if p.kind is p.KEYWORD_ONLY}
    unknown = set(fit_kw) - set(kw)
    if unknown:
        raise TypeError(f"fit_parts: unknown fit keyword(s) {sorted(unknown)} (on_block is fit_parts' own)")
    kw.update(fit_kw)
    return kw


def finish_merged(fitted: Fit, capture, surface, block: int, fit_kw: dict) -> Fit:
    """What :func:`relight.fit` does after its blocks, on a merged set's ``Fit``: with ``model="auto"``
    and ``neighbour_lobes`` (the default), the lobes the lights never sampled taken from the neighbours
    (:mod:`relight.fitting._neighbours`; it reads the capture again, a block at a time). ``fit_kw``: the
    keywords the parts were fitted with. The result is then ``relight.fit``'s, bit for bit."""
    kw = _fit_keywords(fit_kw)
    options = as_options(kw.pop("options"))
    plan = _d._plan(capture, surface, **kw, options=options, block=block, count=False, where="fit_parts")
    if not plan.neighbour_lobes:
        return fitted
    return lobes_from_neighbours(fitted, plan, surface, options.progress)


def _settings(fit_kw: dict, block: int, ndev: int, dt) -> dict:
    """The settings that change a fit's numbers, as JSON: ``fit``'s keywords (progress and on_block left
    out), the block size, the number of devices (it pads the solver's chunk) and the working float."""
    out = {}
    for k, v in sorted(fit_kw.items()):
        if k in ("progress", "devices", "neighbour_lobes"):  # neighbour_lobes acts after the parts (finish_merged)
            continue
        if k == "shadow_ratio" and v is None:  # off, as before the keyword: earlier sets keep their fingerprint
            continue
        if isinstance(v, (str, int, float, bool)) or v is None:
            out[k] = v
        else:  # a solver object: its repr without memory addresses (they differ from run to run)
            out[k] = re.sub(r" at 0x[0-9a-fA-F]+", "", repr(v))
    out.update(block=int(block), devices=int(ndev), dtype=np.dtype(dt).name)
    return out


class _Plan:
    """What :func:`relight.fit` would set up for this capture, surface and settings (the solver, the
    padded shapes, the valid counts), plus the fingerprint of it all."""

    def __init__(self, capture, surface, block: int, fit_kw: dict):
        kw = _fit_keywords(fit_kw)
        options = as_options(kw.pop("options"))
        self.fit = _d._plan(capture, surface, **kw, options=options, block=block, count=False, where="fit_parts")
        self.options = options
        source, P = self.fit.source, self.fit.P
        V, L, _, C = (int(s) for s in source.shape)
        self.rig, self.cameras, self.floor, self.solver_name = (self.fit.rig, self.fit.cameras, self.fit.floor,
                                                                 self.fit.solver_name)
        self.P, self.block, self.dt = P, self.fit.block, self.fit.dt
        # fit's counting pass, reading the radiance too to hash every block's data (dtype and shape
        # included): one more read of the capture, cheap next to fitting it (a few us against ~ms
        # per sample), and the only way a radiance change anywhere is seen by every process.
        h = hashlib.sha256()
        h.update(f"relight.fit_parts/{_FORMAT}/{(V, L, P, C)}".encode())
        self.n_valid = np.zeros(P, np.int64)
        for s, e in self.blocks():
            rad, m = _d.read_block(source, s, e)
            self.n_valid[s:e] = np.sum(m, axis=(0, 1))
            _hash_leaves(h, (rad, m))
            del rad, m
        self.fit.set_counts(self.n_valid)
        # The settings that change the numbers, under the keys fit's keywords had before FitOptions.
        flat = dict(kw, chunk=options.chunk, steps_per_round=options.steps_per_round, rounds=options.rounds,
                    rtol=options.rtol, atol=options.atol)
        self.settings = _settings(flat, self.block, self.fit.devices, self.dt)
        self.surface_hash = _surface_fingerprint(surface)
        _hash_leaves(h, (self.rig, self.cameras))
        h.update(self.surface_hash.encode())
        h.update(json.dumps(self.settings, sort_keys=True).encode())
        self.fingerprint = h.hexdigest()

    def blocks(self) -> list[tuple[int, int]]:
        return [(s, min(s + self.block, self.P)) for s in range(0, self.P, self.block)]

    def manifest(self) -> dict:
        return dict(format=_FORMAT, fingerprint=self.fingerprint, samples=self.P, block=self.block,
                    blocks=[list(b) for b in self.blocks()], settings=self.settings, alpha_floor=self.floor,
                    solver=self.solver_name, dtype=self.dt.name, surface=self.surface_hash)


def _surface_fingerprint(surface) -> str:
    """SHA-256 (hex) of every field of a ``stage.Surface``: what ``merge_parts`` checks a surface by."""
    h = hashlib.sha256()
    _hash_leaves(h, surface)
    h.update(repr(surface.resolution).encode())
    return h.hexdigest()


def _read_manifest(folder: Path) -> dict | None:
    path = folder / MANIFEST
    if not path.exists():
        return None
    try:
        return stage.parse_json(path.read_bytes(), path)
    except (OSError, ValueError) as err:
        raise PartsFingerprintError(f"{path}: not a readable result-set manifest ({err})") from None


def _read_part(path: Path, fingerprint: str) -> dict | None:
    """The arrays of a part written under ``fingerprint``, for the samples its name says; None if absent,
    unreadable, another fit's or of other samples."""
    try:
        s, e = (int(x) for x in path.stem.split("_")[1:3])
        # Our own handle: np.load leaks the one it opens when the zip is corrupt.
        with open(path, "rb") as fh, np.load(fh, allow_pickle=False) as z:
            if str(z["fingerprint"]) != fingerprint or (int(z["start"]), int(z["stop"])) != (s, e):
                return None
            part = {k: z[k] for k in z.files}
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile):
        return None
    if any(part.get(k) is None or part[k].shape != (e - s, *shape) for k, (shape, _) in FIELDS.items()):
        return None
    return part


def _write_part(path: Path, arrays: dict, fingerprint: str, s: int, e: int) -> None:
    buf = io.BytesIO()
    np.savez(buf, fingerprint=np.str_(fingerprint), start=np.int64(s), stop=np.int64(e), **arrays)
    atomic_write_bytes(path, lambda fh: fh.write(buf.getvalue()))


def _prepare(folder: Path, plan: _Plan, overwrite: bool) -> None:
    """Make ``folder`` this fit's result set: refuse another fingerprint's (unless ``overwrite``: then
    delete its parts), write the manifest."""
    folder.mkdir(parents=True, exist_ok=True)
    try:
        old = _read_manifest(folder)
    except PartsFingerprintError:
        if not overwrite:
            raise
        old = None
    if old is not None and old.get("fingerprint") != plan.fingerprint:
        if not overwrite:
            raise PartsFingerprintError(
                f"{folder}: holds the parts of another fit (fingerprint {str(old.get('fingerprint'))[:12]}..., "
                f"this fit's {plan.fingerprint[:12]}...: other data, surface or settings); pass overwrite=True "
                "to replace it, or use another folder")
    if old != plan.manifest():
        # Every process writes the same bytes, so concurrent writers cannot disagree.
        atomic_write_text(folder / MANIFEST, json.dumps(plan.manifest(), indent=1, sort_keys=True))
    if overwrite:
        for path in folder.glob("part_*.npz"):
            if _read_part(path, plan.fingerprint) is None:
                path.unlink(missing_ok=True)


def fit_parts(capture, surface, folder, *, block: int = 4096, process_index: int | None = None,
              process_count: int | None = None, overwrite: bool = False, on_block=None, **fit_kw) -> Path:
    """Fit ``capture`` as :func:`relight.fit` does, writing each block's result to ``folder`` as it is made.

    The samples are cut in blocks of ``block`` as ``relight.fit(..., block=block)`` cuts them; this
    process fits blocks ``process_index, process_index + process_count, ...`` (default
    ``jax.process_index()`` / ``jax.process_count()``: one process per host after
    ``jax.distributed.initialize``) and writes each, atomically, as ``folder/part_<start>_<stop>.npz``;
    ``folder/manifest.json`` holds the fingerprint: SHA-256 of the capture's radiance and mask (every
    byte, dtype and shape: one read of the capture, block by block, in the pass where ``fit`` counts
    the valid observations), its rig and cameras, the surface and the settings (``fit_kw``: ``fit``'s
    keywords, ``progress`` aside; ``block``; the device count; the working float), and every part
    carries it. Resume: a block whose part exists with this fingerprint is skipped. A folder holding
    another fingerprint's set raises :class:`PartsFingerprintError` unless ``overwrite=True`` (then
    its parts are ignored and replaced; the other fit's parts are deleted). ``on_block(start, stop,
    arrays)`` is called after each part is written. Returns ``folder``; :func:`merge_parts` makes the
    ``Fit`` once every process has finished (bit-identical to ``relight.fit(capture, surface,
    block=block, **fit_kw)``)."""
    folder = Path(folder)
    if on_block is not None and not callable(on_block):
        raise TypeError(f"fit_parts: on_block must be a callable on_block(start, stop, arrays) or None, "
                        f"got {on_block!r}")
    pi = jax.process_index() if process_index is None else process_index
    pc = jax.process_count() if process_count is None else process_count
    if isinstance(pc, bool) or not isinstance(pc, (int, np.integer)) or pc < 1:
        raise ValueError(f"fit_parts: process_count must be an int >= 1, got {process_count!r}")
    if isinstance(pi, bool) or not isinstance(pi, (int, np.integer)) or not 0 <= pi < pc:
        raise ValueError(f"fit_parts: process_index must be an int in [0, {pc}), got {process_index!r}")
    plan = _Plan(capture, surface, block, fit_kw)
    _prepare(folder, plan, overwrite)

    phases = _d._Phases(plan.options.progress)
    chosen = dict.fromkeys(plan.fit.rungs, 0)
    blocks = plan.blocks()
    for b, (s, e) in enumerate(blocks):
        if b % pc != pi:
            continue
        path = folder / _part_name(s, e)
        if path.exists() and _read_part(path, plan.fingerprint) is not None:
            continue  # resume: this fit's part is there
        part = _d._fit_block(plan.fit, surface, s, e, phases, chosen)
        _write_part(path, part, plan.fingerprint, s, e)
        if on_block is not None:
            on_block(s, e, part)
    return folder


def merge_parts(folder, surface) -> Fit:
    """The ``Fit`` of a finished result set written by :func:`fit_parts` (the same, bit for bit, as
    ``relight.fit`` with its settings, but for ``model="auto"``'s lobes from the neighbours, which read the
    capture: :func:`relight.fitting.fit_resumable` adds them). ``surface``: the fitted surface (checked
    against the set's fingerprint). Raises :class:`PartsIncompleteError` naming the missing blocks,
    :class:`PartsFingerprintError` for a part of another fit or another surface, FileNotFoundError
    naming ``folder`` without a manifest."""
    folder = Path(folder)
    man = _read_manifest(folder)
    if man is None:
        raise FileNotFoundError(f"merge_parts: {folder} has no {MANIFEST} (not a fit_parts result set)")
    if man.get("format") != _FORMAT:
        raise PartsFingerprintError(f"{folder}: result-set format {man.get('format')!r}, this reader's {_FORMAT}")
    fp, P = man["fingerprint"], int(man["samples"])
    if surface.num_samples != P:
        raise ValueError(f"merge_parts: the set has {P} samples but the surface has {surface.num_samples}")
    dt = np.dtype(man["dtype"])
    kinds = {"f": dt, "i": np.int32, "o": np.float32}
    out = {k: np.zeros((P, *shape), kinds[c]) for k, (shape, c) in FIELDS.items()}
    missing, foreign = [], []
    for s, e in man["blocks"]:
        path = folder / _part_name(s, e)
        if not path.exists():
            missing.append(f"{s}..{e}")
            continue
        part = _read_part(path, fp)
        if part is None:
            foreign.append(path.name)
            continue
        for k in out:
            out[k][s:e] = part[k]
    if foreign:
        raise PartsFingerprintError(f"{folder}: parts {foreign} are unreadable or of another fit than {MANIFEST} "
                                    f"(fingerprint {fp[:12]}...): rerun fit_parts on them")
    if missing:
        raise PartsIncompleteError(f"{folder}: {len(missing)} of {len(man['blocks'])} blocks have no part yet "
                                   f"(samples {', '.join(missing[:8])}{' ...' if len(missing) > 8 else ''})")
    # The surface last: its hash is the one costly check, worth it only for a complete set.
    if _surface_fingerprint(surface) != man.get("surface"):
        raise PartsFingerprintError(f"{folder}: this set was fitted on another surface (same sample count)")
    return fit_from_arrays(out, dt, float(man["alpha_floor"]), man["solver"])
