"""Model-free 6-DoF object tracking from masked RGBD (a CPU stand-in for BundleSDF's tracker).

Per frame i (object points p_W from masked, eroded, flying-pixel-filtered depth, X_WC):
1. prediction: constant body-frame velocity from the last two tracked poses;
2. coarse motion: ORB matches inside the mask against the previous tracked frame and the keyframes (their
   3-D points stored in O), RANSAC over 3-point Kabsch hypotheses gives a candidate X_WO (with
   ``track_ransac_px``, off, first in the camera: pixels across the ray, ransac_thr along it,
   ``geometry.ray_inliers``, ``_feature_motion``);
3. refinement: robust point-to-plane ICP of p_W against the object model built so far (keyframe points
   merged in O on a voxel grid), with the RANSAC inliers as point-to-point terms; from every candidate, the
   best fit (inlier fraction, then residual) wins;
4. lost-track test: too few points, inlier fraction < min_inlier_frac or residual > max_rmse. Lost frames are
   re-localised from the last tracked pose and against all keyframes' features; a re-acquisition after a lost fall
   of a body of revolution far from the fall's landing about its base rim takes that landing (``lost_land``,
   ``_lost_landing``);
5. keyframes: a well-tracked frame far (angle/translation) from every keyframe or showing new surface adds
   its points (those within grow_dist of the model, which rejects mask noise) to the model.
Drift is bounded by (a) frame-to-model rather than frame-to-frame registration, (b) a bundle adjustment of
all keyframe poses (``service.tracking.posegraph``: robust point-to-plane terms between every
pair of overlapping keyframes, keyframe 0 fixed), followed by leave-one-out refinement (each
keyframe re-registered to the model of all the others), (c) a final pass registering every frame to the
refined model, and (d) frame 0 registered to that model as well, the body frame moved by the constant offset
so that X_WO(0) keeps its definition (a mismatch between frame 0 and the merged model would otherwise be an
offset common to every other frame); with ``gauge_frames`` the registration of frame 0 is replaced by the robust
mean over frame 0 and the frames at rest before the robot reaches the object (``service.tracking.gauge``).
Topple landings (``resettle``, on): the pre-fall model tipped about its leading bottom edge onto its leading face
replaces a track far from it a few frames after the landing, the settled frame a keyframe with all its points
(``service.tracking.resettle``); after the loop the join moves along the tipping direction until the object's base
is no longer where the settled frames see the table (``resettle_refine_frames``). The fall's frames of an adopted
join are registered backwards from the settled frame with the turn about the leading bottom edge as one more start
and as the judge among fits that are nearly as good (``resettle_tip_tol``). After the gauge, the settled stretch of
every landing checked is laid flush with the table on the face the pre-fall model lands on, the stretch's keyframes
moved with it, and its frames registered again in the turns about the vertical and horizontal shifts of a resting
object (``resettle_flush_deg``, on).
Frames never tracked keep tracked=False and get poses interpolated (slerp/lerp) between tracked neighbours.
O: origin at the centroid of frame 0's object points in W, axes parallel to W (docs/conventions.md).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Callable

import numpy as np
from scipy.spatial import cKDTree

from service.tracking.geometry import (IcpResult, backproject, depth_continuous, icp,
                                       pixel_normals, ransac_rigid)
from service.tracking.types import TrackingConfig
from service.tracking.voxels import group_sums, voxel_groups
from service.transforms import X_inv, make_X, pose_distance, so3_exp, so3_log

if TYPE_CHECKING:
    from service.tracking.spin import SpinResult
    from service.tracking.tilt import TiltResult

Progress = Callable[[float, str], None] | None


@dataclass
class FrameObs:
    """Object observation of one frame, in W."""

    P_W: np.ndarray  # (N,3)
    N_W: np.ndarray  # (N,3) unit normals
    kp_W: np.ndarray  # (F,3) 3-D feature points
    desc: np.ndarray | None  # (F,32) uint8 ORB descriptors
    n_mask: int
    spin_feats: tuple[np.ndarray, np.ndarray | None] | None = None  # interior keypoints (spin closure on)


@dataclass
class Keyframe:
    index: int
    X_WO: np.ndarray
    P_O: np.ndarray  # points added to the model, in O (pose-dependent: recomputed on refinement)
    P_W: np.ndarray
    N_W: np.ndarray
    kp_O: np.ndarray
    desc: np.ndarray | None
    kp_W: np.ndarray | None = None


def _place_keyframe(kf: Keyframe, X_WO: np.ndarray, carver) -> None:
    """Give the keyframe kf the pose X_WO (4,4): its points and keypoints re-expressed in O from their world
    coordinates, and the carver's copy of its pose updated (``carver`` None: no carver)."""
    kf.X_WO = X_WO
    X_OW = X_inv(X_WO)
    kf.P_O = kf.P_W @ X_OW[:3, :3].T + X_OW[:3, 3]
    kf.kp_O = kf.kp_W @ X_OW[:3, :3].T + X_OW[:3, 3]
    if carver is not None:
        carver.update_pose(kf.index, X_WO)


@dataclass
class ObjectModel:
    """Merged keyframe points in O (voxel-averaged) with normals and a KD-tree."""

    voxel: float
    Q: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    N: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    tree: cKDTree | None = None

    @staticmethod
    def build(voxel: float, parts: list[tuple[np.ndarray, np.ndarray]]) -> "ObjectModel":
        P = np.concatenate([p for p, _ in parts])
        Nn = np.concatenate([n for _, n in parts])
        key = np.floor(P / voxel).astype(np.int64)
        inv, cnt = voxel_groups(key)  # np.unique(key, axis=0)'s groups, faster (service.tracking.voxels)
        Q = group_sums(inv, P, len(cnt))  # np.add.at's sums, bit for bit
        Nm = group_sums(inv, Nn, len(cnt))
        Q /= cnt[:, None]
        Nm /= np.maximum(np.linalg.norm(Nm, axis=1, keepdims=True), 1e-12)
        return ObjectModel(voxel, Q, Nm, cKDTree(Q))


def observe(session, i: int, cfg: TrackingConfig, rng: np.random.Generator) -> FrameObs:
    """Object points, normals and features of frame i, in W."""
    import cv2

    depth = session.depth(i)
    mask = session.mask(i)
    K, X_WC = session.K, session.X_WC
    n_mask = int(mask.sum())
    m = mask.astype(np.uint8)
    if cfg.erode_px > 0:
        k = 2 * cfg.erode_px + 1
        m = cv2.erode(m, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (k, k)))
    ok = (m > 0) & (depth > 0)
    v, u = np.nonzero(ok)
    if len(u) > 2 * cfg.max_points:
        sel = rng.choice(len(u), 2 * cfg.max_points, replace=False)
        u, v = u[sel], v[sel]
    # flying pixels: large depth jump to a 4-neighbour; normals from ±2 px differences
    good = depth_continuous(depth, u, v, cfg.edge_jump)
    N_C, nok = pixel_normals(depth, K, u, v, step=2)
    good &= nok
    u, v, N_C = u[good], v[good], N_C[good]
    if len(u) > cfg.max_points:
        sel = rng.choice(len(u), cfg.max_points, replace=False)
        u, v, N_C = u[sel], v[sel], N_C[sel]
    P_C = backproject(depth, K, u, v)
    R, t = X_WC[:3, :3], X_WC[:3, 3]
    P_W = P_C @ R.T + t
    N_W = N_C @ R.T
    # the table next to the object's base has continuous depth and leaks in with the mask boundary
    above = (P_W[:, 2] > session.table_height + cfg.table_clearance) & ~near_effector(session, i, P_W, cfg)
    P_W, N_W = P_W[above], N_W[above]
    kp_W = np.zeros((0, 3))
    desc = None
    gray = None  # the grey image, converted once for the ORB features and the spin closure's
    if cfg.features and n_mask > 0:
        gray = cv2.cvtColor(session.rgb(i), cv2.COLOR_RGB2GRAY)
        fm = cv2.dilate(mask.astype(np.uint8), np.ones((3, 3), np.uint8)) * 255  # the mask dilated by 1 px
        orb = cv2.ORB_create(nfeatures=cfg.n_features, scaleFactor=1.2, nlevels=4, edgeThreshold=9, patchSize=15,
                             fastThreshold=7)
        kps, des = orb.detectAndCompute(gray, fm)
        if des is not None and len(kps):
            uv = np.array([kp.pt for kp in kps])
            uu = np.clip(np.round(uv[:, 0]).astype(int), 0, depth.shape[1] - 1)
            vv = np.clip(np.round(uv[:, 1]).astype(int), 0, depth.shape[0] - 1)
            good = (depth[vv, uu] > 0) & (m[vv, uu] > 0)
            if good.sum():
                Pc = np.stack([(uv[good, 0] - K[0, 2]) / K[0, 0] * depth[vv[good], uu[good]],
                               (uv[good, 1] - K[1, 2]) / K[1, 1] * depth[vv[good], uu[good]],
                               depth[vv[good], uu[good]]], 1)
                kw = Pc @ R.T + t
                above = kw[:, 2] > session.table_height + cfg.table_clearance
                kp_W = kw[above]
                desc = des[good][above]
    spin_feats = None
    if cfg.spin_closure and n_mask > 0:
        from service.tracking.spin import interior_features

        if gray is None:
            gray = cv2.cvtColor(session.rgb(i), cv2.COLOR_RGB2GRAY)
        spin_feats = interior_features(gray, depth, mask, K, X_WC, cfg.spin_border_px, cfg.spin_features)
    return FrameObs(P_W, N_W, kp_W, desc, n_mask, spin_feats)


def _match(desc_a: np.ndarray | None, desc_b: np.ndarray | None, ratio: float = 0.8) -> np.ndarray:
    """(M,2) index pairs of mutual-ratio-test ORB matches a→b."""
    import cv2

    if desc_a is None or desc_b is None or len(desc_a) < 2 or len(desc_b) < 2:
        return np.zeros((0, 2), int)
    # the two nearest of b per row of a as arrays (what BFMatcher.knnMatch computes, without one Python object per
    # match): a tie for the nearest fails the ratio test whichever index is returned, so the pairs are the same
    d, j = cv2.batchDistance(desc_a, desc_b, cv2.CV_32S, normType=cv2.NORM_HAMMING, K=2)
    q = np.nonzero((d[:, 0] < ratio * d[:, 1].astype(np.float64)) & (d[:, 0] < 64))[0]
    return np.stack([q, j[q, 0]], 1).astype(int).reshape(-1, 2)


def _good(r: IcpResult, cfg: TrackingConfig) -> bool:
    return r.inlier_frac >= cfg.min_inlier_frac and r.rmse <= cfg.max_rmse


def _fit_score(r: IcpResult) -> float:
    """The registration score: inlier fraction minus 0.02 per millimetre of RMSE."""
    return r.inlier_frac - 0.02 * r.rmse / 0.001


def _better(a: IcpResult, b: IcpResult | None) -> bool:
    return b is None or _fit_score(a) > _fit_score(b)


def _jump(X_a: np.ndarray, X_b: np.ndarray, dt: float, cfg: TrackingConfig) -> bool:
    """True when going from pose X_a to X_b in dt seconds needs more than max_speed / max_rate_deg: no pushed
    object moves so (a topple turns at ≈ 200 °/s), but a flip to a symmetric pose of a partly seen box does."""
    dist, ang = pose_distance(X_a, X_b)
    dt = max(float(dt), 1e-6)
    return dist / dt > cfg.max_speed or ang / dt > cfg.max_rate_deg


def near_effector(session, i: int, P_W: np.ndarray, cfg: TrackingConfig) -> np.ndarray:
    """(N,) bool: points within ee_radius + ee_margin of the end-effector sphere centre of frame i (robot
    pixels next to the object). All False when the session has no robot data."""
    if len(getattr(session, "robot_t", ())) == 0 or session.ee_radius <= 0:
        return np.zeros(len(P_W), bool)
    c = np.asarray(session.p_WE[i], float)
    return np.linalg.norm(P_W - c, axis=1) < session.ee_radius + cfg.ee_margin


class FreeSpace:
    """Space seen empty by the keyframes: a point p_O is *seen through* when, in some keyframe k, it projects
    into the image with camera depth z and the depth reading there, min-filtered over a (2r+1)² window (so that
    silhouettes and pose errors of a few pixels do not carve the object's own rim), is larger than z + margin —
    the camera looked past p, so p is empty space. Gripper fingers and other rigidly co-moving clutter adjacent
    to the object lie where earlier keyframes saw the table or background, while surface that was hidden before
    (the underside after a topple) lies behind earlier observations or below the table and is kept."""

    def __init__(self, K: np.ndarray, X_WC: np.ndarray, margin: float, px: int):
        self.K, self.X_CW, self.margin, self.px = K, X_inv(X_WC), float(margin), int(px)
        self.views: list[tuple[np.ndarray, np.ndarray]] = []  # (X_OW-independent X_CO of the keyframe, depth)
        self.indices: list[int] = []

    def add(self, index: int, depth: np.ndarray, X_WO: np.ndarray) -> None:
        from service.sdf.evidence import min_filter_depth

        self.views.append((self.X_CW @ X_WO, min_filter_depth(depth, self.px)))
        self.indices.append(int(index))

    def update_pose(self, index: int, X_WO: np.ndarray) -> None:
        if int(index) in self.indices:
            j = self.indices.index(int(index))
            self.views[j] = (self.X_CW @ X_WO, self.views[j][1])

    def seen_through(self, P_O: np.ndarray) -> np.ndarray:
        from service.sdf.evidence import seen_in_front

        return seen_in_front(np.asarray(P_O, float), ((self.K, X_CO, d) for X_CO, d in self.views), self.margin)


@dataclass
class TrackResult:
    X_WO: np.ndarray  # (N,4,4) interpolated where untracked
    tracked: np.ndarray  # (N,) bool
    inlier_frac: np.ndarray  # (N,)
    rmse: np.ndarray  # (N,)
    model: ObjectModel
    keyframes: list[Keyframe]
    carver: FreeSpace | None = None
    kf_log: list[dict] = field(default_factory=list)  # per keyframe candidate: index, far, new_frac, added, accepted
    n_feat: np.ndarray | None = None  # (N,2) feature correspondences used per frame: tracking, final pass (none: 0)
    spin: "SpinResult | None" = None  # spin closure of a body of revolution (cfg.spin_closure)
    landings: list = field(default_factory=list)  # resettle.Landing of
    # every topple landing joined (cfg.resettle: X_new the join; score_old / score_new the fractions of the pre-fall
    # model the frame sees through at the tracked / joined pose)
    tilt: "TiltResult | None" = None  # tilt closure of an egg-like body (cfg.spin_tilt)
    lost_landings: list[dict] = field(default_factory=list)  # per re-acquisition after a lost fall compared with the
    # turn about the base rim (cfg.lost_land): frame i, last tracked a, fall start g0, tilt and rate (deg, deg/frame),
    # deg / dist the gap (deg, m), adopted


def track(session, cfg: TrackingConfig, progress: Progress = None) -> TrackResult:
    """Track the object through all frames of ``session`` (see module docstring)."""
    import cv2

    rng = np.random.default_rng(cfg.seed)
    n_cv = cv2.getNumThreads()
    cv2.setNumThreads(1)
    try:
        return _track(session, cfg, rng, progress)
    finally:
        cv2.setNumThreads(n_cv)


def _report(progress: Progress, f: float, msg: str) -> None:
    if progress is not None:
        progress(float(f), msg)


def _track(session, cfg: TrackingConfig, rng: np.random.Generator, progress: Progress) -> TrackResult:
    N = session.n_frames
    obs: list[FrameObs] = []
    X = np.tile(np.eye(4), (N, 1, 1))
    tracked = np.zeros(N, bool)
    frac = np.zeros(N)
    rmse = np.full(N, np.inf)

    o0 = observe(session, 0, cfg, rng)
    obs.append(o0)
    if len(o0.P_W) < cfg.min_points:
        from service.errors import StageFailed

        raise StageFailed("tracking", f"frame 0 has {len(o0.P_W)} valid object depth points (< {cfg.min_points}): "
                                      "the object must be visible in the first frame")
    # robust centroid: drop points far from the median (mask noise)
    med = np.median(o0.P_W, 0)
    dd = np.linalg.norm(o0.P_W - med, axis=1)
    keep = dd < 3.0 * np.median(dd) + 0.01
    X[0] = make_X(np.eye(3), o0.P_W.mean(0))  # O origin: centroid of frame 0's object points (conventions)
    tracked[0], frac[0], rmse[0] = True, 1.0, 0.0
    X_OW0 = X_inv(X[0])
    kf0 = Keyframe(0, X[0].copy(), o0.P_W[keep] @ X_OW0[:3, :3].T + X_OW0[:3, 3], o0.P_W[keep], o0.N_W[keep],
                   o0.kp_W @ X_OW0[:3, :3].T + X_OW0[:3, 3], o0.desc, o0.kp_W)
    keyframes = [kf0]
    carver = FreeSpace(session.K, session.X_WC, cfg.carve_margin, cfg.carve_px) if cfg.carve else None
    if carver is not None:
        carver.add(0, session.depth(0), X[0])
    model = _model_from(keyframes, cfg.model_voxel)
    last = [0]  # indices of tracked frames
    kf_log: list[dict] = []
    n_feat = np.zeros((N, 2), int)

    X_CW = X_inv(session.X_WC)
    icp_kw = dict(iters=cfg.icp_iters, dist0=cfg.icp_dist0, dist_min=cfg.icp_dist_min, inlier_dist=cfg.inlier_dist)
    landings: list = []  # resettle.Landing of every topple landing checked (cfg.resettle)
    lost_log: list[dict] = []  # re-acquisitions after a lost fall compared with its landing (cfg.lost_land)
    for i in range(1, N):
        o = observe(session, i, cfg, rng)
        obs.append(o)
        if len(o.P_W) < cfg.min_points:
            X[i] = X[last[-1]]
            continue
        # candidates: constant-velocity prediction and the last tracked pose
        a = last[-1]
        cands = [X[a]]
        if len(last) >= 2 and last[-2] == a - 1 and a == i - 1:
            b = last[-2]
            cands.insert(0, X[a] @ (X_inv(X[b]) @ X[a]))  # X_WO(a) · (body-frame step b→a)
        # features: previous tracked frame and keyframes
        fW, fO = _feature_corr(o, obs[a], X[a], keyframes, lost=(a != i - 1))
        feat_W = feat_O = None
        if len(fW) >= max(6, cfg.feat_min_inliers):
            Xr, inl = _feature_motion(fW, fO, cfg, rng, cam=(session.K, X_CW))
            if Xr is not None:
                Xc = X_inv(Xr)  # fO = Xr fW -> Xr = X_OW
                cands.append(Xc)
                feat_W, feat_O = fW[inl], fO[inl]
                n_feat[i, 0] = len(feat_W)
        best = None
        for Xc in cands:
            if best is not None and _good(best, cfg):
                dt, da = pose_distance(best.X_WO, Xc)
                if dt < 0.01 and da < 5.0:
                    continue  # this start converges to the pose already found
            r = icp(o.P_W, Xc, model.tree, model.Q, model.N, feat_W=feat_W, feat_O=feat_O, **icp_kw)
            if _better(r, best):
                best = r
        if a != i - 1 and not _good(best, cfg):
            # re-localisation: wider search from the last tracked pose and every keyframe pose
            for kf in keyframes[::-1][:8]:
                r = icp(o.P_W, kf.X_WO, model.tree, model.Q, model.N,
                        **{**icp_kw, "dist0": 2 * cfg.icp_dist0})
                if _better(r, best):
                    best = r
        X[i] = best.X_WO
        frac[i], rmse[i] = best.inlier_frac, best.rmse
        if not _good(best, cfg) or _jump(X[a], X[i], session.frame_times[i] - session.frame_times[a], cfg):
            X[i] = X[a]
            continue
        tracked[i] = True
        last.append(i)
        if cfg.lost_land and a != i - 1:  # a re-acquisition after a fall the loop lost: where the fall lands
            rel = _lost_landing(session, i, o, X, last, keyframes, carver, lost_log, cfg)
            if rel is not None:
                best, model = rel
                frac[i], rmse[i] = best.inlier_frac, best.rmse
                last[:] = [i]
        if cfg.resettle:  # after a topple's landing: the pre-fall model tipped onto its leading face
            rel = _resettle_check(session, i, o, X, tracked, keyframes, carver, landings, cfg)
            if rel is not None:
                best, model = rel
                frac[i], rmse[i] = best.inlier_frac, best.rmse
                last[:] = [i]
        # keyframe?
        dists = [pose_distance(kf.X_WO, X[i]) for kf in keyframes]
        far = min(max(d / cfg.kf_dist, ang / cfg.kf_angle_deg) for d, ang in dists) >= 1.0
        new_frac = float(np.mean(best.nn_dist > cfg.inlier_dist))
        if best.inlier_frac >= cfg.kf_min_inlier_frac and (far or new_frac > cfg.kf_new_frac):
            near = best.nn_dist < cfg.grow_dist
            X_OW = X_inv(X[i])
            consistent = True
            st_all = np.zeros(len(near), bool)
            if carver is not None and near.any():
                st = carver.seen_through(o.P_W[near] @ X_OW[:3, :3].T + X_OW[:3, 3])
                consistent = st.mean() <= cfg.carve_frame_frac
                st_all[near] = st
                near[near] &= ~st
            addable = float(np.mean((best.nn_dist > cfg.inlier_dist) & near))
            # a keyframe taken for new surface must add some: points farther than grow_dist (a part of the object
            # split off by an occluder, clutter) or seen through are never added, so counting them alone would make
            # every following frame a keyframe with nothing new (prism push, seed 12: 213 keyframes, 8 min)
            adds = far or addable >= cfg.kf_min_new_add
            kf_log.append(dict(index=i, far=bool(far), new_frac=new_frac, addable=addable, n=len(o.P_W),
                               added=int(near.sum()), beyond=int((best.nn_dist >= cfg.grow_dist).sum()),
                               seen=int(st_all.sum()), accepted=bool(consistent and adds)))
            if consistent and adds:
                kf = Keyframe(i, X[i].copy(), o.P_W[near] @ X_OW[:3, :3].T + X_OW[:3, 3], o.P_W[near], o.N_W[near],
                              o.kp_W @ X_OW[:3, :3].T + X_OW[:3, 3], o.desc, o.kp_W)
                keyframes.append(kf)
                if carver is not None:
                    carver.add(i, session.depth(i), X[i])
                model = _model_from(keyframes, cfg.model_voxel)
        if i % 10 == 0:
            _report(progress, 0.6 * i / N, f"tracking frame {i}/{N}, {len(keyframes)} keyframes")

    if cfg.resettle_refine_frames > 0 and any(ld.adopted for ld in landings):  # the join moved along the tip
        model = _resettle_refine(session, obs, X, tracked, keyframes, carver, landings, cfg) or model
    if any(ld.adopted for ld in landings):  # the fall's frames registered backwards from the settled pose
        _settle_backward(session, obs, X, tracked, frac, rmse, model, landings, cfg, icp_kw)
    if cfg.ba_iters > 0 and len(keyframes) > 2:
        _report(progress, 0.61, f"bundle adjustment of {len(keyframes)} keyframes")
        _bundle_adjust(keyframes, cfg, rng, carver)
        model = _model_from(keyframes, cfg.model_voxel)
    if cfg.refine_rounds > 0 and len(keyframes) > 2:
        _report(progress, 0.62, "refining keyframe poses")
        for _ in range(cfg.refine_rounds):
            _refine_keyframes(keyframes, cfg, carver, icp_kw, X)
            model = _model_from(keyframes, cfg.model_voxel)
    if cfg.final_pass:
        for i in range(1, N):
            o = obs[i]
            if len(o.P_W) < cfg.min_points:
                continue
            start = X[i]
            r = icp(o.P_W, start, model.tree, model.Q, model.N,
                    **{**icp_kw, "dist0": 0.012, "iters": cfg.final_iters})
            X[i], frac[i], rmse[i] = r.X_WO, r.inlier_frac, r.rmse
            tracked[i] = _good(r, cfg)
            if i % 20 == 0:
                _report(progress, 0.62 + 0.18 * i / N, f"final registration {i}/{N}")
        if cfg.regauge_frame0:
            from dataclasses import replace as _replace

            o0 = observe(session, 0, _replace(cfg, max_points=cfg.regauge_points), rng)  # dense: one frame sets O
            model = _regauge(o0, X, model, keyframes, carver, cfg, icp_kw, obs, tracked, session)
        if cfg.resettle_flush_deg > 0 and landings:  # the settled stretch flush with the table, re-registered (after the
            # gauge: the base the object stood on is -z in the final O)
            model = _resettle_flush(session, obs, X, tracked, frac, rmse, keyframes, carver, landings, cfg) or model
        if (cfg.resettle_box_axis or cfg.resettle_box_slide) and landings:  # the settled box's position along the
            # tip axis (and, with resettle_box_slide, along the tipping direction) from its ends
            model = _resettle_axis(session, X, tracked, keyframes, carver, landings, cfg) or model
    spin = tilt = None
    if cfg.spin_closure:
        _report(progress, 0.8, "spin closure")
        spin = _spin_closure(obs, X, model, cfg, session.table_height)
        if cfg.spin_tilt:
            tilt = _spin_tilt(obs, X, model, spin, cfg)
        if cfg.lie_level:  # a lying body of revolution: axis parallel to the table (service.tracking.lying)
            _level_lying(X, model, spin, session.table_height, cfg, keyframes)
        if cfg.lie_axis_ends:  # a lying body of revolution moved along its axis onto the ends its mask shows
            model = _lying_axis(session, X, tracked, model, spin, keyframes, carver, cfg) or model
    X = interpolate_untracked(X, tracked)
    return TrackResult(X, tracked, frac, rmse, model, keyframes, carver, kf_log, n_feat, spin, landings, tilt,
                       lost_log)


def _consistent_in(session, j: int, Q: np.ndarray, cfg: TrackingConfig) -> Callable[[np.ndarray], bool]:
    """Whether a pose X_WO of the model points Q (M,3) is consistent with the table and with frame j's own free space
    (``resettle.pose_consistent``, margins ``landing_table_*`` / ``landing_seen_frac``)."""
    from service.tracking.resettle import pose_consistent

    view = FreeSpace(session.K, session.X_WC, cfg.carve_margin, cfg.carve_px)
    view.add(j, session.depth(j), np.eye(4))
    return lambda X_WO: pose_consistent(X_WO, Q, session.table_height, view, cfg.landing_table_margin,
                                        cfg.landing_table_frac, cfg.landing_seen_frac)


def _resettle_check(session, i: int, o: FrameObs, X: np.ndarray, tracked: np.ndarray, keyframes: list[Keyframe],
                    carver: "FreeSpace | None", landings: list, cfg: TrackingConfig
                    ) -> tuple[IcpResult, ObjectModel] | None:
    """Frame i (just tracked) comes ``resettle_delay`` frames after a topple's fast landing
    (``resettle.find_fall``): its pose from the pre-fall model tipped onto its leading face
    (``resettle.landing_pose``, ``resettle.face_offsets``). When that pose differs from the tracked one by more than
    ``resettle_min_deg`` / ``resettle_min_dist``, the keyframes from the fall's start on are dropped (``keyframes``,
    ``carver`` changed in place), X[i] takes it and frame i becomes a keyframe with all its points; returns (the ICP
    result at the new pose, the new model), else None. Every fall checked is appended to ``landings``."""
    from service.tracking.resettle import Landing, box_landing_pose, face_offsets, find_fall, landing_pose, reach_along

    ev = find_fall(X, tracked, i, cfg.settle_fast_deg, cfg.settle_fall_deg, cfg.resettle_tip_deg,
                   cfg.resettle_min_tip_deg, cfg.resettle_delay, after=max([ld.i for ld in landings], default=0))
    if ev is None:
        return None
    r, g0, _, h = ev
    pre = [kf for kf in keyframes if kf.index < g0]
    if not pre:
        return None
    M = _model_from(pre, cfg.model_voxel)
    if cfg.resettle_box_face:  # a box's leading face from its sides, only for a body resting on the table at frame i
        box = X[0][:3, :3].T @ np.array([0.0, 0.0, -1.0])  # the base it stood on: its normal in O
        top = (o.P_W, o.N_W, cfg.resettle_max_shift) if cfg.resettle_box_drop else None  # the face on top
        Xj, face = box_landing_pose(X[r], h, M.Q, M.N, session.table_height, box,
                                    X[i], lambda: _model_from(keyframes, cfg.model_voxel).Q, cfg.resettle_box_rest,
                                    top=top)
    else:
        Xj, face = landing_pose(X[r], h, M.Q, M.N, session.table_height)
    Xj = face_offsets(Xj, M.Q, M.N, o.P_W, o.N_W, max_shift=cfg.resettle_max_shift)
    Xj = reach_along(Xj, M.Q, o.P_W, np.cross(h, [0.0, 0.0, 1.0]), cfg.resettle_max_shift)
    dt, da = pose_distance(X[i], Xj)
    view = FreeSpace(session.K, session.X_WC, cfg.carve_margin, cfg.carve_px)
    view.add(i, session.depth(i), np.eye(4))  # the frame's own depth, points given in W
    Qs = M.Q[:: max(1, len(M.Q) // 2000)]

    def seen(Xc: np.ndarray) -> float:  # fraction of the pre-fall model where frame i sees the table or background
        return float(np.mean(view.seen_through(Qs @ Xc[:3, :3].T + Xc[:3, 3])))

    s_old, s_new = seen(X[i]), seen(Xj)
    # adopted only for an object that lands on a flat face, when the joined pose is at least as consistent with the
    # frame's free space as the tracked one (the pre-fall model placed with it covers no more pixels where the frame
    # sees the table or background); a wrong track need not be shown wrong by that test (its model fits the upper part)
    far = dt > cfg.resettle_min_dist or da > cfg.resettle_min_deg
    adopt = far and face and s_new <= s_old + cfg.resettle_seen
    landings.append(Landing(g0, i, X[i].copy(), Xj.copy(), s_old, s_new, bool(adopt)))
    if not adopt:
        return None
    return _restart_at(session, i, o, X, Xj, pre, g0, keyframes, carver, cfg)


def _restart_at(session, i: int, o: FrameObs, X: np.ndarray, X_new: np.ndarray, pre: list[Keyframe], g0: int,
                keyframes: list[Keyframe], carver: "FreeSpace | None", cfg: TrackingConfig
                ) -> tuple[IcpResult, ObjectModel]:
    """Frame i takes the pose X_new (4,4, X_WO) from a landing's physics: the keyframes become ``pre`` (those before
    the fall's start g0), the free-space views from g0 on are dropped, frame i becomes a keyframe with all its points
    and the model is rebuilt (``X``, ``keyframes`` and ``carver`` changed in place). Returns the ICP result of frame i
    at X_new against the new model, and that model."""
    from service.tracking.geometry import icp_result

    keyframes[:] = pre
    if carver is not None:
        idx = [k for k, j in enumerate(carver.indices) if j < g0]
        carver.views = [carver.views[k] for k in idx]
        carver.indices = [carver.indices[k] for k in idx]
    X_OW = X_inv(X_new)
    keyframes.append(Keyframe(i, X_new.copy(), o.P_W @ X_OW[:3, :3].T + X_OW[:3, 3], o.P_W, o.N_W,
                              o.kp_W @ X_OW[:3, :3].T + X_OW[:3, 3], o.desc, o.kp_W))
    if carver is not None:
        carver.add(i, session.depth(i), X_new)
    model = _model_from(keyframes, cfg.model_voxel)
    X[i] = X_new
    return icp_result(X_OW, o.P_W, model.tree, model.Q, model.N, cfg.inlier_dist), model


def _axis_tilt(X_WO: np.ndarray, a_O: np.ndarray) -> float:
    """The angle (deg) of the axis a_O (3,) (unit, in O) from the vertical of W under the pose X_WO (4,4)."""
    return float(np.degrees(np.arccos(np.clip((X_WO[:3, :3] @ a_O)[2], -1.0, 1.0))))


def _lost_landing(session, i: int, o: FrameObs, X: np.ndarray, last: list[int], keyframes: list[Keyframe],
                  carver: "FreeSpace | None", log: list[dict], cfg: TrackingConfig
                  ) -> tuple[IcpResult, ObjectModel] | None:
    """Frame i has just been re-acquired (tracked, the frame before it not; ``last`` the tracked frames, i last).
    When the tracked frames before the loss fall (the standing axis a = ẑ of O at frame 0 tilted by at least
    ``lost_land_tilt_deg`` at the last one, a, and tilting faster than ``settle_fall_deg`` per frame over the last 3
    tracked steps), the model of the keyframes before the fall's start g0 is a body of revolution about a
    (``lying.base_rim`` finds an axis line; κ < ``spin_flat_kappa``, ``spin.arc_score``) and the time from a to i is
    enough for it to topple from X[a]'s tilt at that rate onto the table (``lying.topple_time``: a uniform cylinder of
    the model's height and widest radius), the pose X[a] is turned about its base rim's pivot onto the table
    (``lying.rim_landing``). When the re-acquired pose's axis is more than ``lost_land_deg`` from that pose's, or its
    base centre more than ``lost_land_dist`` from it along the axis (``lying.axial_gap``), X[i] takes the turned pose,
    the keyframes from g0 on are dropped and frame i becomes a keyframe with all its points (``keyframes``, ``carver``
    changed in place, as the landing join of ``_resettle_check``); returns (the ICP result at the new pose, the new
    model), else None. Every comparison is appended to ``log``."""
    from service.tracking.lying import axial_gap, base_rim, rim_landing, topple_time
    from service.tracking.spin import arc_score

    prev = last[:-1]
    if len(prev) < 4:
        return None
    a_O = X[0][:3, :3].T @ np.array([0.0, 0.0, 1.0])
    a, k = prev[-1], prev[-4]
    th = _axis_tilt(X[a], a_O)
    rate = (th - _axis_tilt(X[k], a_O)) / (a - k)
    if th < cfg.lost_land_tilt_deg or rate <= cfg.settle_fall_deg:
        return None
    p = len(prev) - 1  # the fall's start: back while the tilt grows faster than settle_fall_deg per frame
    while p > 0 and (_axis_tilt(X[prev[p]], a_O) - _axis_tilt(X[prev[p - 1]], a_O)) / (prev[p] - prev[p - 1]) \
            > cfg.settle_fall_deg:
        p -= 1
    g0 = prev[p]
    pre = [kf for kf in keyframes if kf.index < g0]
    if not pre:
        return None
    M = _model_from(pre, cfg.model_voxel)
    rim = base_rim(M.Q, a_O, session.table_height - float(X[0][:3, 3] @ (X[0][:3, :3] @ a_O)))
    if rim is None:
        return None
    b_O, radius = rim
    if cfg.spin_flat_kappa > 0 and arc_score(M.Q, M.N, a_O, b_O) >= cfg.spin_flat_kappa:
        return None  # flat faces: not a body of revolution about a
    height = float(np.max((M.Q - b_O) @ a_O))  # the model's top above its base
    dt = float(session.frame_times[a + 1] - session.frame_times[a])  # the frame period
    if session.frame_times[i] - session.frame_times[a] < topple_time(np.radians(th), np.radians(rate) / dt, radius,
                                                                     height):
        return None  # the fall cannot have ended yet
    Xc = rim_landing(X[a], a_O, b_O, radius, session.table_height)
    if Xc is None:
        return None
    deg, dist = axial_gap(X[i], Xc, a_O, b_O)
    adopt = deg > cfg.lost_land_deg or dist > cfg.lost_land_dist
    log.append(dict(i=i, a=a, g0=g0, tilt=th, rate=rate, deg=deg, dist=dist, radius=radius, adopted=bool(adopt)))
    if not adopt:
        return None
    return _restart_at(session, i, o, X, Xc, pre, g0, keyframes, carver, cfg)


def _fall_base(session, X_a: np.ndarray, X_b: np.ndarray, X_0: np.ndarray, pre: list[Keyframe],
               cfg: TrackingConfig) -> tuple[np.ndarray, float, np.ndarray] | None:
    """For a topple from pose X_a to X_b: the tipping direction f (3,) and the turn's angle (rad)
    (``resettle.tip_direction``), and the object's base at frame 0 (``resettle.base_points`` of the model of the
    keyframes ``pre`` before the fall, (M, 3) in O); None without a horizontal turn or with fewer than 30 base points."""
    from service.tracking.resettle import base_points, tip_direction

    tip = tip_direction(X_a, X_b)
    if tip is None:
        return None
    B = base_points(_model_from(pre, cfg.model_voxel).Q, X_0, session.table_height)
    if len(B) < 30:
        return None
    return tip[0], tip[1], B


def _resettle_refine(session, obs: list[FrameObs], X: np.ndarray, tracked: np.ndarray, keyframes: list[Keyframe],
                     carver: "FreeSpace | None", landings: list, cfg: TrackingConfig) -> ObjectModel | None:
    """Every adopted topple join (``_resettle_check``) moved forward along its tipping direction f until the
    object's base (``resettle.base_points``: the table plane under the rest pose of frame 0 within the pre-fall
    model's footprint, 5 mm inside it) no longer lies where the settled segment's frames see the table or
    background (``resettle.base_shift``; depth margin 3 mm, 1 px: the base stands vertical behind the landed
    object, where the table is only millimetres behind it). The settled segment: the first
    ``resettle_refine_frames`` tracked frames from the settled frame i on, carried to frame i by their tracked
    poses (the segment is consistent within itself). The shift (at most ``resettle_max_shift``) moves the poses
    from frame i up to the next adopted fall and the keyframes among them. Returns the rebuilt model when a join
    moved, else None."""
    from service.tracking.resettle import base_shift

    adopted = [ld for ld in landings if ld.adopted]
    moved = False
    for k, ld in enumerate(adopted):
        i = ld.i
        end = adopted[k + 1].g0 if k + 1 < len(adopted) else len(X)
        seg = [j for j in range(i, end) if tracked[j] and len(obs[j].P_W) >= cfg.min_points]
        seg = seg[: cfg.resettle_refine_frames]
        pre = [kf for kf in keyframes if kf.index < ld.g0]
        if len(seg) < 3 or not pre:
            continue
        fall = _fall_base(session, X[ld.g0], X[i], X[0], pre, cfg)
        if fall is None:
            continue
        f, _, B = fall
        B_W = B @ X[i][:3, :3].T + X[i][:3, 3]
        view = FreeSpace(session.K, session.X_WC, 0.003, 1)
        X_iinv = X_inv(X[i])
        for j in seg:
            view.add(j, session.depth(j), X[j] @ X_iinv)  # the join's W carried to frame j's W
        s = base_shift(B_W, view.seen_through, f, cfg.resettle_max_shift)
        if s <= 0.0:
            continue
        T = np.eye(4)
        T[:3, 3] = s * f
        for j in range(i, end):
            X[j] = T @ X[j]
        for kf in keyframes:
            if i <= kf.index < end:
                _place_keyframe(kf, T @ kf.X_WO, carver)
        moved = True
    return _model_from(keyframes, cfg.model_voxel) if moved else None


def _resettle_flush(session, obs: list[FrameObs], X: np.ndarray, tracked: np.ndarray, frac: np.ndarray,
                    rmse: np.ndarray, keyframes: list[Keyframe], carver: "FreeSpace | None", landings: list,
                    cfg: TrackingConfig) -> ObjectModel | None:
    """The settled stretch after every topple landing checked (``_resettle_check``, adopted or not): from its
    settled frame i up to the next landing's fall. The face of the pre-fall model (keyframes before the fall) that
    lies on the table at X[i] (``resettle.landed_face``; within ``resettle_flush_square_deg`` made square to the base
    the object stood on at frame 0) is laid flush with the table (``resettle.flush_pose``) in every frame of the stretch
    whose pose has it within ``resettle_flush_deg`` of flat (an object at rest on a face has it on the table; when
    the pre-fall model has no such face, only the base it stood on is made vertical, ``resettle.side_pose``; a body
    with neither a flat side nor a flat face where it lies (``resettle.rests_flat``), such
    as an egg, is left as it is); the
    stretch's keyframes move with their frames and the model is rebuilt (the surface seen after the landing placed by
    the constrained poses); then every such frame is registered again in the motions that keep it resting
    (``resettle.planar_register``: a turn about the vertical and a horizontal shift) and counts as tracked when that
    is a good registration. With ``resettle_flush_rest_tol`` > 0 and frame i laid flush, the frames before i at rest
    with it (``_rest_before``) take frame i's pose moved by the small rigid motion their keypoints show (first the
    flushed pose, for the model; then the final one): not registered themselves, since a box that may still slide
    along its own faces is seen by its print, not by its shape. Updates X, tracked, frac, rmse, keyframes and carver
    in place; returns the rebuilt model, or None when no frame changed."""
    from service.tracking.geometry import icp_result
    from service.tracking.resettle import (box_rest_face, down_pose, flush_pose, landed_face, planar_register,
                                           rests_flat, side_pose)

    base_n = X[0][:3, :3].T @ np.array([0.0, 0.0, -1.0])
    done: list[int] = []
    rest: list[tuple[int, np.ndarray, int]] = []  # (frame at rest before a settled frame i, its motion from i, i)
    for ld in landings:
        i = ld.i
        end = min([l.g0 for l in landings if l.g0 > i], default=len(X))
        pre = [kf for kf in keyframes if kf.index < ld.g0]
        if not pre or not tracked[i]:
            continue
        M = _model_from(pre, cfg.model_voxel)
        down = X[i][:3, :3].T @ np.array([0.0, 0.0, -1.0])  # the face it lies on, in O
        if not rests_flat(M.Q, M.N, base_n, down):
            continue  # a curved body (an egg): no flat face to rest on
        face = landed_face(M.Q, M.N, X[i], session.table_height, tol=0.03, base_n_O=base_n,
                           square_deg=cfg.resettle_flush_square_deg)
        box = None  # the face it lies on, never seen, from a box's sides (resettle_box_flush)
        if face is None and cfg.resettle_box_flush:
            box = box_rest_face(M.Q, M.N, base_n, down)
        for j in range(i, end):
            if not tracked[j] or len(obs[j].P_W) < cfg.min_points:
                continue
            if face is not None:
                Xf, tilt = flush_pose(X[j], face[0], face[1], session.table_height)
            elif box is not None:  # a box on a side it never showed: that side flat on the table
                Xf, tilt = down_pose(X[j], M.Q, box)
            else:  # the face it lies on was never seen: only its base, vertical on a side
                Xf, tilt = side_pose(X[j], M.Q, base_n)
            if tilt > cfg.resettle_flush_deg:
                continue  # not resting on that face
            X[j] = Xf
            done.append(j)
        if cfg.resettle_flush_rest_tol > 0 and i in done:  # the frames at rest before i (laid flush): from frame i
            rest += [(j, Mj, i) for j, Mj in _rest_before(obs, i, ld.g0, cfg)]
    if not done:
        return None
    for j, Mj, i in rest:
        X[j] = Mj @ X[i]
    moved = set(done) | {j for j, _, _ in rest}
    for kf in keyframes:
        if kf.index in moved:
            _place_keyframe(kf, X[kf.index].copy(), carver)
    model = _model_from(keyframes, cfg.model_voxel)
    for j in done if cfg.resettle_flush_planar else []:
        Xp = planar_register(obs[j].P_W, X[j], model.Q, model.N, model.tree)
        r = icp_result(X_inv(Xp), obs[j].P_W, model.tree, model.Q, model.N, cfg.inlier_dist)
        X[j], frac[j], rmse[j] = r.X_WO, r.inlier_frac, r.rmse
        tracked[j] = _good(r, cfg)
    for j, Mj, i in rest:  # frame i's final pose moved by the motion the print shows
        r = icp_result(X_inv(Mj @ X[i]), obs[j].P_W, model.tree, model.Q, model.N, cfg.inlier_dist)
        X[j], frac[j], rmse[j] = r.X_WO, r.inlier_frac, r.rmse
        tracked[j] = tracked[i]
    return model


def _end_points(session, j: int, cfg: TrackingConfig, step: int = 2) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(P_W (N,3) in W, depth (H,W) m, mask (H,W) bool) of frame j: the object's depth points of every ``step``-th
    pixel of the mask (not eroded, not subsampled at random: the mask's outline is what is measured), without flying
    pixels, the table within ``table_clearance`` and the robot's end-effector (as ``observe``)."""
    depth, mask = session.depth(j), session.mask(j).astype(bool)
    v, u = np.nonzero(mask & (depth > 0))
    keep = (u % step == 0) & (v % step == 0)
    u, v = u[keep], v[keep]
    good = depth_continuous(depth, u, v, cfg.edge_jump)
    P_W = backproject(depth, session.K, u[good], v[good]) @ session.X_WC[:3, :3].T + session.X_WC[:3, 3]
    P_W = P_W[(P_W[:, 2] > session.table_height + cfg.table_clearance) & ~near_effector(session, j, P_W, cfg)]
    return P_W, depth, mask


def _end_extents(session, X: np.ndarray, frames: list[int], h: np.ndarray, cfg: TrackingConfig,
                 each: bool = False, standing: bool = False, cache: dict | None = None) -> np.ndarray:
    """(len(frames), 2): per frame j the extent (lo, hi) along the unit body direction h (3,, in O) of frame j's mask
    depth points (``_end_points``) carried into O by X[j] (``resettle.axis_extent``); a row of NaN when the frame has
    fewer than ``min_points`` points or one of its two ends is not seen (``resettle.end_seen``: cut by something
    nearer the camera beyond it, or leaving the image). With ``each`` only the column of the end not seen is NaN
    (lo: the end toward −h, hi: toward +h). With ``standing`` (h the up axis of a box on its base) only the top end is
    tested and lo is the table under the base (``resettle.table_end``: the lower part is dropped with the table
    clearance or hidden). ``cache`` (frame → ``_end_points``' output), when given, is read and filled so that a frame
    measured along two directions is read once."""
    from service.tracking.resettle import axis_extent, end_seen, table_end

    out = np.full((len(frames), 2), np.nan)
    for k, j in enumerate(frames):
        pts = cache.get(j) if cache is not None else None
        if pts is None:
            pts = _end_points(session, j, cfg)
            if cache is not None:
                cache[j] = pts
        P_W, depth, mask = pts
        if len(P_W) < cfg.min_points:
            continue
        h_W = X[j][:3, :3] @ h
        if standing:
            if end_seen(P_W, h_W, depth, mask, session.K, session.X_WC, session.table_height):
                out[k] = axis_extent(P_W, X[j], h)
                out[k, 0] = table_end(X[j], h, session.table_height)
            continue
        seen = [end_seen(P_W, sgn * h_W, depth, mask, session.K, session.X_WC, session.table_height)
                for sgn in (-1.0, 1.0)]
        if all(seen) or (each and any(seen)):
            out[k] = np.where(seen, axis_extent(P_W, X[j], h), np.nan)
    return out


def _resettle_axis(session, X: np.ndarray, tracked: np.ndarray, keyframes: list[Keyframe],
                   carver: "FreeSpace | None", landings: list, cfg: TrackingConfig, stride: int = 2
                   ) -> ObjectModel | None:
    """The settled stretch of every landing checked (as ``_resettle_flush``: settled frame i up to the next fall)
    moved along the box's tip axis so that its ends lie where the frames before the fall saw them
    (``resettle_box_axis``), and along its up axis, which the topple lays along the tipping direction
    (``resettle_box_slide``). A topple turns the box about an axis along one of its sides, h; nothing seen both before
    and after the landing fixes its position along h, nor the landing's slide beyond the pure turn along the tipping
    direction f, but the settled frames see the box's two ends along h and, in some views, along f (the extreme of the
    mask's depth points), and their middle is one point of the rigid box. The axis: the turn from frame 0 to X[i] about
    its axis, made perpendicular to the base normal and taken to the box's side direction nearest it
    (``resettle.box_face`` of the pre-fall model; no box, no shift); the up axis u is the base normal's opposite (the
    standing box's height, lying along f after the turn). Every ``stride``-th tracked frame before the fall (from the
    previous settled frame) and of the stretch: the extent in O (``axis_extent``), kept when both ends are seen
    (``end_seen``); before the fall the extent along u runs from the table under the base (``table_end``: the lower
    part is dropped with the table clearance or hidden) to the top, only its top end tested. ``axis_shift`` gives one
    shift per direction for the stretch or refuses it (along u: settled lengths up to ``resettle_box_slide_short``
    shorter than the standing height, since the reference's base end is exact and both settled ends are outlines,
    counted in at least ``resettle_box_slide_frac`` of the settled frames, at least ``resettle_box_slide_min``: the
    middle of two outlines is biased by half the difference of what each loses). Every frame of the stretch then moves by
    the shifts in W (X_WO's translation only), its keyframes with it, and the model is rebuilt. Updates X, keyframes
    and carver in place; returns the rebuilt model, or None when nothing moved."""
    from service.tracking.resettle import axis_shift, box_face, moved_along

    base_n = X[0][:3, :3].T @ np.array([0.0, 0.0, -1.0])
    moved: list[int] = []
    start = 0
    for ld in sorted(landings, key=lambda l: l.i):
        i, g0 = ld.i, ld.g0
        end = min([l.g0 for l in landings if l.g0 > i], default=len(X))
        pre = [kf for kf in keyframes if kf.index < g0]
        ref_frames = [j for j in range(start, g0, stride) if tracked[j]]
        start = i
        if not pre or not tracked[i] or not ref_frames:
            continue
        a = so3_log(X[0][:3, :3].T @ X[i][:3, :3])
        a = a - (a @ base_n) * base_n
        if np.linalg.norm(a) < 1e-6:
            continue
        M = _model_from(pre, cfg.model_voxel)
        side = box_face(M.Q, M.N, a / np.linalg.norm(a), base_n)
        if side is None:
            continue  # not a box
        h = side[0]
        points: dict[int, tuple] = {}  # frame -> _end_points, read once for both directions

        def ends(frames: list[int], d: np.ndarray, standing: bool = False) -> np.ndarray:
            return _end_extents(session, X, frames, d, cfg, standing=standing, cache=points)

        stretch = [j for j in range(i, end) if tracked[j]]
        shifts = []
        if cfg.resettle_box_axis:
            shifts.append((h, axis_shift(ends(ref_frames, h), ends(stretch[::stride], h))))
        if cfg.resettle_box_slide:
            u = -base_n
            shifts.append((u, axis_shift(ends(ref_frames, u, standing=True), ends(stretch[::stride], u),
                                         len_short=cfg.resettle_box_slide_short,
                                         min_frac=cfg.resettle_box_slide_frac,
                                         min_shift=cfg.resettle_box_slide_min)))
        shifts = [(d, sh) for d, sh in shifts if sh is not None]
        if not shifts:
            continue
        for j in range(i, end):
            for d, sh in shifts:
                X[j] = moved_along(X[j], d, sh)
            moved.append(j)
    if not moved:
        return None
    moved_set = set(moved)
    for kf in keyframes:
        if kf.index in moved_set:
            _place_keyframe(kf, X[kf.index].copy(), carver)
    return _model_from(keyframes, cfg.model_voxel)


def _lying_axis(session, X: np.ndarray, tracked: np.ndarray, model: ObjectModel, spin: "SpinResult",
                keyframes: list[Keyframe], carver: "FreeSpace | None", cfg: TrackingConfig, stride: int = 2
                ) -> ObjectModel | None:
    """Every stretch in which a body of revolution that stood on its base at frame 0 lies on the table
    (``lying.lying_frames`` of ``lying.lying_geometry``, runs of ``lying.lying_runs``) moved along its axis a = ẑ_O so
    that the ends its mask shows lie at the model's ends (``lying.axis_end_shift``, shortfall ``lie_axis_short``): the
    base plane where the table was at frame 0, the top at the median extreme along a of the standing frames (every
    ``stride``-th tracked frame before the first stretch with a within ``lie_level_stand_deg`` of the vertical and its
    top seen). Per stretch, every ``stride``-th lying frame's extent along a with each end kept only where it is seen
    (``_end_extents``), its offset (``lying.axis_end_offsets``) and the running median of the offsets over
    ± ``lie_axis_window`` frames (``lying.axis_end_shift``), or no shift for the stretch. Every frame of the stretch
    moves by its shift (linear between the measured frames) along a in W (translation only,
    ``resettle.moved_along``), its keyframes by the same shift from their own poses (the spin closure and the
    levelling turned the frames, not the keyframes), and the model is rebuilt. Updates X, keyframes and
    carver in place; returns the rebuilt model, or None when nothing moved."""
    from service.tracking.lying import axis_end_offsets, axis_end_shift, lying_frames, lying_geometry, lying_runs
    from service.tracking.resettle import moved_along

    if spin is None or not spin.is_revolution:
        return None
    Q_lying = _lying_points(keyframes, cfg) if cfg.lie_level_views and keyframes else None
    geo = lying_geometry(model.Q, spin.axis_O, cfg.lie_level_stand_deg, Q_lying)
    if geo is None:
        return None
    a, p_O, radius = geo
    lying = lying_frames(X, a, p_O, radius, session.table_height, lie_deg=cfg.lie_level_deg,
                         margin=cfg.lie_level_margin) & tracked
    runs = lying_runs(lying)
    if not runs:
        return None
    base = session.table_height - float(X[0][:3, 3] @ (X[0][:3, :3] @ a))
    stand = [j for j in range(0, runs[0][0], stride)
             if tracked[j] and _axis_tilt(X[j], a) <= cfg.lie_level_stand_deg]
    tops = _end_extents(session, X, stand, a, cfg, each=True)[:, 1]
    tops = tops[np.isfinite(tops)]
    top = float(np.median(tops)) if len(tops) >= 3 else None
    moved: dict[int, float] = {}  # frame -> its shift along a (m)
    for s, e in runs:
        frames = [j for j in range(s, e) if lying[j]][::stride]
        c = axis_end_offsets(base, top, _end_extents(session, X, frames, a, cfg, each=True), cfg.lie_axis_short,
                             cfg.lie_axis_len_tol)
        shift = axis_end_shift(c, np.array(frames), window=cfg.lie_axis_window, spread_tol=cfg.lie_axis_spread,
                               min_shift=cfg.lie_axis_min_shift)
        if shift is None:
            continue
        for j, sh in zip(range(s, e), np.interp(np.arange(s, e), frames, shift)):
            X[j] = moved_along(X[j], a, float(sh))
            moved[j] = float(sh)
    if not moved:
        return None
    for kf in keyframes:  # moved by the frame's shift from their own pose (the closures did not turn the keyframes)
        if kf.index in moved:
            _place_keyframe(kf, moved_along(kf.X_WO, a, moved[kf.index]), carver)
    return _model_from(keyframes, cfg.model_voxel)


def _rest_before(obs: list[FrameObs], i: int, g0: int, cfg: TrackingConfig) -> list[tuple[int, np.ndarray]]:
    """The frames j (g0 < j < i, increasing) before the settled frame i at rest with it, walking back from i to the
    first frame that moved or has fewer than ``min_points`` points, each with the motion M (4,4, in W) from frame i
    to it shown by the keypoints (``geometry.ransac_rigid``, inlier distance ``resettle_flush_rest_ransac``:
    X_WO(j) = M X_WO(i)). At rest: its object points lie on
    frame i's (``resettle.still_fit``: at least ``resettle_flush_rest_frac`` within 1 cm, median point-to-plane
    distance within ``resettle_flush_rest_tol``) and its ORB keypoints matched to frame i's (at least
    ``resettle_flush_rest_matches``) lie within ``resettle_flush_rest_shift`` of their partners (median, in W): the
    surface test alone misses a box sliding or turning about the vertical within its own faces' planes (a frame
    3.9° / 15 mm from rest with a 1.0 mm median), the print does not. A frame whose keypoints give no motion
    (fewer than 6 inliers) ends the walk."""
    from scipy.spatial import cKDTree

    from service.tracking.resettle import still_fit

    P_i, N_i = obs[i].P_W, obs[i].N_W
    if len(P_i) < cfg.min_points:
        return []
    tree = cKDTree(P_i)
    out: list[tuple[int, np.ndarray]] = []
    for j in range(i - 1, g0, -1):
        o = obs[j]
        if len(o.P_W) < cfg.min_points:
            break
        frac, d = still_fit(o.P_W, P_i, N_i, tree)
        if frac < cfg.resettle_flush_rest_frac or d > cfg.resettle_flush_rest_tol:
            break
        m = _match(o.desc, obs[i].desc)
        if len(m) < cfg.resettle_flush_rest_matches:
            break
        A, B = obs[i].kp_W[m[:, 1]], o.kp_W[m[:, 0]]
        if np.median(np.linalg.norm(B - A, axis=1)) > cfg.resettle_flush_rest_shift:
            break
        Mj, _ = ransac_rigid(A, B, cfg.resettle_flush_rest_ransac)
        if Mj is None:
            break
        out.append((j, Mj))
    return out[::-1]


def _settle_backward(session, obs: list[FrameObs], X: np.ndarray, tracked: np.ndarray, frac: np.ndarray,
                     rmse: np.ndarray, model: ObjectModel, landings: list, cfg: TrackingConfig, icp_kw: dict) -> None:
    """The frames g0…i−1 of every adopted landing registered backwards from the settled frame i against ``model``
    (starts: the next frame's pose and the backward constant-velocity prediction), and from their forward pose; the
    better consistent fit wins, a frame with none is lost. With ``resettle_tip_tol`` > 0 the tipping path is one
    more start and decides among the fits that are nearly as good (``_tip_poses``, ``_on_path``). Updates X,
    tracked, frac, rmse in place."""
    from service.tracking.resettle import path_keys

    Q = model.Q[:: max(1, len(model.Q) // 4000)]
    for ld in landings:
        if not ld.adopted:
            continue
        poses = _tip_poses(session, X, tracked, ld, model, cfg) if cfg.resettle_tip_tol > 0 else None
        for j in range(ld.i - 1, ld.g0 - 1, -1):
            o = obs[j]
            if len(o.P_W) < cfg.min_points:
                tracked[j] = False
                continue
            consistent = _consistent_in(session, j, Q, cfg)
            starts = [X[j]]
            if tracked[j + 1]:
                starts.append(X[j + 1])
                if j + 2 < len(X) and tracked[j + 2]:
                    starts.append(X[j + 1] @ (X_inv(X[j + 2]) @ X[j + 1]))
            if poses:  # the path pose the frame's points fit best, among those consistent with its view
                keys = path_keys(o.P_W, poses, model.tree, cfg.inlier_dist)
                k = next((k for k in sorted(range(len(poses)), key=lambda k: keys[k], reverse=True)
                          if consistent(poses[k])), None)
                if k is not None:
                    starts.append(poses[k])
            best, best_ok, fits = None, False, []
            for Xs in starts:
                r = icp(o.P_W, Xs, model.tree, model.Q, model.N, **{**icp_kw, "dist0": 0.02})
                ok = _good(r, cfg) and consistent(r.X_WO)
                fits.append((r, ok))
                if best is None or (ok and not best_ok) or (ok == best_ok and _better(r, best)):
                    best, best_ok = r, ok
            if poses and best_ok:
                best = _on_path([r for r, ok in fits if ok], poses, cfg)
            X[j], frac[j], rmse[j] = best.X_WO, best.inlier_frac, best.rmse
            tracked[j] = best_ok


def _on_path(fits: list[IcpResult], poses: list[np.ndarray], cfg: TrackingConfig) -> IcpResult:
    """Among the (consistent, good) registrations ``fits`` whose score is within ``resettle_tip_tol`` of the best,
    the one nearest to the tipping path ``poses`` (``resettle.path_offset``): where a few faces of a box fit a
    range of poses equally (a face turning within its own plane, half the body hidden), the motion the table
    imposes decides."""
    from service.tracking.resettle import path_offset

    top = max(_fit_score(r) for r in fits)
    near = [r for r in fits if _fit_score(r) >= top - cfg.resettle_tip_tol]
    return min(near, key=lambda r: path_offset(r.X_WO, poses, cfg.resettle_tip_m_deg))


def _tip_poses(session, X: np.ndarray, tracked: np.ndarray, ld, model: ObjectModel, cfg: TrackingConfig
               ) -> list[np.ndarray] | None:
    """The poses X_WO (every degree) of the topple of landing ``ld`` as a turn about its leading bottom edge
    (``resettle.tip_path``): from the last tracked frame a before the fall's start g0 to the settled frame i, about
    the edge of the object's base (``resettle.base_points`` of ``model`` under frame 0's pose, placed at X[a]) at
    its extent along the tipping direction, on the table (``resettle.leading_pivot``). None without a tracked frame
    before g0, a horizontal turn or 30 base points."""
    from service.tracking.resettle import base_points, leading_pivot, tip_direction, tip_path

    a = next((k for k in range(ld.g0 - 1, -1, -1) if tracked[k]), None)
    tip = tip_direction(X[a], X[ld.i]) if a is not None else None
    if tip is None:
        return None
    f, turn = tip
    B = base_points(model.Q, X[0], session.table_height)
    if len(B) < 30:
        return None
    path = tip_path(X[a], X[ld.i], leading_pivot(B @ X[a][:3, :3].T + X[a][:3, 3], f, session.table_height))
    n = max(2, int(np.ceil(np.degrees(turn))))
    return [path(k / n) for k in range(n + 1)]


def _spin_tau(model: ObjectModel, cfg: TrackingConfig) -> float:
    """The threshold of the body-of-revolution test for this model: ``spin_tau``, raised just above the model's own
    score when it covers only a part of a body of revolution (``spin.partial_tau``, with ``spin_arc_tau`` > 0)."""
    if cfg.spin_arc_tau > 0:
        from service.tracking.spin import partial_tau

        return partial_tau(model.Q, model.N, cfg.spin_tau, cfg.spin_sep, cfg.spin_arc_tau)
    return cfg.spin_tau


def _spin_closure(obs: list[FrameObs], X: np.ndarray, model: ObjectModel, cfg: TrackingConfig,
                  table_z: float | None = None) -> "SpinResult":
    """Re-estimate the spin about the symmetry axis of a body of revolution (``service.tracking.spin``) and apply
    it to X (N,4,4) in place; nothing changes when the model is not a body of revolution or has no texture.
    ``table_z``: the table height (m), for the cap of a body that rolls on the table (``spin_cap_roll``)."""
    from service.tracking.spin import apply_spin, find_axis, spin_closure

    tau = _spin_tau(model, cfg)
    axis = find_axis(model.Q, model.N, tau, cfg.spin_sep, cfg.spin_profile)  # (is_revolution, λ̂, a, c), fitted once
    by_kappa = False
    if not axis[0] and cfg.spin_sep_kappa > 0:  # a short open cup: its tilts as weak as its spin (spin.kappa_sep_axis)
        from service.tracking.spin import kappa_sep_axis

        axis = kappa_sep_axis(model.Q, model.N, cfg.spin_sep_kappa, cfg.spin_arc_tau)
        by_kappa = axis[0]
    refused = _flat_faced(model, cfg, axis, len(X))  # a prism the axis test took for a body of revolution
    if refused is not None:
        return refused
    empty = (np.zeros((0, 3)), None)
    feats = [o.spin_feats if o.spin_feats is not None and len(o.P_W) >= cfg.min_points else empty for o in obs]
    cap = _spin_cap(X, model, axis, table_z, cfg)
    common = dict(tau=cfg.spin_tau, tol=cfg.spin_tol, inlier_deg=cfg.spin_inlier_deg,
                  smooth=1 if cfg.spin_twist_smooth > 1 else cfg.spin_smooth,  # twist filtered instead (below)
                  match=_match, sep=cfg.spin_sep, profile=cfg.spin_profile, max_deg=cap)
    common["tau"] = tau
    common["axis"] = axis
    graph = dict(gate_deg=cfg.spin_graph_gate_deg, n_short=cfg.spin_graph_short, rate_deg=cfg.spin_graph_rate_deg,
                 long_votes=cfg.spin_graph_long_votes)
    if cfg.spin_fall and cfg.spin_solver == "mixed":  # the mixed estimate, no spin in topples
        res = _spin_fall(feats, X, model, cfg, common, graph)
    elif cfg.spin_solver == "mixed":  # the chain, the graph's increments over fast stretches (spin.spin_mixed)
        from service.tracking.spin import spin_mixed

        res = spin_mixed(feats, X, model.Q, model.N, min_votes=cfg.spin_min_votes, graph_votes=cfg.spin_graph_votes,
                         fast_span=cfg.spin_mixed_span, fast_rate_deg=cfg.spin_mixed_rate_deg,
                         fast_dilate=cfg.spin_mixed_dilate, fast_votes=cfg.spin_mixed_votes, **common, **graph)
    else:  # the per-frame chain (spin.spin_closure)
        res = spin_closure(feats, X, model.Q, model.N, min_votes=cfg.spin_min_votes, **common)
    if cfg.spin_twist_smooth > 1:  # the body's twist median-filtered instead of the correction (spin.smooth_twist)
        from service.tracking.spin import smooth_twist

        res = smooth_twist(res, X, cfg.spin_twist_smooth, cap)
    if cfg.spin_pivot_deg > 0:  # the tilts of a pivot bridged without spin (service/tracking/fall.py)
        res = _spin_pivot(res, X, cfg, cap)
    if by_kappa:
        from dataclasses import replace as _replace

        res = _replace(res, by_kappa=True)
    X[:] = apply_spin(X, res)
    return res


def _spin_cap(X: np.ndarray, model: ObjectModel, axis: tuple, table_z: float | None, cfg: TrackingConfig
              ) -> float:
    """The cap (deg) of the spin correction of the poses X (N,4,4): ``spin_max_deg``, raised with ``spin_cap_roll`` by
    the roll of a body of revolution lying on the table that the poses do not show as a turn (``lying.unseen_roll``
    with the ``lie_level_*`` geometry; ``axis``: ``spin.find_axis``'s result): the depth fit cannot see a lying body
    of revolution roll (its surface maps onto itself), so the tracked poses may miss all of it while the axis' travel
    across itself measures it. ``spin_max_deg`` itself when the option is off, there is no cap (0), the model is not a
    body of revolution or the table height is not known."""
    if not cfg.spin_cap_roll or cfg.spin_max_deg <= 0 or not axis[0] or table_z is None:
        return cfg.spin_max_deg
    from service.tracking.lying import unseen_roll

    roll = unseen_roll(X, model.Q, table_z, axis[2], stand_deg=cfg.lie_level_stand_deg, lie_deg=cfg.lie_level_deg,
                       margin=cfg.lie_level_margin)
    return cfg.spin_max_deg + float(np.degrees(roll))


def _flat_faced(model: ObjectModel, cfg: TrackingConfig, axis: tuple, n: int) -> "SpinResult | None":
    """The spin result (n frames) of a model that ``axis`` (``spin.find_axis``'s result with the tracker's settings)
    takes for a body of revolution but whose normals leave the meridian planes about it by κ ≥ ``spin_flat_kappa``
    (``spin.flat_faced``): not a body of revolution, no correction, as when the axis test refuses a model; None when
    the closure proceeds (always when the setting is 0)."""
    from service.tracking.spin import SpinResult, flat_faced

    if not flat_faced(model.Q, model.N, axis, cfg.spin_flat_kappa):
        return None
    return SpinResult(False, axis[1], np.zeros(3), np.zeros(3), np.zeros(n), np.zeros(n, int), False)


def _spin_pivot(res: "SpinResult", X: np.ndarray, cfg: TrackingConfig, cap: float | None = None) -> "SpinResult":
    """``res`` with the tilts of a pivot of the poses X (N,4,4) (``fall.pivot_runs``: the axis leaves its direction
    of frame 0 by ``spin_pivot_deg``, less than ``spin_fall_min_deg``, for a body standing at frame 0) bridged without
    spin about the axis (``fall.pivot_bridge``); unchanged for a body that is not one of revolution or a rejected
    correction. A textureless body (``observable`` False, θ = 0) is bridged too: the physics does not need the print
    (its ``observable`` flag, about the texture, is kept). ``cap``: the cap of the correction (deg; None:
    ``spin_max_deg``)."""
    from dataclasses import replace as _replace

    from service.tracking.fall import pivot_bridge, pivot_runs

    if not res.is_revolution or res.rejected:
        return res
    tilts = pivot_runs(X, res.axis_O, cfg.spin_pivot_deg, cfg.spin_fall_edge_deg, cfg.spin_fall_min_deg,
                       cfg.lie_level_stand_deg)
    if not tilts:
        return res
    theta, used = pivot_bridge(res.theta, X, res.axis_O, tilts, cfg.spin_fall_tol_deg)
    if not used.any():
        return res
    cap = cfg.spin_max_deg if cap is None else cap
    if cap > 0 and np.max(np.abs(theta)) > np.radians(cap):
        return res  # as a correction above spin_max_deg anywhere: not applied (spin._finish)
    return _replace(res, theta=theta)


def _level_lying(X: np.ndarray, model: ObjectModel, spin: "SpinResult", table_z: float, cfg: TrackingConfig,
                 keyframes: list[Keyframe] | None = None) -> None:
    """``lying.level_lying`` with the tracker's settings on the poses X (N,4,4), in place: the frames in which a body
    of revolution that stood on its base at frame 0 lies on the table get its axis parallel to the table. With
    ``lie_level_views`` the points of the ``keyframes`` that lie are passed on (``_lying_points``)."""
    if spin is None or not spin.is_revolution:
        return
    from service.tracking.lying import level_lying

    Q_lying = _lying_points(keyframes, cfg) if cfg.lie_level_views and keyframes else None
    X[:], _ = level_lying(X, model.Q, table_z, spin.axis_O, stand_deg=cfg.lie_level_stand_deg,
                          lie_deg=cfg.lie_level_deg, margin=cfg.lie_level_margin, max_deg=cfg.lie_level_max_deg,
                          Q_lying=Q_lying)


def _lying_points(keyframes: list[Keyframe], cfg: TrackingConfig) -> np.ndarray:
    """(M,3) in O: the points of the keyframes whose pose has ẑ_O (the axis of a body that stood on its base at frame
    0) within ``lie_level_deg`` of the horizontal — the views of the body lying on the table (``lying.lying_geometry``
    seeks the straight stretch in them when the merged model has none)."""
    z = np.array([0.0, 0.0, 1.0])
    s = np.sin(np.radians(cfg.lie_level_deg))
    parts = [kf.P_O for kf in keyframes if abs((kf.X_WO[:3, :3] @ z)[2]) <= s]
    return np.vstack(parts) if parts else np.zeros((0, 3))


def _spin_tilt(obs: list[FrameObs], X: np.ndarray, model: ObjectModel, spin: "SpinResult", cfg: TrackingConfig
               ) -> "TiltResult | None":
    """``tilt.tilt_closure`` with the tracker's settings, applied to X (N,4,4) in place, when the spin closure found
    an egg-like body (its axis from the radius profile: the eigen-axis failed the separation test), applied its
    correction, and the model is longer along that axis than across it (``tilt.prolate``); None otherwise."""
    from service.tracking.spin import revolution_axis
    from service.tracking.tilt import apply_tilt, prolate, tilt_closure

    if spin is None or not spin.is_revolution or spin.rejected or not spin.observable or spin.by_kappa:
        return None  # (a cup taken by the κ separation has a definite axis: not an egg)
    if revolution_axis(model.Q, model.N, _spin_tau(model, cfg), cfg.spin_sep)[0]:  # one clearly weakest rotation
        return None
    if not prolate(model.Q, spin.axis_O, spin.point_O):
        return None
    empty = (np.zeros((0, 3)), None)
    feats = [o.spin_feats if o.spin_feats is not None and len(o.P_W) >= cfg.min_points else empty for o in obs]
    res = tilt_closure(feats, X, model.Q, spin.axis_O, spin.point_O, match=_match, voted=spin.votes > 0,
                       tol=cfg.spin_tol, min_votes=cfg.spin_min_votes, smooth=cfg.spin_smooth,
                       reach=cfg.spin_tilt_reach)
    X[:] = apply_tilt(X, res)
    return res


def _spin_fall(feats: list, X: np.ndarray, model: ObjectModel, cfg: TrackingConfig, common: dict, graph: dict):
    """``fall.spin_fall`` with the tracker's settings: the mixed spin estimate, with no spin about the axis over the
    topples where the texture lagged (service/tracking/fall.py)."""
    from service.tracking.fall import spin_fall

    res, _ = spin_fall(feats, X, model.Q, model.N, min_votes=cfg.spin_min_votes, graph_votes=cfg.spin_graph_votes,
                       fast_span=cfg.spin_mixed_span, fast_rate_deg=cfg.spin_mixed_rate_deg,
                       fast_dilate=cfg.spin_mixed_dilate, fast_votes=cfg.spin_mixed_votes,
                       fall_rate_deg=cfg.spin_fall_rate_deg, fall_min_deg=cfg.spin_fall_min_deg,
                       fall_edge_deg=cfg.spin_fall_edge_deg, fall_tol_deg=cfg.spin_fall_tol_deg, **common, **graph)
    return res


def _refine_keyframes(keyframes: list[Keyframe], cfg: TrackingConfig, carver: "FreeSpace | None", icp_kw: dict,
                      X: np.ndarray | None = None) -> None:
    """One leave-one-out round: every keyframe but the first registered (its points P_W, from its pose X_WO) to the
    model of the others, its correspondence radius starting at ``refine_dist0`` (m) and shrinking to
    ``icp_dist_min``; a good registration (``_good``) gives it its new pose (``_place_keyframe``). In place.
    With ``refine_slow_deg`` > 0 and the tracked poses X (N,4,4; X_WO per frame), a keyframe taken in slow motion
    (``_slow_keyframe``) starts at ``refine_slow_dist0`` instead."""
    for k in range(1, len(keyframes)):
        others = _model_from([kf for j, kf in enumerate(keyframes) if j != k], cfg.model_voxel)
        kf = keyframes[k]
        d0 = cfg.refine_dist0
        if cfg.refine_slow_deg > 0 and X is not None and _slow_keyframe(X, kf.index, cfg):
            d0 = cfg.refine_slow_dist0
        r = icp(kf.P_W, kf.X_WO, others.tree, others.Q, others.N, **{**icp_kw, "dist0": d0})
        if _good(r, cfg):
            _place_keyframe(kf, r.X_WO, carver)


def _slow_keyframe(X: np.ndarray, i: int, cfg: TrackingConfig) -> bool:
    """Whether frame i was taken in slow motion: the tracked poses X (N,4,4; X_WO) of frames i − refine_slow_frames
    … i + refine_slow_frames (clipped to the session) turn by at most ``refine_slow_deg`` (degrees) from each frame
    to the next; with ``refine_slow_from_start`` from frame 0 on (no fast turn before the keyframe either)."""
    a = 0 if cfg.refine_slow_from_start else max(0, i - cfg.refine_slow_frames)
    b = min(len(X) - 1, i + cfg.refine_slow_frames)
    return all(pose_distance(X[j], X[j + 1])[1] <= cfg.refine_slow_deg for j in range(a, b))


def _regauge(o0: FrameObs, X: np.ndarray, model: ObjectModel, keyframes: list[Keyframe], carver: "FreeSpace | None",
             cfg: TrackingConfig, icp_kw: dict, obs: list[FrameObs] | None = None,
             tracked: np.ndarray | None = None, session=None) -> ObjectModel:
    """Register frame 0 to the final model like every other frame (pose X̂_0 of the model frame M) and move
    the body frame so that X_WO(0) keeps its definition X_0 (identity rotation, centroid origin):
    X_WO(i) ← X_WO(i) D with D = X̂_0⁻¹ X_0 = X_MO, model and keyframe points p_O = D⁻¹ p_M. Otherwise a
    mismatch between frame 0's own points and the merged model of all keyframes would be an offset common to
    all other frames.
    Updates X, keyframes and carver in place; returns the model in the new frame.
    With ``gauge_frames`` X̂_0 is the robust mean over frame 0 and the frames at rest before the robot reaches the
    object (``service.tracking.gauge``)."""
    if len(o0.P_W) < cfg.min_points:
        return model
    r = icp(o0.P_W, X[0], model.tree, model.Q, model.N,
            **{**icp_kw, "dist0": 0.012, "iters": cfg.final_iters})
    X0_hat = r.X_WO if _good(r, cfg) else None
    if cfg.gauge_frames > 0 and obs is not None and tracked is not None and session is not None:
        X0_hat = _gauge_from_early(session, X0_hat, X, obs, tracked, model, cfg)
    if X0_hat is None:
        return model
    D = X_inv(X0_hat) @ X[0]
    Di = X_inv(D)
    X[1:] = X[1:] @ D
    for kf in keyframes:
        kf.X_WO = kf.X_WO @ D  # keyframe 0 included: its points were placed with the old X_WO(0)
        kf.P_O = kf.P_O @ Di[:3, :3].T + Di[:3, 3]
        kf.kp_O = kf.kp_O @ Di[:3, :3].T + Di[:3, 3]
        if carver is not None:
            carver.update_pose(kf.index, kf.X_WO)
    return _model_from(keyframes, cfg.model_voxel)


def _gauge_from_early(session, X0_hat: np.ndarray | None, X: np.ndarray, obs: list[FrameObs], tracked: np.ndarray,
                      model: ObjectModel, cfg: TrackingConfig) -> np.ndarray | None:
    """X̂_0 from frame 0 and up to ``gauge_frames`` frames at rest before the robot reaches the object
    (``service.tracking.gauge``)."""
    from service.tracking.gauge import gauge_pose, rest_frames

    robot = len(getattr(session, "robot_t", ())) > 0 and session.ee_radius > 0
    rest = rest_frames(X, tracked, np.array([len(o.P_W) for o in obs]), np.asarray(session.p_WE, float) if robot else None,
                       session.ee_radius, model.tree, cfg.gauge_frames, cfg.gauge_ee_margin, cfg.gauge_max_deg,
                       cfg.gauge_max_dist, cfg.min_points)
    return gauge_pose(X0_hat, X, rest)


def _bundle_adjust(keyframes: list[Keyframe], cfg: TrackingConfig, rng: np.random.Generator,
                   carver: "FreeSpace | None") -> None:
    """Joint refinement of the keyframe poses (``service.tracking.posegraph``); keyframe 0 stays fixed."""
    from service.tracking.posegraph import bundle_adjust

    X_OW = np.stack([X_inv(kf.X_WO) for kf in keyframes])
    res = bundle_adjust(X_OW, [kf.P_W for kf in keyframes], [kf.N_W for kf in keyframes],
                        iters=cfg.ba_iters, huber=cfg.ba_huber, rng=rng)
    for kf, X_ow in zip(keyframes[1:], res.X_OW[1:]):
        kf.X_WO = X_inv(X_ow)
        kf.P_O = kf.P_W @ X_ow[:3, :3].T + X_ow[:3, 3]
        kf.kp_O = kf.kp_W @ X_ow[:3, :3].T + X_ow[:3, 3]
        if carver is not None:
            carver.update_pose(kf.index, kf.X_WO)


def _model_from(keyframes: list[Keyframe], voxel: float) -> ObjectModel:
    parts = []
    for kf in keyframes:
        R_OW = kf.X_WO[:3, :3].T
        parts.append((kf.P_O, kf.N_W @ R_OW.T))
    return ObjectModel.build(voxel, parts)


def _feature_corr(o: FrameObs, prev: FrameObs, X_prev: np.ndarray, keyframes: list[Keyframe],
                  lost: bool) -> tuple[np.ndarray, np.ndarray]:
    """3-D correspondences (current point in W, same point in O) from ORB matches: to the previous tracked frame
    (placed in O with its pose X_prev) first, then to the keyframes (placed with theirs)."""
    A, B = [], []
    if o.desc is None:
        return np.zeros((0, 3)), np.zeros((0, 3))
    X_OW = X_inv(X_prev)
    prev_O = prev.kp_W @ X_OW[:3, :3].T + X_OW[:3, 3]
    m = _match(o.desc, prev.desc)
    if len(m):
        A.append(o.kp_W[m[:, 0]])
        B.append(prev_O[m[:, 1]])
    kfs = keyframes if lost else keyframes[-3:]
    for kf in kfs:
        m = _match(o.desc, kf.desc)
        if len(m):
            A.append(o.kp_W[m[:, 0]])
            B.append(kf.kp_O[m[:, 1]])
    if not A:
        return np.zeros((0, 3)), np.zeros((0, 3))
    return np.concatenate(A), np.concatenate(B)


def _feature_motion(fW: np.ndarray, fO: np.ndarray, cfg: TrackingConfig, rng: np.random.Generator,
                    cam: tuple[np.ndarray, np.ndarray] | None = None) -> tuple[np.ndarray | None, np.ndarray]:
    """RANSAC rigid fit (X_OW, inlier mask) of the tracking loop's ORB correspondences fW (current point, W) ↔ fO
    (same point, O): with ``track_ransac_px`` set and ``cam`` = (K (3,3), X_CW (4,4)) given, first in the camera
    (within track_ransac_px pixels across the ray, ransac_thr along it: ``geometry.ray_inliers``); at ``ransac_thr``
    when that finds fewer than ``feat_min_inliers`` (or is off). A keypoint whose patch lies on the silhouette or an
    occluder's edge stays put in the image while a small body turns under it; within the 1 cm ball of a surface that
    moved less than it (a 3 cm egg turning 5°/frame: 2.6 mm) it joins the consensus and pulls the fit toward no
    motion; across the ray it is several pixels from where the surface's motion predicts it."""
    if cfg.track_ransac_px is not None and cam is not None:
        Xr, inl = ransac_rigid(fW, fO, cfg.ransac_thr, rng=rng, min_inliers=cfg.feat_min_inliers,
                               cam=(cam[0], cam[1], cfg.track_ransac_px))
        if Xr is not None:
            return Xr, inl
    return ransac_rigid(fW, fO, cfg.ransac_thr, rng=rng, min_inliers=cfg.feat_min_inliers)


def interpolate_untracked(X_WO: np.ndarray, tracked: np.ndarray) -> np.ndarray:
    """Poses (N,4,4) with untracked frames replaced by interpolation between the nearest tracked frames
    (geodesic for rotation, linear for position); before the first / after the last tracked frame: held."""
    X = X_WO.copy()
    idx = np.nonzero(tracked)[0]
    if len(idx) == 0:
        return X
    for i in np.nonzero(~tracked)[0]:
        k = np.searchsorted(idx, i)
        if k == 0:
            X[i] = X_WO[idx[0]]
        elif k == len(idx):
            X[i] = X_WO[idx[-1]]
        else:
            a, b = idx[k - 1], idx[k]
            s = (i - a) / (b - a)
            Ra, Rb = X_WO[a, :3, :3], X_WO[b, :3, :3]
            R = Ra @ so3_exp(s * so3_log(Ra.T @ Rb))
            X[i] = make_X(R, (1 - s) * X_WO[a, :3, 3] + s * X_WO[b, :3, 3])
    return X
