"""Real RealSense frames (JPEG colour, 16-bit millimetre depth, 8-bit masks, 640x480) pass ingest."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from service.session import ingest

# ``shared/`` sits beside the repository (CI clones it there too)
REAL = Path(__file__).resolve().parents[3] / "shared" / "data" / "real" / "franka_cube_rgbd_sequence"


@pytest.mark.skipif(not REAL.is_dir(), reason="real Franka RGB-D sequence not available")
def test_real_frames_are_accepted(tmp_path):
    src = tmp_path / "src"
    for sub in ("rgb", "depth", "masks"):
        (src / sub).mkdir(parents=True)
    for s in ("0001", "0150", "0300"):
        shutil.copy(REAL / "color" / f"{s}.jpg", src / "rgb")
        shutil.copy(REAL / "depth" / f"{s}.png", src / "depth")
        shutil.copy(REAL / "mask" / f"{s}.png", src / "masks")
    shutil.copy(REAL / "camera_K.txt", src / "cam_K.txt")
    meta = {
        "format": "vysics-session/1",
        "frame_times": [0.0, 149 / 30, 299 / 30],
        "camera": {"depth_scale": 0.001, "T_world_camera": np.eye(4).tolist()},
        "robot": {"ee_radius": 0.0195},
        "table": {"height": 0.0},
    }
    (src / "session.json").write_text(json.dumps(meta))
    (src / "robot.csv").write_text("t,ee_x,ee_y,ee_z\n0,0.4,0,0.1\n10,0.5,0,0.1\n")
    s = ingest(src, tmp_path / "d")
    assert (s.width, s.height, s.n_frames) == (640, 480, 3)
    np.testing.assert_allclose(s.K[0, 0], 380.2484436)
    d = s.depth(0)
    valid = d[d > 0]
    assert 0.3 < np.median(valid) < 1.3  # millimetres scaled to metres
    assert s.mask(0).any() and s.rgb(0).shape == (480, 640, 3)
    assert s.name == "src" and s.friction.object_table == 0.26
