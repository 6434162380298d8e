"""Depth, masks, K and T_world_camera agree with the true mesh at the true pose (noise off)."""

import json

import cv2
import numpy as np
import pytest
import trimesh

from service.synth import SynthSpec, make_session
from service.synth.camera import backproject
from service.transforms import xyzquat_to_pose


def surface_distances(root, frames):
    """Unsigned distance (m) of masked depth points, back-projected to W and mapped to the mesh frame."""
    s = json.loads((root / "session.json").read_text())
    K = np.asarray(s["camera"]["K"])
    X_WC = np.asarray(s["camera"]["T_world_camera"])
    mesh = trimesh.load(root / "ground_truth" / "mesh.obj", force="mesh")
    poses = np.loadtxt(root / "ground_truth" / "poses.csv", delimiter=",", skiprows=1)
    pq = trimesh.proximity.ProximityQuery(mesh)
    out = []
    for i in frames:
        z = cv2.imread(str(root / "depth" / f"{i:06d}.png"), cv2.IMREAD_UNCHANGED).astype(float) * s["camera"]["depth_scale"]
        m = cv2.imread(str(root / "masks" / f"{i:06d}.png"), cv2.IMREAD_UNCHANGED) > 0
        p_W = backproject(z, K, m) @ X_WC[:3, :3].T + X_WC[:3, 3]
        X_WM = xyzquat_to_pose(poses[i, 1:8])
        p_M = (p_W - X_WM[:3, 3]) @ X_WM[:3, :3]
        out.append(np.abs(pq.signed_distance(p_M)))
    return np.concatenate(out)


def test_tiny_depth_lies_on_true_surface(clean_tiny):
    _, res = clean_tiny
    d = surface_distances(res.session_dir, [0, 30, 59])
    assert len(d) > 300
    assert np.median(d) < 1.5e-3
    assert np.percentile(d, 90) < 4e-3


@pytest.mark.parametrize("kind", ["l_block"])
def test_vga_depth_lies_on_true_surface_within_a_millimetre(kind, tmp_path):
    spec = SynthSpec(object=kind, interaction="push", seed=4, preset="full", n_frames=6, noise=False, occlusion="none")
    res = make_session(spec, tmp_path / "vga")
    d = surface_distances(res.session_dir, [0, 5])
    assert len(d) > 2000
    assert np.median(d) < 1e-3


def test_wrong_pose_is_detected(clean_tiny, tmp_path):
    """The check itself can fail: shift the recorded poses by 5 mm and the median distance grows."""
    import shutil

    _, res = clean_tiny
    root = tmp_path / "moved"
    shutil.copytree(res.session_dir, root)
    p = np.loadtxt(root / "ground_truth" / "poses.csv", delimiter=",", skiprows=1)
    p[:, 1] += 0.005
    np.savetxt(root / "ground_truth" / "poses.csv", p, delimiter=",", header="t,x,y,z,qw,qx,qy,qz", comments="")
    assert np.median(surface_distances(root, [0])) > 1.5e-3


def test_heavy_occlusion_in_band(noisy_tiny):
    _, res = noisy_tiny
    h = res.occlusion_per_frame
    assert 0.4 <= np.nanmedian(h) <= 0.7
    assert res.occlusion_in_band >= 0.6


def test_no_occlusion_means_object_fully_visible(clean_tiny):
    _, res = clean_tiny
    # only the robot arm can hide the object; most frames show all of it
    assert np.nanmedian(res.occlusion_per_frame) < 0.05
