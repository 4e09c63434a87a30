"""The calibration result: GeometryCalibration, its JSON report, text table and files."""

from __future__ import annotations

import json
import math
from contextlib import AbstractContextManager, nullcontext
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import tomli_w

from espin.core.config import Config, config_digest
from espin.core.errors import ConfigError, RVEFileError
from espin.core.output_folder import OutputFolder
from espin.geometry.targets import GeometryTargets
from espin.imaging.geometry_calibration.matching import DistributionMatch
from espin.imaging.geometry_calibration.options import _written_data
from espin.imaging.geometry_calibration.search import ValleyPoint

__all__ = [
    "SCHEMA",
    "SCHEMA_VERSION",
    "MECHANICS_NOTE",
    "CALIBRATION_OUTPUTS",
    "GeometryCalibration",
    "MeasuredImage",
    "output_files",
    "claim_output",
]

SCHEMA = "espin.geometry_calibration"
SCHEMA_VERSION = 1
MECHANICS_NOTE = (
    "New deposition parameters change the network and so the mechanics: fit the fiber "
    "parameters again (espin fit) before using stresses of the calibrated mat."
)
CALIBRATION_OUTPUTS = ("config.toml", "calibration.json", "calibration.txt", "comparison.png")
"""The files a calibration writes into a folder."""


@dataclass(frozen=True, eq=False)
class MeasuredImage:
    """The analysed SEM image of a calibration's targets.

    Attributes
    ----------
    pixels : (rows, cols) float64
        Grey levels of the analysed part (the data bar left out).
    um_per_px : float [um / px]
        Pixel size.
    label : str
        What it is (file name).
    """

    pixels: np.ndarray
    um_per_px: float
    label: str


@dataclass(frozen=True, eq=False)
class GeometryCalibration:
    """Result of :func:`calibrate_geometry`.

    Attributes
    ----------
    config : Config
        The calibrated configuration (base config with the found deposition parameters and
        ``output.window_ratio`` set to the observation window). ``espin generate`` and
        ``espin simulate`` take it as it is.
    base : Config
        The base configuration.
    targets : GeometryTargets
        What was matched.
    parameters : dict
        The found values by config key, and ``fitted`` (the keys that were searched).
    matches : tuple of DistributionMatch
        Per targeted distribution, measured on mats of ``config`` (its layer side, unless the
        window does not fit: then the search RVE), pooled over the seeds.
    valley : tuple of ValleyPoint
        Best deviation per segment length (``fit="both"`` only).
    search : dict
        Window, RVE sides, seeds, layers, evaluations and wall time [s].
    warnings : tuple of str
        What the user must know (targets out of reach, window larger than the layer...).
    image : MeasuredImage or None
        The analysed SEM image the targets were measured on, when known: the files then
        include ``comparison.png``.
    """

    config: Config
    base: Config
    targets: GeometryTargets
    parameters: dict[str, Any]
    matches: tuple[DistributionMatch, ...]
    valley: tuple[ValleyPoint, ...] = ()
    search: dict[str, Any] = field(default_factory=dict)
    warnings: tuple[str, ...] = ()
    image: MeasuredImage | None = None

    def _fitted_text(self) -> list[tuple[str, str]]:
        """(config key, value) of the searched parameters."""
        return [
            (
                key,
                f"{self.parameters[key]:.4g}" if isinstance(self.parameters[key], float) else str(self.parameters[key]),
            )
            for key in self.parameters["fitted"]
        ]

    def __repr__(self) -> str:
        """One line: the fitted parameters, the KS distance of each matched distribution, the
        observation window [um] and the warnings' count."""
        fitted = ", ".join(f"{key.removeprefix('rve.')} {value}" for key, value in self._fitted_text())
        ks = ", ".join(f"{m.quantity} {m.ks:.3f}" for m in self.matches)
        warned = f", {len(self.warnings)} warnings" if self.warnings else ""
        return f"GeometryCalibration({fitted}; KS {ks}; window {self.search.get('window_um', math.nan):.4g} um{warned})"

    def _repr_html_(self) -> str:
        """The fitted parameters and the KS distances as an HTML table (Jupyter)."""
        from espin.core.html import html_table

        rows = [
            *self._fitted_text(),
            *((f"KS {m.quantity}", f"{m.ks:.4f}") for m in self.matches),
            ("observation window", f"{self.search.get('window_um', math.nan):.4g} um"),
            *(("warning", w) for w in self.warnings),
        ]
        return html_table(f"GeometryCalibration of {self.targets.source}", rows)

    def match(self, quantity: str) -> DistributionMatch:
        """The match of one quantity (``tortuosity``, ``orientation_deg``, ``diameter_um``)."""
        for m in self.matches:
            if m.quantity == quantity:
                return m
        raise KeyError(f"{quantity} was not a target")

    @property
    def report(self) -> dict[str, Any]:
        """JSON-ready description of the calibration (units in the key names)."""
        from espin.core.version import __version__

        return {
            "schema": SCHEMA,
            "schema_version": SCHEMA_VERSION,
            "espin_version": __version__,
            "source": self.targets.source,
            "parameters": _finite_or_none(self.parameters),
            "matches": [_match_json(m) for m in self.matches],
            "valley": [_finite_or_none(v.__dict__) for v in self.valley],
            "search": self.search,
            "warnings": list(self.warnings),
            "note": MECHANICS_NOTE,
        }

    def format_table(self) -> str:
        """Plain-text report for the command line."""
        s = self.search
        lines = [
            f"targets: {self.targets.source}; observation window {s['window_um']:.4g} um "
            f"({s['window_source']}), chords >= {s['min_chord_um']:.3g} um",
            f"virtual measurement: {s['sampling_description']}",
            "parameters",
        ]
        fitted = set(self.parameters["fitted"])
        for key, value in self.parameters.items():
            if key == "fitted":
                continue
            shown = (
                json.dumps(value)
                if isinstance(value, dict)
                else f"{value:.6g}"
                if isinstance(value, float)
                else str(value)
            )
            lines.append(f"  {key:<24} {shown}{'   (fitted)' if key in fitted else ''}")
        lines.append(
            "match in the observation window (KS distance: 0 same, 1 disjoint; p: "
            "two-sample KS p-value, descriptive only - the parameters were fitted to "
            "this sample and the virtual pieces are not independent, so p is optimistic)"
        )
        for m in self.matches:
            n_target = "-" if m.n_target is None else f"{m.n_target:,}"
            p = "-" if m.p_value is None else f"{m.p_value:.2g}"
            lines.append(
                f"  {m.quantity:<16} KS {m.ks:.4f}  descriptive p {p:<7} target {m.target} "
                f"(n {n_target}), virtual n {m.n_virtual:,}"
            )
            for name, target, virtual in m.summary:
                lines.append(f"      {name:<14} target {target:<10.4g} virtual {virtual:.4g}")
        whole = s.get("whole_portion_tortuosity")
        if whole:
            lines.append(
                f"whole fibers across the window (the calibrated mat's window portions, edge to "
                f"edge, as tracing fibers by hand measures them; inferred from the pieces through "
                f"the walk): tortuosity median {whole['median']:.4g} (half-normal scale "
                f"{whole['halfnorm_scale_from_median']:.3g} from the median), mean "
                f"{whole['mean']:.4g} (n {whole['n']:,})"
            )
        tracer = s.get("tracer") or {}
        if "tortuosity_bias" in tracer:
            lines.append(
                f"tracer bias: renderings of the first fitted walk ({_walk_text(tracer['first_walk'])}) "
                f"measured like the image against their true pieces map the measured tortuosity to the "
                f"true one quantile by quantile (median shift {tracer['tortuosity_bias']:+.4f}); the "
                "tortuosity target above is the sample so corrected"
            )
        check = tracer.get("rendered_check")
        if check:
            ks = ", ".join(
                f"{k.removeprefix('ks_')} {check[k]:.3f}"
                for k in ("ks_diameter_um", "ks_orientation_deg", "ks_tortuosity")
                if check[k] is not None
            )
            lines.append(
                f"rendered check ({check['renderings']} synthetic SEM images of the calibrated "
                f"mat measured like the image, {check['fibers']} traced fibers, against the "
                f"image's {len(self.targets.tortuosity) if self.targets.tortuosity is not None else '-'}): "
                f"KS {ks}; edge to edge {check['n_crossing']} fibers, U-turns "
                f"{_fmt(check['u_turn_fraction'])} (image {_fmt(check['target_u_turn_fraction'])} of "
                f"{check['target_n_crossing']}), straightness {_fmt(check['straightness'])} "
                f"(image {_fmt(check['target_straightness'])})"
            )
        if self.valley:
            lines.append(
                "tortuosity valley (segment length and deviation are only identifiable "
                "together, through the persistence length)"
            )
            lines.append(f"  {'segment_ratio':>13} {'max_deviation_deg':>17} {'persistence / D':>15} {'KS':>7}")
            for v in self.valley:
                lines.append(
                    f"  {v.segment_ratio:>13.3g} {v.max_deviation_deg:>17.2f} {v.persistence_ratio:>15.1f} {v.ks:>7.4f}"
                )
        lines.append(
            f"search: {len(s['seeds'])} seeds x {s['layers']} layers, RVE side "
            f"{s['search_side_um']:.4g} um (search) / {s['check_side_um']:.4g} um "
            f"(match), {s['evaluations']} evaluations, {s['elapsed_s']:.1f} s"
        )
        lines += [f"  {n}" for n in s["notes"]]
        lines += [f"warning: {w}" for w in self.warnings]
        lines.append(f"note: {MECHANICS_NOTE}")
        return "\n".join(lines)

    def write(self, path: str | Path, *, overwrite: bool = False) -> dict[str, Path]:
        """Write the calibrated config and the report, never over another run's files.

        Parameters
        ----------
        path
            A ``.toml`` file: the config there and the report beside it as
            ``<stem>.calibration.json``. Any other path is a folder (created if needed):
            ``config.toml``, ``calibration.json`` and ``calibration.txt`` in it, with its
            ``run.json`` manifest (:mod:`espin.core.output_folder`).
        overwrite
            Replace existing files (another run's results in a folder) instead of refusing.

        Returns
        -------
        dict
            The files written, by kind (``config``, ``report``, ``table`` for a folder, and
            ``comparison`` when the targets were measured on a known image).

        Raises
        ------
        ConfigError
            If the path is an existing file that is not a ``.toml`` (it would be a folder), or
            holds results already and ``overwrite`` is False (:func:`claim_output`).
        RVEFileError
            If a file cannot be written.
        """
        with claim_output(path, config_digest(self.config), overwrite=overwrite):
            return self.write_files(path)

    def write_files(self, path: str | Path) -> dict[str, Path]:
        """Write the files of :meth:`write` where the caller has claimed (:func:`claim_output`).

        Each file is written atomically; a ``.toml`` file's earlier report is removed before
        the new config is written, so the two never disagree.
        """
        from espin.core.atomic import atomic_write_bytes

        files = output_files(path)
        header = "".join(f"# {line}\n" for line in self._header_lines())
        text = header + tomli_w.dumps(_written_data(self.config))
        report = json.dumps(self.report, indent=2, allow_nan=False) + "\n"
        try:
            files["report"].unlink(missing_ok=True)
            files["comparison"].unlink(missing_ok=True)  # never another run's
            atomic_write_bytes(files["config"], text.encode("utf-8"))
            atomic_write_bytes(files["report"], report.encode("utf-8"))
            if "table" in files:
                atomic_write_bytes(files["table"], (self.format_table() + "\n").encode("utf-8"))
        except OSError as err:
            raise RVEFileError(f"cannot write the calibration to {path}: {err}") from None
        if self.image is None:
            files.pop("comparison")
        else:
            self.save_comparison(files["comparison"])
        return files

    def save_comparison(self, path: str | Path) -> Path:
        """Write the measured image beside a synthetic SEM rendering of a mat of the calibrated
        config (its seed), at the same pixel size and field of view
        (:mod:`~espin.imaging.geometry_calibration.comparison`)."""
        from espin.imaging.geometry_calibration.comparison import RENDERED_LAYERS, render_like, save_comparison

        if self.image is None:
            raise ConfigError("the calibration has no measured image to compare with")
        picture = self.image.pixels
        rendering = render_like(self.config, picture.shape, self.image.um_per_px, seed=self.config.rve.seed)
        walk = self.config.rve.walk
        return save_comparison(
            picture,
            rendering,
            self.image.um_per_px,
            path,
            f"measured: {self.image.label}",
            f"calibrated mat ({walk} walk), top {RENDERED_LAYERS} layers, synthetic SEM",
        )

    def _header_lines(self) -> list[str]:
        from espin.core.version import __version__

        lines = [
            f"Written by espin {__version__} calibrate-geometry from {self.targets.source}.",
            "Deposition parameters fitted to the measured geometry (observation window "
            f"{self.search['window_um']:.4g} um):",
        ]
        lines += [f"  {m.quantity}: KS {m.ks:.4f}" for m in self.matches]
        lines += [
            "New deposition parameters change the mechanics: fit the fiber parameters",
            "again (espin fit) before using stresses of this mat.",
        ]
        return lines


def output_files(path: str | Path) -> dict[str, Path]:
    """The files a calibration writes at ``path``, by kind: ``config`` and ``report`` (a
    ``.toml`` file and ``<stem>.calibration.json`` beside it), and ``table`` (a folder).

    Raises
    ------
    ConfigError
        If a ``.toml`` path is a folder, or another path an existing file.
    """
    path = Path(path)
    if path.suffix == ".toml":
        if path.is_dir():
            raise ConfigError(f"{path} is a folder: give a .toml file or a folder name without .toml")
        return {
            "config": path,
            "report": path.with_name(f"{path.stem}.calibration.json"),
            "comparison": path.with_name(f"{path.stem}.comparison.png"),
        }
    if path.exists() and not path.is_dir():
        raise ConfigError(
            f"{path} is an existing file: a path without .toml is a folder "
            "(config.toml, calibration.json, calibration.txt); give a .toml file or a folder"
        )
    return {
        "config": path / "config.toml",
        "report": path / "calibration.json",
        "table": path / "calibration.txt",
        "comparison": path / "comparison.png",
    }


def claim_output(path: str | Path, digest: str, *, overwrite: bool = False) -> AbstractContextManager:
    """Check where a calibration will be written, before the work.

    A folder is claimed by an :class:`~espin.core.output_folder.OutputFolder` (the folder
    policy and its ``run.json``; returned, finished when the ``with`` block ends). A ``.toml``
    file has no folder to claim: it is refused if it or its report exists, unless
    ``overwrite``.

    Parameters
    ----------
    path
        As in :meth:`GeometryCalibration.write`.
    digest
        What identifies the run's inputs (recorded in ``run.json``).
    overwrite
        Replace the files of another run instead of refusing.

    Raises
    ------
    ConfigError
        If the path is of the wrong kind (:func:`output_files`) or holds results and
        ``overwrite`` is False.
    """
    files = output_files(path)
    if "table" in files:
        return OutputFolder.claim(path, "calibrate-geometry", digest, CALIBRATION_OUTPUTS, overwrite=overwrite)
    existing = [str(f) for f in files.values() if f.exists()]
    if existing and not overwrite:
        one = len(existing) == 1
        raise ConfigError(
            f"{' and '.join(existing)} already exist{'s' if one else ''}; pass --overwrite "
            f"(overwrite=True in Python) to replace {'it' if one else 'them'}, or choose "
            "another -o path"
        )
    return nullcontext()


def _finite_or_none(d: dict[str, Any]) -> dict[str, Any]:
    """``d`` with non-finite floats (an infinite persistence length) as None, for JSON."""
    return {k: None if isinstance(v, float) and not math.isfinite(v) else v for k, v in d.items()}


def _match_json(m: DistributionMatch) -> dict[str, Any]:
    out = _finite_or_none(m.__dict__)
    out["summary"] = [{"statistic": n, "target": t, "virtual": v} for n, t, v in m.summary]
    return out


def _fmt(x: float | None) -> str:
    return "-" if x is None else f"{x:.3f}"


def _walk_text(walk: dict[str, Any]) -> str:
    return ", ".join(f"{k} {v:g}" if isinstance(v, float) else f"{k} {v}" for k, v in walk.items())
