"""RealSense-like sensor noise for synthetic frames (deterministic given the numpy Generator).

Depth (metres along the optical axis, 0 = no reading):
- axial noise sigma(z) = 0.0008 + 0.0018 z^2 m (about 2 mm at 0.8 m, D4xx-like growth with z^2), split into
  an independent per-pixel part (80 %) and a smooth part (20 %, a 1/8-resolution Gaussian field
  upsampled bilinearly) that mimics the correlated stereo-matching error;
- dropout at depth discontinuities: pixels within 1 px of a jump > 1.5 cm are lost with probability 0.6,
  and 30 % of the remaining ones become *flying pixels* (a random blend of the nearest and farthest
  depth of their 3x3 neighbourhood);
- random dropout of 0.3 % of the pixels and a few small holes;
- quantisation to the depth unit happens when the PNG is written (value = round(z / depth_scale)).
Mask: at a few random boundary places a 7x7 patch is dilated or eroded by one pixel.
Colour: additive Gaussian noise, sigma 2 grey levels.
Robot: the measured sphere centre gets Gaussian noise of 0.2 mm per axis (commands stay exact).
"""

from __future__ import annotations

import cv2
import numpy as np

DEPTH_SIGMA_A = 0.0008  # m
DEPTH_SIGMA_B = 0.0018  # 1/m   sigma = a + b z^2
EDGE_JUMP = 0.015  # m
EDGE_DROP_P = 0.6
RANDOM_DROP_P = 0.003
FLYING_P = 0.3
ROBOT_SIGMA = 0.0002  # m


def depth_sigma(z: np.ndarray) -> np.ndarray:
    return DEPTH_SIGMA_A + DEPTH_SIGMA_B * np.asarray(z) ** 2


def noisy_depth(z: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """(H,W) metric depth -> noisy depth with dropouts (0 = no reading)."""
    h, w = z.shape
    valid = z > 0
    sig = depth_sigma(z)
    white = rng.standard_normal((h, w), dtype=np.float32)
    hs, ws = max(h // 8, 2), max(w // 8, 2)
    smooth = cv2.resize(rng.standard_normal((hs, ws)).astype(np.float32), (w, h), interpolation=cv2.INTER_LINEAR)
    out = z + sig * (np.sqrt(0.8) * white + np.sqrt(0.2) * smooth / max(float(smooth.std()), 1e-6))
    # depth discontinuities
    zz = np.where(valid, z, 0.0)
    jump = np.zeros((h, w), bool)
    dx = np.abs(np.diff(zz, axis=1)) > EDGE_JUMP
    dy = np.abs(np.diff(zz, axis=0)) > EDGE_JUMP
    jump[:, 1:] |= dx
    jump[:, :-1] |= dx
    jump[1:, :] |= dy
    jump[:-1, :] |= dy
    jump = cv2.dilate(jump.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
    r = rng.random((h, w), dtype=np.float32)
    drop = (jump & (r < EDGE_DROP_P)) | (r > 1.0 - RANDOM_DROP_P)
    # flying pixels: blend of the near and far surface at the remaining edge pixels
    zf = np.where(valid, z, np.inf).astype(np.float32)
    near = cv2.erode(zf, np.ones((3, 3), np.uint8))
    far = cv2.dilate(np.where(valid, z, 0.0).astype(np.float32), np.ones((3, 3), np.uint8))
    fly = jump & ~drop & (r < EDGE_DROP_P + FLYING_P * (1.0 - EDGE_DROP_P)) & np.isfinite(near) & (far > 0)
    a = rng.random((h, w), dtype=np.float32)
    out = np.where(fly, np.where(fly, near, 0.0) + a * (far - np.where(fly, near, 0.0)), out)
    for _ in range(int(rng.integers(0, 4))):
        cy, cx = int(rng.integers(0, h)), int(rng.integers(0, w))
        r = int(rng.integers(1, max(2, w // 100) + 2))
        cv2.circle(drop.view(np.uint8), (cx, cy), r, 1, -1)
    out[drop | ~valid] = 0.0
    return np.maximum(out, 0.0)


def noisy_mask(mask: np.ndarray, rng: np.random.Generator, n_patches: int = 4) -> np.ndarray:
    """Dilate or erode the mask by one pixel inside a few random 7x7 patches on its boundary."""
    m = mask.astype(np.uint8)
    edge = (cv2.dilate(m, np.ones((3, 3), np.uint8)) != cv2.erode(m, np.ones((3, 3), np.uint8)))
    ys, xs = np.nonzero(edge)
    if len(ys) == 0:
        return mask.copy()
    out = m.copy()
    dil = cv2.dilate(m, np.ones((3, 3), np.uint8))
    ero = cv2.erode(m, np.ones((3, 3), np.uint8))
    h, w = m.shape
    for _ in range(n_patches):
        k = int(rng.integers(0, len(ys)))
        y0, x0 = max(ys[k] - 3, 0), max(xs[k] - 3, 0)
        y1, x1 = min(ys[k] + 4, h), min(xs[k] + 4, w)
        src = dil if rng.random() < 0.5 else ero
        out[y0:y1, x0:x1] = src[y0:y1, x0:x1]
    return out.astype(bool)


def misregister_mask(mask: np.ndarray, z: np.ndarray, offset_px: int) -> tuple[np.ndarray, np.ndarray]:
    """(mask, z) with the mask (H,W) bool shifted ``offset_px`` along x and the object's depth z (H,W) m copied
    into the strip of background the shifted mask covers (from the object pixel ``offset_px`` before it)."""
    if offset_px == 0:
        return mask, z
    shifted = np.zeros_like(mask)
    src = np.where(mask, z, 0.0)
    bled = np.zeros_like(z)
    if offset_px > 0:
        shifted[:, offset_px:] = mask[:, :-offset_px]
        bled[:, offset_px:] = src[:, :-offset_px]
    else:
        shifted[:, :offset_px] = mask[:, -offset_px:]
        bled[:, :offset_px] = src[:, -offset_px:]
    strip = shifted & ~mask & (bled > 0)
    z = z.copy()
    z[strip] = bled[strip]
    return shifted, z


def noisy_rgb(rgb: np.ndarray, rng: np.random.Generator, sigma: float = 2.0) -> np.ndarray:
    n = rng.standard_normal(rgb.shape, dtype=np.float32) * np.float32(sigma)
    return np.clip(rgb.astype(np.float32) + n, 0, 255).astype(np.uint8)


def noisy_robot(p: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """(M,3) measured sphere centres + Gaussian noise of ROBOT_SIGMA per axis."""
    return p + rng.normal(0.0, ROBOT_SIGMA, p.shape)
