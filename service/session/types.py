"""The validated session, as every later stage sees it (no ground truth in here)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np


@dataclass(frozen=True)
class Friction:
    object_table: float = 0.26
    object_robot: float = 0.15


@dataclass(frozen=True)
class Session:
    """A session that passed validation, unpacked on disk under ``root``.

    Arrays are per camera frame (N frames) unless named ``robot_*`` (M robot samples).
    Frames: W world (robot base, z up), C camera (OpenCV). Units SI.
    """

    name: str
    root: Path  # folder holding session.json (after unpacking)
    sha256: str  # content hash of the uploaded archive / folder
    frame_times: np.ndarray  # (N,) s, robot clock
    K: np.ndarray  # (3,3) px
    X_WC: np.ndarray  # (4,4) camera pose in world (camera.T_world_camera)
    depth_scale: float  # m per depth unit
    width: int  # px
    height: int  # px
    rgb_files: tuple[Path, ...]  # (N,) absolute paths
    depth_files: tuple[Path, ...]
    mask_files: tuple[Path, ...]
    robot_t: np.ndarray  # (M,) s
    robot_p_WE: np.ndarray  # (M,3) sphere centre in W (after FK when joints are given)
    robot_cmd_WE: np.ndarray | None  # (M,3) commanded sphere centre, if recorded
    p_WE: np.ndarray  # (N,3) sphere centre interpolated to the frame times
    cmd_WE: np.ndarray | None  # (N,3) commanded position at the frame times
    ee_radius: float  # m
    table_height: float  # z of the table surface in W, m
    table_height_detected: bool  # True when it was detected from depth (table.height = null)
    friction: Friction
    mass: float | None  # kg, if declared
    has_ground_truth: bool  # ground_truth/ present (read by evaluation only)

    @property
    def n_frames(self) -> int:
        return len(self.frame_times)

    def depth(self, i: int) -> np.ndarray:
        """Depth of frame i in metres along the optical axis, float32 (H,W); 0 = no reading."""
        import cv2

        d = cv2.imread(str(self.depth_files[i]), cv2.IMREAD_UNCHANGED)
        return d.astype(np.float32) * np.float32(self.depth_scale)

    def rgb(self, i: int) -> np.ndarray:
        """Colour of frame i, uint8 (H,W,3) in RGB order."""
        import cv2

        return cv2.cvtColor(cv2.imread(str(self.rgb_files[i]), cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)

    def mask(self, i: int) -> np.ndarray:
        """Object mask of frame i, bool (H,W)."""
        import cv2

        return cv2.imread(str(self.mask_files[i]), cv2.IMREAD_UNCHANGED) > 0
