"""Visible-geometry SDF: a dense voxel grid in O fitted to depth rays with BundleSDF's losses.

Public API: :func:`fit_sdf`, :func:`sdf_query`, :func:`extract_mesh`, :class:`RaySet`, :class:`SdfConfig`,
:class:`SdfGrid`, plus :func:`rays_from_frame` (rays of one masked depth frame) and :func:`contradicted_readings`
(object rays other views saw through).
"""

from service.sdf.evidence import contradicted_readings
from service.sdf.fit import fit_sdf, hull_sdf, make_grid_geometry
from service.sdf.grid import extract_mesh, query_torch, sdf_query
from service.sdf.rays import rays_from_frame
from service.sdf.types import RaySet, SdfConfig, SdfGrid

__all__ = ["fit_sdf", "hull_sdf", "make_grid_geometry", "extract_mesh", "query_torch", "sdf_query",
           "rays_from_frame", "contradicted_readings", "RaySet", "SdfConfig", "SdfGrid"]
