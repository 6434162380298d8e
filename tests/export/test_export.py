"""Export: URDF text, collision pieces, and the round trip through pybullet."""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest
import trimesh

from service.export import (
    EXT_NS,
    ExportConfig,
    MeshPaths,
    apply_damping,
    check_inertial,
    get_X_WO,
    load_object,
    make_collision_pieces,
    partner_dynamics,
    read_extension,
    set_X_WO,
    urdf_xml,
    write_model,
)
from service.export import collision as collision_mod
from service.mesh import Mesh
from service.model import ObjectModel
from service.session.types import Friction
from service.transforms import make_X, so3_exp

p = pytest.importorskip("pybullet")

SIZE = np.array([0.10, 0.06, 0.04])


def box_mesh(size=SIZE) -> Mesh:
    return Mesh.from_trimesh(trimesh.creation.box(tuple(size)))


def l_mesh() -> Mesh:
    """An L-shaped (non-convex) prism: 10 cm arms, 2 cm thick, 4 cm tall, watertight."""
    poly = np.array([(-0.05, -0.05), (0.05, -0.05), (0.05, 0.05), (0.03, 0.05), (0.03, -0.03), (-0.05, -0.03)])
    n = len(poly)
    v = np.vstack([np.c_[poly, np.full(n, -0.02)], np.c_[poly, np.full(n, 0.02)]])
    top = [(4, 5, 0), (4, 0, 1), (4, 1, 2), (4, 2, 3)]  # fan from the reflex corner, counter-clockwise
    faces = [(a + n, b + n, c + n) for a, b, c in top] + [(a, c, b) for a, b, c in top]
    for i in range(n):
        j = (i + 1) % n
        faces += [(i, j, j + n), (i, j + n, i + n)]
    m = trimesh.Trimesh(v, np.array(faces), process=True)
    assert m.is_watertight and m.volume > 0
    return Mesh.from_trimesh(m)


def box_inertia(mass, size):
    a, b, c = size
    return mass / 12.0 * np.diag([b * b + c * c, a * a + c * c, a * a + b * b])


def model(mesh=None, mass=0.5, com=(0.0, 0.0, 0.0), inertia=None, friction=Friction(0.3, 0.2), effects=None, collision=()):
    mesh = mesh or box_mesh()
    inertia = box_inertia(mass, SIZE) if inertia is None else inertia
    return ObjectModel(
        visual=mesh,
        collision=collision,
        mass=mass,
        mass_declared=True,
        com_O=np.asarray(com, float),
        inertia_O=np.asarray(inertia, float),
        friction=friction,
        effects=dict(effects or {}),
    )


@pytest.fixture()
def client():
    cid = p.connect(p.DIRECT)
    yield cid
    p.disconnect(cid)


def add_plane(cid, z=0.0):
    shape = p.createCollisionShape(p.GEOM_PLANE, physicsClientId=cid)
    plane = p.createMultiBody(0, shape, basePosition=[0, 0, z], physicsClientId=cid)
    return plane


# ---------------------------------------------------------------- pure URDF text


def test_urdf_xml_is_pure_and_well_formed(tmp_path):
    R = so3_exp(np.array([0.3, -0.2, 0.5]))
    inertia = R @ np.diag([1e-4, 2e-4, 2.5e-4]) @ R.T
    m = model(com=(0.01, -0.005, 0.002), inertia=inertia, effects={"restitution": 0.4, "linear_damping": 0.1, "foo": 2.0})
    text = urdf_xml(m, MeshPaths("meshes/fused.obj", ("meshes/collision_0.obj", "meshes/collision_1.obj")))
    assert list(tmp_path.iterdir()) == []
    root = ET.fromstring(text)
    links = root.findall("link")
    assert [lk.attrib["name"] for lk in links] == ["object"]
    link = links[0]
    assert float(link.find("contact/lateral_friction").attrib["value"]) == 0.3
    assert float(link.find("contact/restitution").attrib["value"]) == 0.4
    assert link.find("inertial/origin").attrib["xyz"].split() == ["0.01", "-0.005", "0.002"]
    ine = link.find("inertial/inertia").attrib
    assert float(ine["ixy"]) == pytest.approx(inertia[0, 1], rel=1e-12)
    assert float(ine["iyz"]) == pytest.approx(inertia[1, 2], rel=1e-12)
    assert [c.find("geometry/mesh").attrib["filename"] for c in link.findall("collision")] == [
        "meshes/collision_0.obj",
        "meshes/collision_1.obj",
    ]
    assert link.find("visual/geometry/mesh").attrib["filename"] == "meshes/fused.obj"
    params = {e.attrib["name"]: float(e.attrib["value"]) for e in root.iter(f"{{{EXT_NS}}}param")}
    assert params == {"object_robot_friction": 0.2, "linear_damping": 0.1, "foo": 2.0}


@pytest.mark.parametrize(
    "mass,inertia",
    [
        (0.0, np.diag([1e-4, 1e-4, 1e-4])),
        (-1.0, np.diag([1e-4, 1e-4, 1e-4])),
        (0.5, np.diag([1e-4, 1e-4, -1e-4])),
        (0.5, np.diag([1e-4, 1e-4, 3e-4])),  # triangle inequality broken
        (0.5, np.array([[1e-4, 5e-5, 0], [0, 1e-4, 0], [0, 0, 1e-4]])),  # not symmetric
        (float("nan"), np.diag([1e-4, 1e-4, 1e-4])),
    ],
)
def test_invalid_inertial_rejected(mass, inertia):
    with pytest.raises(ValueError):
        check_inertial(mass, np.zeros(3), inertia)
    with pytest.raises(ValueError):
        urdf_xml(model(mass=mass, inertia=inertia), MeshPaths(collision=("c.obj",)))


# ---------------------------------------------------------------- collision pieces


def test_convex_mesh_gives_its_exact_hull():
    pieces = make_collision_pieces(box_mesh(), ExportConfig.fast())
    assert len(pieces) == 1
    tm = pieces[0].to_trimesh()
    assert tm.is_watertight and tm.is_convex
    assert tm.volume == pytest.approx(np.prod(SIZE), rel=1e-9)


@pytest.fixture(scope="module")
def l_pieces():
    return make_collision_pieces(l_mesh(), ExportConfig.fast())


def test_nonconvex_mesh_is_decomposed(l_pieces):
    mesh = l_mesh()
    tm = mesh.to_trimesh()
    assert tm.is_watertight and not tm.is_convex
    pieces = l_pieces
    assert len(pieces) >= 2
    for piece in pieces:
        t = piece.to_trimesh()
        assert t.is_watertight and t.is_convex and t.volume > 0
    # the union covers the L and does not fill its notch: the notch centre lies outside every piece
    notch = np.array([[-0.01, 0.01, 0.0]])
    inside = [bool(piece.to_trimesh().contains(notch)[0]) for piece in pieces]
    assert not any(inside)
    arm = np.array([[-0.04, -0.04, 0.0], [0.04, 0.04, 0.0]])
    for q in arm:
        assert any(bool(piece.to_trimesh().contains(q[None])[0]) for piece in pieces)
    total = sum(piece.to_trimesh().volume for piece in pieces)
    assert total == pytest.approx(tm.volume, rel=0.25)


def test_vhacd_failure_falls_back_to_hull(monkeypatch):
    def boom(mesh, cfg):
        raise RuntimeError("vhacd failed")

    monkeypatch.setattr(collision_mod, "_vhacd", boom)
    mesh = l_mesh()
    pieces = make_collision_pieces(mesh, ExportConfig.fast())
    assert len(pieces) == 1
    assert pieces[0].to_trimesh().volume == pytest.approx(mesh.to_trimesh().convex_hull.volume, rel=1e-9)


def test_parse_multi_obj_against_naive():
    text = "o a\nv 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 2 3\nf 1 2 4\no b\nv 5 5 5\nv 6 5 5\nv 5 6 5\nf 5 6 7\nf -1 -2 -3\n"
    a, b = collision_mod.parse_multi_obj(text)
    assert np.allclose(a.vertices, [[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]])
    assert a.faces.tolist() == [[0, 1, 2], [0, 1, 3]]
    assert np.allclose(b.vertices, [[5, 5, 5], [6, 5, 5], [5, 6, 5]])
    assert b.faces.tolist() == [[0, 1, 2], [2, 1, 0]]


# ---------------------------------------------------------------- files and pybullet


def test_write_model_files(tmp_path, l_pieces):
    path = write_model(model(mesh=l_mesh(), collision=l_pieces), tmp_path)
    assert path == tmp_path / "object.urdf"
    assert (tmp_path / "meshes" / "fused.obj").exists()
    pieces = sorted((tmp_path / "meshes").glob("collision_*.obj"))
    assert len(pieces) >= 2
    root = ET.parse(path).getroot()
    assert len(root.findall("link/collision")) == len(pieces)
    assert Mesh.load(tmp_path / "meshes" / "fused.obj").to_trimesh().is_watertight
    assert [q.name for q in tmp_path.iterdir() if q.name.startswith(".")] == []
    # a re-export with fewer pieces leaves no stale piece behind
    write_model(model(), tmp_path)
    assert [q.name for q in (tmp_path / "meshes").glob("collision_*.obj")] == ["collision_0.obj"]


def test_dynamics_read_back(tmp_path, client):
    R = so3_exp(np.array([0.3, -0.2, 0.5]))
    inertia = R @ np.diag([1.0e-4, 2.0e-4, 2.5e-4]) @ R.T
    com = np.array([0.01, -0.005, 0.002])
    path = write_model(model(mass=0.37, com=com, inertia=inertia, effects={"restitution": 0.4}), tmp_path)
    body = load_object(path, client, position=(1.0, 2.0, 3.0))
    info = p.getDynamicsInfo(body, -1, physicsClientId=client)
    assert info[0] == pytest.approx(0.37)
    assert info[1] == pytest.approx(0.3)  # lateral friction
    assert info[5] == pytest.approx(0.4)  # restitution
    assert np.allclose(info[3], com, atol=1e-9)
    Rl = np.array(p.getMatrixFromQuaternion(info[4])).reshape(3, 3)
    assert np.allclose(Rl @ np.diag(info[2]) @ Rl.T, inertia, atol=1e-10)
    X = get_X_WO(body, client)
    assert np.allclose(X, make_X(np.eye(3), [1.0, 2.0, 3.0]), atol=1e-9)
    X_new = make_X(so3_exp(np.array([0.1, 0.7, -0.3])), np.array([0.2, -0.1, 0.5]))
    set_X_WO(body, X_new, client)
    assert np.allclose(get_X_WO(body, client), X_new, atol=1e-9)


def test_no_restitution_by_default(tmp_path, client):
    body = load_object(write_model(model(), tmp_path), client)
    assert p.getDynamicsInfo(body, -1, physicsClientId=client)[5] == 0.0
    assert partner_dynamics(tmp_path / "object.urdf") == {
        "table": {"lateralFriction": 1.0, "restitution": 0.0},
        "robot": {"lateralFriction": pytest.approx(0.2 / 0.3), "restitution": 0.0},
    }


@pytest.mark.parametrize("shape", ["box", "L"])
def test_drop_comes_to_rest_on_plane(tmp_path, client, shape, request):
    p.setGravity(0, 0, -9.81, physicsClientId=client)
    add_plane(client)
    if shape == "box":
        m = model()
    else:  # multi-piece collision; 4 cm tall like the box
        m = model(mesh=l_mesh(), collision=request.getfixturevalue("l_pieces"), com=(0.01, -0.01, 0.0))
    path = write_model(m, tmp_path)
    R0 = so3_exp(np.array([0.15, -0.1, 0.4]))
    body = load_object(path, client)
    set_X_WO(body, make_X(R0, [0.0, 0.0, 0.08]), client)
    for _ in range(480):
        p.stepSimulation(physicsClientId=client)
    X = get_X_WO(body, client)
    # lands on its largest face: O's z axis vertical, centre at half the height
    assert abs(abs(X[2, 2]) - 1.0) < 1e-3
    assert X[2, 3] == pytest.approx(SIZE[2] / 2, abs=2.5e-3 if shape == "L" else 1.5e-3)
    v, w = p.getBaseVelocity(body, physicsClientId=client)
    assert np.linalg.norm(v) < 1e-2 and np.linalg.norm(w) < 1e-1


def test_viscous_damping_from_extension(tmp_path, client):
    """Free flight without gravity: v(t) = v0 e^{-b t}, ω(t) = ω0 e^{-b_ω t}; undamped stays put."""
    p.setGravity(0, 0, 0, physicsClientId=client)
    p.setPhysicsEngineParameter(fixedTimeStep=1 / 240, physicsClientId=client)
    R = so3_exp(np.array([0.3, -0.2, 0.5]))
    inertia = R @ np.diag([1.0e-4, 2.0e-4, 2.5e-4]) @ R.T
    path_a = write_model(model(inertia=inertia, effects={"linear_damping": 0.8, "angular_damping": 1.5}), tmp_path / "a")
    damped = load_object(path_a, client)
    free = load_object(write_model(model(), tmp_path / "b"), client, position=(1, 0, 0))
    ext = read_extension(path_a)
    assert ext["linear_damping"] == 0.8 and ext["angular_damping"] == 1.5
    w0 = np.array([0.0, 0.0, 2.0])  # a spin about a non-principal axis: check the decay of |L|·
    for b in (damped, free):
        p.resetBaseVelocity(b, [0.5, 0, 0], w0.tolist(), physicsClientId=client)
    for _ in range(240):
        apply_damping(damped, client, ext["linear_damping"], ext["angular_damping"])
        p.stepSimulation(physicsClientId=client)
    v_d, w_d = (np.asarray(x) for x in p.getBaseVelocity(damped, physicsClientId=client))
    v_f = np.asarray(p.getBaseVelocity(free, physicsClientId=client)[0])
    assert v_f[0] == pytest.approx(0.5, rel=1e-6)  # Bullet's own damping is off
    assert v_d[0] == pytest.approx(0.5 * np.exp(-0.8), rel=0.02)
    # torque −b I ω makes the angular momentum decay as e^{-b t} (no other torque)
    pos, orn = p.getBasePositionAndOrientation(damped, physicsClientId=client)
    R_WI = np.array(p.getMatrixFromQuaternion(orn)).reshape(3, 3)
    lam = np.asarray(p.getDynamicsInfo(damped, -1, physicsClientId=client)[2])
    L = R_WI @ (lam * (R_WI.T @ w_d))
    assert np.linalg.norm(L) == pytest.approx(np.linalg.norm(inertia @ w0) * np.exp(-1.5), rel=0.03)


def test_effects_in_contact_and_friction(tmp_path, client):
    fx = {
        "restitution": 0.3,
        "spinning_friction": 0.002,
        "rolling_friction": 0.001,
        "contact_stiffness": 5e4,
        "friction_scale_table": 2.0,
        "friction_scale_robot": 0.5,
        "table_tilt_x": 0.01,
    }
    path = write_model(model(effects=fx), tmp_path)
    body = load_object(path, client)
    info = p.getDynamicsInfo(body, -1, physicsClientId=client)
    assert info[1] == pytest.approx(0.6)  # 0.3 scaled by 2
    assert info[5] == pytest.approx(0.3)
    assert info[6] == pytest.approx(0.001)  # rolling
    assert info[7] == pytest.approx(0.002)  # spinning
    assert info[9] == pytest.approx(5e4)  # contact stiffness
    assert info[8] == pytest.approx(2 * np.sqrt(5e4 * 0.5))  # default contact damping
    ext = read_extension(path)
    assert ext == {"object_robot_friction": pytest.approx(0.1), "table_tilt_x": 0.01}
    assert partner_dynamics(path)["robot"]["lateralFriction"] == pytest.approx(0.1 / 0.6)
    assert partner_dynamics(path)["table"] == {"lateralFriction": 1.0, "restitution": 1.0}
