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
# # 15 minutes with espin
#
# Generate a virtual electrospun mat, pull on it, read its stress-strain curve and properties,
# look at it in 3-D, and find the files to open in ParaView. Run it cell by cell in Jupyter
# (`pip install ".[test]"` installs Jupyter's kernel with espin's docs tools; or
# `pip install jupyterlab` beside espin), or download it as a script.
#
# The mat here is small (an RVE of 100 fiber diameters, 5 layers, a few seconds per test) so
# that the tutorial runs in a minute. With *balanced sampling* (fibers placed by a
# low-discrepancy sequence instead of independently at random) a mat of this size already
# gives the modulus and yield stress of the paper's much larger PLLA mat within 2 %
# ([Geometry](../geometry.md#realization-scatter-and-balanced-sampling)).

# %%
import tempfile
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np

import espin

work = Path(tempfile.mkdtemp(prefix="espin-15min-"))  # every file of this tutorial goes here
print(espin.__version__, work)

# %% [markdown]
# ## A virtual mat
#
# `espin.generate` takes a preset (`"plla"`: the paper's PLLA mat, Tables 2 and 3), a TOML
# config or a `Config`, and any key as `section__key=value`. The keys and their units are in
# [Configuration](../configuration.md).

# %%
rve = espin.generate("plla", rve__size_ratio=100, rve__layers=5, rve__sampling="balanced", rve__seed=1)
rve

# %% [markdown]
# The statistics an SEM image would show (diameters, orientations, tortuosity in an
# observation window) against the config's targets:

# %%
stats = espin.network_statistics(rve.mat, rve.network, rve.config)
print(stats.format_table())

# %% [markdown]
# ## The mat in 3-D
#
# The fibers are polylines deposited layer by layer (`rve.mat`: vertices in µm, one layer per
# fiber diameter in thickness). Drawn with matplotlib, one colour per layer:

# %%
mat = rve.mat
fig = plt.figure(figsize=(7, 6))
ax = fig.add_subplot(projection="3d")
colours = plt.cm.viridis(np.linspace(0.0, 1.0, mat.n_layers))
for fiber in range(mat.n_fibers):
    xy = mat.vertices[mat.fiber_offsets[fiber]:mat.fiber_offsets[fiber + 1]]
    layer = mat.fiber_layer[fiber]
    z = np.full(len(xy), (layer + 0.5) * mat.thickness / mat.n_layers)
    ax.plot(xy[:, 0], xy[:, 1], z, color=colours[layer], linewidth=0.8)
ax.set_xlabel("x [µm]")
ax.set_ylabel("y [µm]")
ax.set_zlabel("z [µm]")
ax.set_box_aspect((1.0, 1.0, 0.25))
ax.set_title(f"{mat.n_fibers} fibers in {mat.n_layers} layers, side {mat.size:.1f} µm")
plt.show()

# %% [markdown]
# ## A tensile test
#
# `espin.simulate` pulls the mat along x with the lateral edges held (the paper's test) and
# writes the results folder. In a notebook it shows a progress bar with the time left.
# `curve_marks` marks the bilinear fit's $E$, yield point and $H$ on the folder's
# `curve.png`, as `espin simulate` does.

# %%
from espin.analysis.properties import curve_marks

result = espin.simulate(rve, work / "test", loading__max_strain=0.15, loading__steps=15, curve_marks=curve_marks)
result

# %% [markdown]
# The curve as a table: strain, the nominal stress $P'_{11}$ [MPa], the paper's Eq. 17 stress,
# the fractions of fibers recruited (taut) and yielded, and the solver's counts per step.

# %%
curve = result.to_dataframe()
curve.head()

# %% [markdown]
# ## Its properties
#
# A bilinear fit gives the modulus $E$, the yield point and the post-yield modulus $H$
# ([Properties](../properties.md)):

# %%
from espin.analysis.properties import bilinear_stress

props = espin.curve_properties(result.strain, result.stress())
print(f"E = {props.modulus_MPa:.0f} MPa, yield {props.yield_stress_MPa:.2f} MPa at "
      f"{100 * props.yield_strain:.2f} % strain, H = {props.post_yield_modulus_MPa:.1f} MPa")

# %%
fig, ax = plt.subplots(figsize=(6, 4))
ax.plot(100 * result.strain, result.stress(), "o-", label="virtual mat")
ax.plot(100 * result.strain, bilinear_stress(props, result.strain), "--",
        label="bilinear fit")
ax.plot(100 * props.yield_strain, props.yield_stress_MPa, "k*", markersize=12, label="yield point")
ax.set_xlabel("strain [%]")
ax.set_ylabel("$P'_{11}$ [MPa]")
ax.legend()
plt.show()

# %% [markdown]
# ## The results folder
#
# The same run wrote everything to disk: the curve, the results in HDF5, the figures and the
# files for ParaView. Nothing is overwritten: running the cell again stops with an error
# naming `--overwrite` (`overwrite=True` here).

# %%
sorted(p.name for p in (work / "test").iterdir())

# %%
from IPython.display import Image

Image(filename=str(work / "test" / "curve.png"), width=520)

# %% [markdown]
# `espin.load_results` reads a results folder (or its `results.h5`) back, e.g. in another
# session:

# %%
saved = espin.load_results(work / "test")
saved

# %% [markdown]
# ## In ParaView
#
# Open `deformation.pvd` (one file per step in `vtk/`) and `network.vtu` from the results
# folder: all VTK files are centred on the RVE and overlay. Each step holds the *reference*
# network with the point data `displacement_um`: apply **Warp By Vector** to see it deformed
# (a scale factor above 1 exaggerates), colour by `stress_MPa`, `axial_force_uN` or
# `chord_strain`, and play the steps; the step's strain is in the field data `strain`.

# %%
print(work / "test" / "deformation.pvd")

# %% [markdown]
# ## Next
#
# * the whole paper-size test from a terminal: `espin simulate plla -o plla_test` (a few
#   minutes on 2 cores);
# * [From an SEM image to a curve](sem_to_curve.py): your own mat;
# * [Fit your curves](fit_curves.py): the fiber parameters from your tensile tests.
