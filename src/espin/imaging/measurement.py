"""Measuring an SEM image of a fiber mat: :func:`measure` and its result.

Pipeline (one module per step): read the image and its scale (:mod:`espin.imaging.image`;
``um_per_px``, else the scale bar :mod:`espin.imaging.scale`, else the microscope's TIFF tags
:mod:`espin.imaging.metadata`), leave out the data bar (the rows given, else the one found by
:mod:`espin.imaging.databar`) -> fiber pixels (:mod:`espin.imaging.segment`) -> fibers traced through
crossings (:mod:`espin.imaging.trace`) -> local widths (:mod:`espin.imaging.widths`) -> per-fiber
diameter, orientation and tortuosity as the paper defines them (section 2.2: contour over
end-to-end length, orientation of the end-to-end line) -> fully visible (top) fibers against
partly hidden deeper ones (:mod:`espin.imaging.visibility`) -> fitted distributions
(:mod:`espin.imaging.distributions`; the diameter of the visible fibers is the primary one,
the hidden ones' and all fibers' are reported besides) and the image's structure-tensor
orientation (:mod:`espin.imaging.orientation`).

Long-range shape: the edge of the analysed image each traced fiber's ends lie on, and of the
fibers traced from edge to edge the fraction that leave through the edge they entered (U-turn
fraction) and their mean end-to-end over contour length (straightness), with
:func:`espin.geometry.pieces.crossing_statistics`, as for the window portions of a virtual mat
(:func:`espin.geometry.pieces.window_crossings`). An end lies on an edge when it is within
:data:`EDGE_NEAR` w of it, or when the fiber, continued straight from it, reaches the edge
within :data:`EDGE_REACH` w (see there why).
"""

from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, cast

import numpy as np
import pandas as pd

from espin.core.errors import ConfigError, SEMError
from espin.core.html import html_table
from espin.core.output_folder import OutputFolder
from espin.geometry.fibers_csv import EDGE_NAMES, FIBER_COLUMNS, write_fibers_csv
from espin.geometry.pieces import CrossingStatistics, border_edges, crossing_statistics
from espin.imaging.databar import DataBar, detect_data_bar
from espin.imaging.distributions import (
    DiameterFits,
    FittedDistributions,
    fit_diameter_families,
    fit_distributions,
)
from espin.imaging.image import as_grey, parse_rows, read_image, row_slice
from espin.imaging.metadata import MetadataScale, read_pixel_size
from espin.imaging.orientation import image_angle_deg, structure_tensor_orientation
from espin.imaging.polarity import bright_fibers
from espin.imaging.pores import PoreStructure, mat_structure
from espin.imaging.scale import ScaleBar, detect_scale_bar
from espin.imaging.segment import MIN_WIDTH_PX, segment_fibers
from espin.imaging.trace import trace_fibers
from espin.imaging.visibility import Visibility, fiber_visibility
from espin.imaging.widths import WidthSamples, fiber_diameters, local_widths

__all__ = [
    "SEMMeasurement",
    "measure",
    "measurement_digest",
    "SCHEMA",
    "MEASURE_OUTPUTS",
    "EDGE_NEAR",
    "EDGE_REACH",
    "SCALE_AGREEMENT",
]

SCHEMA = "espin.sem.measurement/1"
"""Schema of ``measurement.toml``."""
MEASURE_OUTPUTS = ("fibers.csv", "measurement.toml", "histograms.png", "overlay.png", "orientation_map.png")
"""The files a measurement writes into its folder (glob patterns relative to it)."""
EDGE_NEAR = 0.2
"""A traced fiber's end within this many fiber widths w (the tracer's) of an edge of the
analysed image lies on it. The mask is padded by replication before skeletonizing, so a
skeleton runs out to the border, and :func:`espin.imaging.trace.trace_fibers` keeps the ends
there: they lay within 0.14 w of the edge on 36 images of virtual mats (0, 20 and 40 deg
waviness, 60 D windows) and within 0.09 w on the two real images (PLGA-1500_1: 2.4 px, w =
26 px); the next ends lay 0.23 w and more inside, but for the cut tips of Vs (see
:data:`EDGE_REACH`), from 0.18 w."""
EDGE_REACH = 2.0
"""An end farther inside lies on the edge that the fiber, continued straight from it (the
direction of its last w of arc), reaches within this many widths w. The tracer pulls some ends
of fibers that reach the edge back: a crossing less than w from the edge leaves a stub shorter
than w, pruned as a spur, and the unpaired end at that junction loses the pixels within w of
it, so the end lies up to 2 w inside; where two fibers reach the border together, the padded
skeleton joins them in a V that is cut at its tip, a few pixels inside. On virtual mats about
a fifth of the ends of fibers reaching the edge were pulled back. A distance alone cannot tell
them from the ends of a fiber running along the edge: with 1 w, 3 of 89 edge-to-edge traces
on straight fibers were U-turns, and curling fibers (40 deg, 100 D window) read a U-turn
fraction of 0.33 against a true 0.20; with this rule 0 of 107 and 0.21 (12 images each)."""

SCALE_AGREEMENT = 0.02
"""A given scale (``um_per_px`` or the scale bar) and the pixel size of the image's metadata
that differ by more than this fraction are noted in the result (the given one is used)."""

Rows = tuple[int, int] | str


REPR_NAME_LENGTH = 40
"""``repr(SEMMeasurement)`` shows at most this many characters of the image's file name (its end)."""


@dataclass(frozen=True, eq=False, repr=False)
class SEMMeasurement:
    """What :func:`measure` found in one SEM image.

    Attributes
    ----------
    fibers : pandas.DataFrame
        One row per traced fiber: ``fiber`` (int), ``diameter_um`` (blurred flat profile
        fitted to the fiber's median profile, :func:`espin.imaging.widths.fiber_diameters`),
        ``orientation_deg`` (end-to-end axis, [0, 180)), ``tortuosity`` (contour /
        end-to-end, >= 1), ``contour_length_um``, ``end_to_end_um``, ``start_edge`` and
        ``end_edge`` (edge of the analysed image that the first / last end lies on:
        ``bottom``, ``right``, ``top``, ``left``, or "" inside the image), ``visible`` (bool:
        a fully visible top fiber, :mod:`espin.imaging.visibility`; the primary diameter
        population).
    widths_um : (n,) float64 [um]
        All local width samples.
    um_per_px : float [um / px]
        Pixel size.
    field_of_view_um : tuple[float, float] [um]
        Width and height of the analysed image (after cropping).
    dominant_direction_deg : float [deg]
        Structure-tensor dominant fiber axis, [0, 180).
    coherency : float
        Structure-tensor coherency, 0 (isotropic) to 1 (parallel).
    fits : FittedDistributions
        Diameter of the visible fibers (normal, lognormal and two-normal mixture, chosen by
        BIC; ``diameter_mean_um`` and ``diameter_sd_um`` are the normal's), uniform or von
        Mises orientation (AIC) and half-normal tortuosity of all fibers.
    diameter_hidden : DiameterFits
        The same diameter fits for the fibers not visible (partly hidden, deeper).
    diameter_all : DiameterFits
        And for all fibers.
    visibility : Visibility
        Features and class of each fiber of ``fibers`` (same order).
    n_crossing : int
        Traced fibers whose two ends lie on edges of the analysed image (``start_edge`` and
        ``end_edge`` of ``fibers`` both set).
    u_turn_fraction : float
        Of those, the fraction whose two ends lie on the same edge (NaN if none).
    straightness : float
        Their mean end-to-end distance over contour length, each continued straight to the
        edge where an end was pulled back (:data:`EDGE_REACH`); 1 for straight fibers, NaN if
        none.
    min_chord_um : float [um]
        Traced fibers with a shorter end-to-end length were dropped.
    typical_width_px : float [px]
        Fiber width that scaled the filters.
    image : (rows, cols) float64
        The analysed grey image (cropped).
    mask : (rows, cols) bool
        Fiber pixels of the analysed image (:attr:`espin.imaging.segment.Segmentation.mask`).
    pores : PoreStructure
        Porosity, pore sizes and intersection density of the analysed image
        (:func:`espin.imaging.pores.mat_structure` on ``mask`` and ``junctions_px``).
    rows : tuple[int, int]
        Rows of the original image that were analysed (start, stop).
    paths_px : list of (n_i, 2) float64 [px]
        Centre line (row, col) of each fiber of ``fibers``, in the same order.
    width_samples : WidthSamples
        Where and across which normal each local width was measured (px; ``fiber`` indexes
        ``paths_px``).
    junctions_px : (n, 2) float64 [px]
        Junction centres (row, col) of the skeleton.
    scale_bar : ScaleBar or None
        The detected scale bar, when the scale came from one.
    scale_bar_um : float or None [um]
        Its length as given.
    scale_source : str
        Where ``um_per_px`` came from: ``"um_per_px"`` (given), ``"scale_bar"`` or
        ``"metadata"`` (the image's TIFF tags, :mod:`espin.imaging.metadata`).
    metadata : MetadataScale or None
        The pixel size the image's tags record, and the tag (used or not).
    scale_note : str
        Why the metadata's pixel size was not used although it differs from the given scale,
        or why the metadata was not read; "" if nothing to note.
    data_bar : DataBar or None
        The data bar found and left out (:func:`espin.imaging.databar.detect_data_bar`), None
        when none was found or the rows were given (``crop_rows``, ``crop_bottom_px``,
        ``scale_bar_rows``) or detection was off.
    polarity : str
        Which way round the image was and what was done (:func:`espin.imaging.polarity.bright_fibers`).
    source : str
        The image file (or ``"array"``).
    inputs_digest : str
        :func:`measurement_digest` of the image and the options (recorded in ``run.json``).
    """

    fibers: pd.DataFrame
    widths_um: np.ndarray
    um_per_px: float
    field_of_view_um: tuple[float, float]
    dominant_direction_deg: float
    coherency: float
    fits: FittedDistributions
    diameter_hidden: DiameterFits
    diameter_all: DiameterFits
    visibility: Visibility
    n_crossing: int
    u_turn_fraction: float
    straightness: float
    min_chord_um: float
    typical_width_px: float
    image: np.ndarray
    mask: np.ndarray
    pores: PoreStructure
    rows: tuple[int, int]
    paths_px: list[np.ndarray]
    width_samples: WidthSamples
    junctions_px: np.ndarray
    scale_bar: ScaleBar | None
    scale_bar_um: float | None
    source: str
    inputs_digest: str
    scale_source: str
    metadata: MetadataScale | None
    scale_note: str
    data_bar: DataBar | None = None
    polarity: str = ""

    def __repr__(self) -> str:
        """One line: image name, scale [um/px], fibers traced (visible), diameter of the visible
        fibers mean +- sd [um], dominant direction [deg] and coherency."""
        name = Path(self.source).name
        if len(name) > REPR_NAME_LENGTH:
            name = "..." + name[3 - REPR_NAME_LENGTH :]
        d = self.fits.diameter
        return (
            f"SEMMeasurement({name}, {self.um_per_px:.4g} um/px, {len(self.fibers)} fibers "
            f"({int(self.fibers['visible'].sum())} visible), diameter {d.mean_um:.3g} +- {d.sd_um:.2g} um, "
            f"direction {self.dominant_direction_deg:.0f} deg, coherency {self.coherency:.2f})"
        )

    def _repr_html_(self) -> str:
        """The printed table of :meth:`table_rows` as an HTML table (Jupyter)."""
        return html_table(f"SEMMeasurement of {self.source}", self.table_rows())

    def summary(self) -> dict[str, Any]:
        """The summary written to ``measurement.toml`` (units in the key names)."""
        from espin.core.version import __version__

        f = self.fibers
        fits = self.fits
        scale: dict[str, Any] = {"source": self.scale_source}
        if self.metadata is not None:
            scale |= {"metadata_tag": self.metadata.source, "metadata_um_per_px": self.metadata.um_per_px}
        if self.scale_note:
            scale["note"] = self.scale_note
        if self.scale_bar is not None:
            scale |= {
                "scale_bar_um": self.scale_bar_um,
                "scale_bar_px": self.scale_bar.length_px,
                "scale_bar_kind": self.scale_bar.kind,
                "scale_bar_ticks": self.scale_bar.n_ticks,
                "scale_bar_rows": list(self.scale_bar.row_range),
            }
        return {
            "schema": SCHEMA,
            "espin_version": __version__,
            "units": "lengths um, angles deg (counter-clockwise from +x, y up)",
            "source": self.source,
            "um_per_px": self.um_per_px,
            "field_of_view_um": list(self.field_of_view_um),
            "min_chord_um": self.min_chord_um,
            "image": {
                "rows_analysed": list(self.rows),
                "size_px": [int(self.image.shape[1]), int(self.image.shape[0])],
                "typical_width_px": self.typical_width_px,
                "data_bar": None if self.data_bar is None else self.data_bar.describe(),
                "polarity": self.polarity,
            },
            "scale": scale,
            "counts": {
                "fibers": len(f),
                "width_samples": len(self.widths_um),
                "junctions": len(self.junctions_px),
                "visible": int(f["visible"].sum()),
                "hidden": int((~f["visible"]).sum()),
            },
            "diameter": {
                "population": "visible",
                **fits.diameter.summary(),
                "visibility_rule": self.visibility.rule,
                "brightness_threshold": self.visibility.threshold,
            },
            "diameter_hidden": {"population": "hidden", **self.diameter_hidden.summary()},
            "diameter_all": {
                "population": "all",
                **self.diameter_all.summary(),
                "local_mean_um": _nan_stat(np.mean, self.widths_um),
                "local_sd_um": _nan_stat(np.std, self.widths_um),
            },
            "orientation": {
                "dominant_direction_deg": self.dominant_direction_deg,
                "coherency": self.coherency,
                "selection": "AIC",
                "distribution": fits.orientation_model,
                "von_mises_mean_deg": fits.orientation_mean_deg,
                "von_mises_kappa": fits.orientation_kappa,
                "aic_uniform": fits.orientation_aic_uniform,
                "aic_von_mises": fits.orientation_aic_von_mises,
            },
            "tortuosity": {
                "distribution": "halfnorm",
                "loc": fits.tortuosity_loc,
                "scale": fits.tortuosity_scale,
                "mean": _nan_stat(np.mean, f["tortuosity"]),
                "sd": _nan_stat(np.std, f["tortuosity"]),
            },
            "crossing": {
                "n_crossing": self.n_crossing,
                "u_turn_fraction": self.u_turn_fraction,
                "straightness": self.straightness,
                "edge_near_widths": EDGE_NEAR,
                "edge_reach_widths": EDGE_REACH,
            },
            "pores": self.pores.summary(),
        }

    def table_rows(self) -> list[tuple[str, str]]:
        """(quantity, value) pairs for a short printed table."""
        f, fits = self.fibers, self.fits
        orient = (
            "uniform"
            if fits.orientation_model == "uniform"
            else f"von Mises, mean {fits.orientation_mean_deg:.1f} deg, kappa {fits.orientation_kappa:.3g}"
        )
        bar = [] if self.data_bar is None else [("data bar", f"{self.data_bar.describe()}, left out (found)")]
        return [
            ("scale", f"{self.um_per_px:.5g} um/px" + self._scale_text()),
            *bar,
            ("field of view", f"{self.field_of_view_um[0]:.4g} x {self.field_of_view_um[1]:.4g} um"),
            (
                "fibers traced",
                f"{len(f)} (end-to-end >= {self.min_chord_um:.3g} um, median "
                f"{_nan_stat(np.median, f['end_to_end_um']):.3g} um)",
            ),
            ("diameter", self._diameter_text(fits.diameter, "visible fibers")),
            ("  hidden fibers", self._diameter_text(self.diameter_hidden, "partly hidden, deeper")),
            (
                "  all fibers",
                f"mean {self.diameter_all.mean_um:.4g} +- "
                f"{self.diameter_all.sd_um:.3g} um ({self.diameter_all.n}; "
                f"{len(self.widths_um)} local widths)",
            ),
            (
                "orientation",
                f"dominant {self.dominant_direction_deg:.1f} deg, coherency "
                f"{self.coherency:.3f}; fibers: {orient} (AIC)",
            ),
            (
                "tortuosity",
                f"mean {_nan_stat(np.mean, f['tortuosity']):.4f}; half-normal loc 1, "
                f"scale {fits.tortuosity_scale:.4f} (of the traced pieces; whole "
                "fibers across the image: espin calibrate-geometry)",
            ),
            ("edge to edge", self._crossing_text()),
            *self.pores.table_rows(),
        ]

    @staticmethod
    def _diameter_text(fits: DiameterFits, population: str) -> str:
        if fits.n == 0:
            return f"none ({population})"
        text = f"{fits.mean_um:.4g} +- {fits.sd_um:.3g} um, median {fits.median_um:.4g} ({fits.n} {population}"
        if not fits.chosen:
            return text + ")"
        if fits.chosen == "mixture" and fits.mixture is not None:
            m = fits.mixture
            family = (
                f"mixture {m.weight:.2f} x {m.mean_1:.3g} +- {m.sd_1:.2g} and "
                f"{1 - m.weight:.2f} x {m.mean_2:.3g} +- {m.sd_2:.2g}"
            )
        else:
            family = fits.chosen
        return text + f"; {family} by BIC)"

    def _scale_text(self) -> str:
        if self.scale_bar is not None:
            text = f" (bar {self.scale_bar.length_px:.1f} px = {self.scale_bar_um:g} um)"
        elif self.scale_source == "metadata" and self.metadata is not None:
            text = f" ({self.metadata.source})"
        else:
            text = ""
        return text + (f"; {self.scale_note}" if self.scale_note else "")

    def _crossing_text(self) -> str:
        if self.n_crossing == 0:
            return "no fiber traced across the image"
        return (
            f"{self.n_crossing} fibers traced across the image; U-turn fraction "
            f"{self.u_turn_fraction:.3f}, straightness {self.straightness:.4f}"
        )

    def write(self, folder: str | Path, figures: bool = True, *, overwrite: bool = False) -> dict[str, Path]:
        """Write ``fibers.csv``, ``measurement.toml`` and (optionally) the figures, with the
        folder's ``run.json`` manifest (:mod:`espin.core.output_folder`).

        Parameters
        ----------
        folder : str or Path
            Output folder (created if needed).
        figures : bool
            Also write ``histograms.png`` and ``overlay.png``.
        overwrite : bool
            Replace another run's results in ``folder`` (its :data:`MEASURE_OUTPUTS` are
            removed first) instead of refusing.

        Returns
        -------
        dict[str, Path]
            The files written, by kind.

        Raises
        ------
        ConfigError
            If ``folder`` holds another run's results and ``overwrite`` is False.
        """
        with OutputFolder.claim(folder, "measure", self.inputs_digest, MEASURE_OUTPUTS, overwrite=overwrite):
            return self.write_files(folder, figures)

    def write_files(self, folder: str | Path, figures: bool = True) -> dict[str, Path]:
        """Write the files of :meth:`write` into a folder the caller has claimed
        (:class:`espin.core.output_folder.OutputFolder`)."""
        import tomli_w

        from espin.core.atomic import atomic_write_bytes

        folder = Path(folder)
        files = {
            "fibers": write_fibers_csv(self.fibers, folder / "fibers.csv"),
            "summary": atomic_write_bytes(
                folder / "measurement.toml", tomli_w.dumps(_toml_ready(self.summary())).encode()
            ),
        }
        if figures:
            from espin.imaging.figures import (
                save_histograms,
                save_orientation_map,
                save_overlay,
            )

            files["histograms"] = save_histograms(self, folder / "histograms.png")
            files["overlay"] = save_overlay(self, folder / "overlay.png")
            files["orientation_map"] = save_orientation_map(self, folder / "orientation_map.png")
        return files


def measure(
    image: str | Path | np.ndarray,
    *,
    um_per_px: float | None = None,
    scale_bar_um: float | None = None,
    scale_bar_rows: Rows | None = None,
    crop_rows: Rows | None = None,
    crop_bottom_px: int | None = None,
    width_px: float | None = None,
    max_bend_deg: float = 35.0,
    min_length_diameters: float = 3.0,
    detect_data_bar: bool = True,
    invert: bool | None = None,
) -> SEMMeasurement:
    """Measure fiber diameters, orientations and tortuosities on an SEM image.

    Parameters
    ----------
    image : str, Path or (rows, cols[, channels]) array
        A TIFF (palette and 16-bit included), PNG or JPEG file, or an image array.
    um_per_px : float [um / px], optional
        Pixel size. Give this, or ``scale_bar_um`` with ``scale_bar_rows``; with neither, the
        pixel size recorded in the TIFF file's microscope tags (FEI, Zeiss) or ImageJ
        description is used (:mod:`espin.imaging.metadata`; never its dpi). A given scale
        always wins; one that differs from the metadata by more than
        :data:`SCALE_AGREEMENT` is noted in the result.
    scale_bar_um : float [um], optional
        Length of the scale bar printed on the image (of the span of its tick marks).
    scale_bar_rows : "START:STOP" or (start, stop), optional
        Image rows that hold the whole scale bar (Python slice; negative counts from the
        bottom). Unless ``crop_rows``/``crop_bottom_px`` say otherwise, the rows from START
        down are cropped away (the data bar), or up to STOP if the bar is in the top half.
    crop_rows : "START:STOP" or (start, stop), optional
        Rows to analyse (e.g. ``0:880`` to leave out a data bar below row 880).
    crop_bottom_px : int [px], optional
        Leave out this many rows at the bottom (alternative to ``crop_rows``).
    width_px : float [px], optional
        Typical fiber width, >= 3; estimated from the image when not given.
    max_bend_deg : float [deg]
        Largest bend at which a fiber is traced through a junction, in (0, 90].
    min_length_diameters : float
        Traced fibers whose end-to-end length is below this many typical diameters are dropped
        (an analyst does not measure stubs), in [1, 100].
    detect_data_bar : bool
        With none of ``crop_rows``, ``crop_bottom_px`` and ``scale_bar_rows``, find the
        microscope's data bar (a separate band or text overlaid on the image, at the bottom or
        the top: :func:`espin.imaging.databar.detect_data_bar`) and leave it out.
    invert : bool or None
        None: check that the fibers are bright on a dark background and refuse dark ones
        (:mod:`espin.imaging.polarity`); True: invert the image first (dark fibers on a bright
        background); False: measure it as it is, unchecked. Recorded in ``measurement.toml``
        (``image.polarity``).

    Returns
    -------
    SEMMeasurement

    Raises
    ------
    ConfigError
        An option is missing, contradictory or out of range, or there is no scale (no option
        and no metadata); checked before any work.
    SEMError
        The image is unreadable, the scale bar is not in the given rows, the metadata records
        non-square pixels (without a given scale), there are no fibers, or the fibers look dark
        on a bright background (without ``invert``).
    """
    digest, metadata, note = _checked_inputs(
        image,
        dict(
            um_per_px=um_per_px,
            scale_bar_um=scale_bar_um,
            scale_bar_rows=scale_bar_rows,
            crop_rows=crop_rows,
            crop_bottom_px=crop_bottom_px,
            width_px=width_px,
            max_bend_deg=max_bend_deg,
            min_length_diameters=min_length_diameters,
            detect_data_bar=detect_data_bar,
            invert=invert,
        ),
    )
    bar_rows = parse_rows(scale_bar_rows, "scale_bar_rows") if scale_bar_rows is not None else None
    keep_rows = parse_rows(crop_rows, "crop_rows") if crop_rows is not None else None
    if isinstance(image, (str, Path)):
        grey, source = read_image(image), str(image)
    else:
        grey, source = as_grey(np.asarray(image), source="image array"), "array"
    n_rows = grey.shape[0]
    bar_slice = crop_rows_slice = data_bar = None
    if bar_rows is not None:
        bar_slice = row_slice(bar_rows, n_rows, "scale_bar_rows")
    if keep_rows is not None:
        crop_rows_slice = row_slice(keep_rows, n_rows, "crop_rows")
    elif crop_bottom_px:
        if crop_bottom_px >= n_rows - 16:
            raise ConfigError(f"crop_bottom_px = {crop_bottom_px} must leave at least 16 of the image's {n_rows} rows")
        crop_rows_slice = slice(0, n_rows - crop_bottom_px)
    elif bar_slice is not None:
        in_bottom = bar_slice.start >= n_rows / 2
        crop_rows_slice = slice(0, bar_slice.start) if in_bottom else slice(bar_slice.stop, n_rows)
    elif crop_bottom_px is None and detect_data_bar:
        found_rows, data_bar = _find_data_bar(grey)
        crop_rows_slice = slice(*found_rows)
    if crop_rows_slice is None:
        crop_rows_slice = slice(0, n_rows)
    if crop_rows_slice.stop - crop_rows_slice.start < 16:
        raise ConfigError("the rows left to analyse (crop_rows, or above/below scale_bar_rows) must be at least 16")

    bar = detect_scale_bar(grey, bar_slice) if bar_slice is not None else None
    if bar is not None:
        scale, scale_source = float(cast(float, scale_bar_um)) / bar.length_px, "scale_bar"  # given with its rows
    elif um_per_px is not None:
        scale, scale_source = float(um_per_px), "um_per_px"
    else:  # checked: the metadata holds a pixel size
        scale, scale_source = cast(MetadataScale, metadata).um_per_px, "metadata"
    analysed = grey[crop_rows_slice]
    if width_px is not None and width_px > min(analysed.shape) / 4:
        raise ConfigError(
            f"width_px = {width_px:g} is more than a quarter of the analysed image "
            f"({analysed.shape[1]} x {analysed.shape[0]} px): fibers that wide cannot be "
            "traced; give the typical fiber width in pixels, or leave it out to estimate it"
        )
    analysed, polarity = bright_fibers(analysed, invert, source)
    scale_fields = {
        "scale_bar": bar,
        "scale_bar_um": None if bar is None else float(cast(float, scale_bar_um)),
        "scale_source": scale_source,
        "metadata": metadata,
        "scale_note": note or _scale_note(scale, scale_source, metadata),
        "data_bar": data_bar,
        "polarity": polarity,
    }
    return _measure_grey(
        analysed,
        scale,
        width_px,
        max_bend_deg,
        min_length_diameters,
        source,
        (crop_rows_slice.start, crop_rows_slice.stop),
        digest,
        scale_fields,
    )


def _find_data_bar(grey: np.ndarray) -> tuple[tuple[int, int], DataBar | None]:
    """The rows to analyse without the data bar :func:`espin.imaging.databar.detect_data_bar`
    finds, and the bar; all rows and None when what would be left is under 16 rows."""
    rows, bar = detect_data_bar(grey)
    if rows[1] - rows[0] < 16:
        return (0, grey.shape[0]), None
    return rows, bar


def measurement_digest(image: str | Path | np.ndarray, **options: Any) -> str:
    """SHA-256 (hex) of what a measurement starts from: the image file's bytes (or the array's
    shape, type and values) and the options of :func:`measure`, which are checked first.

    Parameters
    ----------
    image
        The image file or array given to :func:`measure`.
    **options
        Every option of :func:`measure` (``um_per_px`` ... ``min_length_diameters``;
        ``detect_data_bar`` may be left out, default True).

    Raises
    ------
    ConfigError
        An option is missing, contradictory or out of range, or there is no scale: no option
        gives one and the image's metadata records no pixel size.
    SEMError
        The image file does not exist or cannot be read, or (without a given scale) its
        metadata records non-square pixels.
    """
    return _checked_inputs(image, options)[0]


def _checked_inputs(image: str | Path | np.ndarray, options: dict[str, Any]) -> tuple[str, MetadataScale | None, str]:
    """:func:`measurement_digest`, with the image's metadata pixel size and a note on why the
    metadata was not read (see :func:`_image_metadata`)."""
    options = {"detect_data_bar": True, "invert": None, **options}
    invert = options.pop("invert")
    if invert not in (None, True, False):
        raise ConfigError(f"invert = {invert!r}: must be True, False or None (check)")
    _check_options(**options)
    if invert is not None:
        options["invert"] = invert
    given = options["um_per_px"] is not None or options["scale_bar_um"] is not None
    metadata, note = _image_metadata(image, given)
    if isinstance(image, (str, Path)):
        digest = hashlib.sha256(_file_digest(Path(image)))
    else:
        array = np.asarray(image)
        digest = hashlib.sha256(f"{array.shape} {array.dtype}".encode())
        digest.update(array.tobytes())
    # detect_data_bar is recorded only when off, invert only when given: the digests of earlier runs stay valid
    recorded = {k: v for k, v in options.items() if k != "detect_data_bar" or not v}
    digest.update(repr(sorted(recorded.items())).encode())
    return digest.hexdigest(), metadata, note


def _image_metadata(image: str | Path | np.ndarray, given: bool) -> tuple[MetadataScale | None, str]:
    """The pixel size the image file's tags record (:func:`espin.imaging.metadata.read_pixel_size`)
    and a note.

    With a given scale, the metadata is only compared with it: an error reading it (non-square
    pixels, an unreadable file) becomes the note. Without one, that error is raised, and no
    pixel size in the metadata is the "no scale" :class:`ConfigError`.
    """
    is_file = isinstance(image, (str, Path)) and Path(image).is_file()
    if given:
        try:
            return (read_pixel_size(cast(Path, image)) if is_file else None), ""
        except SEMError as err:
            return None, f"the image's metadata is not used: {err}"
    metadata = read_pixel_size(cast(Path, image)) if is_file else None  # a file is named by a path
    if metadata is None:
        where = (
            "no pixel size in the image's metadata (FEI or Zeiss microscope tags, an "
            "ImageJ description with a length unit; the dpi of a TIFF is not one)"
            if isinstance(image, (str, Path))
            else "an image array has no metadata"
        )
        raise ConfigError(
            "no scale: give um_per_px (--um-per-px), or scale_bar_um (--scale-bar-um, "
            "the bar's length in um) with scale_bar_rows (--scale-bar-rows START:STOP, "
            f"the image rows that hold it); {where}"
        )
    return metadata, ""


def _scale_note(um_per_px: float, scale_source: str, metadata: MetadataScale | None) -> str:
    """A note when the given scale and the metadata's pixel size differ by more than
    :data:`SCALE_AGREEMENT`; "" otherwise."""
    if metadata is None or scale_source == "metadata":
        return ""
    off = abs(metadata.um_per_px - um_per_px) / um_per_px
    if off <= SCALE_AGREEMENT:
        return ""
    given = "the scale bar" if scale_source == "scale_bar" else "um_per_px"
    return (
        f"the image's metadata ({metadata.source}) gives {metadata.um_per_px:.5g} um/px, "
        f"{off:.1%} off the {um_per_px:.5g} um/px of {given}, which is used"
    )


def _file_digest(path: Path) -> bytes:
    """SHA-256 of an image file's bytes, read in chunks (a regular file only: a pipe or a
    device would block or never end)."""
    if path.exists() and not path.is_dir() and not path.is_file():
        raise SEMError(f"image {str(path)!r} is not a regular file (a pipe or a device); expected an image file")
    try:
        with open(path, "rb") as fh:
            return hashlib.file_digest(fh, "sha256").digest()
    except FileNotFoundError:
        raise SEMError(f"image {str(path)!r}: no such file") from None
    except IsADirectoryError:
        raise SEMError(f"image {str(path)!r} is a directory; expected an image file") from None
    except OSError as err:
        raise SEMError(f"image {str(path)!r} cannot be read: {err.strerror}") from None


def _measure_grey(
    grey: np.ndarray,
    um_per_px: float,
    width_px: float | None,
    max_bend_deg: float,
    min_length_diameters: float,
    source: str,
    rows: tuple[int, int],
    inputs_digest: str,
    scale_fields: dict[str, Any],
) -> SEMMeasurement:
    """Measure an analysed grey image; ``scale_fields`` are the :class:`SEMMeasurement` fields
    that say where ``um_per_px`` came from (``scale_bar`` ... ``scale_note``) and the data
    bar left out (``data_bar``)."""
    seg = segment_fibers(grey, width_px)
    traced = trace_fibers(seg.mask, seg.width_px, max_bend_deg)
    crossings = np.concatenate([traced.junctions, traced.shared])
    samples = local_widths(seg.flat, traced.paths, crossings, seg.width_px)
    typical = float(np.median(samples.width_px)) if len(samples.width_px) else seg.width_px
    min_chord_px = min_length_diameters * typical

    paths = traced.paths
    chord_vec = np.array([p[-1] - p[0] for p in paths]).reshape(-1, 2)
    chord = np.hypot(*chord_vec.T)
    contour = np.array([np.hypot(*np.diff(p, axis=0).T).sum() for p in paths])
    kept = np.flatnonzero(chord >= min_chord_px)
    if len(kept) == 0:
        raise SEMError(
            f"no fibers found: no traced fiber is at least {min_length_diameters:g} typical "
            f"widths ({min_chord_px:.1f} px) long end to end; is this an image of fibers?"
        )
    diameter_px = fiber_diameters(seg.flat, samples, len(paths), seg.width_px)[kept]
    renumber = np.full(len(paths), -1)
    renumber[kept] = np.arange(len(kept))
    on_kept = renumber[samples.fiber] >= 0
    samples = samples.subset(on_kept, renumber[samples.fiber[on_kept]])
    visibility = fiber_visibility(grey, [paths[i] for i in kept], samples, traced.junctions, crossings, seg.width_px)
    visible = visibility.visible & np.isfinite(diameter_px)
    contour_px = np.maximum(contour[kept], chord[kept])
    edges, edge_to_edge = _edge_crossings([paths[i] for i in kept], contour_px, grey.shape, seg.width_px)
    names = np.array(EDGE_NAMES + ("",))  # index -1 (inside the image) -> ""
    fibers = pd.DataFrame(
        {
            "fiber": np.arange(len(kept), dtype=np.int64),
            "diameter_um": diameter_px * um_per_px,
            "orientation_deg": image_angle_deg(chord_vec[kept, 0], chord_vec[kept, 1]) % 180.0,
            "tortuosity": np.maximum(contour[kept] / chord[kept], 1.0),
            "contour_length_um": contour_px * um_per_px,
            "end_to_end_um": chord[kept] * um_per_px,
            "start_edge": names[edges[:, 0]],
            "end_edge": names[edges[:, 1]],
            "visible": visible,
        },
        columns=list(FIBER_COLUMNS),
    )
    direction, coherency = structure_tensor_orientation(seg.flat)
    diameter_um = fibers["diameter_um"].to_numpy()
    fits = fit_distributions(
        diameter_um[visible], fibers["orientation_deg"].to_numpy(), fibers["tortuosity"].to_numpy()
    )
    return SEMMeasurement(
        fibers=fibers,
        widths_um=samples.width_px * um_per_px,
        um_per_px=um_per_px,
        field_of_view_um=(grey.shape[1] * um_per_px, grey.shape[0] * um_per_px),
        dominant_direction_deg=direction,
        coherency=coherency,
        fits=fits,
        diameter_hidden=fit_diameter_families(diameter_um[~visible]),
        diameter_all=fit_diameter_families(diameter_um),
        visibility=visibility,
        n_crossing=edge_to_edge.n_crossing,
        u_turn_fraction=edge_to_edge.u_turn_fraction,
        straightness=edge_to_edge.straightness,
        min_chord_um=min_chord_px * um_per_px,
        typical_width_px=typical,
        image=grey,
        mask=seg.mask,
        pores=mat_structure(seg.mask, traced.junctions, um_per_px),
        rows=rows,
        paths_px=[paths[i] for i in kept],
        width_samples=samples,
        junctions_px=traced.junctions,
        source=source,
        inputs_digest=inputs_digest,
        **scale_fields,
    )


def _edge_crossings(
    paths: list[np.ndarray], contour_px: np.ndarray, shape: tuple[int, int], width_px: float
) -> tuple[np.ndarray, CrossingStatistics]:
    """Edge of the analysed image at both ends of each traced fiber, and the crossing
    statistics of the fibers traced from edge to edge.

    Parameters
    ----------
    paths : list of (n_i, 2) float64 [px]
        Centre lines (row, col), one point per pixel of arc length.
    contour_px : (n,) float64 [px]
        Their contour lengths.
    shape : (rows, cols)
        Size of the analysed image.
    width_px : float [px]
        Fiber width w the tracer worked with.

    Returns
    -------
    edges : (n, 2) int64
        Edge of the first and last end: 0 bottom, 1 right, 2 top, 3 left (y up), -1 inside.
    CrossingStatistics
        Of the fibers with both ends on edges, each continued straight to the edge where an
        end was pulled back (:data:`EDGE_REACH`): count, U-turn fraction, straightness.
    """
    rows, cols = shape
    lower, upper = np.zeros(2), np.array([cols - 1.0, rows - 1.0])  # outermost pixel centres
    ends = np.zeros((len(paths), 2, 2))
    added = np.zeros(len(paths))
    for i, path in enumerate(paths):
        xy = np.column_stack([path[:, 1], rows - 1.0 - path[:, 0]])  # x right, y up
        for side, oriented in enumerate((xy[::-1], xy)):
            ends[i, side], extension = _end_on_edge(oriented, lower, upper, width_px)
            added[i] += extension
    tol = EDGE_NEAR * width_px
    edges = border_edges(ends.reshape(-1, 2), lower, upper, tol).reshape(-1, 2)
    return edges, crossing_statistics(ends[:, 0], ends[:, 1], contour_px + added, lower, upper, tol)


def _end_on_edge(
    oriented: np.ndarray, lower: np.ndarray, upper: np.ndarray, width_px: float
) -> tuple[np.ndarray, float]:
    """The last point of a centre line (x, y) [px], or where its straight continuation leaves
    the rectangle [lower, upper] if that is within :data:`EDGE_REACH` w (and the point is not
    within :data:`EDGE_NEAR` w of an edge already); and the length [px] added.

    A point just outside the rectangle (the smoothing can carry an end on the border a pixel
    or two out) is moved onto it.
    """
    end = oriented[-1]
    if min(np.min(end - lower), np.min(upper - end)) <= EDGE_NEAR * width_px:
        return np.clip(end, lower, upper), 0.0
    back = oriented[-1 - min(max(int(round(width_px)), 1), len(oriented) - 1)]
    direction = end - back
    norm = float(np.hypot(*direction))
    if norm == 0.0:
        return end, 0.0
    direction = direction / norm
    with np.errstate(divide="ignore", invalid="ignore"):
        steps = np.where(
            direction > 0, (upper - end) / direction, np.where(direction < 0, (lower - end) / direction, np.inf)
        )
    reach = float(np.min(steps))
    if reach > EDGE_REACH * width_px:
        return end, 0.0
    return np.clip(end + reach * direction, lower, upper), reach


def _check_options(
    um_per_px: float | None,
    scale_bar_um: float | None,
    scale_bar_rows: Any,
    crop_rows: Any,
    crop_bottom_px: int | None,
    width_px: float | None,
    max_bend_deg: float,
    min_length_diameters: float,
    detect_data_bar: bool,
) -> None:
    """Every option error, before any work (ConfigError naming the parameter)."""
    if um_per_px is not None and not (_finite(um_per_px) and 1e-6 <= um_per_px <= 1e3):
        raise ConfigError(f"um_per_px must be a number in [1e-6, 1000] (1 pm to 1 mm per pixel), got {um_per_px!r}")
    if scale_bar_um is not None and not (_finite(scale_bar_um) and 1e-6 <= scale_bar_um <= 1e6):
        raise ConfigError(f"scale_bar_um must be a number in [1e-6, 1e6] um, got {scale_bar_um!r}")
    if um_per_px is not None and (scale_bar_um is not None or scale_bar_rows is not None):
        raise ConfigError("give um_per_px, or scale_bar_um with scale_bar_rows, not both")
    if um_per_px is None and (scale_bar_um is not None or scale_bar_rows is not None):
        if scale_bar_um is None:
            raise ConfigError("scale_bar_rows needs scale_bar_um (the bar's length in um)")
        if scale_bar_rows is None:
            raise ConfigError("scale_bar_um needs scale_bar_rows (START:STOP, the image rows that hold the bar)")
        parse_rows(scale_bar_rows, "scale_bar_rows")
    if crop_rows is not None:
        parse_rows(crop_rows, "crop_rows")
        if crop_bottom_px is not None:
            raise ConfigError("give crop_rows or crop_bottom_px, not both")
    if crop_bottom_px is not None and (int(crop_bottom_px) != crop_bottom_px or crop_bottom_px < 0):
        raise ConfigError(f"crop_bottom_px must be an integer >= 0, got {crop_bottom_px!r}")
    if width_px is not None and not (_finite(width_px) and width_px >= MIN_WIDTH_PX):
        raise ConfigError(f"width_px must be a number >= {MIN_WIDTH_PX:g}, got {width_px!r}")
    if not (_finite(max_bend_deg) and 0 < max_bend_deg <= 90):
        raise ConfigError(f"max_bend_deg must be in (0, 90], got {max_bend_deg!r}")
    if not (_finite(min_length_diameters) and 1 <= min_length_diameters <= 100):
        raise ConfigError(f"min_length_diameters must be in [1, 100], got {min_length_diameters!r}")
    if not isinstance(detect_data_bar, (bool, np.bool_)):
        raise ConfigError(f"detect_data_bar must be True or False, got {detect_data_bar!r}")


def _finite(x: Any) -> bool:
    return isinstance(x, (int, float, np.integer, np.floating)) and not isinstance(x, bool) and math.isfinite(float(x))


def _nan_stat(func: Any, values: Any) -> float:
    x = np.asarray(values, dtype=float)
    x = x[np.isfinite(x)]
    return float(func(x)) if len(x) else math.nan


def _toml_ready(value: Any) -> Any:
    """Plain Python values for tomli_w (NaN kept: TOML has nan)."""
    if isinstance(value, dict):
        return {k: _toml_ready(v) for k, v in value.items() if v is not None}
    if isinstance(value, (list, tuple)):
        return [_toml_ready(v) for v in value]
    if isinstance(value, (np.integer,)):
        return int(value)
    if isinstance(value, (np.floating,)):
        return float(value)
    return value
