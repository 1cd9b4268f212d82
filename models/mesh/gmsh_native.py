"""gmsh's own files that meshio's gmsh readers do not read, read by gmsh's library (the `gmsh`
wheel, a default dependency: `magnet generate` meshes with it): partitioned meshes (MSH 4.1's
$PartitionedEntities, written by `gmsh -part N` and Mesh.PartitionCreateTopology), MSH 4.0 files
(parametric nodes), and files saved with Mesh.SaveAll beside physical groups (elements outside
every group: meshio's cell data then do not match its cell blocks). A partitioned mesh's ghost
cells (Mesh.PartitionCreateGhostCells: each partition's copies of its neighbours' cells) are left
out.

meshio stays the first reader of every .msh file (models/mesh/read.py); this one reads a file
meshio refused only where the file itself looks sound (models.mesh.locate finds no place where it
goes wrong, or it is MSH 4.0, whose node layout that scan does not follow), so that a corrupted
file keeps meshio's refusal with its place. gmsh's library is C++: the CLI and the service read
with it in the sandbox's child only (read.NativeReaderNeeded), like VTK's readers.

The result is a meshio.Mesh as meshio's own readers make it (cell blocks by meshio's type names,
one block per element type and entity, `gmsh:physical` and `gmsh:geometrical` cell data, physical
names in field_data), so read.mesh_from_meshio does the rest as for every gmsh file.
"""

from __future__ import annotations

import os

import numpy as np

from models.errors import MeshError

GMSH_HEAD = 4096  # bytes of the head that hold $MeshFormat


def worth_trying(path: str) -> bool:
    """True when a .msh file that meshio refused looks sound: MSH 1.0 or 4.0, or a file in which our scan
    of its sections (models.mesh.locate) finds nothing wrong."""
    try:
        with open(path, "rb") as f:
            head = f.read(GMSH_HEAD)
    except OSError:
        return False
    if head.startswith(b"$NOD"):  # MSH 1.0 ($NOD / $ELM), which meshio does not read
        return True
    if not head.startswith(b"$MeshFormat"):
        return False
    lines = head.split(b"\n", 2)
    version = lines[1].split()[0] if len(lines) > 1 and lines[1].split() else b""
    if version in (b"4", b"4.0"):
        return True
    from models.mesh.locate import locate

    return locate(path, "gmsh") is None


def read_gmsh(path: str):
    """The file read by gmsh's library, as a meshio.Mesh (see the module docstring); MeshError in
    our words where gmsh cannot read it (gmsh's own text is never shown)."""
    import gmsh

    name = os.path.basename(path)
    own = not gmsh.isInitialized()
    if own:
        gmsh.initialize(readConfigFiles=False, interruptible=False)
    prev = gmsh.model.getCurrent() if not own else None
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.option.setNumber("General.Verbosity", 0)
        gmsh.model.add("magnet-read")
        try:
            gmsh.merge(path)
        except Exception:  # noqa: BLE001  (gmsh raises a bare Exception with its log's last line)
            raise MeshError(
                f"cannot read {name} with gmsh's library: it is corrupted or not a gmsh mesh"
            ) from None
        return _as_meshio(name)
    finally:
        if own:
            gmsh.finalize()
        else:
            gmsh.model.remove()
            if prev:
                gmsh.model.setCurrent(prev)


def _as_meshio(name: str):
    import gmsh
    import meshio
    from meshio.gmsh.common import _gmsh_to_meshio_order, _gmsh_to_meshio_type

    tags, coords, _ = gmsh.model.mesh.getNodes(returnParametricCoord=False)
    tags = np.asarray(tags, dtype=np.int64)
    if tags.size == 0:
        raise MeshError(f"cannot read {name} with gmsh's library: the file holds no nodes")
    points = np.asarray(coords, dtype=np.float64).reshape(-1, 3)
    tags, first = np.unique(tags, return_index=True)  # (a node is listed once per entity it is on)
    points = points[first]
    cells, physical, geometrical = [], [], []
    for dim, tag in gmsh.model.getEntities():
        if dim < 1 or gmsh.model.getType(dim, tag).startswith("Ghost"):
            continue  # (a partition's ghost cells: copies of its neighbours' cells)
        types, _, nodes = gmsh.model.mesh.getElements(dim, tag)
        if not len(types):
            continue
        groups = gmsh.model.getPhysicalGroupsForEntity(dim, tag)
        parent = gmsh.model.getParent(dim, tag)
        if not len(groups) and parent[0] == dim:  # a partition's entity: its parent's groups
            groups = gmsh.model.getPhysicalGroupsForEntity(*parent)
        group = int(groups[0]) if len(groups) else 0
        entity = int(parent[1]) if parent[0] == dim else int(tag)
        for t, n in zip(types, nodes, strict=True):
            kind = _gmsh_to_meshio_type.get(int(t))
            if kind is None:
                raise MeshError(
                    f"cannot read {name} with gmsh's library: it holds gmsh elements of type {int(t)}"
                )
            ids = np.searchsorted(tags, np.asarray(n, dtype=np.int64))
            per = gmsh.model.mesh.getElementProperties(int(t))[3]
            if ids.size % per or (ids.size and (ids.max() >= tags.size)):
                raise MeshError(
                    f"cannot read {name} with gmsh's library: its elements refer to missing nodes"
                )
            data = _gmsh_to_meshio_order(kind, ids.reshape(-1, per))
            cells.append(meshio.CellBlock(kind, np.asarray(data, dtype=np.int64)))
            physical.append(np.full(len(data), group, dtype=np.int64))
            geometrical.append(np.full(len(data), entity, dtype=np.int64))
    if not cells:
        raise MeshError(f"cannot read {name} with gmsh's library: the file holds no elements")
    field = {}
    for dim, tag in gmsh.model.getPhysicalGroups():
        label = gmsh.model.getPhysicalName(dim, tag)
        if label:
            field[label] = np.array([tag, dim])
    cell_data = {"gmsh:physical": physical, "gmsh:geometrical": geometrical}
    if not gmsh.model.getPhysicalGroups():
        cell_data = {"gmsh:geometrical": geometrical}
    return meshio.Mesh(points, cells, cell_data=cell_data, field_data=field)
