"""Constructed interior features of a textured cylinder (shared by the spin tests): surface points in rings of
``N_AZ`` azimuths about the axis, and per frame their positions in W with descriptors that carry the point id (bytes
0-1) and the frame (byte 2), so that a test's matcher decides which pairs match."""

from __future__ import annotations

import numpy as np

from tests.tracking.test_spin import R_CYL

N_AZ, HEIGHTS = 200, (-0.03, 0.0, 0.03)  # rings of N_AZ azimuths (1.8° apart) at these heights along the axis


def cylinder_features(a: np.ndarray, c: np.ndarray, e1: np.ndarray, X_frames: np.ndarray) -> list:
    """[(points (F,3) in W, descriptors (F,32) uint8)] per pose of X_frames (N,4,4): the cylinder of axis ``a``
    through ``c`` (in O), azimuth 0 along ``e1`` (unit, perpendicular to a)."""
    b1 = np.cross(a, e1)
    phi = np.radians(np.arange(N_AZ) * 360.0 / N_AZ)
    P_O = np.concatenate([c + h * a + R_CYL * (np.cos(phi)[:, None] * e1 + np.sin(phi)[:, None] * b1)
                          for h in HEIGHTS])
    feats = []
    ids = np.arange(len(P_O))
    for i, X in enumerate(X_frames):
        des = np.zeros((len(P_O), 32), np.uint8)
        des[:, 0], des[:, 1], des[:, 2] = ids % 256, ids // 256, i
        feats.append((P_O @ X[:3, :3].T + X[:3, 3], des))
    return feats
