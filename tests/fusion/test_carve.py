"""Free-space votes of points against depth images, and the table-contact classification of physible points."""

from __future__ import annotations

import numpy as np

from service.fusion.carve import free_space_votes, min_depth
from service.fusion.stage import table_contacts

K = np.array([[50.0, 0, 19.5], [0, 50.0, 14.5], [0, 0, 1]])


def wall(depth: float, hole: tuple[slice, slice] | None = None) -> np.ndarray:
    D = np.full((30, 40), depth, np.float32)
    if hole is not None:
        D[hole] = 0.0
    return D


def test_min_depth_is_a_window_minimum_and_zero_spreads():
    D = wall(1.0)
    D[10, 10] = 0.5
    D[20, 30] = 0.0
    m = min_depth(D, 1)
    assert m[9, 9] == 0.5 and m[11, 11] == 0.5 and m[12, 12] == 1.0
    assert m[19, 29] == 0.0 and m[21, 31] == 0.0 and m[22, 32] == 1.0
    assert np.array_equal(min_depth(D, 0), D)


def test_points_in_front_of_a_reading_are_free_behind_are_not():
    X_OC = np.eye(4)  # camera at O's origin looking along +z
    pts = np.array([[0, 0, 0.5], [0, 0, 0.995], [0, 0, 1.5], [0, 0, -0.5], [10.0, 0, 1.0]])
    free, obs = free_space_votes(pts, [wall(1.0)], [X_OC], K, margin=0.01, radius_px=1)
    assert free.tolist() == [1, 0, 0, 0, 0]  # in front; within the margin; behind; behind the camera; off-image
    assert obs.tolist() == [1, 1, 1, 0, 0]
    # a missing reading near the pixel is no evidence
    free, obs = free_space_votes(pts[:1], [wall(1.0, (slice(14, 16), slice(20, 21)))], [X_OC], K, radius_px=1)
    assert free.tolist() == [0] and obs.tolist() == [0]
    # two frames, the second one with the camera moved behind the point: counted per frame
    X2 = np.eye(4)
    X2[2, 3] = 0.8
    free, obs = free_space_votes(pts[:1], [wall(1.0), wall(1.0)], [X_OC, X2], K, margin=0.01, radius_px=0)
    assert free.tolist() == [1] and obs.tolist() == [1]


def test_table_contacts_need_the_downward_normal_at_table_height():
    X_WO = np.repeat(np.eye(4)[None], 3, 0)
    X_WO[:, 2, 3] = 0.02  # O 2 cm above the table (z = 0)
    c, s = np.cos(0.3), np.sin(0.3)
    X_WO[2, :3, :3] = [[1, 0, 0], [0, c, -s], [0, s, c]]  # tilted about x in the last frame
    tracked = np.array([True, True, True])
    down_tilted = -X_WO[2, 2, :3]
    P = np.array([[0.01, 0.0, -0.02], [0.01, 0.0, -0.02], [0.03, 0.0, 0.0], [0.0, 0.0, -0.05],
                  -0.02 * down_tilted / np.linalg.norm(down_tilted) * -1])
    N = np.array([[0, 0, -1.0], [1.0, 0, 0], [0, 0, -1.0], [0, 0, -1.0], down_tilted])
    got = table_contacts(P, N, X_WO, tracked, table_height=0.0)
    # on the table with the table's normal; a sphere contact (sideways); -z but 2 cm above the table;
    # -z but 3 cm below it; the tilted frame's normal at its table height
    assert got.tolist() == [True, False, False, False, True]
    assert not table_contacts(P, N, X_WO, np.array([False, False, True]), 0.0)[0]  # only tracked frames count
    assert table_contacts(np.zeros((0, 3)), np.zeros((0, 3)), X_WO, tracked, 0.0).shape == (0,)


def test_penetrating_points_below_the_table_or_inside_the_end_effector():
    from service.fusion.stage import penetrating

    X_WO = np.repeat(np.eye(4)[None], 2, 0)
    X_WO[:, 2, 3] = 0.02
    c, s = np.cos(0.5), np.sin(0.5)
    X_WO[1, :3, :3] = [[c, 0, s], [0, 1, 0], [-s, 0, c]]  # tilted about y in the second frame
    p_WE = np.array([[0.10, 0.0, 0.06], [np.nan, np.nan, np.nan]])  # sphere only known in frame 0
    P = np.array([
        [0.0, 0.0, -0.02],   # on the table in frame 0, above it in frame 1 (tilt about the origin)
        [0.0, 0.0, -0.03],   # 1 cm below the table in frame 0
        [0.04, 0.0, -0.02],  # on the table at frame 0, sinks 1.7 cm below it in the tilted frame 1
        [0.09, 0.0, 0.04],   # inside the sphere (radius 2 cm) in frame 0
        [0.075, 0.0, 0.04],  # 5 mm outside it
    ])
    got = penetrating(P, X_WO, np.array([True, True]), 0.0, p_WE, 0.02, tol=0.003)
    assert got.tolist() == [False, True, True, True, False]
    # untracked frames do not count; without the robot only the table does
    assert penetrating(P, X_WO, np.array([True, False]), 0.0, p_WE, 0.02, tol=0.003).tolist() == [False, True, False, True, False]
    assert penetrating(P, X_WO, np.array([True, True]), 0.0, None, 0.0, tol=0.003).tolist() == [False, True, True, False, False]
