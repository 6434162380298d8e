"""Fusion stage: a box seen from one side only, contacts on its hidden faces (sim-to-recover)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from service.errors import StageFailed
from service.fusion import FusionConfig, FusionInputs, LossWeights, run, session_rays
from service.fusion.stage import fusion_bounds, select_frames
from service.sdf import extract_mesh, fit_sdf, sdf_query
from tests.fusion.scenes import HALF, box_mesh, box_sdf, chamfer, face_points, hidden_contacts, write_box_session

CFG = FusionConfig.fast()


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    session, X_WO = write_box_session(tmp_path_factory.mktemp("box_session"))
    tracked = np.ones(len(X_WO), bool)
    rays = session_rays(session, X_WO, tracked, CFG)
    visible = fit_sdf(rays, dataclasses.replace(CFG.sdf, steps=60))  # the first (vision-only) pass
    P, N = hidden_contacts(np.random.default_rng(0))
    inputs = FusionInputs(session, X_WO, tracked, visible, P, N, box_mesh())
    return inputs, visible, extract_mesh(visible)


def face_error(grid, axis, sign):
    pts, _ = face_points(300, axis, sign, np.random.default_rng(1), margin=0.2)
    return float(np.mean(sdf_query(grid, pts)))


def test_run_recovers_hidden_faces(scene):
    inputs, visible, visible_mesh = scene
    progress = []
    out = run(inputs, CFG, progress=lambda f, m: progress.append(f))
    truth = box_mesh()
    c_vis, c_fused = chamfer(visible_mesh, truth), chamfer(out.mesh, truth)
    assert c_vis > 0.005  # the vision-only surface misses the hidden half
    assert c_fused < 0.5 * c_vis and c_fused < 0.003
    for axis, sign in [(0, -1.0), (2, -1.0), (1, -1.0)]:  # hidden faces with contacts
        assert abs(face_error(visible, axis, sign)) > 0.005
        assert abs(face_error(out.sdf, axis, sign)) < 0.002
    tm = out.mesh.to_trimesh()
    assert tm.is_watertight
    assert tm.volume == pytest.approx(np.prod(2 * HALF), rel=0.15)
    assert out.metrics["physible_points"] == 70 and out.metrics["anchors"] > 0
    assert progress[0] == 0.0 and progress[-1] == 1.0 and all(np.diff(progress) >= 0)


def test_contact_losses_attach_hidden_faces_from_visible_start(scene):
    """From the vision-only grid, the support-point/hyperplane/convexity terms alone close the box."""
    inputs, _, _ = scene
    cfg = dataclasses.replace(CFG, init="visible", sdf=dataclasses.replace(CFG.sdf, steps=80))
    with_terms = run(inputs, cfg)
    without = run(inputs, dataclasses.replace(cfg, weights=LossWeights(sp=0.0, hc=0.0, cvx=0.0)))
    truth = box_mesh()
    assert chamfer(with_terms.mesh, truth) < 0.75 * chamfer(without.mesh, truth)
    assert abs(face_error(with_terms.sdf, 0, -1.0)) < 0.5 * abs(face_error(without.sdf, 0, -1.0))


def test_bounds_cover_visible_and_physible():
    vis = np.random.default_rng(0).uniform(-0.05, 0.05, size=(500, 3))
    P = np.array([[0.0, 0.0, -0.12], [0.09, 0.0, 0.0]])
    b = fusion_bounds(vis, None, P, pad=0.02)
    assert np.all(b[0] <= np.minimum(vis.min(0), P.min(0)) - 0.02 + 1e-3)
    assert np.all(b[1] >= P.max(0) + 0.02 - 1e-12)


def test_select_frames_spreads_over_tracked():
    tracked = np.zeros(100, bool)
    tracked[10:90] = True
    idx = select_frames(tracked, 5)
    assert len(idx) == 5 and idx[0] == 10 and idx[-1] == 89 and tracked[idx].all()
    assert select_frames(tracked, 1000).tolist() == list(range(10, 90))


def test_bad_inputs(scene):
    inputs, _, _ = scene
    with pytest.raises(ValueError, match="X_WO"):
        run(dataclasses.replace(inputs, X_WO=inputs.X_WO[:-1]), CFG)
    with pytest.raises(ValueError, match="tracked"):
        run(dataclasses.replace(inputs, tracked=inputs.tracked[:-1]), CFG)
    with pytest.raises(StageFailed):
        run(dataclasses.replace(inputs, tracked=np.zeros_like(inputs.tracked)), CFG)
    with pytest.raises(ValueError):
        run(dataclasses.replace(inputs, physible_normals_O=inputs.physible_normals_O[:3]), CFG)
    with pytest.raises(ValueError):
        FusionConfig(init="nope")
    with pytest.raises(ValueError, match="table_points"):
        FusionConfig(table_points="nope")


def test_far_physible_outliers_are_dropped(scene):
    inputs, _, _ = scene
    P = np.vstack([inputs.physible_points_O, [[2.0, 0.0, 0.0]]])
    N = np.vstack([inputs.physible_normals_O, [[1.0, 0.0, 0.0]]])
    cfg = dataclasses.replace(CFG, sdf=dataclasses.replace(CFG.sdf, steps=5))
    out = run(dataclasses.replace(inputs, physible_points_O=P, physible_normals_O=N), cfg)
    assert out.metrics["physible_dropped"] == 1
    assert out.sdf.bounds_O[1][0] < 0.5  # the grid was not stretched to the outlier


def test_no_contacts_and_no_physible_mesh(scene):
    """Without a physible set the pass is a vision-only refit; it still returns a closed surface."""
    inputs, _, _ = scene
    cfg = dataclasses.replace(CFG, sdf=dataclasses.replace(CFG.sdf, steps=5))
    empty = dataclasses.replace(inputs, physible_points_O=np.zeros((0, 3)), physible_normals_O=np.zeros((0, 3)))
    out = run(empty, cfg)
    assert out.mesh.to_trimesh().is_watertight and out.metrics["sp_samples"] == 0
    from service.mesh import Mesh

    no_mesh = dataclasses.replace(inputs, physible_mesh=Mesh(np.zeros((0, 3)), np.zeros((0, 3), np.int64)))
    out = run(no_mesh, cfg)
    assert out.metrics["anchors"] == 0 and out.metrics["hc_samples"] == 0 and out.metrics["sp_samples"] > 0


def test_session_rays_filter_table_and_outliers(scene):
    inputs, visible, _ = scene
    s, X, tr = inputs.session, inputs.X_WO, inputs.tracked
    plain = session_rays(s, X, tr, CFG)
    with_sdf = session_rays(s, X, tr, CFG, visible)
    n_plain, n_sdf = int((plain.depth > 0).sum()), int((with_sdf.depth > 0).sum())
    assert n_sdf >= 0.9 * n_plain  # the visible SDF explains the observed points
    far = dataclasses.replace(visible, origin_O=visible.origin_O + np.array([0.2, 0.0, 0.0]))
    assert int((session_rays(s, X, tr, CFG, far).depth > 0).sum()) == 0
    high = dataclasses.replace(s, table_height=0.03)
    rays = session_rays(high, X, tr, CFG)
    surf_O = rays.surface_points_O
    assert 0 < len(surf_O) < n_plain
    # O and W differ by a translation only in this scene (z offset HALF[2] plus the frame's slide)
    assert np.all(surf_O[:, 2] + HALF[2] > 0.03 + CFG.table_clearance - 1e-3)


def test_depth_jump_tests_drop_blends_and_contours():
    """A flying pixel between a near plate and the far background fails both tests; its neighbours at the contour
    fail them too; a pixel next to a missing reading fails only the tracking's test (holes count as jumps)."""
    from service.tracking.geometry import depth_continuous

    def depth_jump_free(D, u, v, jump):
        return depth_continuous(D, u, v, jump, holes=False)

    D = np.full((9, 9), 1.0)
    D[:, :4] = 0.5  # near plate on the left, background at 1 m
    D[4, 4] = 0.75  # blend at the step
    D[1, 1] = 0.0  # a hole inside the plate
    v, u = np.indices(D.shape).reshape(2, -1)
    for test in (depth_jump_free, depth_continuous):
        ok = test(D, u, v, 0.01).reshape(D.shape)
        assert not ok[4, 4] and not ok[4, 3] and not ok[2, 3]  # the blend, the contour of the plate
        assert ok[6, 1] and ok[6, 7]  # inside the plate, inside the background
    assert depth_jump_free(D, u, v, 0.01).reshape(D.shape)[1, 2]
    assert not depth_continuous(D, u, v, 0.01).reshape(D.shape)[1, 2]


def test_session_rays_drop_flying_pixels(scene):
    inputs, _, _ = scene
    s, X, tr = inputs.session, inputs.X_WO, inputs.tracked
    off = dataclasses.replace(CFG, drop_flying=False)
    n_all = int((session_rays(s, X, tr, off).depth > 0).sum())
    fly = session_rays(s, X, tr, dataclasses.replace(CFG, drop_flying=True))
    n_fly = int((fly.depth > 0).sum())
    assert 0 < n_fly < n_all  # the box's contour pixels (a jump to the table behind) go
    kept = fly.surface_points_O
    allp = session_rays(s, X, tr, off).surface_points_O
    dropped = allp[np.min(np.linalg.norm(allp[:, None] - kept[None], axis=2), axis=1) > 1e-9]
    edge = lambda P: np.sort(HALF - np.abs(P), axis=1)[:, 1]  # noqa: E731  distance of a face point to its nearest edge
    assert len(dropped) and np.median(edge(dropped)) < np.median(edge(kept))  # the silhouette rim goes
    out: list = []
    session_rays(s, X, tr, dataclasses.replace(CFG, drop_flying=True), flying_out=out)
    rim = np.concatenate(out)  # every removed reading (all pixels, not only the ray grid), for the hull start
    assert len(rim) > len(dropped) and np.all(np.abs(box_sdf(rim)) < 0.004) and np.median(edge(rim)) < 0.004


def test_flat_view_without_contacts_falls_back_to_visible_start():
    """One camera square to the +x face sees a flat patch: no hull exists, the visible grid is the start."""
    from service.fusion import fuse
    from service.sdf.grid import grid_points
    from service.sdf.types import SdfGrid
    from tests.fusion.scenes import box_sdf, camera_rays

    rays = camera_rays(np.array([[0.4, 0.0, 0.0]]), n_px=24)
    surf = rays.surface_points_O
    assert len(surf) > 10 and np.ptp(surf[:, 0]) < 1e-9  # all on the plane x = +half_x
    lo, voxel = -HALF - 0.03, 0.005
    shape = tuple(int(n) for n in np.ceil(2 * (HALF + 0.03) / voxel) + 1)
    values = box_sdf(grid_points(lo, voxel, shape).reshape(-1, 3)).reshape(shape).astype(np.float32)
    visible = SdfGrid(lo, voxel, values)
    cfg = dataclasses.replace(CFG, sdf=dataclasses.replace(CFG.sdf, steps=3))
    out = fuse(rays, visible, np.zeros((0, 3)), np.zeros((0, 3)), None, cfg)
    assert out.mesh.to_trimesh().is_watertight
    assert chamfer(out.mesh, box_mesh()) < 0.004  # it kept the (here exact) visible start


def test_halfspace_below_the_table_stays_outside(scene):
    """A plane through the box (z_O = -0.01): the fused geometry keeps nothing on its outer side."""
    from service.fusion import fuse

    inputs, visible, _ = scene
    rays = session_rays(inputs.session, inputs.X_WO, inputs.tracked, CFG)
    plane = np.array([0.0, 0.0, -1.0, -0.01])  # n·p + b > 0  <=>  z < -0.01
    out = fuse(rays, visible, inputs.physible_points_O, inputs.physible_normals_O, inputs.physible_mesh, CFG,
               halfspace_O=plane)
    z = out.mesh.vertices[:, 2]
    assert z.min() > -0.01 - out.sdf.voxel
    assert z.max() > HALF[2] - 0.004  # the top is still there
    assert out.mesh.to_trimesh().is_watertight


def test_table_contacts_give_planes_not_points(scene):
    """Table witness points spread 2 cm past the hidden +y face (a face-on-table contact fixes the plane, not
    where on it the witness lies): used as points they pull the surface out to them; as planes they do not."""
    from service.fusion import fuse

    inputs, visible, _ = scene
    rays = session_rays(inputs.session, inputs.X_WO, inputs.tracked, CFG)
    rng = np.random.default_rng(3)
    n_out = 30
    Q = np.stack([rng.uniform(-0.03, 0.03, n_out), np.full(n_out, HALF[1] + 0.02), np.full(n_out, -HALF[2])], 1)
    P = np.concatenate([inputs.physible_points_O, Q])
    N = np.concatenate([inputs.physible_normals_O, np.tile([0.0, 0.0, -1.0], (n_out, 1))])
    table = np.concatenate([inputs.physible_normals_O[:, 2] < -0.9, np.ones(n_out, bool)])
    cfg = dataclasses.replace(CFG, sdf=dataclasses.replace(CFG.sdf, steps=80))
    as_points = fuse(rays, visible, P, N, inputs.physible_mesh, dataclasses.replace(cfg, table_points="points"),
                     table_mask=table)
    as_planes = fuse(rays, visible, P, N, inputs.physible_mesh, dataclasses.replace(cfg, table_points="footprint"),
                     table_mask=table)
    probe = Q + np.array([0.0, 0.0, 0.01])  # 1 cm above the table, 2 cm past the true face
    assert np.mean(sdf_query(as_points.sdf, probe)) < 0.004
    assert np.mean(sdf_query(as_planes.sdf, probe)) > 0.01
    assert as_planes.metrics["physible_table"] == table.sum()
    truth = box_mesh()
    assert chamfer(as_planes.mesh, truth) < chamfer(as_points.mesh, truth)
    with pytest.raises(ValueError, match="table_mask"):
        fuse(rays, visible, P, N, None, cfg, table_mask=table[:-1])


def test_penetration_filter_uses_only_poses_the_depth_agrees_with(scene):
    """A wrong pose that sinks the box 3 cm into the table would drop every bottom contact; its depth disagrees
    with the visible SDF, so it is not used to judge the physible points."""
    inputs, _, _ = scene
    cfg = dataclasses.replace(CFG, sdf=dataclasses.replace(CFG.sdf, steps=5))
    X_bad = inputs.X_WO.copy()
    X_bad[3, 2, 3] -= 0.03
    bad = dataclasses.replace(inputs, X_WO=X_bad)
    out = run(bad, cfg)
    assert out.metrics["physible_penetrating_dropped"] == 0
    assert out.metrics["frames_pose_checked"] == len(X_bad) - 1
    unchecked = run(bad, dataclasses.replace(cfg, pose_residual_max=np.inf))
    assert unchecked.metrics["physible_penetrating_dropped"] >= 40  # every bottom contact, at least
    assert run(inputs, cfg).metrics["physible_penetrating_dropped"] == 0


def test_seen_through_fin_is_carved_and_unsupported_thin_part_removed(scene):
    """A fin standing 2 cm on the seen top face, 6 mm thick, that the camera sees through onto the top face: it
    stays without the removals, goes with the free-space carving (default; up to the 1 cm margin), and mostly goes
    with the thin-part removal alone (no depth point or contact within 4 mm of most of it)."""
    from service.sdf.grid import grid_points
    from service.sdf.types import SdfGrid
    from tests.fusion.scenes import box_sdf

    inputs, visible, _ = scene
    P = grid_points(visible.origin_O, visible.voxel, visible.shape).reshape(-1, 3)
    fin = box_sdf(P - [0.015, 0.0, 0.03], half=np.array([0.01, 0.003, 0.01])).reshape(visible.shape)
    finned = SdfGrid(visible.origin_O, visible.voxel, np.minimum(visible.values, fin).astype(np.float32))
    assert extract_mesh(finned).to_trimesh().bounds[1, 2] > 0.035
    # the tiny session renders no background: a depth window touching the silhouette holds no reading, so 1 px
    cfg = dataclasses.replace(CFG, init="visible", sdf=dataclasses.replace(CFG.sdf, steps=3), carve_radius_px=1)
    inp = dataclasses.replace(inputs, visible_sdf=finned)
    keep = run(inp, dataclasses.replace(cfg, carve_free_space=False, thin_open_radius=0.0))
    assert cfg.thin_open_radius == 0.0  # off by default
    assert keep.mesh.to_trimesh().bounds[1, 2] > 0.035
    assert keep.metrics["carved_voxels"] == 0 and keep.metrics["thin_unsupported_voxels"] == 0
    carved = run(inp, cfg)
    assert carved.metrics["carved_voxels"] > 0 and carved.metrics["removal_fallback"] == 0
    assert carved.mesh.to_trimesh().bounds[1, 2] < HALF[2] + cfg.carve_margin + 2 * finned.voxel
    assert carved.mesh.to_trimesh().is_watertight
    thin = run(inp, dataclasses.replace(cfg, carve_free_space=False, thin_open_radius=0.005))
    assert thin.metrics["thin_unsupported_voxels"] > 0

    def above_top(grid):  # solid volume more than 4 mm above the top face, m³
        Q = grid_points(grid.origin_O, grid.voxel, grid.shape).reshape(-1, 3)
        return float(((grid.values.reshape(-1) < 0) & (Q[:, 2] > HALF[2] + 0.004)).sum() * grid.voxel ** 3)

    assert above_top(keep.sdf) > 0.5 * 0.02 * 0.006 * 0.016  # most of the fin is there without the removals
    assert above_top(thin.sdf) < 0.5 * above_top(keep.sdf)  # most of it; the part near the face stays

    def below_top(grid):  # solid volume below the top face, m³
        Q = grid_points(grid.origin_O, grid.voxel, grid.shape).reshape(-1, 3)
        return float(((grid.values.reshape(-1) < 0) & (Q[:, 2] < HALF[2] - 0.004)).sum() * grid.voxel ** 3)

    # carving keeps the rest of the object (what 3 steps from the one-sided visible start have of it)
    assert below_top(carved.sdf) == pytest.approx(below_top(keep.sdf), rel=0.02) and below_top(keep.sdf) > 0


@pytest.mark.parametrize("field, value", [("carve_margin", -0.01), ("carve_radius_px", -1), ("carve_min_frac", 1.5),
                                          ("carve_min_frames", 0), ("thin_open_radius", -0.005),
                                          ("thin_support", float("nan")), ("edge_jump", -0.01)])
def test_config_refuses_bad_removal_settings(field, value):
    with pytest.raises(ValueError, match=f"FusionConfig.{field}"):
        FusionConfig(**{field: value})
