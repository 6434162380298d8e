"""Table-plane detection on synthetic depth, and robot-log interpolation to the frame times."""

from __future__ import annotations

import numpy as np
import pytest

from service.session import ingest
from service.session.robot import check_coverage, interpolate
from service.session.table import TablePlaneConfig, detect_table_plane
from service.errors import InvalidSession
from tests.session.conftest import K, Spec, look_at, render, write_session


@pytest.mark.parametrize("table_z,noise", [(0.0, 0.002), (0.043, 0.004), (-0.12, 0.003)])
def test_table_height_recovered_from_noisy_depth(table_z, noise):
    rng = np.random.default_rng(7)
    X_WC = look_at(np.array([0.1, -0.2, table_z + 0.7]), np.array([0.55, 0.05, table_z]))
    K2 = K.copy()  # the fixture K is for 32x24; scale it to 64x48
    K2[:2] *= 2
    K2[0, 2], K2[1, 2] = 31.5, 23.5
    depths, masks = [], []
    for i in range(5):
        lo = [0.5 + 0.01 * i, 0.0, table_z]
        hi = [0.6 + 0.01 * i, 0.1, table_z + 0.08]
        d, m = render(X_WC, K2, table_z, lo, hi, w=64, h=48, noise=noise, rng=rng)
        depths.append(d.astype(np.float32))
        masks.append(m)
    assert all(m.sum() > 10 for m in masks)
    plane = detect_table_plane(depths, masks, K2, X_WC)
    assert plane is not None
    assert abs(plane.height - table_z) < 0.005
    assert plane.normal_W[2] > np.cos(np.deg2rad(2.0))


def test_table_below_object_preferred_over_higher_shelf():
    """A larger horizontal surface above the object (a shelf) must not be taken for the table."""
    table_z = 0.0
    X_WC = look_at(np.array([0.0, 0.0, 0.8]), np.array([0.5, 0.0, 0.0]))
    K2 = np.array([[60.0, 0, 31.5], [0, 60.0, 23.5], [0, 0, 1]])
    d_t, m = render(X_WC, K2, table_z, [0.45, -0.05, 0.0], [0.55, 0.05, 0.06], w=64, h=48)
    d_s, _ = render(X_WC, K2, 0.15, [9, 9, 9], [9.1, 9.1, 9.1], w=64, h=48)  # shelf at z = 0.15
    u = np.arange(64)[None, :].repeat(48, 0)
    shelf = u < 44  # the shelf covers most of the image, the table only the right part
    d = np.where(shelf & ~m, d_s, d_t).astype(np.float32)
    plane = detect_table_plane([d], [m], K2, X_WC)
    assert plane is not None and abs(plane.height - table_z) < 0.005


def test_no_plane_returns_none():
    rng = np.random.default_rng(0)
    d = rng.uniform(0.3, 1.5, (24, 32)).astype(np.float32)
    X_WC = look_at(np.array([0.0, 0.0, 0.8]), np.array([0.5, 0.0, 0.0]))
    assert detect_table_plane([d], [np.zeros_like(d, bool)], K, X_WC, TablePlaneConfig(min_inliers=100)) is None


def test_table_detected_through_ingest(tmp_path):
    src = write_session(tmp_path / "src", Spec(table_z=0.031, noise=0.002, meta={"table": {"height": None}}))
    s = ingest(src, tmp_path / "d")
    assert s.table_height_detected
    assert abs(s.table_height - 0.031) < 0.005


def test_declared_table_height_is_used(tmp_path):
    s = ingest(write_session(tmp_path / "src", Spec(table_z=0.031)), tmp_path / "d")
    assert not s.table_height_detected and s.table_height == 0.031


def test_interpolation_is_linear_and_exact_on_lines(tmp_path):
    t = np.array([-0.05, 0.02, 0.1, 0.17, 0.25, 0.33])
    f = lambda s: np.stack([0.3 + 0.2 * s, -0.1 - 0.5 * s, 0.05 + 0.0 * s], axis=1)  # noqa: E731
    rows = [["t", "ee_x", "ee_y", "ee_z", "cmd_x", "cmd_y", "cmd_z", "extra"]]
    for ti, p in zip(t, f(t)):
        rows.append([ti, *p, *(p + 0.01), "ignored"])
    s = ingest(write_session(tmp_path / "src", Spec(n=4, fps=10.0, robot_rows=rows)), tmp_path / "d")
    np.testing.assert_allclose(s.robot_t, t)
    np.testing.assert_allclose(s.p_WE, f(np.arange(4) / 10.0), atol=1e-12)
    np.testing.assert_allclose(s.cmd_WE, f(np.arange(4) / 10.0) + 0.01, atol=1e-12)


def test_interpolate_piecewise_against_naive():
    rng = np.random.default_rng(1)
    t = np.cumsum(rng.uniform(0.01, 0.1, 30))
    y = rng.standard_normal((30, 3))
    s = np.sort(rng.uniform(t[0], t[-1], 50))
    got = interpolate(t, y, s)
    for i, si in enumerate(s):
        k = min(np.searchsorted(t, si, side="right") - 1, len(t) - 2)
        w = (si - t[k]) / (t[k + 1] - t[k])
        np.testing.assert_allclose(got[i], (1 - w) * y[k] + w * y[k + 1], atol=1e-12)


def test_coverage_tolerance_half_a_frame():
    ft = np.arange(10) / 30.0
    check_coverage(np.array([0.01, 0.3]), ft)  # starts 10 ms late: within 16.7 ms
    with pytest.raises(InvalidSession, match="cover every frame"):
        check_coverage(np.array([0.02, 0.3]), ft)  # 20 ms late
    with pytest.raises(InvalidSession, match="cover every frame"):
        check_coverage(np.array([0.0, 0.27]), ft)  # ends 30 ms early


def test_frames_just_outside_robot_span_hold_end_values(tmp_path):
    rows = [["t", "ee_x", "ee_y", "ee_z"], [0.02, 0.3, 0.0, 0.05], [0.3, 0.6, 0.0, 0.05]]
    s = ingest(write_session(tmp_path / "src", Spec(n=4, fps=10.0, robot_rows=rows)), tmp_path / "d")
    assert s.p_WE[0, 0] == pytest.approx(0.3)
    assert s.p_WE[1, 0] == pytest.approx(0.3 + 0.3 * (0.08 / 0.28))


def test_table_preferred_over_larger_floor_below():
    """The camera sees more floor (z = -0.75) than table (z = 0): the table under the object wins."""
    X_WC = look_at(np.array([-0.2, 0.0, 0.9]), np.array([0.6, 0.0, -0.4]))
    K2 = np.array([[50.0, 0, 31.5], [0, 50.0, 23.5], [0, 0, 1]])
    lo, hi = [0.45, -0.05, 0.0], [0.55, 0.05, 0.08]
    d_table, m = render(X_WC, K2, 0.0, lo, hi, w=64, h=48)
    d_floor, _ = render(X_WC, K2, -0.75, [9, 9, 9], [9.1, 9.1, 9.1], w=64, h=48)
    # the table is the rectangle x in [0.2, 0.8], |y| < 0.35; elsewhere the ray reaches the floor
    u, v = np.meshgrid(np.arange(64), np.arange(48))
    r = np.stack([(u - 31.5) / 50.0, (v - 23.5) / 50.0, np.ones_like(u, float)], -1) @ X_WC[:3, :3].T
    p = X_WC[:3, 3] + d_table[..., None] * r
    on_table = (p[..., 0] > 0.2) & (p[..., 0] < 0.8) & (np.abs(p[..., 1]) < 0.35)
    d = np.where(m | on_table, d_table, d_floor).astype(np.float32)
    n_floor, n_table = (~on_table & ~m).sum(), on_table.sum()
    assert n_floor > 2 * n_table > 0.4 * n_floor  # more floor than table in view
    plane = detect_table_plane([d], [m], K2, X_WC)
    assert plane is not None and abs(plane.height) < 0.005


def test_slices_through_a_tall_occluder_are_not_a_table():
    """The object's lower part is hidden (its mask starts 6 cm up), so horizontal slices through a tall
    unmasked box next to it lie below z_max; they must not be taken for the table."""
    X_WC = look_at(np.array([0.1, -0.4, 0.5]), np.array([0.5, 0.0, 0.0]))
    K2 = np.array([[60.0, 0, 31.5], [0, 60.0, 23.5], [0, 0, 1]])
    rng = np.random.default_rng(2)
    d_obj, m_obj = render(X_WC, K2, 0.0, [0.45, -0.05, 0.0], [0.57, 0.07, 0.12], w=64, h=48)
    d_wall, m_wall = render(X_WC, K2, 0.0, [0.3, 0.1, 0.0], [0.7, 0.35, 0.5], w=64, h=48)
    d = np.where(m_wall & ~(m_obj & (d_obj < d_wall)), d_wall, d_obj)
    d = (d + rng.normal(0, 0.002, d.shape) * (d > 0)).astype(np.float32)
    u, v = np.meshgrid(np.arange(64), np.arange(48))
    r = np.stack([(u - 31.5) / 60.0, (v - 23.5) / 60.0, np.ones_like(u, float)], -1) @ X_WC[:3, :3].T
    z = (X_WC[:3, 3] + d[..., None] * r)[..., 2]
    mask = m_obj & (d <= d_obj + 1e-6) & (z > 0.06)
    assert mask.sum() > 20
    plane = detect_table_plane([d], [mask], K2, X_WC)
    assert plane is not None and abs(plane.height) < 0.005


def test_slightly_tilted_table_from_calibration_error():
    """X_WC off by 3 deg: the table is tilted in W; its height under the object is still found."""
    from service.transforms import so3_exp

    X_true = look_at(np.array([0.0, -0.2, 0.7]), np.array([0.5, 0.0, 0.0]))
    K2 = np.array([[60.0, 0, 31.5], [0, 60.0, 23.5], [0, 0, 1]])
    d, m = render(X_true, K2, 0.0, [0.45, -0.05, 0.0], [0.55, 0.05, 0.08], w=64, h=48, noise=0.002)
    p0 = np.array([0.5, 0.0, 0.0])  # rotate the world about a table point under the object
    R = so3_exp(np.deg2rad(3.0) * np.array([1.0, 0.5, 0.0]) / np.linalg.norm([1.0, 0.5]))
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = p0 - R @ p0
    X_bad = T @ X_true
    plane = detect_table_plane([d.astype(np.float32)], [m], K2, X_bad)
    assert plane is not None
    n_true = R @ np.array([0.0, 0.0, 1.0])
    assert np.degrees(np.arccos(min(1.0, plane.normal_W @ n_true))) < 1.0
    # expected: the rotated table plane's z under the object's centroid (seen through X_bad)
    from service.session.table import back_project

    xy = back_project(d.astype(np.float32), K2, X_bad, m)[:, :2].mean(axis=0)
    z_exp = p0[2] - (n_true[0] * (xy[0] - p0[0]) + n_true[1] * (xy[1] - p0[1])) / n_true[2]
    assert abs(plane.height - z_exp) < 0.005
