"""Figures logged with training runs: predicted vs true height over test trajectories.

The paper's simulated-trajectory figure: for each of a few test trajectories, the true height
over ground ``d*`` [m] and the height the model predicts at each frame ``t`` from the window of
``H`` frames ending at ``t`` (the frame its metrics score), over time [s].
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from uavturb.io import shards


@torch.no_grad()
def predict_last_frames(module: torch.nn.Module, depth: np.ndarray, window: int, batch: int = 64) -> np.ndarray:
    """Height [m] at every frame from the window of ``window`` frames ending there.

    Parameters
    ----------
    module : a :class:`~uavturb.systems.HeightModule` (``module(depth) -> (d, state)``).
    depth : (T, H, W) z-depth [m].
    window : frames per window.

    Returns
    -------
    (T,) float array; ``nan`` for the first ``window - 1`` frames.
    """
    T = len(depth)
    out = np.full(T, np.nan)
    if T < window:
        return out
    module.eval()
    param = next(module.parameters())
    device, dtype = param.device, param.dtype  # e.g. a GPU, or bf16 weights (trainer.precision=bf16-true)
    x = torch.from_numpy(np.array(depth, np.float32)).unsqueeze(1)  # (T, 1, H, W), a writable copy
    ends = np.arange(window - 1, T)
    for s in range(0, len(ends), batch):
        e = ends[s:s + batch]
        idx = torch.from_numpy(e[:, None] - np.arange(window - 1, -1, -1)[None, :])
        d, _ = module(x[idx].to(device, dtype))
        out[e] = d[:, -1].float().cpu().numpy()
    return out


def figure_test_heights(module: torch.nn.Module, folders: list[str | Path], window: int, n: int = 3):
    """Predicted vs true height [m] over time [s] for the first ``n`` trajectories of ``folders`` (a Figure)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    folders = list(folders)[:n]
    fig, axes = plt.subplots(len(folders), 1, figsize=(8, 2.2 * len(folders)), squeeze=False, sharex=False)
    for ax, folder in zip(axes[:, 0], folders):
        tr = shards.read_trajectory(folder)
        d_hat = predict_last_frames(module, tr.depth, window)
        t = np.asarray(tr.t) - tr.t[0]
        ok = np.isfinite(d_hat)
        rmse = float(np.sqrt(np.mean((d_hat[ok] - tr.d[ok]) ** 2))) if ok.any() else float("nan")
        ax.plot(t, tr.d, color="k", lw=1.2, label="true d")
        ax.plot(t, d_hat, color="tab:orange", lw=1.2, label=f"predicted (window {window})")
        ax.set_ylabel("height [m]")
        ax.set_title(f"{tr.meta['scene_id']} / {Path(folder).name}: RMSE {rmse:.3f} m", fontsize=9)
        ax.grid(alpha=0.3)
    axes[0, 0].legend(loc="upper right", fontsize=8)
    axes[-1, 0].set_xlabel("time [s]")
    fig.tight_layout()
    return fig


def plot_test_heights(module: torch.nn.Module, folders: list[str | Path], window: int, path: str | Path,
                      n: int = 3) -> Path:
    """Save :func:`figure_test_heights` as a PNG; returns its path."""
    import matplotlib.pyplot as plt

    fig = figure_test_heights(module, folders, window, n)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
