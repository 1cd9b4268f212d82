"""Truncated HDF5 and netCDF files (Exodus II, CGNS, VTKHDF, MED, .cas.h5) are told as truncated
before a native reader opens them (models/mesh/containers.py): outside sweep U cut a meshio-written
Exodus file at every tenth of its length and each was refused as "it cannot be opened as an
Exodus II file"; the headers of both containers say how long the file is."""

from __future__ import annotations

import h5py
import numpy as np
import pytest
from scipy.io import netcdf_file

from models.errors import MeshError
from models.mesh.containers import truncated
from models.mesh.read import read_mesh


def _hdf5(path, libver):
    with h5py.File(path, "w", libver=libver) as f:
        f.create_dataset("coordinates", data=np.arange(30000, dtype=np.float64).reshape(-1, 3))
        f.create_group("blocks").create_dataset("connectivity", data=np.arange(40000, dtype=np.int64))
    return path


def _netcdf(path, version):
    f = netcdf_file(str(path), "w", version=version)
    f.createDimension("time_step", None)
    f.createDimension("num_nodes", 5000)
    f.createVariable("coordx", "d", ("num_nodes",))[:] = np.arange(5000.0)
    f.createVariable("connect1", "i", ("num_nodes",))[:] = 1
    f.createVariable("time_whole", "d", ("time_step",))[0] = 0.5
    f.createVariable("vals", "d", ("time_step", "num_nodes"))[0, :] = 1.0
    f.title = "written at test time"
    f.close()
    return path


@pytest.mark.parametrize(
    "make, name",
    [
        (lambda p: _hdf5(p, "earliest"), "m.exo"),  # superblock version 0
        (lambda p: _hdf5(p, "latest"), "m.cgns"),  # version 3
        (lambda p: _hdf5(p, "earliest"), "m.vtkhdf"),
        (lambda p: _netcdf(p, 1), "m.exo"),  # CDF-1
        (lambda p: _netcdf(p, 2), "m.e"),  # CDF-2, 64-bit offsets
    ],
)
def test_a_cut_container_is_said_to_be_truncated(tmp_path, make, name):
    path = make(tmp_path / name)
    data = path.read_bytes()
    assert truncated(str(path), data[:4096]) is None  # (whole: the reader speaks for itself)
    for frac in (0.1, 0.5, 0.9, 0.99):
        cut = tmp_path / f"cut{int(frac * 100)}{path.suffix}"
        cut.write_bytes(data[: int(len(data) * frac)])
        with pytest.raises(
            MeshError, match=rf"^cannot read {cut.name} as .*: the file is truncated: it holds"
        ):
            read_mesh(str(cut))
