"""A grid of images with row and column titles and colour bars, as one uint8 picture: the previews people look at
without the report beside them (issue 29: an unlabelled preview.png)."""

from __future__ import annotations

import numpy as np


def labelled_grid(rows, row_titles, col_titles, scales=None, dpi: int = 100) -> np.ndarray:
    """The images ``rows`` (a list of rows, each a list of uint8 [h, w, 3] images of one size) laid out as a
    grid under ``col_titles`` and beside ``row_titles``, each image at one pixel per pixel, and a colour bar
    under every image whose ``scales`` entry is given.

    Args:
        rows: R lists of C uint8 images [h, w, 3], all of the same h and w.
        row_titles: R strings, written left of each row.
        col_titles: C strings, written above the columns.
        scales: None, or R lists of C entries: None (no bar) or ``(vmin, vmax, label, cmap)``, the scale the
            image was coloured with (matplotlib colormap name).
        dpi: the figure's resolution (text size is in points, so it sets the text's pixel size).

    Returns:
        uint8 [H, W, 3]: the figure, rendered by matplotlib's Agg backend (no window, no global pyplot state).
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.cm import ScalarMappable
    from matplotlib.colors import Normalize
    from matplotlib.figure import Figure

    n_rows, n_cols = len(rows), len(rows[0])
    if len(row_titles) != n_rows or len(col_titles) != n_cols or any(len(r) != n_cols for r in rows):
        raise ValueError(f"labelled_grid: {n_rows} x {n_cols} images need {n_rows} row and {n_cols} column titles")
    h, w = rows[0][0].shape[:2]
    bar_px, title_px, left_px, gap_px = 46, 28, 28, 8
    cell_h = h + bar_px + gap_px
    width = left_px + n_cols * (w + gap_px)
    height = title_px + n_rows * cell_h
    fig = Figure(figsize=(width / dpi, height / dpi), dpi=dpi, facecolor="white")
    canvas = FigureCanvasAgg(fig)
    for i, row in enumerate(rows):
        top = title_px + i * cell_h
        for j, img in enumerate(row):
            x0 = left_px + j * (w + gap_px)
            ax = fig.add_axes((x0 / width, 1 - (top + h) / height, w / width, h / height))
            ax.imshow(np.asarray(img), interpolation="nearest")
            ax.set_axis_off()
            if i == 0:
                ax.set_title(col_titles[j], fontsize=10, pad=4)
            if j == 0:
                fig.text(4 / width, 1 - (top + h / 2) / height, row_titles[i], rotation=90, va="center",
                         ha="left", fontsize=10)
            scale = None if scales is None else scales[i][j]
            if scale is not None:
                vmin, vmax, label, cmap = scale
                cax = fig.add_axes((x0 / width, 1 - (top + h + 14) / height, w / width, 10 / height))
                bar = fig.colorbar(ScalarMappable(Normalize(vmin, vmax), cmap), cax=cax, orientation="horizontal")
                bar.ax.tick_params(labelsize=7, length=2, pad=1)
                bar.set_label(label, fontsize=7, labelpad=1)
    canvas.draw()
    return np.asarray(canvas.buffer_rgba())[..., :3].copy()
