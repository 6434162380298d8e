"""Figures of the tracking stage for the report (matplotlib, Agg backend; nothing is written unless the caller
gives a path).

- ``pose_error_figure(t, X_WO, X_ref, tracked=None)``: translation (mm) and rotation (deg) error over time against
  reference poses, after the fixed body-frame offset X_OR = X_WO(0)⁻¹ X_ref(0).
- ``velocity_figure(out)``: filtered v_WO_W and w_WO_O.
- ``overlay_frames(session, out, frames, path=None)``: the visible mesh's vertices projected with the tracked
  poses over a few RGB frames (and the object mask outline), as one image (H', W', 3) uint8, optionally saved as
  PNG.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from service.transforms import X_inv, pose_errors, project_to_pixels


def _plt():
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    return plt


def pose_errors_vs_reference(X_WO: np.ndarray, X_ref: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(translation error m (N,), rotation error rad (N,)) after the fixed offset X_OR = X_WO(0)⁻¹ X_ref(0)."""
    X_OR = X_inv(X_WO[0]) @ X_ref[0]
    return pose_errors(X_WO @ X_OR, X_ref)


def pose_error_figure(t: np.ndarray, X_WO: np.ndarray, X_ref: np.ndarray, tracked: np.ndarray | None = None,
                      title: str = "pose error", path: Path | None = None):
    """Figure of the pose error over time; saved as PNG to ``path`` if given. Returns the figure."""
    plt = _plt()
    et, er = pose_errors_vs_reference(X_WO, X_ref)
    fig, ax = plt.subplots(2, 1, figsize=(7, 4.5), sharex=True)
    ax[0].plot(t, 1e3 * et, lw=1)
    ax[0].set_ylabel("translation error (mm)")
    ax[1].plot(t, np.degrees(er), lw=1, color="C1")
    ax[1].set_ylabel("rotation error (deg)")
    ax[1].set_xlabel("time (s)")
    if tracked is not None and (~tracked).any():
        for a in ax:
            a.fill_between(t, 0, 1, where=~tracked, color="0.85", transform=a.get_xaxis_transform(), label="lost")
        ax[0].legend(loc="upper right")
    ax[0].set_title(f"{title}: median {1e3 * np.median(et):.1f} mm / {np.degrees(np.median(er)):.2f}°")
    fig.tight_layout()
    if path is not None:
        fig.savefig(path, dpi=120)
    return fig


def velocity_figure(out, path: Path | None = None):
    """Filtered linear (W) and angular (body) velocities of a TrackingOutputs. Returns the figure."""
    plt = _plt()
    fig, ax = plt.subplots(2, 1, figsize=(7, 4.5), sharex=True)
    for k, c in enumerate("xyz"):
        ax[0].plot(out.t, out.v_WO_W[:, k], lw=1, label=f"v_{c}")
        ax[1].plot(out.t, out.w_WO_O[:, k], lw=1, label=f"ω_{c}")
    ax[0].set_ylabel("v_WO_W (m/s)")
    ax[1].set_ylabel("w_WO_O (rad/s)")
    ax[1].set_xlabel("time (s)")
    ax[0].legend(ncol=3, fontsize=8)
    ax[1].legend(ncol=3, fontsize=8)
    fig.tight_layout()
    if path is not None:
        fig.savefig(path, dpi=120)
    return fig


def overlay_frames(session, out, frames=None, path: Path | None = None, max_points: int = 4000) -> np.ndarray:
    """Visible-mesh vertices (green: in front, tracked pose) over RGB frames, tiled in a row. Returns uint8 RGB."""
    import cv2

    if frames is None:
        frames = np.linspace(0, session.n_frames - 1, 4).round().astype(int)
    V = np.asarray(out.visible_mesh.vertices, float)
    if len(V) > max_points:
        V = V[np.random.default_rng(0).choice(len(V), max_points, replace=False)]
    K = session.K
    tiles = []
    for i in frames:
        img = session.rgb(int(i)).copy()
        X_CO = X_inv(session.X_WC) @ out.X_WO[int(i)]
        P = V @ X_CO[:3, :3].T + X_CO[:3, 3]
        u, v, inb = project_to_pixels(P, K, img.shape, z_min=1e-3)
        img[v[inb], u[inb]] = (0, 255, 0) if out.tracked[int(i)] else (255, 0, 0)
        m = session.mask(int(i)).astype(np.uint8)
        cnts, _ = cv2.findContours(m, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
        cv2.drawContours(img, cnts, -1, (255, 255, 0), 1)
        cv2.putText(img, f"frame {int(i)}", (5, 15), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (255, 255, 255), 1)
        tiles.append(img)
    out_img = np.concatenate(tiles, 1)
    if path is not None:
        cv2.imwrite(str(path), cv2.cvtColor(out_img, cv2.COLOR_RGB2BGR))
    return out_img
