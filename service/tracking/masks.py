"""Object masks trimmed by colour at their border, for the visible-geometry SDF and the visible set V.

An uploaded mask can be off by a few pixels: on the real cube video the given mask is shifted about 7 px sideways
from the colour image, so a strip of table inside it back-projects onto the plane of the cube's side face and
reaches 2-4 cm past the cube's far edge, where no other view can carve it away (docs/tracking-findings.md, "Masks
trimmed by colour").

Trim: GrabCut (Rother, Kolmogorov, Blake, "GrabCut: interactive foreground extraction using iterated graph cuts",
SIGGRAPH 2004; ``cv2.grabCut``) on a crop around the mask. Two Gaussian-mixture colour models (5 components each),
one of the object and one of the background, and a graph cut that minimises

    E(α) = Σ_p −log p(c_p | GMM_{α_p}) + γ Σ_{p~q} [α_p ≠ α_q] exp(−β ‖c_p − c_q‖²)

over the labels α (object / background), alternating with refits of the two models (``iters`` times). Seeds: the
mask eroded by ``band_px`` is certainly object, the ring of ``band_px`` outside it probably background, farther
pixels certainly background; the ``band_px`` border inside the mask is left to the cut. Only pixels of the given
mask can stay object (the trim never adds pixels: near an occluder of the object's colour, growth would add the
occluder). A mask whose core (eroded by ``band_px``) is empty, or whose trim would remove more than
``max_removed`` of it, is kept as given: the colour models need seeds, and a cut that takes most of a mask is
the colour test failing, not the mask.
"""

from __future__ import annotations

import numpy as np


def trim_mask(rgb: np.ndarray, mask: np.ndarray, band_px: int = 6, iters: int = 3, pad: int = 20,
              max_removed: float = 0.5) -> np.ndarray:
    """(H,W) bool: ``mask`` (H,W) bool without the border pixels whose colour the cut gives to the background.
    ``rgb`` (H,W,3) uint8."""
    import cv2

    mask = np.asarray(mask, bool)
    if band_px <= 0 or not mask.any():
        return mask
    v, u = np.nonzero(mask)
    h, w = mask.shape
    y0, y1 = max(int(v.min()) - pad, 0), min(int(v.max()) + pad + 1, h)
    x0, x1 = max(int(u.min()) - pad, 0), min(int(u.max()) + pad + 1, w)
    m = mask[y0:y1, x0:x1].astype(np.uint8)
    k = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * band_px + 1, 2 * band_px + 1))
    core = cv2.erode(m, k) > 0
    ring = cv2.dilate(m, k) > 0
    if not core.any() or m.all():  # no object or no background seeds
        return mask
    g = np.full(m.shape, cv2.GC_BGD, np.uint8)
    g[ring] = cv2.GC_PR_BGD
    g[m > 0] = cv2.GC_PR_FGD
    g[core] = cv2.GC_FGD
    bgd, fgd = np.zeros((1, 65)), np.zeros((1, 65))
    cv2.setRNGSeed(0)  # the k-means start of the colour models draws from OpenCV's global generator
    try:
        cv2.grabCut(np.ascontiguousarray(rgb[y0:y1, x0:x1]), g, None, bgd, fgd, iters, cv2.GC_INIT_WITH_MASK)
    except cv2.error:  # degenerate colour models (e.g. a uniform crop): keep the given mask
        return mask
    keep = (g == cv2.GC_FGD) | (g == cv2.GC_PR_FGD)
    out = mask.copy()
    out[y0:y1, x0:x1] &= keep
    if out.sum() < (1.0 - max_removed) * mask.sum():
        return mask
    return out


class TrimmedMasks:
    """The session as the visible-geometry stage reads it: the same data, each frame's mask trimmed by
    ``trim_mask`` (computed once per frame). Every other attribute is the session's own.

    Whether to use it: the trim takes the rim of exact masks where colours blend (0.6-6 % of the pixels, the most on
    a round body's shaded limb), but almost nothing deeper than 3 px (<= 0.3 %); a mask a few pixels off the object
    loses the strip of background it covers, 4-8 % of its pixels deeper than 3 px. ``run`` uses the trimmed masks
    only when ``strip_fraction`` over the SDF frames reaches ``TrackingConfig.mask_trim_min``."""

    def __init__(self, session, band_px: int, iters: int):
        self._session = session
        self._band_px = band_px
        self._iters = iters
        self._cache: dict[int, tuple[np.ndarray, np.ndarray]] = {}  # frame: (given mask, trimmed mask)

    def _pair(self, i: int) -> tuple[np.ndarray, np.ndarray]:
        i = int(i)
        if i not in self._cache:
            s = self._session
            given = s.mask(i)
            self._cache[i] = (given, trim_mask(s.rgb(i), given, self._band_px, self._iters))
        return self._cache[i]

    def mask(self, i: int) -> np.ndarray:
        return self._pair(i)[1]

    def strip_fraction(self, frames, deep_px: int) -> float:
        """Median over ``frames`` (with a non-empty given mask) of the fraction of mask pixels the trim removes at
        least ``deep_px`` inside the given mask (Euclidean distance to its outside; nan without such frames)."""
        import cv2

        fr = []
        for i in frames:
            given, trimmed = self._pair(i)
            if given.any():
                inside = cv2.distanceTransform(given.astype(np.uint8), cv2.DIST_L2, 3)
                fr.append(float((given & ~trimmed & (inside >= deep_px)).sum() / given.sum()))
        return float(np.median(fr)) if fr else float("nan")

    def __getattr__(self, name):
        return getattr(self._session, name)
