# %% [markdown]
# # chirpmap from Python: simulate, map, plot
#
# A notebook-style script (cells marked `# %%`, runnable as a plain script or
# in Jupyter/VS Code). Install first, from the repository root:
#
#     pip install ./crates/chirpmap-py matplotlib
#
# then `python examples/python/plot_map.py [OUT.png]`.

# %%
import sys

import matplotlib

if len(sys.argv) > 1:
    matplotlib.use("Agg")  # writing a file: no window needed
import matplotlib.pyplot as plt
import numpy as np

import chirpmap

# %% [markdown]
# ## 1. Simulate the paper's default scene
# Three random circles, one listener walking at 10 m/s, the particle model of
# §II.B. `seed` fixes the run bit for bit (the CLI's `--seed`).

# %%
run = chirpmap.simulate(seed=3)
print(run)
print("first echoes (" + ", ".join(chirpmap.ECHO_COLUMNS) + "):")
print(run.echoes[:3])

# %% [markdown]
# ## 2. Map the same echoes again, on a coarser grid around the obstacles
# `map_echoes` takes any (n, 5..9) array in the echoes.csv columns.

# %%
coarse = chirpmap.map_echoes(run.echoes, bounds=(-40, -40, 40, 40), cell=0.25)
print(coarse)

# %% [markdown]
# ## 3. Plot: `grid` rows are y, so `origin="lower"` with `extent`
# (x_min, x_max, y_min, y_max) puts every cell where it is in the world.

# %%
fig, axes = plt.subplots(1, 2, figsize=(12, 5.5), constrained_layout=True)
for ax, m, title in [
    (axes[0], run, f"simulate(seed={run.seed}): 0.1 m cells"),
    (axes[1], coarse, "map_echoes(..., cell=0.25)"),
]:
    # Log scale: a few cells collect most of the ellipse weight.
    im = ax.imshow(np.log1p(m.grid), extent=m.extent, origin="lower", cmap="viridis")
    ax.scatter(m.highlights[:, 0], m.highlights[:, 1], s=40, facecolors="none", edgecolors="red", label="highlights")
    ax.plot(run.echoes[:, 2], run.echoes[:, 3], "w-", lw=1, label="listener path")
    ax.plot([0], [0], "w*", ms=12, label="source")
    ax.set(title=title, xlabel="x (m)", ylabel="y (m)", xlim=m.extent[:2], ylim=m.extent[2:])
    fig.colorbar(im, ax=ax, label="log(1 + accumulated weight)")
# The obstacles are listed in the resolved scene (TOML; tomllib from Python 3.11).
try:
    import tomllib

    obstacles = tomllib.loads(run.scene).get("obstacles", [])
except ImportError:
    obstacles = []
for ax in axes:
    for o in obstacles:
        if "center" in o:
            ax.add_patch(plt.Circle(o["center"], o["radius"], fill=False, color="orange", lw=1.5))
        else:
            ax.add_patch(plt.Polygon(o["vertices"], fill=False, color="orange", lw=1.5))
axes[0].legend(loc="lower left")
# The paper's two scores (run.scores also holds the surface metrics).
scores = ", ".join(f"{k} {run.scores[k]:.3f}" for k in ("score_obstacle", "score_highlight") if run.scores[k] is not None)
fig.suptitle(f"Acoustic ellipses: {len(run.echoes)} echoes; {scores}")

# %%
if len(sys.argv) > 1:
    fig.savefig(sys.argv[1], dpi=100)
    print("wrote", sys.argv[1])
else:
    plt.show()
