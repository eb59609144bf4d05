"""mks_sim.io: point-cloud and mesh files (PLY, PCD, NPY/NPZ, STL, OBJ)."""

from mks_sim.io.mesh import read_mesh, write_mesh, write_obj, write_ply_mesh, write_stl
from mks_sim.io.pointcloud import (
    PointCloud,
    read_point_cloud,
    write_npy,
    write_npz,
    write_pcd,
    write_ply,
    write_point_cloud,
)

__all__ = [
    "PointCloud",
    "read_mesh",
    "read_point_cloud",
    "write_mesh",
    "write_npy",
    "write_npz",
    "write_obj",
    "write_pcd",
    "write_ply",
    "write_ply_mesh",
    "write_point_cloud",
    "write_stl",
]
