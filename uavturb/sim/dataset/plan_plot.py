"""Figure of one planned (and flown) trajectory: top view and altitude profile."""

from __future__ import annotations

import numpy as np

from uavturb.scene.indoor import Scene
from uavturb.scene.queries import height_below
from uavturb.sim.dataset.planning import PlannedTrajectory


def plot_flight(scene: Scene, plan: PlannedTrajectory, path: str, states: np.ndarray | None = None,
                t: np.ndarray | None = None) -> str:
    """Top view (free-space map, random points in visiting order, planned corners, reference and
    flown paths) and altitude profile (reference, flown, surface below) of one trajectory,
    written to ``path`` (PNG, matplotlib Agg). Returns ``path``."""
    import os

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ref = plan.reference
    tt = np.arange(0.0, ref.duration, 0.05)
    sp = ref(tt)
    g = plan.grid
    fig, (ax, az) = plt.subplots(1, 2, figsize=(14, 5.5), gridspec_kw={"width_ratios": [1.1, 1.4]})
    ext = [g.origin[0] - g.res / 2, g.origin[0] + (g.shape[0] - 0.5) * g.res,
           g.origin[1] - g.res / 2, g.origin[1] + (g.shape[1] - 0.5) * g.res]
    surf = np.where(g.occ, np.nan, g.surface)
    ax.imshow(np.where(g.occ, 1.0, np.nan).T, origin="lower", extent=ext, cmap="Greys", vmin=0, vmax=1.5)
    im = ax.imshow(surf.T, origin="lower", extent=ext, cmap="YlGn", alpha=0.6)
    fig.colorbar(im, ax=ax, fraction=0.04, label="surface below [m]")
    ax.plot(sp.p[:, 0], sp.p[:, 1], "b-", lw=1, label="reference")
    if states is not None:
        ax.plot(states[:, 0], states[:, 1], "r--", lw=0.8, label="flown")
    c = plan.corners
    ax.plot(c[:, 0], c[:, 1], "k.", ms=4, label="corners (A*)")
    marks = {"floor": "s", "top": "^", "free": "o"}
    for rank, k in enumerate(plan.order):
        x, y = plan.points[k, :2]
        ax.plot(x, y, marks[plan.kinds[k]], color="C1", ms=8)
        ax.annotate(str(rank), (x, y), textcoords="offset points", xytext=(5, 5))
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(f"scene {scene.seed} ({scene.kind}), trajectory {plan.seed}: Christofides order")
    ax.legend(loc="best", fontsize=7)
    d = height_below(scene, sp.p)
    az.plot(tt, sp.p[:, 2], "b-", lw=1, label="reference z")
    az.plot(tt, sp.p[:, 2] - d, "g-", lw=1, label="surface below")
    if states is not None and t is not None:
        az.plot(t, states[:, 2], "r--", lw=0.8, label="flown z")
    for name, color in (("edge_pass", "C3"), ("landing", "C4"), ("takeoff", "C2"), ("hover_low", "C0")):
        for i, (a, b) in enumerate(ref.notes.get(name, [])):
            az.axvspan(a, b, color=color, alpha=0.15, label=name if i == 0 else None)
    az.set_xlabel("t [s]")
    az.set_ylabel("height [m]")
    az.legend(loc="upper right", fontsize=7)
    az.set_title("altitude profile")
    fig.tight_layout()
    tmp = f"{path}.tmp.png"
    fig.savefig(tmp, dpi=110)
    plt.close(fig)
    os.replace(tmp, path)
    return path

