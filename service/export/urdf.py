"""URDF of the object model (bundle format ``vysics-bundle/1``) and loading it back into pybullet.

One link ``object`` whose frame is O. ``<inertial>``: mass m, centre of mass c_O (origin xyz, no
rotation) and the full inertia tensor I about c_O in O's axes (ixx … izz; pybullet diagonalises it
when loaded with ``URDF_USE_INERTIA_FROM_FILE``). ``<visual>`` → ``meshes/fused.obj``;
``<collision>`` → one element per convex piece ``meshes/collision_<i>.obj``.

What pybullet's URDF parser reads from a link's ``<contact>`` (bullet3 ``UrdfParser::parseLink``):
``lateral_friction``, ``rolling_friction``, ``spinning_friction``, ``restitution``, ``stiffness`` +
``damping`` (contact), ``inertia_scaling``, ``friction_anchor`` — each as a ``value`` attribute.
Bullet combines two bodies' friction and restitution by **product** (rolling/spinning friction as
r₀μ₁ + μ₀r₁); the object's ``lateral_friction`` is μ(object, table) and its ``restitution`` is e, so
a scene built around the object gives the table friction 1 and restitution 1, and the robot sphere
friction μ(object, robot) / μ(object, table) — ``partner_dynamics`` returns these numbers.
Effects (names of ``service.sim.effects``): ``restitution``, ``rolling_friction``,
``spinning_friction``, ``contact_stiffness``/``contact_damping`` go into ``<contact>``;
``friction_object_table``, ``friction_scale_table``, ``friction_scale_robot`` are folded into the two
friction coefficients. pybullet has no URDF element for a body's velocity damping, and its
``changeDynamics`` damping is not viscous (Bullet applies −m·b·(1 + |v|)·v); the viscous rates
``linear_damping``/``angular_damping`` (1/s: force −m b v at the CoM, torque −b I ω), μ(object, robot)
and every other effect go into the extension element ``<vysics:dynamics>`` (namespace ``EXT_NS``),
which pybullet ignores; ``load_object`` turns Bullet's own damping off and ``apply_damping`` applies
the viscous forces before a step.
"""

from __future__ import annotations

import math
import shutil
import tempfile
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path
from xml.sax.saxutils import quoteattr

import numpy as np

from service.export.collision import make_collision_pieces
from service.export.types import ExportConfig
from service.model import ObjectModel
from service.transforms import X_inv, mat_to_quat, pose_from_xyzw, quat_to_xyzw

EXT_NS = "https://vysics.dev/urdf-extension/1"
URDF_NAME = "object.urdf"
VISUAL_PATH = "meshes/fused.obj"

# effects pybullet reads from <contact>: effect key -> element name
CONTACT_EFFECTS = {
    "restitution": "restitution",
    "rolling_friction": "rolling_friction",
    "spinning_friction": "spinning_friction",
    "contact_stiffness": "stiffness",
    "contact_damping": "damping",
}
# effects folded into the friction coefficients
FRICTION_EFFECTS = ("friction_object_table", "friction_scale_table", "friction_scale_robot")


@dataclass(frozen=True)
class MeshPaths:
    """Mesh file names relative to the URDF's folder (forward slashes)."""

    visual: str = VISUAL_PATH
    collision: tuple[str, ...] = ()


def check_inertial(mass: float, com_O: np.ndarray, inertia_O: np.ndarray) -> None:
    """Raise ValueError unless m > 0, c finite (3,), I symmetric (3,3) positive definite and
    satisfying the triangle inequalities of its principal moments (a physical rigid body)."""
    if not (np.isfinite(mass) and mass > 0):
        raise ValueError(f"mass must be finite and > 0, got {mass}")
    c = np.asarray(com_O, float)
    if c.shape != (3,) or not np.all(np.isfinite(c)):
        raise ValueError(f"com_O must be a finite (3,) vector, got {c}")
    inertia = np.asarray(inertia_O, float)
    if inertia.shape != (3, 3) or not np.all(np.isfinite(inertia)):
        raise ValueError(f"inertia_O must be a finite (3,3) matrix, got shape {inertia.shape}")
    scale = max(float(np.abs(inertia).max()), 1e-300)
    if np.abs(inertia - inertia.T).max() > 1e-6 * scale:
        raise ValueError("inertia_O must be symmetric")
    ev = np.linalg.eigvalsh(0.5 * (inertia + inertia.T))
    if ev.min() <= 0:
        raise ValueError(f"inertia_O must be positive definite, principal moments {ev}")
    if ev[0] + ev[1] < ev[2] * (1 - 1e-6):
        raise ValueError(f"inertia_O breaks the triangle inequality, principal moments {ev}")


def _f(x: float) -> str:
    return repr(float(x))


def effective_friction(model: ObjectModel) -> tuple[float, float]:
    """(μ(object, table), μ(object, robot)) after the accepted friction effects."""
    fx = model.effects
    mu_t = float(fx.get("friction_object_table", model.friction.object_table))
    mu_t *= float(fx.get("friction_scale_table", 1.0))
    mu_r = float(model.friction.object_robot) * float(fx.get("friction_scale_robot", 1.0))
    return mu_t, mu_r


def contact_values(model: ObjectModel) -> dict[str, float]:
    """The ``<contact>`` children (element name -> value) of the model, friction first."""
    out = {"lateral_friction": effective_friction(model)[0]}
    fx = model.effects
    for key in ("restitution", "rolling_friction", "spinning_friction"):
        if key in fx:
            out[CONTACT_EFFECTS[key]] = float(fx[key])
    k = float(fx.get("contact_stiffness", 0.0))
    if k > 0:  # Bullet needs both; same default damping as service.sim (critical for the mass)
        d = float(fx.get("contact_damping", 0.0))
        out["stiffness"] = k
        out["damping"] = d if d > 0 else 2.0 * math.sqrt(k * float(model.mass))
    return out


def extension_values(model: ObjectModel) -> dict[str, float]:
    """What goes into ``<vysics:dynamics>``: μ(object, robot) and the effects pybullet cannot read."""
    ext = {"object_robot_friction": effective_friction(model)[1]}
    for key, val in model.effects.items():
        if key not in CONTACT_EFFECTS and key not in FRICTION_EFFECTS:
            ext[key] = float(val)
    return ext


def urdf_xml(model: ObjectModel, mesh_paths: MeshPaths) -> str:
    """The URDF text of ``model`` referring to the given mesh files (no file is touched)."""
    check_inertial(model.mass, model.com_O, model.inertia_O)
    if not mesh_paths.collision:
        raise ValueError("urdf_xml needs at least one collision mesh path")
    for key, val in model.effects.items():
        if not math.isfinite(float(val)):
            raise ValueError(f"effect {key!r} must be finite, got {val}")
    mu_t, mu_r = effective_friction(model)
    if not (math.isfinite(mu_t) and mu_t >= 0 and math.isfinite(mu_r) and mu_r >= 0):
        raise ValueError(f"friction coefficients must be finite and >= 0, got {mu_t}, {mu_r}")
    c = np.asarray(model.com_O, float)
    inertia = 0.5 * (np.asarray(model.inertia_O, float) + np.asarray(model.inertia_O, float).T)
    lines = [
        '<?xml version="1.0"?>',
        f'<robot name="object" xmlns:vysics="{EXT_NS}">',
        '  <link name="object">',
        "    <contact>",
    ]
    for elem, val in contact_values(model).items():
        lines.append(f'      <{elem} value="{_f(val)}"/>')
    lines += [
        "    </contact>",
        "    <inertial>",
        f'      <origin xyz="{_f(c[0])} {_f(c[1])} {_f(c[2])}" rpy="0 0 0"/>',
        f'      <mass value="{_f(model.mass)}"/>',
        f'      <inertia ixx="{_f(inertia[0, 0])}" ixy="{_f(inertia[0, 1])}" ixz="{_f(inertia[0, 2])}"'
        f' iyy="{_f(inertia[1, 1])}" iyz="{_f(inertia[1, 2])}" izz="{_f(inertia[2, 2])}"/>',
        "    </inertial>",
        "    <visual>",
        '      <origin xyz="0 0 0" rpy="0 0 0"/>',
        f"      <geometry><mesh filename={quoteattr(mesh_paths.visual)}/></geometry>",
        "    </visual>",
    ]
    for i, path in enumerate(mesh_paths.collision):
        lines += [
            f'    <collision name="piece_{i}">',
            '      <origin xyz="0 0 0" rpy="0 0 0"/>',
            f"      <geometry><mesh filename={quoteattr(path)}/></geometry>",
            "    </collision>",
        ]
    ext = extension_values(model)
    lines.append("    <vysics:dynamics>")
    for key, val in ext.items():
        lines.append(f"      <vysics:param name={quoteattr(key)} value=\"{_f(val)}\"/>")
    lines += ["    </vysics:dynamics>", "  </link>", "</robot>", ""]
    return "\n".join(lines)


def write_model(model: ObjectModel, out_dir: Path, cfg: ExportConfig | None = None) -> Path:
    """Write ``object.urdf``, ``meshes/fused.obj`` and ``meshes/collision_<i>.obj`` into ``out_dir``.

    Uses ``model.collision`` when given, otherwise decomposes ``model.visual`` with
    ``make_collision_pieces(model.visual, cfg)``. Files are written in a temporary folder inside
    ``out_dir`` and moved into place, the URDF last. Returns the URDF's path.
    """
    out_dir = Path(out_dir)
    if model.visual.is_empty:
        raise ValueError("the model's visual mesh is empty")
    pieces = model.collision or make_collision_pieces(model.visual, cfg)
    paths = MeshPaths(VISUAL_PATH, tuple(f"meshes/collision_{i}.obj" for i in range(len(pieces))))
    text = urdf_xml(model, paths)  # validates before anything is written
    out_dir.mkdir(parents=True, exist_ok=True)
    (out_dir / "meshes").mkdir(exist_ok=True)
    with tempfile.TemporaryDirectory(prefix=".export_", dir=out_dir) as tmp:
        tmp = Path(tmp)
        model.visual.save_obj(tmp / VISUAL_PATH)
        for piece, rel in zip(pieces, paths.collision):
            piece.save_obj(tmp / rel)
        for old in (out_dir / "meshes").glob("collision_*.obj"):  # stale pieces of an earlier export
            old.unlink()
        for rel in (VISUAL_PATH, *paths.collision):
            shutil.move(str(tmp / rel), str(out_dir / rel))
        (tmp / URDF_NAME).write_text(text)
        shutil.move(str(tmp / URDF_NAME), str(out_dir / URDF_NAME))
    return out_dir / URDF_NAME


def read_extension(urdf_path: Path) -> dict[str, float]:
    """The ``<vysics:dynamics>`` parameters of a URDF written by ``write_model`` ({} if none)."""
    root = ET.parse(str(urdf_path)).getroot()
    out: dict[str, float] = {}
    for elem in root.iter(f"{{{EXT_NS}}}param"):
        out[elem.attrib["name"]] = float(elem.attrib["value"])
    return out


def partner_dynamics(urdf_path: Path) -> dict[str, dict[str, float]]:
    """``changeDynamics`` keywords for the table and the robot sphere so that Bullet's product
    combination gives the model's μ(object, table), μ(object, robot) and restitution e."""
    root = ET.parse(str(urdf_path)).getroot()
    mu_t = float(root.find("link/contact/lateral_friction").attrib["value"])
    mu_r = read_extension(urdf_path).get("object_robot_friction", mu_t)
    has_e = root.find("link/contact/restitution") is not None
    table = {"lateralFriction": 1.0, "restitution": 1.0 if has_e else 0.0}
    robot = {"lateralFriction": mu_r / mu_t if mu_t > 0 else 0.0, "restitution": 0.0}
    return {"table": table, "robot": robot}


def load_object(
    urdf_path: Path,
    client: int,
    *,
    position=(0.0, 0.0, 0.0),
    orientation_xyzw=(0.0, 0.0, 0.0, 1.0),
) -> int:
    """Load the object into a pybullet client as written: inertia from the file (not recomputed
    from the collision shapes), Bullet's own velocity damping off (its default is 0.04; use
    ``apply_damping`` for the model's viscous damping). ``position``/``orientation_xyzw`` place
    frame O in W (pybullet's quaternion order x,y,z,w). Returns the body id."""
    import pybullet as p

    body = p.loadURDF(
        str(urdf_path),
        basePosition=list(position),
        baseOrientation=list(orientation_xyzw),
        flags=p.URDF_USE_INERTIA_FROM_FILE,
        physicsClientId=client,
    )
    p.changeDynamics(body, -1, linearDamping=0.0, angularDamping=0.0, physicsClientId=client)
    return body


def apply_damping(body: int, client: int, linear_damping: float, angular_damping: float) -> None:
    """Apply the viscous damping force −m b_v v (at the CoM) and torque −b_ω I ω for the next
    ``stepSimulation`` (pybullet clears external forces after each step), as ``service.sim`` does."""
    import pybullet as p

    if linear_damping <= 0 and angular_damping <= 0:
        return
    info = p.getDynamicsInfo(body, -1, physicsClientId=client)
    pos, orn = p.getBasePositionAndOrientation(body, physicsClientId=client)
    v, w = p.getBaseVelocity(body, physicsClientId=client)
    R_WI = pose_from_xyzw(pos, orn)[:3, :3]
    force = -float(info[0]) * linear_damping * np.asarray(v)
    torque = -angular_damping * (R_WI @ (np.asarray(info[2]) * (R_WI.T @ np.asarray(w))))
    p.applyExternalForce(body, -1, force.tolist(), list(pos), p.WORLD_FRAME, physicsClientId=client)
    p.applyExternalTorque(body, -1, torque.tolist(), p.WORLD_FRAME, physicsClientId=client)


def _X_OI(body: int, client: int) -> np.ndarray:
    """Pose of pybullet's base inertial frame I (CoM, principal axes) in O."""
    import pybullet as p

    info = p.getDynamicsInfo(body, -1, physicsClientId=client)
    return pose_from_xyzw(info[3], info[4])


def get_X_WO(body: int, client: int) -> np.ndarray:
    """X_WO (4,4) of a body loaded by ``load_object``. pybullet's ``getBasePositionAndOrientation``
    returns the inertial frame I (CoM, principal axes), not the link frame O: X_WO = X_WI · X_OI⁻¹."""
    import pybullet as p

    pos, orn = p.getBasePositionAndOrientation(body, physicsClientId=client)
    return pose_from_xyzw(pos, orn) @ X_inv(_X_OI(body, client))


def set_X_WO(body: int, X_WO: np.ndarray, client: int) -> None:
    """Place frame O at X_WO (4,4): resets the base inertial frame to X_WO · X_OI."""
    import pybullet as p

    X_WI = np.asarray(X_WO, float) @ _X_OI(body, client)
    p.resetBasePositionAndOrientation(body, X_WI[:3, 3].tolist(), quat_to_xyzw(mat_to_quat(X_WI[:3, :3])),
                                      physicsClientId=client)
