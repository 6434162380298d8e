"""Inputs and outputs of the tracking and visible-geometry stage."""

from __future__ import annotations

from dataclasses import dataclass, field, fields

import numpy as np

from service.mesh import Mesh
from service.sdf.types import SdfConfig, SdfGrid
from service.session.types import Session


@dataclass(frozen=True)
class TrackingInputs:
    session: Session


@dataclass(frozen=True)
class TrackingOutputs:
    t: np.ndarray  # (N,) frame times, s
    X_WO: np.ndarray  # (N,4,4) object pose per frame
    tracked: np.ndarray  # (N,) bool: False where the track was lost (pose interpolated/held)
    v_WO_W: np.ndarray  # (N,3) velocity of O's origin in W, filtered backward differences, m/s
    w_WO_O: np.ndarray  # (N,3) angular velocity in O (body) axes, rad/s
    sdf: SdfGrid  # visible-geometry SDF in O
    visible_mesh: Mesh  # marching cubes of sdf, frame O
    visible_points_O: np.ndarray  # (K,3) the visible set V (hull points that pass the visibility check)
    frames_lost: int
    # spin closure (TrackingConfig.spin_closure): None when off or the shape is not a body of revolution; else the
    # symmetry axis in O (3,) and whether the texture let the spin about it be measured (False: textureless, the
    # spin is unobservable and the poses keep the tracker's, whose rotation about the axis is then arbitrary)
    spin_axis_O: np.ndarray | None = None
    spin_observable: bool | None = None
    # masks of the visible-geometry stage (TrackingConfig.mask_trim): median over the SDF frames of the fraction of
    # mask pixels, mask_trim_deep_px or more inside the mask, that the colour trim gives to the background (None: not
    # measured), and whether the trimmed masks were used
    mask_strip_fraction: float | None = None
    masks_trimmed: bool = False


def _visible_sdf() -> SdfConfig:
    # the visible SDF weighs space seen empty 300 (BundleSDF: 1): vertices the band of other readings and the hull
    # start left in space the frames had seen empty carried 36-50 % of the error of the prism and the mug
    # (docs/tracking-findings.md, "free space seen by other frames as evidence"); the fusion stage has its own SdfConfig
    return SdfConfig(w_empty=300.0)


@dataclass(frozen=True)
class TrackingConfig:
    """Settings of tracking and the visible-geometry SDF. ``fast()`` is the reduced preset used by tests.

    Distances in metres, angles in degrees where named ``_deg``."""

    seed: int = 0
    # per-frame observation
    max_points: int = 1200  # object points per frame (depth subsampled to about this many)
    erode_px: int = 2  # mask erosion before back-projection (edge pixels mix object and background)
    edge_jump: float = 0.01  # depth jump (m, plus 2 % of depth) to a neighbour that marks a flying pixel
    table_clearance: float = 0.005  # points lower than this above the table plane are dropped
    min_points: int = 40  # fewer valid object points: frame not trackable
    ee_margin: float = 0.004  # points within ee_radius + this of the end-effector centre are dropped (robot data only)
    below_table_outside: bool = True  # the half-space below the table at frame 0 (in O) is outside the object
    # free-space gating of model growth and SDF rays: a point is rejected when a keyframe saw through it, i.e. its
    # depth there (min-filtered over carve_px pixels) exceeds the point's depth by more than carve_margin
    carve: bool = True
    carve_margin: float = 0.01
    carve_px: int = 3
    carve_frame_frac: float = 0.05  # a frame with more of its object points seen through is inconsistent with the
    # model (wrong pose or clutter in the mask): it neither becomes a keyframe nor supervises the SDF
    features: bool = True  # ORB features inside the mask for the coarse motion
    n_features: int = 400
    # registration
    icp_iters: int = 12
    icp_dist0: float = 0.03  # initial correspondence radius
    icp_dist_min: float = 0.006  # final correspondence radius
    inlier_dist: float = 0.008  # a point within this distance of the model is an inlier
    ransac_thr: float = 0.01
    feat_min_inliers: int = 12  # fewer RANSAC inliers among the ORB matches: no feature candidate or terms (6 matches
    # of a repeated texture gave a consistent wrong pose, 56° off, on a still box: strike session 511)
    # tracking loop, ORB matches: the consensus measured in the camera (geometry.ray_inliers): a match is an inlier when
    # its keypoint lies within track_ransac_px pixels of the prediction across the ray and ransac_thr along it (the depth
    # reading); None: off (the isotropic ransac_thr ball). First, before ransac_thr, which takes over when it finds
    # fewer than feat_min_inliers. Development eggs: of the 1 cm consensus's inliers in a roll 38 % do not
    # follow the surface (keypoints 2-8 px from where it moved them, within 1 cm: 7.7 px at 0.8 m across the ray).
    # Off: 2 px gained on 18 of 22 development eggs and on 704, 710, 711, and lost on the evaluation 703 and 707
    # (docs/tracking-findings.md, "Eggs: why the loop's increment in a roll is short"). Re-judged with the defaults of
    # 9c88efd on fresh 1950-1973: pose targets met 11 -> 11 of 24, rotation medians lower on 12, worst rotation higher
    # on 9, median translation median 1.22 -> 1.39 mm: off ("The camera consensus ... re-judged on the main of 23 Nov")
    track_ransac_px: float | None = None
    min_inlier_frac: float = 0.35  # below: lost track
    max_rmse: float = 0.006  # above: lost track
    max_speed: float = 1.5  # a pose farther than this (m/s) or
    max_rate_deg: float = 600.0  # turned more than this (°/s) from the last tracked pose is a jump: lost track
    # (a flip to a symmetric pose fits a partly seen box as well as the true one; strike session 511, frame 153:
    # 103° in one frame, inlier fraction 0.98, taken as a keyframe)
    # object model
    model_voxel: float = 0.003  # voxel of the accumulated keyframe point model
    kf_angle_deg: float = 10.0  # new keyframe when this far (or kf_dist) from every keyframe
    kf_dist: float = 0.03
    kf_new_frac: float = 0.15  # ... or when this fraction of points lies off the model (farther than inlier_dist)
    kf_min_new_add: float = 0.02  # ... and at least this fraction are off-model points it adds (within grow_dist,
    # not seen through); without it, points that are never added keep the trigger on in every frame
    kf_min_inlier_frac: float = 0.5
    grow_dist: float = 0.015  # points farther than this from the model are not added (mask noise)
    refine_rounds: int = 2  # leave-one-out keyframe refinement rounds after the bundle adjustment (0: off)
    # starting correspondence radius (m) of that refinement's ICP (it shrinks to icp_dist_min); off at 0.015 (the
    # former fixed value). A keyframe's points on surface only it saw (a tilt turns a face into view) find other
    # keyframes' surface 6-15 mm away and pull its pose (docs/tracking-findings.md, "Worst frames of pivots just
    # over 5°"); icp_dist_min (0.006) matches only within the displacement a pose already registered can be off by
    refine_dist0: float = 0.015
    # with refine_slow_deg > 0 (0: off) only keyframes whose tracked poses turn by at most refine_slow_deg per frame
    # over ± refine_slow_frames frames around them (at rest, a slow tilt) start at refine_slow_dist0 (m); the others
    # (a fall, a fast roll) keep refine_dist0: a pose registered in slow motion is only a few mm off, one taken in
    # fast motion can be farther off than the small radius corrects
    refine_slow_deg: float = 0.0
    refine_slow_frames: int = 2
    # with it, the turn is checked from frame 0 to refine_slow_frames after the keyframe: a keyframe at rest after a
    # fall inherits the fall's error (a topple's settled keyframes 13-17 mm off) and keeps refine_dist0
    refine_slow_from_start: bool = False
    refine_slow_dist0: float = 0.006
    ba_iters: int = 10  # keyframe bundle adjustment (service.tracking.posegraph) iterations (0: off)
    ba_huber: float = 0.002  # Huber threshold of its point-to-plane residuals
    final_pass: bool = True  # re-register every frame against the final model
    final_iters: int = 6
    regauge_frame0: bool = True  # frame 0 registered to the final model too; O moved so X_WO(0) keeps its definition
    regauge_points: int = 8000  # points of frame 0 in that registration
    # velocities
    median_kernel: int = 3
    # visible geometry
    sdf: SdfConfig = field(default_factory=_visible_sdf)
    sdf_frames: int = 30  # frames whose rays supervise the SDF
    sdf_stride: int = 3  # pixel stride of the rays
    sdf_ring_px: int = 30  # dilation of the mask for free-space rays
    sdf_erode_px: int = 2  # erosion of the mask for object rays
    sdf_denoise: float = 0.015  # object rays farther than this from the model are dropped
    # object rays within sdf_silhouette_px (0: off) of a silhouette (a non-mask pixel behind them, none in front:
    # visible.silhouette_pixels), or with sdf_silhouette_margin (m) only those of them more than that behind the plane
    # of the mask's interior (visible.blended_pixels: a sensor's blend of object and background), get a band of
    # sdf_silhouette_back (m) behind their reading instead of the fit's τ, or with sdf_silhouette_drop no ray at all.
    # Off: on the real cube video the blended readings make its long extent, but every variant loses on the
    # synthetic development sessions (docs/tracking-findings.md, "The real cube's long extent")
    sdf_silhouette_px: int = 0
    sdf_silhouette_back: float = 0.0
    sdf_silhouette_margin: float | None = None
    sdf_silhouette_drop: bool = False
    visible_samples: int = 3000  # samples on the convex hull of the visible mesh (plus its vertices)
    visible_depth_tol: float = 0.01  # |z_render − z_obs| for the visibility check
    visible_frames: int = 30
    # spin closure of a body of revolution (service.tracking.spin): the rotation about the symmetry axis, which the
    # geometry cannot see, re-estimated per frame from ORB keypoints well inside the mask matched against frame 0
    # and earlier corrected frames; only when the final model's weakest direction is a rotation (λ̂ < spin_tau).
    # On: bottle topple 704 20.5° -> 6.0° median rotation error, egg 707 10.4° -> 6.8°, bottle pivot 711 1.77° ->
    # 1.47°, mug 708 1.21° -> 0.74°; other sessions and the real cube identical (docs/tracking-findings.md)
    spin_closure: bool = True
    spin_tau: float = 0.03  # λ̂ below which the model counts as a body of revolution (1/3: fully constrained)
    spin_sep: float = 0.5  # ... and at most this times the next eigenvalue (one weak direction, not a near-sphere)
    spin_border_px: int = 8  # keypoints at least this far inside the object mask (silhouette/occluder edges)
    spin_features: int = 400  # ORB keypoints per frame for it
    spin_tol: float = 0.006  # radius/height (m) about the axis within which a match votes
    spin_inlier_deg: float = 3.0  # half width of the vote window
    spin_min_votes: int = 8  # fewer votes: the frame's spin is interpolated from its neighbours
    spin_smooth: int = 5  # median filter (frames) of the spin correction
    # the SDF starts from the hull of the observed points with the voxels a keyframe saw through set outside
    # (visible.carved_init; the mug's mouth and cavity: 708 4.73 -> 3.99 mm, the others unchanged,
    # docs/tracking-findings.md)
    sdf_carve_init: bool = True
    sdf_carve_value: float = 0.005  # S (m) given to those voxels
    # spin closure: axis of a model whose weak rotations mix (an egg) refitted to its radius profile ("mixed"), every
    # axis so ("always") or none ("off"); "multi": as "mixed", the refit started from every rotation eigen-axis too
    # (spin.profile_starts), the best profile fit kept (egg 707 6.91 -> 6.82 deg median, 30.39 -> 28.44 worst; the other
    # evaluation sessions identical; development egg 1002 29.49 -> 13.09, docs/tracking-findings.md); a correction above
    # spin_max_deg in any frame is not applied (0: no cap)
    spin_profile: str = "multi"
    spin_max_deg: float = 120.0
    # the cap raised by the roll of a lying body of revolution that the tracked poses do not show as a turn (the axis
    # point's travel across the axis over the straight stretch's radius, minus the poses' own twist, over the frames
    # lie_level finds lying; lying.unseen_roll): the depth fit cannot see such a roll, so the correction that restores
    # it may exceed spin_max_deg (development bottle topple 1565: 125 deg needed, 94 deg of unseen roll,
    # 46.27 -> 1.21 deg median; docs/tracking-findings.md "The cap of the spin correction and the unseen roll")
    spin_cap_roll: bool = False
    # gauge of the body frame (service.tracking.gauge): X̂_0 = robust mean of frame 0's registration to the final model
    # and of the final poses of up to gauge_frames frames at rest — before the end effector comes within ee_radius +
    # gauge_ee_margin of the model, within gauge_max_deg / gauge_max_dist of frame 0 (0: frame 0 alone; no robot data:
    # frame 0 alone). On: l_block 702 2.72° / 5.40° -> 1.59° / 4.04°, no material loss elsewhere
    # (docs/tracking-findings.md, "Worst frames")
    gauge_frames: int = 30
    gauge_max_deg: float = 5.0
    gauge_max_dist: float = 0.01
    gauge_ee_margin: float = 0.02
    # the table and the frame's free space as a test of a pose (resettle.pose_consistent; the fall's frames registered
    # backwards from an adopted join): a pose whose model lies more than
    # landing_table_margin below the table (over landing_table_frac of its points) or covers pixels where the frame
    # sees through it is inconsistent
    landing_table_margin: float = 0.01
    landing_table_frac: float = 0.02
    landing_seen_frac: float = 0.05  # ... or more of its points where the frame's depth reading lies behind them
    sdf_band_px: int = 1  # min filter (pixels) of the views' depth for sdf_drop_contradicted (silhouettes do not count)
    # object rays whose point sdf_contradict_views of the SDF's frames saw in front of their own reading by more than
    # sdf_contradict_margin (min filter sdf_band_px) are dropped (visible.drop_contradicted; flying pixels,
    # misregistered edges; with w_empty 300: 12 evaluation sessions 0.2-1.3 mm better, egg 707 +0.06,
    # docs/tracking-findings.md)
    sdf_drop_contradicted: bool = True
    sdf_contradict_margin: float = 0.005
    sdf_contradict_views: int = 3  # ... by at least this many frames
    # a topple's fall (resettle.find_fall): its last fast step turns more than settle_fast_deg per frame, the fall
    # starts where the steps turn more than settle_fall_deg per frame
    settle_fast_deg: float = 8.0
    settle_fall_deg: float = 2.0
    # spin closure solver: "chain" (each frame's pooled votes against frame 0 and earlier corrected frames) or "mixed"
    # (default; spin.spin_mixed: the chain, with the increments of a one-parameter pose graph over frame pairs —
    # spin.spin_links, solve_spin_graph: spin_graph_short links to the nearest earlier frames, plus longer links only
    # between frames whose views differ by less than spin_graph_gate_deg and by at most spin_graph_rate_deg per frame
    # between them; links need spin_graph_votes votes — over fast stretches where the chain has few votes: 704
    # 17.3°/22.0° -> 5.2°/7.9°, 707, 708, 711 within 0.05° median; docs/tracking-findings.md "Mixed spin estimate")
    spin_solver: str = "mixed"
    spin_graph_gate_deg: float = 10.0
    spin_graph_rate_deg: float = 0.5  # 0: no rate test
    spin_graph_votes: int = 6
    spin_graph_short: int = 2  # short links per frame (the nearest earlier frames; the k-th weighs 1/k²)
    spin_graph_long_votes: int = 12  # votes a longer link needs (a false one ties distant frames)
    # spin_solver "mixed" (spin.spin_mixed): the chain, except in fast stretches — tracked rotation above
    # spin_mixed_rate_deg per frame over spin_mixed_span frames, widened by spin_mixed_dilate frames each side — where
    # the chain pooled fewer than spin_mixed_votes votes: those frames (widened again) take the graph's increments
    # (docs/tracking-findings.md, "Mixed spin estimate")
    spin_mixed_rate_deg: float = 2.0
    spin_mixed_span: int = 4
    spin_mixed_dilate: int = 4
    spin_mixed_votes: int = 60

    # masks of the visible-geometry stage (SDF rays, contradiction test, V) trimmed by colour at their border
    # (service.tracking.masks.trim_mask: GrabCut seeded with the mask eroded by mask_trim_px as object and the ring
    # of mask_trim_px outside as probable background; never adds pixels), used only when the trim takes at least
    # mask_trim_min of the mask pixels mask_trim_deep_px or more inside the mask (median over the SDF frames): a
    # segmentation misregistered with the colour image covers a strip of background (real cube video 7.5 %, lab
    # sessions with masks 7 px off 4.2-5.7 %), exact masks lose only the rim where colours blend (lab <= 0.3 %; there
    # trimming moved the surface by -0.1..+0.3 mm). Tracking itself reads the given masks.
    mask_trim: bool = True
    mask_trim_px: int = 6
    mask_trim_iters: int = 3
    mask_trim_deep_px: int = 3
    mask_trim_min: float = 0.01
    # the settled object after a topple's landing (service.tracking.resettle; docs/tracking-findings.md "Settled object
    # joined by the fall's physics"): resettle_delay frames after the last fast step of the loop (> settle_fast_deg per
    # frame), when the steps from resettle_tip_deg per frame on turned >= resettle_min_tip_deg about a horizontal axis,
    # the pose of the pre-fall model tipped about its leading bottom edge onto its leading (flat) face (corrected by the
    # faces both views show, at most resettle_max_shift; the yaw is not corrected) replaces the tracked pose when they
    # differ by resettle_min_deg / resettle_min_dist (the join itself is 1-3 deg / 5-18 mm off on the development
    # topples) and the frame sees through at most resettle_seen more of the pre-fall model at the new pose than at the
    # tracked one; the fall's keyframes are dropped, the frame becomes a keyframe with all its points and the fall is
    # registered backwards from it
    resettle: bool = True  # on: evaluation 710 15.69 deg / 58.55 mm -> 2.72 deg / 6.31 mm median, all others identical
    resettle_delay: int = 6
    resettle_tip_deg: float = 0.3
    resettle_min_tip_deg: float = 8.0
    resettle_min_deg: float = 8.0
    resettle_min_dist: float = 0.03
    resettle_max_shift: float = 0.03
    resettle_seen: float = 0.02
    # a box whose leading face the pre-fall model never saw (it tips away from the camera): the join takes the leading
    # face from the box's seen flat sides (resettle.box_face: at right angles to each other, squared to the base it
    # stood on; the side direction nearest the tipping direction, at the model's extent along it) instead of leaving
    # the fall unjoined (docs/tracking-findings.md "Carton topples that tip away from the camera"), for a body resting
    # on the table only (resettle_box_rest). On: development carton topples 1559 17.01 -> 0.28 deg, 1617 15.83 -> 1.64
    # deg median (4 of 25 sessions changed, all gain in rotation), the 12 synthetic evaluation sessions and the real
    # video identical (without the rest gate the real video's carried cube got a false join: rotation p90 2.17 -> 50.74)
    resettle_box_face: bool = True
    # ... only for a body resting on the table at the settled frame (resettle.on_table): the lowest point of the
    # tracker's model under the tracked pose at most this (m) above the table plane. A landing is a body coming to rest
    # on the table; a box held and turned by a gripper in the air is not (the real video's carried cube at its false
    # join: 66.5 mm). The tolerance is the sensor and tracking noise (a few mm) plus the strip of the box next to the
    # face it now lies on, which the model may lack (that face was never seen, and heavy occlusion hides the seen
    # sides' edges near it): development 1564 7.9 mm under the true pose, 9.5 mm under the tracked one
    resettle_box_rest: float = 0.015
    # ... and moved by the drop the face on top of the landed box shows (resettle.top_face_drop): the leading face taken
    # from the box's sides lies at the model's extent, short by the strip the model lacks, so the join turns about an
    # edge d short and leaves the box d short along the tipping direction and d low; the settled frame's face on top
    # (the trailing face, seen before the fall) measured d (development 1564: 10.8 mm against the join's 10.8 mm low).
    # Off: the joins it moves come nearer the truth (fresh development 1720-1735: 12.6-40.9 -> 7.1-16.4 mm) but none
    # of those was adopted; on the design sessions translation median -2.0 mm on 1571 and 1617, rotation median
    # 1571 1.06 -> 1.56 deg and worst frames up (docs/tracking-findings.md "The offset a box-face join leaves")
    resettle_box_drop: bool = False
    # the settled stretch of a box lying on a side it never showed (resettle.box_rest_face, down_pose): that side (the
    # box direction of its seen flat sides nearest the downward one) laid flat on the table in the flush step (two
    # tilts) instead of only its base made vertical (one tilt: the roll about the box's long axis is left free;
    # development 1617 1.13 deg of it over the settled stretch). Off: design sessions rotation median 1617 1.64 -> 1.22
    # deg, 1564 1.03 -> 0.83 deg; fresh development sessions -0.20..+0.18 deg median, worst translation up on 6 of 7
    resettle_box_flush: bool = False
    # the settled stretch of a box after a topple moved along the tip axis h so that the box's two ends along h (the
    # extreme of the mask's depth points along h, both ends seen: nothing nearer the camera beyond them) have their
    # middle where the frames before the fall saw it (tracker._resettle_axis, resettle.axis_extent / end_seen /
    # axis_shift: one shift for the stretch, refused when the lengths disagree, the frames' shifts spread or it is
    # under 2 mm). The landing's sideways slide (+-6 mm) is seen by nothing else. On: development carton topples 1724
    # 9.40 -> 2.45 mm, 1732 9.58 -> 3.18 mm, 1730 14.47 -> 8.45 mm translation median; 39 of 44 development sessions
    # and the evaluation identical (docs/tracking-findings.md "The box's position along the tip axis")
    resettle_box_axis: bool = True
    # the settled stretch of a box after a topple also moved along its up axis u, which the topple lays along the
    # tipping direction f, so that the middle of its two ends along u (the extreme of the settled mask's depth points,
    # both ends seen) lies where the frames before the fall had it (from the table under the base to the top seen):
    # the landing's slide beyond the pure turn about the leading edge (tracker._resettle_axis, resettle.table_end,
    # axis_shift with len_short). Counted are settled frames whose length is at most resettle_box_slide_short (m)
    # shorter than the standing height (both settled ends are outlines and lose pixels, the reference's base is the
    # table) and at most 6 mm longer; refused when fewer than resettle_box_slide_frac of the settled frames count
    # (an end hidden: the base faces away from the tip, often behind the box), their shifts spread more than 3 mm or
    # it is under resettle_box_slide_min (m): the middle of two outlines is biased by half the difference of what
    # each outline loses (oat cartons 1730 +2.0, 1891 +4.6, 1902 -7.9 mm with true poses). Off: design oat carton
    # 1730 8.45 -> 1.33 mm translation median, the other 11 design carton topples and all 12 judge sessions
    # (1898-1909) unmoved (an end hidden, the ridge end, under the floor) (docs/tracking-findings.md "A toppled box's
    # slide along the tipping direction")
    resettle_box_slide: bool = False
    resettle_box_slide_short: float = 0.02
    resettle_box_slide_frac: float = 0.3
    resettle_box_slide_min: float = 0.005
    # support closure (visible.support_feet): the SDF's initial hull also takes the foot of every observed surface
    # point on the table plane at frame 0 (the object rests on the table, so the never-seen space below what was
    # seen is object unless a keyframe saw it empty, which the carving then removes); needs below_table_outside.
    # Off: the hidden lower part and the back are closed by the hull of the seen points 1-2 cm above the table.
    # Acts only with below_table_outside (the plane); on, with sdf_support_open and its gate (docs/tracking-findings.md)
    sdf_support_hull: bool = True
    # the join moved along the tipping direction by the settled segment's own evidence (tracker._resettle_refine,
    # resettle.base_shift): the base must not lie where the first resettle_refine_frames tracked frames from the settled
    # frame on see the table or background; 0: off. 30: development 820 7.30 -> 6.46 mm, oat 830 7.81 -> 1.23 mm median
    resettle_refine_frames: int = 30
    # the support closure does not reach under seen-empty space (visible.open_columns): the voxels it adds whose column
    # upward meets space a keyframe saw empty before a seen surface (the voxels of the observed points dilated by
    # sdf_support_open_dilate voxels) keep the start of the hull of the seen points (a mug's cavity behind its near
    # wall, seen into through the mouth); only with sdf_support_hull
    sdf_support_open: bool = True
    sdf_support_open_dilate: int = 1
    # ... and when more than this fraction of the voxels the closure adds are so, it is dropped altogether (1: never)
    sdf_support_open_gate: float = 0.2  # development: boxes, prisms, bottle, egg, l_block 0.00; mugs 0.41-0.52
    # where the support closure shaped the SDF's start: V on the convex hull of the visible mesh's vertices that pass
    # V's visibility check, not of the whole mesh, whose hull spans the closure of the unseen part, 1-3 mm outside
    # the seen band where it starts from the widest noisy points (milk carton 912 V 1.77 -> 1.28 mm, without the
    # closure 1.27); elsewhere V is unchanged
    visible_hull_seen: bool = True
    # spin closure (spin.smooth_twist): median-filter the corrected twist of the body (its rotation about the axis since
    # frame 0, tracked + correction) over this many frames instead of the correction alone over spin_smooth; the
    # tracker's own twist jitters 1-3° from frame to frame and the correction must carry that; 0 or 1: off, the
    # correction median-filtered over spin_smooth as before (docs/tracking-findings.md "Twist smoothed instead of the
    # correction"; development bottle pivots 911 7.05° -> 4.17°, 553 7.08° -> 3.53° worst frame)
    spin_twist_smooth: int = 15
    # a body of revolution does not turn about its own axis while it topples (service.tracking.fall: no force on it
    # has a moment about the axis): over a topple of the tracked poses (the axis' angle from the vertical changing by
    # more than spin_fall_rate_deg per frame and by >= spin_fall_min_deg in all, trimmed by spin_fall_edge_deg at
    # both ends) the spin correction takes the increments that leave the tracked rotation no twist about the axis,
    # when the default estimate's spin change over it differs from theirs by more than spin_fall_tol_deg (spin_solver
    # "mixed" only); docs/tracking-findings.md "Fall without spin"
    spin_fall: bool = True  # on: evaluation 704 5.21 -> 2.08 deg median rotation (worst 7.86 -> 9.73), others identical
    spin_fall_rate_deg: float = 0.4
    spin_fall_min_deg: float = 45.0
    spin_fall_edge_deg: float = 1.0
    spin_fall_tol_deg: float = 3.0
    # nor while a pivot tilts it onto the rim of its base and lets it back (service.tracking.fall: pivot_runs,
    # pivot_bridge): over each tilt of the tracked poses whose axis leaves frame 0's direction by more than
    # spin_fall_edge_deg, reaches spin_pivot_deg and comes back, the spin correction keeps the tracked rotation free of
    # twist about the axis from the upright frame before the tilt, the difference to the correction of the upright
    # frame after it spread along the tilt, unless the correction already stays within spin_fall_tol_deg of that
    # bridge; 0: off (docs/tracking-findings.md "Worst frames of milk-carton topples and bottle pivots")
    spin_pivot_deg: float = 5.0  # on: development bottle pivots 1471 11.13 -> 3.15, 1474 13.84 -> 5.79 deg worst;
    # evaluation 711 1.11 / 6.26 -> 1.15 / 4.16 deg, the others identical
    # a body of revolution lying on the table has its axis parallel to the table plane (its widest straight stretch,
    # the lowest generator line, touches the table): after the spin closure, when the body stood on its base at
    # frame 0 (found axis within lie_level_stand_deg of the vertical: the axis is then the vertical of frame 0) and
    # its profile has a straight widest stretch, every frame with the axis within lie_level_deg of the horizontal (it
    # and its 3 neighbours on each side) and that stretch within lie_level_margin of the table is turned about the
    # horizontal through its centroid's axis point until the axis is horizontal (at most lie_level_max_deg;
    # service.tracking.lying, docs/tracking-findings.md "Lying body levelled")
    lie_level: bool = True  # on: development 531 4.94 -> 2.68 deg median; evaluation 704 1.91 / 10.05 -> 1.44 / 8.58
    lie_level_stand_deg: float = 15.0
    lie_level_deg: float = 15.0
    lie_level_margin: float = 0.015
    lie_level_max_deg: float = 10.0
    # when the merged model's profile about ẑ has no straight stretch (the lying keyframes, attached to the standing
    # ones tilted by a few degrees in the fast fall, smear it: development bottle topples 1641, 1658, 1659: 5-30 mm of
    # the 50 mm needed), the stretch is sought in the points of the keyframes whose pose has ẑ within lie_level_deg of
    # the horizontal, about their own axis (lying.lying_views_stretch); the levelling is then lie_level's
    # (docs/tracking-findings.md "Bottle topples: the lying body's tilt made in the fall")
    lie_level_views: bool = True  # on: development 1641 7.46 -> 4.93 deg median; fresh 1694, 1696, 1699, 1700 gain
    # 0.67-2.42 deg median, 14 of 18 identical; evaluation identical bit for bit
    # a body of revolution lying on the table after a topple (lie_level's geometry and lying frames) moved along its
    # axis so that the ends its mask shows (resettle.end_seen / axis_extent, each end only where it is seen) lie at
    # the model's ends: the base plane where the table was at frame 0, the top where the standing frames saw it
    # (tracker._lying_axis, lying.axis_end_offsets / axis_end_shift). Both ends seen: the middles compared, the length
    # within lie_axis_len_tol (m) of the model's less 2 lie_axis_short; one end: that end less the mask's shortfall
    # lie_axis_short (m). Per frame the running median of the offsets over +-lie_axis_window frames; a stretch is
    # refused when fewer than half its frames count, their offsets spread (interquartile, about the running median)
    # more than lie_axis_spread or the stretch's median is under lie_axis_min_shift. The cylinder's side cannot see a
    # slide along the axis (docs/tracking-findings.md "A lying bottle's position along its axis"). Off: design bottle
    # topples 1697 27.44 -> 2.84 mm, 1788 60.49 -> 6.00 mm translation median (1697's surface 3.63 -> 5.37 mm); judge
    # 1871, 1874 gain (14.25 -> 4.84, 9.76 -> 1.83 mm) but 1870, 1876, 1878 lose 10-19 mm (only the cap end seen, and
    # cut where end_seen says seen) and 1879 6.6 mm (the ends' shortfalls differ: 0 and 16.7 mm)
    lie_axis_ends: bool = False
    lie_axis_short: float = 0.006
    lie_axis_len_tol: float = 0.008
    lie_axis_window: float = 15.0
    lie_axis_spread: float = 0.004
    lie_axis_min_shift: float = 0.008
    # a fall the loop loses (the frames after the landing show a part of a body of revolution the model does not hold,
    # or holds misplaced): a re-acquisition after the loss, when the last tracked poses fall (ẑ_O tilted by at least
    # lost_land_tilt_deg and tilting faster than settle_fall_deg per frame over the last 3 tracked steps) of a model
    # that is a body of revolution about ẑ_O (κ < spin_flat_kappa), no earlier than a uniform cylinder of the model's
    # height and radius takes to topple from there at that rate (lying.topple_time), is compared with the last fall
    # pose moved down until its base rim's pivot is on the table and turned about it until the axis is horizontal
    # (lying.rim_landing): more
    # than lost_land_deg between their axes or lost_land_dist between their base centres along the axis and the
    # turned pose replaces it (the fall's keyframes dropped, the frame a keyframe with all its points;
    # tracker._lost_landing; docs/tracking-findings.md "Bottle topples lost in the fall: the landing by the turn about
    # the base rim")
    lost_land: bool = True  # on: design bottle topples 1692, 1693, 1695 89.5/39.7/112.8 -> 4.2/3.9/4.8 deg median,
    # 68.4/101.4/65.2 -> 10.6/7.5/3.5 mm; judge 1780 28.66 -> 3.90 deg, 71.60 -> 16.07 mm; 1787 96.97 -> 16.51 mm
    # (24.52 -> 28.84 deg, surface 1.52 -> 4.74 mm); 15 of 18 design and 11 of 13 judge sessions identical
    lost_land_tilt_deg: float = 20.0
    lost_land_deg: float = 30.0
    lost_land_dist: float = 0.03
    # a model that fails the λ̂ test of a body of revolution (spin_tau: it scales a rotation by the model's extent, so a
    # model covering a short band of the body fails) is taken for one when its weakest direction is one clear
    # rotation whose normals lie in the meridian planes, κ = Σ (n·(a×d))² / Σ |a×d|² < spin_arc_tau (the motion seen
    # by the surface as a fraction of the arc each point moves), and its radius profile fits within 2 mm
    # (spin.partial_tau; 0: off; docs/tracking-findings.md "Bodies of revolution seen in part")
    spin_arc_tau: float = 0.08  # development partial bottle pivots 940, 941, 943, 944: worst 6.2-7.8 -> 2.5-3.4 deg
    # a model the body-of-revolution test takes for one (spin_tau, spin_arc_tau) is refused when its normals leave the
    # meridian planes about the closure's axis by κ >= spin_flat_kappa (κ as for spin_arc_tau: flat faces, a prism
    # whose spin the λ̂ test, scaled by the model's length, misses); no correction then (spin.flat_faced; 0: off;
    # docs/tracking-findings.md "Boxes are not bodies of revolution")
    spin_flat_kappa: float = 0.12
    # a model that the λ̂ and separation tests refuse (a short open cup: no base seen, its tilts nearly as weak as its
    # spin) is taken for a body of revolution about its weakest rotation's eigen-axis when that rotation's κ <
    # spin_arc_tau, its radius profile fits within 2 mm and the next weakest rotation's κ is at least spin_sep_kappa
    # times larger (the separation judged by where the normals point; spin.kappa_sep_axis; no tilt closure then;
    # 0: off; docs/tracking-findings.md "Mug pivots: the turn about the mug's own axis"). 2: design mug pivots 1818,
    # 1819, 1910 worst 5.71/5.93/6.37 -> 3.07/5.03/5.50 deg; judge: gains on 2 of 8 mug pivots (1916 6.02 -> 4.59 deg
    # worst) and 3 of 4 mug pushes, loses on none, bottles identical; off because the rule asked for 4 of 8 pivots
    spin_sep_kappa: float = 0.0
    # egg-like bodies (the spin axis found by its radius profile: every rotation about the centre weak): after the spin
    # closure, the rotations about the two short axes re-estimated from interior keypoints matched to frame 0 and
    # earlier corrected frames, in the frames whose spin the texture measured, when the model is longer along its axis
    # than across (service.tracking.tilt; only with spin_closure on; docs/tracking-findings.md "Eggs: where the error
    # comes from"; the evaluation sessions, egg 707 included, identical bit for bit)
    spin_tilt: bool = True  # development eggs 512 7.31 -> 5.54 deg median, 922 17.05 -> 14.39, 924 3.23 -> 1.54
    # (re-measured on the later development eggs: acts on 9 fresh ones, off gains on 3, loses on 2, mixed on 3, level on
    # 1; off gains on 1361, 1362, 1370: kept on; docs/tracking-findings.md "Does the tilt closure still earn its
    # place?")
    # the tilt closure's correction kept only near the frames it measured: a frame d frames from the nearest one keeps
    # max(0, 1 - d/spin_tilt_reach) of it, beyond that the loop's own pose (tilt.reach_weights); 0: off, the correction
    # interpolated between measured frames and held at the ends (the earlier outputs, bit for bit). A companion of
    # track_ransac_px (docs/tracking-findings.md "Eggs with the camera consensus: what the later stages do"): 15 with
    # px 2 on development eggs 1361 25.50 -> 22.63, 1362 18.40 -> 10.65 deg median, 1371 34.06 -> 35.46; judge (fresh
    # eggs 1980-1985, bottle topples 1992-1993): gains on 1 of 6 eggs, 1983's worst frame +0.57 deg: off
    spin_tilt_reach: int = 0
    # the settled stretch after every topple landing checked (tracker._resettle_flush; after the final pass):
    # the face of the pre-fall model that lies on the table at the settled frame (resettle.landed_face) is laid flush
    # with the table in every frame of the stretch whose pose has it within resettle_flush_deg of flat
    # (resettle.flush_pose: an object at rest on a face has it on the table; two tilts and the height), the stretch's
    # keyframes moved with their frames and the model rebuilt, then each frame re-registered in the motions that keep it
    # resting (a turn about the vertical and a horizontal shift, resettle.planar_register; 0: off)
    resettle_flush_deg: float = 10.0  # on: development topples: 7 of 7 lower median rotation
    # (docs/tracking-findings.md, "Worst frames of l_block 702 and milk_carton topple 710")
    # the landed face's fitted normal made square to the base the object stood on at frame 0 when within
    # resettle_flush_square_deg of it (a side of a prism standing on its base; 0: the fitted normal as it is)
    resettle_flush_square_deg: float = 5.0
    # the second pass over the flushed stretch (resettle.planar_register) on or off (the poses only laid flush)
    resettle_flush_planar: bool = True
    # the frames before the settled frame at rest with it (tracker._rest_before): their object points lie on the
    # settled frame's (resettle.still_fit: at least resettle_flush_rest_frac of them within 1 cm, median
    # point-to-plane distance <= resettle_flush_rest_tol) and their ORB keypoints matched to its (at least
    # resettle_flush_rest_matches) lie within resettle_flush_rest_shift of them (median): the object has moved by
    # a few millimetres at most since, so they take the settled frame's final pose moved by the rigid motion their
    # keypoints show (geometry.ransac_rigid, inlier distance resettle_flush_rest_ransac), walking back from the
    # settled frame to the first frame that moved (0: off)
    resettle_flush_rest_tol: float = 0.002  # on: development milk_carton 1304 worst 7.64 -> 5.48 deg, 1306's rest
    # frames 9.23 -> 1.82 deg; evaluation 703 / 710 within 0.01 deg of their medians, 710's worst (6.30) not reached
    resettle_flush_rest_frac: float = 0.9
    resettle_flush_rest_shift: float = 0.008
    resettle_flush_rest_matches: int = 10
    resettle_flush_rest_ransac: float = 0.004
    # the fall's frames of an adopted join (tracker._settle_backward) on the tipping path: between the last frame
    # standing and the settled frame the object turns about its leading bottom edge on the table (resettle.tip_path,
    # resettle.leading_pivot); each frame is registered from one more start, the path pose its points fit best
    # (resettle.path_keys), and among the consistent registrations whose fit score (inlier fraction - 0.02 per mm of
    # RMSE) is within resettle_tip_tol of the best the one nearest to the path wins (rotation in degrees plus
    # resettle_tip_m_deg degrees per metre of translation); the fit alone cannot tell them apart (0: off)
    resettle_tip_tol: float = 0.02  # on: development oat_carton 1381 worst 13.85 -> 7.83 deg, 1387 14.52 -> 6.52 deg;
    # evaluation 710 medians within 0.02 deg / 0.01 mm, worst translation 6.50 -> 5.18 mm, its worst rotation (6.30) not reached
    resettle_tip_m_deg: float = 500.0

    def __post_init__(self) -> None:
        for f in fields(self):  # a switch given as "no" or 0 would otherwise act as its truth value
            if f.type in ("bool", bool) and not isinstance(getattr(self, f.name), (bool, np.bool_)):
                raise ValueError(f"TrackingConfig.{f.name} must be true or false, not {getattr(self, f.name)!r}")
        for name in ("max_speed", "max_rate_deg", "kf_min_new_add", "spin_tau", "spin_sep",
                     "spin_border_px", "spin_tol", "spin_inlier_deg", "gauge_frames", "gauge_max_deg",
                     "gauge_max_dist", "gauge_ee_margin",
                     "landing_table_margin", "landing_table_frac", "landing_seen_frac"):
            if not getattr(self, name) >= 0:
                raise ValueError(f"TrackingConfig.{name} must be >= 0, not {getattr(self, name)!r}")
        if not (isinstance(self.refine_dist0, (int, float)) and not isinstance(self.refine_dist0, bool)
                and self.icp_dist_min <= self.refine_dist0 < float("inf")):
            raise ValueError(f"TrackingConfig.refine_dist0 must be finite and >= icp_dist_min = {self.icp_dist_min} (m), "
                             f"not {self.refine_dist0!r}")
        for name in ("resettle_box_slide_short", "resettle_box_slide_frac", "resettle_box_slide_min"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not 0 <= v < float("inf") \
                    or (name == "resettle_box_slide_frac" and v > 1):
                raise ValueError(f"TrackingConfig.{name} must be a finite number >= 0"
                                 f"{' and <= 1' if name.endswith('frac') else ' (m)'}, not {v!r}")
        if not (isinstance(self.refine_slow_deg, (int, float)) and not isinstance(self.refine_slow_deg, bool)
                and 0 <= self.refine_slow_deg < float("inf")):
            raise ValueError(f"TrackingConfig.refine_slow_deg must be finite and >= 0 (degrees per frame; 0: off), "
                             f"not {self.refine_slow_deg!r}")
        if isinstance(self.refine_slow_frames, bool) or not isinstance(self.refine_slow_frames, (int, np.integer)) \
                or self.refine_slow_frames < 1:
            raise ValueError(f"TrackingConfig.refine_slow_frames must be an integer >= 1, not {self.refine_slow_frames!r}")
        if not (isinstance(self.refine_slow_dist0, (int, float)) and not isinstance(self.refine_slow_dist0, bool)
                and self.icp_dist_min <= self.refine_slow_dist0 < float("inf")):
            raise ValueError(f"TrackingConfig.refine_slow_dist0 must be finite and >= icp_dist_min = "
                             f"{self.icp_dist_min} (m), not {self.refine_slow_dist0!r}")
        if not (isinstance(self.spin_tilt_reach, int) and not isinstance(self.spin_tilt_reach, bool)
                and self.spin_tilt_reach >= 0):
            raise ValueError(f"TrackingConfig.spin_tilt_reach must be an int >= 0 (frames), not {self.spin_tilt_reach!r}")
        for name in ("spin_features", "spin_min_votes", "spin_smooth"):
            if not getattr(self, name) >= 1:
                raise ValueError(f"TrackingConfig.{name} must be >= 1, not {getattr(self, name)!r}")

        v = self.track_ransac_px
        if v is not None and (isinstance(v, bool) or not isinstance(v, (int, float)) or not v > 0):
            raise ValueError(f"TrackingConfig.track_ransac_px must be None or > 0 (pixels), not {v!r}")
        if self.spin_profile not in ("off", "mixed", "multi", "always"):
            raise ValueError("TrackingConfig.spin_profile must be 'off', 'mixed', 'multi' or 'always', "
                             f"not {self.spin_profile!r}")
        if self.spin_solver not in ("chain", "mixed"):
            raise ValueError(f"TrackingConfig.spin_solver must be 'chain' or 'mixed', not {self.spin_solver!r}")
        if not self.spin_mixed_rate_deg >= 0:
            raise ValueError(f"TrackingConfig.spin_mixed_rate_deg must be >= 0, not {self.spin_mixed_rate_deg!r}")
        if not self.spin_mixed_span >= 1:
            raise ValueError(f"TrackingConfig.spin_mixed_span must be >= 1, not {self.spin_mixed_span!r}")
        if not self.spin_mixed_votes >= 0:
            raise ValueError(f"TrackingConfig.spin_mixed_votes must be >= 0, not {self.spin_mixed_votes!r}")
        if not self.spin_mixed_dilate >= 0:
            raise ValueError(f"TrackingConfig.spin_mixed_dilate must be >= 0, not {self.spin_mixed_dilate!r}")
        if not (isinstance(self.spin_twist_smooth, int) and self.spin_twist_smooth >= 0):
            raise ValueError(f"TrackingConfig.spin_twist_smooth must be an int >= 0, not {self.spin_twist_smooth!r}")
        for name in ("spin_graph_gate_deg", "spin_graph_rate_deg"):
            if not getattr(self, name) >= 0:
                raise ValueError(f"TrackingConfig.{name} must be >= 0, not {getattr(self, name)!r}")
        for name in ("spin_graph_votes", "spin_graph_short", "spin_graph_long_votes"):
            if not getattr(self, name) >= 1:
                raise ValueError(f"TrackingConfig.{name} must be >= 1, not {getattr(self, name)!r}")
        if not self.spin_max_deg >= 0:
            raise ValueError(f"TrackingConfig.spin_max_deg must be >= 0, not {self.spin_max_deg!r}")
        for name in ("sdf_band_px", "sdf_contradict_margin"):
            if not getattr(self, name) >= 0:
                raise ValueError(f"TrackingConfig.{name} must be >= 0, not {getattr(self, name)!r}")
        if not self.sdf_contradict_views >= 1:
            raise ValueError(f"TrackingConfig.sdf_contradict_views must be >= 1, not {self.sdf_contradict_views!r}")
        for name in ("settle_fast_deg", "settle_fall_deg"):
            if not getattr(self, name) >= 0:
                raise ValueError(f"TrackingConfig.{name} must be >= 0, not {getattr(self, name)!r}")
        if not 0 < self.lost_land_tilt_deg < 90:
            raise ValueError("TrackingConfig.lost_land_tilt_deg must be in (0, 90) degrees, "
                             f"not {self.lost_land_tilt_deg!r}")
        for name in ("lost_land_deg", "lost_land_dist"):
            if not getattr(self, name) > 0:
                raise ValueError(f"TrackingConfig.{name} must be > 0, not {getattr(self, name)!r}")
        for name in ("mask_trim_px", "mask_trim_iters", "mask_trim_deep_px"):
            if not getattr(self, name) >= 1:
                raise ValueError(f"TrackingConfig.{name} must be >= 1, not {getattr(self, name)!r}")
        if not 0 <= self.mask_trim_min <= 1:
            raise ValueError(f"TrackingConfig.mask_trim_min must be in [0, 1], not {self.mask_trim_min!r}")
        if not (isinstance(self.sdf_silhouette_px, int) and not isinstance(self.sdf_silhouette_px, bool)
                and self.sdf_silhouette_px >= 0):
            raise ValueError(f"TrackingConfig.sdf_silhouette_px must be an int >= 0, not {self.sdf_silhouette_px!r}")
        if not 0 <= self.sdf_silhouette_back <= self.sdf.trunc:
            raise ValueError(f"TrackingConfig.sdf_silhouette_back must be in [0, sdf.trunc = {self.sdf.trunc}], not "
                             f"{self.sdf_silhouette_back!r}")
        if self.sdf_silhouette_margin is not None and not self.sdf_silhouette_margin >= 0:
            raise ValueError(f"TrackingConfig.sdf_silhouette_margin must be None or >= 0, not {self.sdf_silhouette_margin!r}")
        if not self.sdf_carve_value > 0:
            raise ValueError(f"TrackingConfig.sdf_carve_value must be > 0 (outside), not {self.sdf_carve_value!r}")
        for name in ("resettle_tip_deg", "resettle_min_tip_deg", "resettle_min_deg", "resettle_min_dist",
                     "resettle_max_shift", "resettle_seen"):
            if not getattr(self, name) >= 0:
                raise ValueError(f"TrackingConfig.{name} must be >= 0, not {getattr(self, name)!r}")
        if not 0.0 <= self.resettle_box_rest < float("inf"):
            raise ValueError(f"TrackingConfig.resettle_box_rest must be finite and >= 0 (m), not {self.resettle_box_rest!r}")
        if not self.resettle_delay >= 1:
            raise ValueError(f"TrackingConfig.resettle_delay must be >= 1, not {self.resettle_delay!r}")
        for name in ("resettle_flush_deg", "resettle_flush_square_deg"):
            if not 0.0 <= getattr(self, name) < 90.0:
                raise ValueError(f"TrackingConfig.{name} must be in [0, 90), not {getattr(self, name)!r}")
        rest_ok = {  # the frames at rest before the settled frame: each setting's own range
            "resettle_flush_rest_tol": self.resettle_flush_rest_tol >= 0,
            "resettle_flush_rest_frac": 0.0 < self.resettle_flush_rest_frac <= 1.0,
            "resettle_flush_rest_shift": self.resettle_flush_rest_shift > 0,
            "resettle_flush_rest_ransac": self.resettle_flush_rest_ransac > 0,
            "resettle_flush_rest_matches": isinstance(self.resettle_flush_rest_matches, int)
            and not isinstance(self.resettle_flush_rest_matches, bool) and self.resettle_flush_rest_matches >= 1,
        }
        bad = [name for name, ok in rest_ok.items() if not ok]
        if bad:
            raise ValueError(f"TrackingConfig.{bad[0]} out of range ({getattr(self, bad[0])!r}): "
                             "resettle_flush_rest_tol must be >= 0, resettle_flush_rest_frac in (0, 1], "
                             "resettle_flush_rest_shift and resettle_flush_rest_ransac > 0, resettle_flush_rest_matches "
                             "an int >= 1")
        for name in ("resettle_tip_tol", "resettle_tip_m_deg"):
            if not 0.0 <= getattr(self, name) < np.inf:
                raise ValueError(f"TrackingConfig.{name} must be >= 0 and finite, not {getattr(self, name)!r}")
        if not (isinstance(self.resettle_refine_frames, int) and self.resettle_refine_frames >= 0):
            raise ValueError(f"TrackingConfig.resettle_refine_frames must be an int >= 0, not {self.resettle_refine_frames!r}")
        if not (isinstance(self.sdf_support_open_dilate, int) and self.sdf_support_open_dilate >= 0):
            raise ValueError(f"TrackingConfig.sdf_support_open_dilate must be an int >= 0, not "
                             f"{self.sdf_support_open_dilate!r}")
        if not 0 <= self.sdf_support_open_gate <= 1:
            raise ValueError(f"TrackingConfig.sdf_support_open_gate must be in [0, 1], not {self.sdf_support_open_gate!r}")
        for name in ("spin_fall_rate_deg", "spin_fall_edge_deg", "spin_fall_tol_deg"):
            if not getattr(self, name) >= 0:
                raise ValueError(f"TrackingConfig.{name} must be >= 0, not {getattr(self, name)!r}")
        if not 0.0 <= self.spin_pivot_deg < self.spin_fall_min_deg:
            raise ValueError(f"TrackingConfig.spin_pivot_deg must be >= 0 and below spin_fall_min_deg "
                             f"({self.spin_fall_min_deg!r}), not {self.spin_pivot_deg!r}")
        if not 0 < self.spin_fall_min_deg <= 90:
            raise ValueError(f"TrackingConfig.spin_fall_min_deg must be in (0, 90], not {self.spin_fall_min_deg!r}")
        for name in ("lie_level_stand_deg", "lie_level_deg", "lie_level_max_deg"):
            if not 0 < getattr(self, name) < 90:
                raise ValueError(f"TrackingConfig.{name} must be in (0, 90), not {getattr(self, name)!r}")
        for name in ("lie_axis_short", "lie_axis_len_tol", "lie_axis_window", "lie_axis_spread", "lie_axis_min_shift"):
            if not 0.0 <= getattr(self, name) < np.inf:
                raise ValueError(f"TrackingConfig.{name} must be >= 0 and finite (m), not {getattr(self, name)!r}")
        if not self.lie_level_margin >= 0:
            raise ValueError(f"TrackingConfig.lie_level_margin must be >= 0, not {self.lie_level_margin!r}")
        if not 0 <= self.spin_arc_tau < 1:
            raise ValueError(f"TrackingConfig.spin_arc_tau must be in [0, 1), not {self.spin_arc_tau!r}")
        if not 0 <= self.spin_flat_kappa < 1:
            raise ValueError(f"TrackingConfig.spin_flat_kappa must be in [0, 1), not {self.spin_flat_kappa!r}")
        if not (isinstance(self.spin_sep_kappa, (int, float)) and not isinstance(self.spin_sep_kappa, bool)
                and 0 <= self.spin_sep_kappa < float("inf")):
            raise ValueError(f"TrackingConfig.spin_sep_kappa must be a finite number >= 0, not {self.spin_sep_kappa!r}")

    @classmethod
    def fast(cls) -> "TrackingConfig":
        from dataclasses import replace

        return cls(max_points=600, erode_px=1, min_points=15, icp_iters=10, refine_rounds=1, sdf=replace(SdfConfig.fast(), w_empty=300.0), sdf_frames=10,
                   sdf_stride=2, sdf_ring_px=8, visible_samples=600, visible_frames=10, n_features=200)
