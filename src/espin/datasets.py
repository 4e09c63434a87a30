"""Sample data to try espin on: an SEM-like image and specimen curves (``espin example-data``).

Both are synthetic, made by espin, not measured (the real test images in the development
repository are GPL and are not shipped):

* :func:`sem_image`: a wavy polydisperse virtual mat rendered as an SEM image by
  :func:`espin.imaging.synthetic.render_sem` (three layers in depth, noise, blur, uneven
  illumination) with a microscope's data bar along the bottom, saved as an 8-bit TIFF whose
  ImageJ tags record the pixel size (so ``espin measure`` needs no scale option).
* :func:`specimen_curves`: three tensile curves shaped like the paper's PLLA specimens (E about
  210 MPa, yield about 6 MPa near 3 % strain, post-yield modulus about 5 MPa, to 30 % strain),
  with specimen-to-specimen scatter and load-cell noise.
* :func:`calibrated_config`: the config ``espin calibrate-geometry`` makes from the sample
  image (default options), a wavy polydisperse mat ready to generate and simulate: the step
  that takes about a minute, done in advance.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from espin.core.atomic import atomic_write, atomic_write_bytes

__all__ = ["SEM_UM_PER_PX", "sem_image", "specimen_curves", "calibrated_config"]

SEM_UM_PER_PX = 0.05
"""Pixel size of the sample image [um / px]."""

_SEM_MAT = {
    "rve.diameter_um": 0.45,
    "rve.diameter_sd_um": 0.1,
    "rve.walk": "smooth",
    "rve.waviness_deg": 12.0,
    "rve.size_ratio": 100,
    "rve.layers": 4,
    "rve.seed": 7,
}


def sem_image(path: str | Path, *, seed: int = 7) -> Path:
    """Write the sample SEM image (TIFF, about 800 x 860 px, 40 um wide) to ``path``.

    Parameters
    ----------
    path
        The file to write (``.tif``).
    seed
        Seed of the virtual mat and of the image noise.

    Returns
    -------
    Path
        ``path``.
    """
    import tifffile

    from espin.core.config import load_config
    from espin.geometry.deposition import deposit
    from espin.imaging.synthetic import render_sem

    rve = load_config("plla", _SEM_MAT | {"rve.seed": seed}).rve
    sem = render_sem(deposit(rve), um_per_px=SEM_UM_PER_PX, side_um=40.0, layers=3, seed=seed, data_bar="band")
    pixels = np.round(255.0 * np.clip(sem.image, 0.0, 1.0)).astype(np.uint8)
    path = Path(path)
    per_um = 1.0 / sem.um_per_px
    return atomic_write(
        path,
        lambda tmp: tifffile.imwrite(tmp, pixels, imagej=True, resolution=(per_um, per_um), metadata={"unit": "um"}),
    )


def specimen_curves(folder: str | Path, *, seed: int = 0) -> list[Path]:
    """Write three specimen curves ``spec1.csv`` .. ``spec3.csv`` (columns ``strain``,
    ``stress_MPa``; 601 points, every 0.05 % strain to 30 %, as a tensile machine logging at a
    fixed rate gives, so the ISO 527 chord range 0.05-0.25 % holds five) into ``folder``.

    Each is a smooth bilinear curve, sigma = E e - (E - H) w ln(1 + exp((e - e_y) / w)) with
    E = 210 MPa, H = 4.8 MPa, e_y = 3 %, w = 0.4 %, scaled by its specimen's factor (0.95, 1,
    1.06) plus Gaussian noise of 0.02 MPa.

    Returns
    -------
    list of Path
        The three files.
    """
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    strain = np.linspace(0.0, 0.3, 601)
    modulus, hardening, knee, width = 210.0, 4.8, 0.03, 0.004
    shape = modulus * strain - (modulus - hardening) * width * np.logaddexp(0.0, (strain - knee) / width)
    shape -= shape[0]
    paths = []
    for k, factor in enumerate((0.95, 1.0, 1.06), start=1):
        stress = factor * shape + rng.normal(0.0, 0.02, strain.size)
        stress[0] = 0.0
        table = np.c_[strain, stress]

        def write(tmp: Path, table: np.ndarray = table) -> None:
            np.savetxt(tmp, table, delimiter=",", header="strain,stress_MPa", comments="", fmt="%.6g")

        paths.append(atomic_write(folder / f"spec{k}.csv", write))
    return paths


def calibrated_config(path: str | Path) -> Path:
    """Write the sample image's calibrated mat (a TOML config) to ``path``.

    It is what ``espin example-data && espin measure mat.tif -o measured && espin
    calibrate-geometry measured -o sem_mat.toml`` writes: lognormal diameters 0.49 +- 0.17 um
    and a smooth wavy walk (waviness 14 deg over 9 segments) fitted to the image's diameters,
    orientations and tortuosity; the fiber parameters are the ``plla`` preset's.

    Parameters
    ----------
    path
        The file to write (``.toml``).

    Returns
    -------
    Path
        ``path``.
    """
    from importlib.resources import files

    return atomic_write_bytes(path, files("espin").joinpath("sample_data", "calibrated_mat.toml").read_bytes())
