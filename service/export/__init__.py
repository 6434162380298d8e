"""Export: the object model as a pybullet-loadable URDF with meshes (bundle format)."""

from service.export.collision import convex_hull, make_collision_pieces
from service.export.types import ExportConfig
from service.export.urdf import (
    EXT_NS,
    MeshPaths,
    apply_damping,
    check_inertial,
    effective_friction,
    get_X_WO,
    load_object,
    partner_dynamics,
    read_extension,
    set_X_WO,
    urdf_xml,
    write_model,
)

__all__ = [
    "EXT_NS",
    "ExportConfig",
    "MeshPaths",
    "apply_damping",
    "check_inertial",
    "effective_friction",
    "convex_hull",
    "get_X_WO",
    "load_object",
    "make_collision_pieces",
    "partner_dynamics",
    "read_extension",
    "set_X_WO",
    "urdf_xml",
    "write_model",
]
