# ---
# jupyter:
#   jupytext:
#     formats: py:percent
#   kernelspec:
#     display_name: Python 3
#     language: python
#     name: python3
# ---

# %% [markdown]
# # From an SEM image to a curve
#
# Measure an SEM image of an electrospun mat, find the deposition parameters that make a
# virtual mat look like it, and pull on that mat. The image here is espin's sample
# (`espin example-data` writes it as `mat.tif`): a synthetic SEM image of a wavy mat with
# fibers of several diameters, with a microscope's data bar, its pixel size in the TIFF tags.
# Use your own image instead: `espin.measure` reads TIFF, PNG and JPEG
# ([From your SEM image](../sem.md)).

# %%
import os
import tempfile
from pathlib import Path

import matplotlib.pyplot as plt

import espin
from espin import datasets
from espin.imaging.image import read_image

work = Path(tempfile.mkdtemp(prefix="espin-sem-"))
image = datasets.sem_image(work / "mat.tif")

fig, ax = plt.subplots(figsize=(6, 6))
ax.imshow(read_image(image), cmap="gray")
ax.set_axis_off()
plt.show()

# %% [markdown]
# ## Measure
#
# `espin.measure` reads the pixel size from the TIFF's tags (or takes `um_per_px=`, or a
# scale bar), leaves the data bar out, traces each fiber through the crossings, and measures
# its diameter, orientation and tortuosity. Fibers fully visible on top are told apart from
# deeper, partly hidden ones: only their diameters count.

# %%
measurement = espin.measure(image)
measurement

# %%
measurement.fibers.head()

# %% [markdown]
# `write` saves the measurement: `fibers.csv`, `measurement.toml` (the fitted distributions),
# and the figures; `overlay.png` shows what was traced, to check by eye.

# %%
files = measurement.write(work / "measured")
from IPython.display import Image

Image(filename=str(files["overlay"]), width=520)

# %% [markdown]
# ## Calibrate the deposition
#
# `espin.calibrate_geometry` searches the deposition parameters (diameter distribution, walk
# and its waviness, orientation) whose virtual mats, observed in the same window as the
# image, give the measured distributions. It generates and measures many small mats: with its
# default 8 seeds per candidate it took 3.4 min on 2 cores shared with other jobs
# (`espin calibrate-geometry measured -o sem_mat.toml` from a terminal, on the branch of
# issue 38). The docs' test runs it with 2 seeds, only the paper walk (the walk the default
# options choose for this image, below) and without the check on rendered images, which is
# quicker and can land elsewhere: compare with the full result below.

# %%
quick = os.environ.get("ESPIN_TUTORIAL_QUICK") == "1"
options = {"seeds": 2, "walk": "paper", "rendered_check": False} if quick else {}
calibration = espin.calibrate_geometry(work / "measured", **options)
calibration

# %%
print(calibration.format_table())

# %% [markdown]
# The calibrated config keeps everything else of the base config (`plla` by default: the
# fiber law, the loading). A calibrated mat of this image ships with espin
# (`espin.datasets.calibrated_config`, `calibrated_mat.toml` of `espin example-data`): the
# full calibration as espin 0.1.0 ran it on 2026-12-02, which chose the smooth walk
# (waviness 14 deg). Today's calibration with its default options (8 seeds and the rendered
# check, as above without `ESPIN_TUTORIAL_QUICK`) picks the paper walk for the same image:
# 13.8 deg between segments, walk score 1.33 against 2.31 for the best smooth walk (the
# report's `walk:` line; measured on the branch of issue 38, 3.4 min on 2 shared cores). Both
# match the image about equally (KS of tortuosity, orientation and diameter 0.13 / 0.08 /
# 0.14 today, 0.10 / 0.12 / 0.12 for the shipped mat): the image does not tell the two walks
# apart sharply. The docs keep the shipped mat so that their numbers stay comparable; for
# your own image, use the calibration you run.

# %%
shipped = espin.load_config(datasets.calibrated_config(work / "calibrated_mat.toml"))
for key in ("diameter_um", "diameter_sd_um", "diameter_distribution", "walk", "waviness_deg",
            "waviness_length_ratio"):
    print(f"{key:<24} this run {getattr(calibration.config.rve, key)!s:<12} shipped {getattr(shipped.rve, key)}")

# %% [markdown]
# ## Pull on the calibrated mat
#
# The calibrated mat is generated like any other. Here at a small size (100 fiber diameters,
# 5 layers, balanced sampling) next to the paper's straight-fiber PLLA mat of the same size;
# both keep the `plla` fiber law, which has not been fitted to this mat: fit it to your
# tensile tests before trusting its stresses ([Fit your curves](fit_curves.py)).

# %%
small = {"rve__size_ratio": 100, "rve__layers": 5, "rve__sampling": "balanced",
         "loading__max_strain": 0.1, "loading__steps": 10}
wavy = espin.simulate(shipped, **small)  # no folder: the curves are all we need here
straight = espin.simulate("plla", **small)

fig, ax = plt.subplots(figsize=(6, 4))
for result, label in ((wavy, "mat of the image (wavy, polydisperse)"), (straight, "plla (straight fibers)")):
    ax.plot(100 * result.strain, result.stress(), "o-", label=label)
ax.set_xlabel("strain [%]")
ax.set_ylabel("$P'_{11}$ [MPa]")
ax.legend()
plt.show()

# %% [markdown]
# Their properties side by side (bilinear fit, [Properties](../properties.md)) and the fraction
# of fibers recruited (taut) at 1 % strain: wavy fibers stay slack for longer.

# %%
for result, label in ((wavy, "image"), (straight, "plla")):
    props = espin.curve_properties(result.strain, result.stress())
    print(f"{label:<6} E {props.modulus_MPa:6.1f} MPa, yield {props.yield_stress_MPa:5.2f} MPa at "
          f"{100 * props.yield_strain:.2f} %, recruited at 1 % strain {result.recruited_fraction[1]:.3f}")
