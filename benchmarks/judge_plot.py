"""The judge report's reliability diagram (matplotlib, Agg): the judge's collapse frequency against the
planner's mean predicted risk per bin, one panel per noise level, from `summarize`'s data."""
from __future__ import annotations

from pathlib import Path


def plot(summary: dict, path: Path) -> None:
    """Reliability diagram: observed collapse frequency against mean predicted risk, one panel per noise."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    noises = sorted({r["noise"] for r in summary["reliability"]})
    fig, axes = plt.subplots(1, max(1, len(noises)), figsize=(5.5 * max(1, len(noises)), 5), squeeze=False)
    for ax, noise in zip(axes[0], noises):
        ax.plot([0, 1], [0, 1], color="0.7", lw=1, ls="--", label="calibrated")
        for rel in (r for r in summary["reliability"] if r["noise"] == noise):
            for pool, style in (("all", "-o"), ("physics", ":s")):
                pts = [b for b in rel[pool] if b["steps"]]
                if not pts:
                    continue
                xs, ys = [b["predicted"] for b in pts], [b["observed"] for b in pts]
                line, = ax.plot(xs, ys, style, label=f"{rel['engine']}, {pool} steps")
                for b, x, y in zip(pts, xs, ys):
                    ax.annotate(str(b["steps"]), (x, y), textcoords="offset points", xytext=(4, 4),
                                fontsize=7, color=line.get_color())
        ax.set(xlim=(-0.02, 1.02), ylim=(-0.02, 1.02), xlabel="predicted risk (bin mean)",
               ylabel="collapse frequency on the judge", title=f"noise {noise * 100:g} cm (labels: steps)")
        ax.legend(fontsize=7, loc="upper left")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
