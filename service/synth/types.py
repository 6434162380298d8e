"""Specification and result of a synthetic session (see docs/synthetic-lab.md)."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

INTERACTIONS: tuple[str, ...] = ("push", "pivot", "topple", "strike")
OCCLUSION_LEVELS: dict[str, float] = {"none": 0.0, "light": 0.25, "heavy": 0.55}


@dataclass(frozen=True)
class Preset:
    width: int
    height: int
    n_frames: int
    fps: float = 30.0
    description: str = ""


PRESETS: dict[str, Preset] = {
    "tiny": Preset(160, 120, 60, 30.0, "160x120, 60 frames (2 s) at 30 Hz: tests"),
    "small": Preset(320, 240, 150, 30.0, "320x240, 150 frames (5 s) at 30 Hz: quick experiments"),
    "full": Preset(640, 480, 300, 30.0, "640x480, 300 frames (10 s) at 30 Hz: like the real sessions"),
}


@dataclass(frozen=True)
class HiddenEffects:
    """Physical effects the declared session does not mention (all off by default).

    Their true values go only to the sidecar ``<session>.effects.json``, never into the session.
    """

    restitution: float = 0.0  # coefficient of restitution of the object (table and robot contacts)
    linear_damping: float = 0.0  # viscous rate b (1/s): v decays as exp(-b t) in free motion
    angular_damping: float = 0.0  # viscous rate (1/s) on the angular velocity
    com_offset: tuple[float, float, float] = (0.0, 0.0, 0.0)  # CoM - volume centroid, in the mesh frame, m
    table_tilt: tuple[float, float] = (0.0, 0.0)  # gravity tilt (rad) about world x and y
    friction_object_table: float | None = None  # true object-table friction (declared stays the prior)
    clock_offset: float = 0.0  # s added to robot.csv timestamps relative to the frames
    friction_object_robot: float | None = None  # true object-robot (sphere) friction (declared stays the prior)

    def __post_init__(self) -> None:
        def num(name, lo, hi):
            v = getattr(self, name)
            if not isinstance(v, (int, float)) or not lo <= float(v) <= hi:
                raise ValueError(f"effect {name}={v!r}: expected a number in [{lo}, {hi}]")

        def vec(name, n, bound):
            v = getattr(self, name)
            try:
                ok = len(v) == n and all(isinstance(x, (int, float)) and abs(float(x)) <= bound for x in v)
            except TypeError:
                ok = False
            if not ok:
                raise ValueError(f"effect {name}={v!r}: expected {n} numbers with |value| <= {bound}")
            object.__setattr__(self, name, tuple(float(x) for x in v))

        num("restitution", 0.0, 1.0)
        num("linear_damping", 0.0, 50.0)
        num("angular_damping", 0.0, 50.0)
        num("clock_offset", -1.0, 1.0)
        vec("com_offset", 3, 0.05)
        vec("table_tilt", 2, 0.3)
        if self.friction_object_table is not None:
            num("friction_object_table", 0.0, 2.0)
        if self.friction_object_robot is not None:
            num("friction_object_robot", 0.0, 2.0)

    def active(self) -> dict[str, object]:
        """The effects that differ from their 'off' value."""
        off = HiddenEffects()
        return {f.name: getattr(self, f.name) for f in dataclasses.fields(self) if getattr(self, f.name) != getattr(off, f.name)}

    @staticmethod
    def sample(rng: np.random.Generator, names: tuple[str, ...]) -> "HiddenEffects":
        """Random plausible values for the effects in ``names`` (others off)."""
        v: dict[str, object] = {}
        for n in names:
            if n == "restitution":
                v[n] = float(rng.uniform(0.3, 0.6))
            elif n == "linear_damping":
                v[n] = float(rng.uniform(0.5, 3.0))
            elif n == "angular_damping":
                v[n] = float(rng.uniform(0.5, 3.0))
            elif n == "com_offset":
                v[n] = tuple(float(x) for x in rng.uniform(-0.015, 0.015, 3))
            elif n == "table_tilt":
                v[n] = tuple(float(x) for x in rng.uniform(-0.05, 0.05, 2))
            elif n == "friction_object_table":
                v[n] = float(rng.uniform(0.12, 0.5))
            elif n == "clock_offset":
                v[n] = float(rng.choice([-1, 1]) * rng.uniform(0.03, 0.12))
            elif n == "friction_object_robot":
                v[n] = float(rng.uniform(0.05, 0.6))
            else:
                raise ValueError(f"unknown hidden effect {n!r}")
        return HiddenEffects(**v)


@dataclass(frozen=True)
class SynthSpec:
    """Everything that determines a synthetic session; the same spec gives byte-identical files."""

    object: str = "baking_box"  # one of service.synth.OBJECT_KINDS
    interaction: str = "push"  # push | pivot | topple | strike (impulsive pushes: the object slides free)
    seed: int = 0
    preset: str = "tiny"  # tiny | small | full
    occlusion: str | float = "none"  # none | light | heavy, or a target hidden fraction in [0, 0.8]
    noise: bool = True  # sensor noise (depth, dropouts, mask, colour)
    effects: HiddenEffects = field(default_factory=HiddenEffects)
    declare_mass: bool = True  # write object.mass into session.json (else null)
    declare_table_height: bool = True  # write table.height (else null: detect from depth)
    table_height: float | None = 0.0  # z of the table in W; None = random in [-0.05, 0.05] from the seed
    name: str | None = None  # session name (default: <object>_<interaction>_<seed>)
    # optional overrides
    n_frames: int | None = None
    resolution: tuple[int, int] | None = None  # (width, height)
    fps: float | None = None
    mass: float | None = None  # kg (default: the catalogue's)
    scale: float = 1.0  # object size factor
    camera_distance: float | None = None  # m (default: random in [0.6, 0.9])
    camera_side: str = "side"  # side (-y) | front (+x, facing the robot) | other_side (+y) | random
    rgb_format: str = "jpg"  # jpg (quality 92, like the real sessions) | png
    friction_object_table: float = 0.26  # declared prior (and true value unless effects override it)
    friction_object_robot: float = 0.15
    rolling_friction: float = 0.0005  # m, rolling resistance object-table (base physics, not declared)
    physics_hz: float = 240.0
    # segmentation misregistered with the colour image (the real cube video's mask sits ~7 px sideways): the mask is
    # shifted this many px along the image x axis (sign = direction) and the object's depth bleeds into the strip of
    # background it covers (a stereo sensor's edge fattening); 0: masks and depth as rendered
    mask_offset_px: int = 0

    def session_name(self) -> str:
        return self.name or f"{self.object}_{self.interaction}_{self.seed:03d}"

    def occlusion_target(self) -> float:
        if isinstance(self.occlusion, str):
            if self.occlusion not in OCCLUSION_LEVELS:
                raise ValueError(f"occlusion {self.occlusion!r}: expected one of {list(OCCLUSION_LEVELS)} or a number")
            return OCCLUSION_LEVELS[self.occlusion]
        t = float(self.occlusion)
        if not 0.0 <= t <= 0.8:
            raise ValueError(f"occlusion {t}: target hidden fraction must be in [0, 0.8]")
        return t

    def frame_geometry(self) -> tuple[int, int, int, float]:
        """(width, height, n_frames, fps) after applying overrides to the preset."""
        if self.preset not in PRESETS:
            raise ValueError(f"preset {self.preset!r}: expected one of {list(PRESETS)}")
        p = PRESETS[self.preset]
        w, h = self.resolution or (p.width, p.height)
        return int(w), int(h), int(self.n_frames or p.n_frames), float(self.fps or p.fps)

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


@dataclass(frozen=True)
class SynthResult:
    session_dir: Path
    sidecar_path: Path  # <session_dir>.effects.json (outside the session)
    n_frames: int
    width: int
    height: int
    occlusion_mean: float  # mean over frames of the hidden fraction of the object (occluders and arm)
    occlusion_per_frame: np.ndarray  # (N,) hidden fraction per frame (nan where the object is out of view)
    occlusion_in_band: float  # fraction of frames with 0.4 <= hidden <= 0.7
    contacts: tuple[tuple[float, float], ...]  # robot-object contact intervals (s, frame clock)
    object_travel: float  # m, displacement of the object's centroid first -> last frame
    object_rotation: float  # rad, rotation angle first -> last frame
    elapsed: float  # s of wall time
