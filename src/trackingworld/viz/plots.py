"""The camera-path plot (PNG): top view, side view and rotation over time, against ground truth when given.

Plain matplotlib on the Agg canvas (no pyplot, no global backend switch; evo's plot module sets the global
backend on import, which a headless server does not want).
"""

from __future__ import annotations

import os

import numpy as np

from trackingworld.eval.trajectory import apply_sim3, camera_metrics, sim3_from_trajectories
from trackingworld.geometry import invert_pose, rotation_angle_deg, transform
from trackingworld.io.atomic import atomic_path


def _local(poses_c2w: np.ndarray, ref_c2w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Camera centres in the reference camera's axes (x right, y down, z forward) and the rotation angle of
    each camera relative to the first, degrees."""
    c = transform(invert_pose(ref_c2w), poses_c2w[:, :3, 3])
    rel = np.einsum("ij,tjk->tik", poses_c2w[0, :3, :3].T, poses_c2w[:, :3, :3])
    return c, rotation_angle_deg(rel)


def plot_camera_path(poses_c2w: np.ndarray, out_png: str | os.PathLike, gt_c2w: np.ndarray | None = None,
                     title: str = "camera path") -> dict:
    """Write the plot; returns what it drew (``ate`` etc. when ground truth is given).

    With ``gt_c2w`` [T,4,4] the estimate is Sim(3)-aligned to it (Umeyama, as ``eval`` does) and both are drawn
    in the ground truth's first-camera axes."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    est = np.asarray(poses_c2w, np.float64)
    info: dict = {"frames": len(est)}
    if gt_c2w is not None:
        gt = np.asarray(gt_c2w, np.float64)[: len(est)]
        al = sim3_from_trajectories(est, gt)
        est = apply_sim3(al, est)
        m = camera_metrics(np.asarray(poses_c2w, np.float64), gt, al)
        info.update({k: m[k] for k in ("ate", "rte", "rre", "ate_pct_path")})
        ref = gt[0]
    else:
        gt, ref = None, est[0]
    c, ang = _local(est, ref)
    fig = Figure(figsize=(12, 4), dpi=110)
    FigureCanvasAgg(fig)
    axes = fig.subplots(1, 3)
    panels = ((0, 2, "x right [m]", "z forward [m]", "top view"), (2, 1, "z forward [m]", "y down [m]", "side view"))
    series = [("estimate" if gt is None else "estimate (Sim(3)-aligned)", c, ang, "tab:orange")]
    if gt is not None:
        cg, ag = _local(gt, ref)
        series.insert(0, ("ground truth", cg, ag, "k"))
    for ax, (i, j, xl, yl, name) in zip(axes[:2], panels, strict=True):
        for label, cc, _, color in series:
            ax.plot(cc[:, i], cc[:, j], "-", color=color, lw=1.8, label=label)
            ax.plot(cc[0, i], cc[0, j], "o", color=color, ms=6)
            ax.plot(cc[-1, i], cc[-1, j], "s", color=color, ms=6)
        ax.set_xlabel(xl)
        ax.set_ylabel(yl)
        ax.set_title(f"{name} (o first, s last frame)")
        ax.set_aspect("equal", adjustable="datalim")
        ax.grid(alpha=0.3)
    axes[1].invert_yaxis()  # y down: up is up on the page
    for label, _, aa, color in series:
        axes[2].plot(np.arange(len(aa)), aa, "-", color=color, lw=1.8, label=label)
    axes[2].set_xlabel("frame")
    axes[2].set_ylabel("rotation from frame 0 [deg]")
    axes[2].set_title("rotation")
    axes[2].grid(alpha=0.3)
    axes[0].legend(loc="best", fontsize=8)
    sub = title
    if "ate" in info:
        pct = info["ate_pct_path"]
        sub += f" | ATE {info['ate']:.4f} m" + (f" ({pct:.2f}% of path)" if pct is not None else "")
        sub += f", RTE {info['rte']:.4f} m, RRE {info['rre']:.3f} deg"
    fig.suptitle(sub)
    fig.tight_layout()
    with atomic_path(out_png) as tmp:
        fig.savefig(tmp, format="png")
    return info
