"""The plot of a model-validation sweep (``verification.sweep``), seed 000's Fig. 7 analog: per
solver, per target and axis, a box of the absolute localization error over the experiments
(median line, 25th-75th percentile box, min-max whiskers, mean as a circle), on a log scale
beside the seed's largest error (1.6 mm, model against EM tracker)."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from tissue_reference.meshes.io import save_figure

__all__ = ["PLOT_FILE", "write_plot"]

PLOT_FILE = "sweep_errors.png"


def write_plot(folder, result: dict) -> Path:
    """``folder``/sweep_errors.png of a ``sweep`` result (made with its parents when missing);
    returns its path."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    names = list(result["summary"]) or ["(no solver)"]
    targets, axes = result["targets"], ("x", "y", "z")
    fig, panels = plt.subplots(len(names), 1, figsize=(max(6.4, 1.3 * len(targets)),
                                                       3.6 * len(names)), squeeze=False)
    seed = result["seed_fig7"]["max_abs_error_mm"]
    for ax, name in zip(panels[:, 0], names):
        data, pos, colors = [], [], []
        for i, t in enumerate(targets):
            for j, a in enumerate(axes):
                e = np.array([abs(r["solvers"][name]["error_mm"][t][j])
                              for r in result["experiments"]]) if name in result["summary"] \
                    else np.array([])
                data.append(e[e > 0] if e.size else e)
                pos.append(4 * i + j)
                colors.append(f"C{j}")
        kept = [(d, p, c) for d, p, c in zip(data, pos, colors) if d.size]
        if kept:
            box = ax.boxplot([d for d, _, _ in kept], positions=[p for _, p, _ in kept],
                             whis=(0, 100), widths=0.7, patch_artist=True, showmeans=True,
                             meanprops={"marker": "o", "markerfacecolor": "orange",
                                        "markeredgecolor": "orange"},
                             medianprops={"color": "red"})
            for patch, (_, _, c) in zip(box["boxes"], kept):
                patch.set_facecolor(c)
                patch.set_alpha(0.35)
        ax.set_yscale("log")
        ax.axhline(seed, ls="--", color="k", lw=1,
                   label=f"seed 000 Fig. 7: largest error ~{seed:g} mm (model vs EM tracker)")
        ax.set_xticks([4 * i + 1 for i in range(len(targets))], targets)
        for j, a in enumerate(axes):
            ax.plot([], [], "s", color=f"C{j}", alpha=0.5, label=a)
        ax.set_ylabel("|model - reference| (mm)")
        n = len(result["experiments"])
        ax.set_title(f"{name}: localization error over {n} experiments (zeros not drawn)",
                     fontsize=10)
        ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(0.0, -0.08), ncol=4,
                  frameon=False)
    fig.tight_layout()
    return save_figure(fig, folder / PLOT_FILE)
