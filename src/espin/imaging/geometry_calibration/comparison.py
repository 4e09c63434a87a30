"""The measured SEM image beside a synthetic SEM rendering of the calibrated mat.

``comparison.png`` shows what the calibration means: the image rows ``espin measure``
analysed, and the top layers of a mat generated from the calibrated config, rendered by
:func:`espin.imaging.synthetic.render_sem` at the same pixel size over the same field of view.

Units: um, pixels.
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from espin.core.config import Config

__all__ = ["MeasuredView", "render_like", "save_comparison", "RENDERED_LAYERS"]

RENDERED_LAYERS = 3
"""Top layers of the calibrated mat drawn in the rendering (deeper ones are hidden in an SEM)."""


@dataclass(frozen=True)
class MeasuredView:
    """The part of an SEM image that ``espin measure`` analysed.

    Attributes
    ----------
    path : Path
        The image file.
    rows : (int, int)
        First and last + 1 image rows analysed (the data bar left out).
    um_per_px : float [um / px]
        Pixel size.
    """

    path: Path
    rows: tuple[int, int]
    um_per_px: float

    @classmethod
    def from_measure_folder(cls, folder: str | Path) -> MeasuredView | None:
        """The view recorded in a measure folder's ``measurement.toml``; None when the folder
        has none, or its image is neither where it was measured nor beside the folder (an
        image path recorded relative to where ``espin measure`` ran)."""
        toml = Path(folder) / "measurement.toml"
        try:
            with open(toml, "rb") as fh:
                data = tomllib.load(fh)
            source = Path(data["source"])
            rows = tuple(int(r) for r in data["image"]["rows_analysed"])
            um_per_px = float(data["um_per_px"])
        except (OSError, KeyError, TypeError, ValueError, tomllib.TOMLDecodeError):
            return None
        for path in (source, Path(folder).parent / source):
            if path.is_file():
                return cls(path, (rows[0], rows[1]), um_per_px)
        return None

    def read(self) -> np.ndarray:
        """The analysed rows of the image, grey levels in [0, 1]."""
        from espin.imaging.image import read_image

        return read_image(self.path)[self.rows[0] : self.rows[1]]


def render_like(config: Config, shape: tuple[int, int], um_per_px: float, seed: int = 0) -> np.ndarray:
    """A synthetic SEM image of a mat of ``config``, of ``shape`` (rows, cols) pixels of
    ``um_per_px``: :data:`RENDERED_LAYERS` layers deposited like the config's (on a layer
    enlarged to the field of view if it is smaller), the window centred."""
    from espin.geometry.deposition import deposit
    from espin.imaging.synthetic import render_sem

    side = max(shape) * um_per_px
    # Only the statistics of the layers matter: the drawn layers alone, on a layer at least
    # as large as the field of view.
    layers = min(RENDERED_LAYERS, config.rve.layers)
    rve = config.rve.model_copy(update={"size_um": max(side, config.rve.side_um), "size_ratio": None, "layers": layers})
    rendered = render_sem(deposit(rve), um_per_px=um_per_px, side_um=side, layers=layers, seed=seed)
    return rendered.image[: shape[0], : shape[1]]


def save_comparison(
    image: np.ndarray, rendering: np.ndarray, um_per_px: float, path: str | Path, image_label: str, rendering_label: str
) -> Path:
    """Write the image and the rendering side by side, on one scale [um], as a PNG."""
    from matplotlib.figure import Figure

    from espin.core.figures import save_figure

    rows, cols = image.shape
    extent = (0.0, cols * um_per_px, 0.0, rows * um_per_px)
    # 1.3 in for the title, the panel titles and the x label: constrained layout does not make
    # room beyond the figure for images of fixed aspect (with 0.9 in, "x [µm]" was cut off).
    fig = Figure(figsize=(12.0, 11.0 * rows / (2.0 * cols) + 1.3), layout="constrained")
    axes = fig.subplots(1, 2, sharex=True, sharey=True)
    for ax, picture, label in ((axes[0], image, image_label), (axes[1], rendering, rendering_label)):
        low, high = np.percentile(picture, [0.5, 99.5])
        ax.imshow(
            picture, cmap="gray", vmin=low, vmax=max(high, low + 1e-9), extent=extent, interpolation="antialiased"
        )
        ax.set_title(label, fontsize=10)
        ax.set_xlabel("x [µm]")
    axes[0].set_ylabel("y [µm]")
    fig.suptitle(
        f"same pixel size ({um_per_px:.4g} µm/px) and field of view "
        f"({cols * um_per_px:.3g} × {rows * um_per_px:.3g} µm)",
        fontsize=10,
    )
    return save_figure(fig, path, dpi=110)
