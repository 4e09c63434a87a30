"""Measuring a batch of SEM images: per-image results, a summary table and pooled statistics.

:func:`measure_batch` measures each image with :func:`espin.imaging.measurement.measure`
(the same options for all; without ``um_per_px`` each image's scale comes from its own scale
bar option or metadata) and writes, into one output folder::

    run.json            the batch's manifest (running until the last file is written)
    images.csv          one row per image (:data:`IMAGE_COLUMNS`), failed images with their error
    pooled.toml         pooled statistics over the images measured
    <image stem>/       each image's usual outputs and its own run.json

**Pooled statistics.** Fibers are pooled over the images (each fiber counts once), the
porosity and the intersection density are area-weighted (all images' non-fiber area, or
junctions, over all images' area). Fibers of one image are not independent samples of the
mat (they share its spot, its focus, its threshold), so the confidence intervals come from a
*cluster bootstrap*: :data:`BOOTSTRAP_RESAMPLES` resamples of whole images with replacement,
the pooled statistic recomputed on each, the 2.5 and 97.5 percentiles (fixed seed
:data:`BOOTSTRAP_SEED`: a rerun writes the same numbers). The per-image spread is the standard
deviation (ddof 1) across images of each image's own value. With one image the intervals
collapse onto the estimate and the spread is NaN (left out of ``pooled.toml``).

**Diameter population.** The pooled diameters are ``diameter_um`` of the fibers table, of the
rows whose ``visible`` column is True (the fully visible fibers, :mod:`espin.imaging.visibility`).

**Errors.** Every image's options and scale are checked first: a :class:`ConfigError` (an
option out of range, an image with no scale) stops the batch before any image is measured.
An image that cannot be measured (:class:`SEMError`: unreadable, no fibers; or a
:class:`ConfigError` that only this image raises, e.g. ``crop_bottom_px`` larger than it) is
reported in ``images.csv`` with its error, and the batch goes on.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, cast

import numpy as np
import pandas as pd

from espin.core.errors import ConfigError, SEMError
from espin.core.output_folder import OutputFolder, inputs_digest
from espin.imaging.measurement import MEASURE_OUTPUTS, SEMMeasurement, measure, measurement_digest
from espin.imaging.pores import PoreStructure

__all__ = [
    "BatchMeasurement",
    "measure_batch",
    "image_files",
    "pooled_statistics",
    "IMAGE_SUFFIXES",
    "IMAGE_COLUMNS",
    "BATCH_OUTPUTS",
    "BATCH_SCHEMA",
    "BOOTSTRAP_RESAMPLES",
    "BOOTSTRAP_SEED",
]

BATCH_SCHEMA = "espin.sem.batch/1"
"""Schema of ``pooled.toml``."""
IMAGE_SUFFIXES = (".tif", ".tiff", ".png", ".jpg", ".jpeg")
"""Files of a folder that are measured (case-insensitive)."""
BATCH_OUTPUTS = ("images.csv", "pooled.toml", "*/run.json", *(f"*/{p}" for p in MEASURE_OUTPUTS))
"""What a batch folder holds (glob patterns relative to it)."""
BOOTSTRAP_RESAMPLES = 2000
"""B, resamples of whole images for the confidence intervals."""
BOOTSTRAP_SEED = 0
"""Seed of the bootstrap's generator."""
IMAGE_COLUMNS = (
    "file",
    "status",
    "error",
    "folder",
    "um_per_px",
    "scale_source",
    "rows_analysed",
    "n_fibers",
    "n_diameters",
    "diameter_mean_um",
    "diameter_sd_um",
    "diameter_median_um",
    "orientation_model",
    "orientation_mean_deg",
    "orientation_kappa",
    "dominant_direction_deg",
    "coherency",
    "tortuosity_mean",
    "porosity",
    "pore_diameter_median_um",
    "pore_inscribed_median_um",
    "n_pores",
    "n_junctions",
    "intersection_density_per_um2",
    "intersections_per_um_fiber",
    "n_crossing",
    "u_turn_fraction",
    "straightness",
)
"""Columns of ``images.csv`` (``status``: ``ok`` or ``failed``, with the ``error``)."""
_COUNT_COLUMNS = ("n_fibers", "n_diameters", "n_pores", "n_junctions", "n_crossing")

Progress = Callable[[int, int, dict[str, Any]], None]


@dataclass(frozen=True, eq=False)
class BatchMeasurement:
    """What :func:`measure_batch` wrote.

    Attributes
    ----------
    images : pandas.DataFrame
        The rows of ``images.csv`` (:data:`IMAGE_COLUMNS`), one per image, in the order given.
    pooled : dict
        The content of ``pooled.toml``.
    folder : Path
        The output folder.
    """

    images: pd.DataFrame
    pooled: dict[str, Any]
    folder: Path

    @property
    def n_failed(self) -> int:
        """Images that could not be measured."""
        return int((self.images["status"] != "ok").sum())


@dataclass(frozen=True, eq=False)
class _Sample:
    """What the pooled statistics need of one measured image."""

    diameter_um: np.ndarray
    orientation_deg: np.ndarray
    tortuosity: np.ndarray
    structure: PoreStructure
    coherency: float
    n_crossing: int
    u_turn_fraction: float


def image_files(paths: Sequence[str | Path]) -> list[Path]:
    """The image files of ``paths``: a folder stands for its files with an image suffix
    (:data:`IMAGE_SUFFIXES`, sorted by name, not recursive), any other path for itself (a
    missing or unreadable file is the measurement's error); each file once.

    Raises
    ------
    ConfigError
        A folder holds no image.
    """
    files: list[Path] = []
    for path in map(Path, paths):
        if path.is_dir():
            found = sorted(p for p in path.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES and p.is_file())
            if not found:
                raise ConfigError(f"folder {path} holds no image ({', '.join(IMAGE_SUFFIXES)})")
            files.extend(found)
        else:
            files.append(path)
    return list(dict.fromkeys(files))


def measure_batch(
    images: Sequence[str | Path],
    out: str | Path,
    *,
    overwrite: bool = False,
    figures: bool = True,
    progress: Progress | None = None,
    **options: Any,
) -> BatchMeasurement:
    """Measure several SEM images with the same options (module notes).

    Parameters
    ----------
    images : sequence of str or Path
        Image files and folders (:func:`image_files`).
    out : str or Path
        Output folder, claimed with a ``run.json`` manifest (:mod:`espin.core.output_folder`).
    overwrite : bool
        Replace another run's results in ``out`` instead of refusing.
    figures : bool
        Write each image's figures (histograms, overlay, orientation map).
    progress : callable, optional
        Called after each image with (its index from 1, the number of images, its row of
        ``images.csv`` as a dict).
    **options
        Options of :func:`espin.imaging.measurement.measure` (``um_per_px``, ``crop_rows``,
        ...), the same for every image.

    Returns
    -------
    BatchMeasurement

    Raises
    ------
    ConfigError
        An option is out of range, an image has no scale, a folder holds no image, or ``out``
        holds another run's results and ``overwrite`` is False; before any image is measured.
    """
    options = _measure_options(options)
    files = image_files(images)
    digests: list[str | None] = []
    errors: dict[int, str] = {}
    for i, path in enumerate(files):
        try:
            digests.append(measurement_digest(path, **options))
        except SEMError as err:
            digests.append(None)
            errors[i] = str(err)
        except ConfigError as err:
            raise ConfigError(f"{path.name}: {err}") from None
    out = Path(out)
    names = _folder_names(files)
    digest = inputs_digest(files, sorted(options.items()), figures)
    rows, samples = [], []
    with OutputFolder.claim(out, "measure-batch", digest, BATCH_OUTPUTS, overwrite=overwrite, inputs=files) as claimed:
        for i, (path, name) in enumerate(zip(files, names)):
            row, sample = _measure_one(path, out / name, digests[i], errors.get(i), figures, options)
            rows.append(row)
            if sample is not None:
                samples.append(sample)
            if progress is not None:
                progress(i + 1, len(files), row)
        table = pd.DataFrame(rows, columns=list(IMAGE_COLUMNS)).astype({c: "Int64" for c in _COUNT_COLUMNS})
        pooled = pooled_statistics(samples) | {"n_images": len(files), "n_failed": len(files) - len(samples)}
        _write_table(table, out / "images.csv")
        _write_toml(pooled, out / "pooled.toml")
        claimed.mark(len(files) - len(samples), len(files))
    return BatchMeasurement(images=table, pooled=pooled, folder=out)


def _measure_options(options: dict[str, Any]) -> dict[str, Any]:
    """Every option of :func:`espin.imaging.measurement.measure`, the defaults filled in.

    Raises
    ------
    ConfigError
        An option :func:`~espin.imaging.measurement.measure` does not have.
    """
    import inspect

    defaults = {
        name: p.default
        for name, p in inspect.signature(measure).parameters.items()
        if p.kind is inspect.Parameter.KEYWORD_ONLY
    }
    unknown = sorted(set(options) - set(defaults))
    if unknown:
        raise ConfigError(f"measure has no option {', '.join(unknown)} (options: {', '.join(defaults)})")
    return defaults | options


def _measure_one(
    path: Path, folder: Path, digest: str | None, error: str | None, figures: bool, options: dict[str, Any]
) -> tuple[dict[str, Any], _Sample | None]:
    """Measure one image into its folder: its row of ``images.csv`` and what the pooling
    needs (None when it failed)."""
    row: dict[str, Any] = {"file": str(path), "status": "failed", "error": error or "", "folder": ""}
    if error is not None:
        return row, None
    try:
        # An image without an error has its digest.
        with OutputFolder.claim(folder, "measure", cast(str, digest), MEASURE_OUTPUTS):
            m = measure(path, **options)
            m.write_files(folder, figures)
    except (SEMError, ConfigError) as err:
        row["error"] = str(err)
        return row, None
    except Exception as err:  # noqa: BLE001 - a bug on one image: reported, the batch goes on
        row["error"] = f"unexpected {type(err).__name__}: {err} (please report it)"
        return row, None
    sample = _sample(m)
    return row | _image_row(m, sample) | {"status": "ok", "folder": folder.name}, sample


def _sample(m: SEMMeasurement) -> _Sample:
    f = m.fibers
    return _Sample(
        diameter_um=_finite(f["diameter_um"][f["visible"].to_numpy(dtype=bool)]),
        orientation_deg=_finite(f["orientation_deg"]),
        tortuosity=_finite(f["tortuosity"]),
        structure=m.pores,
        coherency=m.coherency,
        n_crossing=m.n_crossing,
        u_turn_fraction=m.u_turn_fraction,
    )


def _image_row(m: SEMMeasurement, s: _Sample) -> dict[str, Any]:
    """One measured image's values of :data:`IMAGE_COLUMNS`."""
    fits, st = m.fits, s.structure
    return {
        "um_per_px": m.um_per_px,
        "scale_source": m.scale_source,
        "rows_analysed": f"{m.rows[0]}:{m.rows[1]}",
        "n_fibers": len(m.fibers),
        "n_diameters": len(s.diameter_um),
        "diameter_mean_um": _mean(s.diameter_um),
        "diameter_sd_um": _sd(s.diameter_um, ddof=0),
        "diameter_median_um": _median(s.diameter_um),
        "orientation_model": fits.orientation_model,
        "orientation_mean_deg": fits.orientation_mean_deg,
        "orientation_kappa": fits.orientation_kappa,
        "dominant_direction_deg": m.dominant_direction_deg,
        "coherency": m.coherency,
        "tortuosity_mean": _mean(s.tortuosity),
        "porosity": st.porosity,
        "pore_diameter_median_um": st.pore_diameter_median_um,
        "pore_inscribed_median_um": st.pore_inscribed_median_um,
        "n_pores": len(st.pore_diameter_um),
        "n_junctions": st.n_junctions,
        "intersection_density_per_um2": st.intersection_density_per_um2,
        "intersections_per_um_fiber": st.intersections_per_um,
        "n_crossing": m.n_crossing,
        "u_turn_fraction": m.u_turn_fraction,
        "straightness": m.straightness,
    }


def pooled_statistics(
    samples: Sequence[_Sample], resamples: int = BOOTSTRAP_RESAMPLES, seed: int = BOOTSTRAP_SEED
) -> dict[str, Any]:
    """Pooled statistics over measured images, with per-image spread and cluster-bootstrap
    95 % confidence intervals (module notes); the content of ``pooled.toml``.

    Parameters
    ----------
    samples
        One per measured image.
    resamples : int
        Bootstrap resamples B.
    seed : int
        Seed of the bootstrap's generator.

    Returns
    -------
    dict
        TOML-ready sections (units in the key names); NaN where there is nothing to pool (left
        out of ``pooled.toml``).
    """
    from espin.core.version import __version__

    n = len(samples)
    head = {
        "schema": BATCH_SCHEMA,
        "espin_version": __version__,
        "n_measured": n,
        "bootstrap": {"resamples": resamples, "seed": seed, "unit": "image", "interval": "percentile, 95 %"},
    }
    if n == 0:
        return head
    counts = _resample_counts(n, resamples, seed)
    d = [s.diameter_um for s in samples]
    t = [s.tortuosity for s in samples]
    st = [s.structure for s in samples]
    area = np.array([x.area_um2 for x in st])
    open_area = np.array([x.porosity for x in st]) * area
    junctions = np.array([x.n_junctions for x in st], dtype=float)
    crossing = np.array([s.n_crossing for s in samples], dtype=float)
    u_turns = np.nan_to_num([s.u_turn_fraction * s.n_crossing for s in samples])
    coherency = np.array([s.coherency for s in samples])
    return head | {
        "diameter": {
            "population": "fully visible fibers (visible True)",
            "n_fibers": int(sum(map(len, d))),
            **_stat("mean_um", *_pooled_mean(d, counts)),
            **_stat("median_um", *_pooled_median(d, counts)),
            "sd_um": _sd(np.concatenate(d), ddof=1),
            "image_sd_of_mean_um": _sd([_mean(x) for x in d], ddof=1),
        },
        "orientation": _orientation(samples, counts)
        | {
            **_stat("coherency_mean", *_ratio(coherency, np.ones(n), counts)),
            "image_sd_of_coherency": _sd(coherency, ddof=1),
        },
        "tortuosity": {
            **_stat("mean", *_pooled_mean(t, counts)),
            **_stat("median", *_pooled_median(t, counts)),
            "image_sd_of_mean": _sd([_mean(x) for x in t], ddof=1),
        },
        "porosity": {
            "weighting": "area (all images' non-fiber area over their area)",
            **_stat("porosity", *_ratio(open_area, area, counts)),
            "image_sd": _sd([x.porosity for x in st], ddof=1),
        },
        "pores": {
            "pore_size": "equivalent-circle diameter of the pores inside each image",
            "n_pores": int(sum(len(x.pore_diameter_um) for x in st)),
            **_stat("pore_diameter_median_um", *_pooled_median([x.pore_diameter_um for x in st], counts)),
            "image_sd_of_median_um": _sd([x.pore_diameter_median_um for x in st], ddof=1),
        },
        "intersections": {
            "n_junctions": int(junctions.sum()),
            "area_um2": float(area.sum()),
            **_stat("density_per_um2", *_ratio(junctions, area, counts)),
            "image_sd_of_density_per_um2": _sd(junctions / area, ddof=1),
        },
        "crossing": {
            "n_crossing": int(crossing.sum()),
            **_stat("u_turn_fraction", *_ratio(u_turns, crossing, counts)),
        },
    }


def _resample_counts(n: int, resamples: int, seed: int) -> np.ndarray:
    """(B, n) how often each image is drawn in each resample of n images with replacement."""
    drawn = np.random.default_rng(seed).integers(0, n, size=(resamples, n))
    counts = np.zeros((resamples, n))
    np.add.at(counts, (np.repeat(np.arange(resamples), n), drawn.ravel()), 1.0)
    return counts


def _pooled_mean(values: list[np.ndarray], counts: np.ndarray) -> tuple[float, np.ndarray]:
    """Mean of the pooled values, and of each resample."""
    return _ratio(np.array([x.sum() for x in values]), np.array([len(x) for x in values], float), counts)


def _ratio(num: np.ndarray, den: np.ndarray, counts: np.ndarray) -> tuple[float, np.ndarray]:
    """sum(num) / sum(den) over the images, and over each resample's images."""
    total = float(den.sum())
    with np.errstate(invalid="ignore", divide="ignore"):
        boot = (counts @ num) / (counts @ den)
    return (float(num.sum()) / total if total > 0 else math.nan), boot


def _pooled_median(values: list[np.ndarray], counts: np.ndarray, chunk: int = 200) -> tuple[float, np.ndarray]:
    """Median of the pooled values, and of each resample (each value weighted by how often
    its image is drawn; the lower weighted median), ``chunk`` resamples at a time."""
    pooled = np.concatenate(values)
    if len(pooled) == 0:
        return math.nan, np.full(len(counts), math.nan)
    image = np.repeat(np.arange(len(values)), [len(x) for x in values])
    order = np.argsort(pooled, kind="stable")
    ordered, owner = pooled[order], image[order]
    boot = np.empty(len(counts))
    for start in range(0, len(counts), chunk):
        weights = np.cumsum(counts[start : start + chunk][:, owner], axis=1)
        half = 0.5 * weights[:, -1:]
        boot[start : start + chunk] = np.where(
            weights[:, -1] > 0, ordered[np.argmax(weights >= half, axis=1)], math.nan
        )
    return float(np.median(pooled)), boot


def _orientation(samples: Sequence[_Sample], counts: np.ndarray) -> dict[str, Any]:
    """Axial mean direction and mean resultant length of the pooled fiber orientations
    (doubled angles), with their intervals; the direction's interval is taken on the
    differences from the estimate, wrapped to [-90, 90) deg."""
    theta = [np.radians(2.0 * s.orientation_deg) for s in samples]
    n = np.array([len(x) for x in theta], dtype=float)
    c, cb = _ratio(np.array([np.cos(x).sum() for x in theta]), n, counts)
    s, sb = _ratio(np.array([np.sin(x).sum() for x in theta]), n, counts)
    direction = math.degrees(0.5 * math.atan2(s, c)) % 180.0
    boot_direction = np.degrees(0.5 * np.arctan2(sb, cb))
    wrapped = (boot_direction - direction + 90.0) % 180.0 - 90.0
    lo, hi = _interval(wrapped)
    return {
        "n_fibers": int(n.sum()),
        "axial_mean_deg": direction,
        "ci95_axial_mean_deg": [direction + lo, direction + hi],
        **_stat("resultant_length", math.hypot(c, s), np.hypot(cb, sb)),
    }


def _stat(key: str, estimate: float, boot: np.ndarray) -> dict[str, Any]:
    return {key: estimate, f"ci95_{key}": list(_interval(boot))}


def _interval(boot: np.ndarray) -> tuple[float, float]:
    """2.5 and 97.5 percentiles of the finite bootstrap values (NaN if none)."""
    x = boot[np.isfinite(boot)]
    if len(x) == 0:
        return math.nan, math.nan
    lo, hi = np.percentile(x, [2.5, 97.5])
    return float(lo), float(hi)


def _folder_names(files: Sequence[Path]) -> list[str]:
    """Each image's output folder: its stem; where stems repeat (ignoring case, as the file
    systems of macOS and Windows do), its name with the dot as ``_`` (``a_tif``, ``a_png``),
    and a number after that if it still repeats."""
    stems = [p.stem.casefold() for p in files]
    names = [p.name.replace(".", "_") if stems.count(p.stem.casefold()) > 1 else p.stem for p in files]
    folded = [name.casefold() for name in names]
    return [f"{name}_{i + 1}" if folded.count(name.casefold()) > 1 else name for i, name in enumerate(names)]


def _write_table(table: pd.DataFrame, path: Path) -> Path:
    from espin.core.atomic import atomic_write_bytes

    return atomic_write_bytes(path, table.to_csv(index=False, lineterminator="\n").encode("utf-8"))


def _not_finite(value: Any) -> bool:
    """Whether a value is a number that is not finite, or a list holding one."""
    if isinstance(value, (list, tuple)):
        return any(map(_not_finite, value))
    return isinstance(value, (float, np.floating)) and not np.isfinite(value)


def _write_toml(data: dict[str, Any], path: Path) -> Path:
    import tomli_w

    from espin.core.atomic import atomic_write_bytes

    return atomic_write_bytes(path, tomli_w.dumps(_plain(data)).encode("utf-8"))


def _plain(value: Any) -> Any:
    """Plain Python values for tomli_w; a value that is None or not a finite number (nothing to
    pool, e.g. the spread of one image) is left out."""
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items() if v is not None and not _not_finite(v)}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if isinstance(value, np.integer):
        return int(value)
    if isinstance(value, np.floating):
        return float(value)
    return value


def _finite(x: Any) -> np.ndarray:
    a = np.asarray(x, dtype=float)
    return a[np.isfinite(a)]


def _mean(x: Any) -> float:
    a = _finite(x)
    return float(a.mean()) if len(a) else math.nan


def _median(x: Any) -> float:
    a = _finite(x)
    return float(np.median(a)) if len(a) else math.nan


def _sd(x: Any, ddof: int) -> float:
    a = _finite(x)
    return float(a.std(ddof=ddof)) if len(a) > ddof else math.nan
