"""Groups that meshio's readers hand over apart from a tag array, made one with its names
(models.mesh.read calls it on every meshio read): Abaqus element sets, MED families, SU2 markers."""

from __future__ import annotations

import re

import numpy as np

from models.mesh.cells import TAG_NAMES

_AUTO_SET = re.compile(r"^(Point|Curve|Line|Surface|Volume)\d+$")  # gmsh's per-entity set names


_SU2_MARKER = re.compile(rb"^\s*MARKER_TAG\s*=\s*(\S+)", re.MULTILINE)


def named_groups(m, file_type: str, path: str, dims: list[int]):
    """Groups that meshio's readers hand over as something other than a tag array, made one (a
    `group` cell data and field_data names), where the file has no tag array of ours:
    Abaqus element sets (*ELSET, meshio's cell_sets; gmsh's per-entity sets 'Surface1' ... only for
    cells in no named set), MED families (meshio's cell_tags: family -> group names) and SU2 markers
    (meshio numbers them 1, 2, ... and drops their MARKER_TAG names: read back from the file).
    dims: the topological dimension of each of m's cell blocks."""
    families = getattr(m, "cell_tags", None)
    med = file_type == "med" and "cell_tags" in m.cell_data and bool(families)
    if not med and any(k in m.cell_data for k in TAG_NAMES):
        return m
    if file_type == "su2" and "su2:tag" in m.cell_data:
        top = max(dims)
        with open(path, "rb") as fh:
            names = [n.decode("utf-8", "replace") for n in _SU2_MARKER.findall(fh.read())]
        if not names:
            return m
        m.cell_data["group"] = [np.asarray(t, dtype=np.int64) for t in m.cell_data["su2:tag"]]
        m.field_data = {**m.field_data, **{n: np.array([i + 1, top - 1]) for i, n in enumerate(names)}}
        return m
    if med:  # MED: a family per cell, its groups' names
        groups: dict[str, int] = {}
        fam_to = {}
        for fam, names in families.items():
            if names:
                fam_to[int(fam)] = groups.setdefault(str(names[0]), len(groups) + 1)
        if not groups:  # (families without groups: gmsh's export of a mesh with no physical group)
            del m.cell_data["cell_tags"]
            return m
        keys = np.fromiter(fam_to, dtype=np.int64, count=len(fam_to))
        vals = np.fromiter(fam_to.values(), dtype=np.int64, count=len(fam_to))
        order = np.argsort(keys)
        keys, vals = keys[order], vals[order]
        tags = []
        for block in m.cell_data["cell_tags"]:
            fam = np.asarray(block, dtype=np.int64).reshape(-1)
            if not keys.size:
                tags.append(np.zeros(fam.size, dtype=np.int64))
                continue
            at = np.clip(np.searchsorted(keys, fam), 0, keys.size - 1)
            tags.append(np.where(keys[at] == fam, vals[at], 0))
        del m.cell_data["cell_tags"]  # (the families' numbers: no groups of the user's)
        m.cell_data["group"] = tags
        m.field_data = {**m.field_data, **_set_dims(groups, tags, dims)}
        return m
    sets = getattr(m, "cell_sets", None) or {}
    if sets:  # Abaqus *ELSET: the named sets first, then gmsh's per-entity ones
        # a cell goes to the smallest named set that holds it (a set of every element, EALL or an
        # instance's, never hides the materials inside it); the groups are numbered as the file
        # lists them (named, then per-entity), whatever the sets' sizes
        def size(name):
            return sum(np.asarray(x).size for x in sets[name])

        auto = {n: bool(_AUTO_SET.match(str(n))) for n in sets}
        names = sorted(sets, key=lambda n: (auto[n], size(n)))
        tags = [np.zeros(len(c.data), dtype=np.int64) for c in m.cells]
        groups = {}
        for name in names:
            for b, idx in enumerate(sets[name][: len(tags)]):
                idx = np.asarray(idx, dtype=np.int64).reshape(-1)
                if idx.size == 0 or idx.max() >= tags[b].size or idx.min() < 0:
                    continue
                free = idx[tags[b][idx] == 0]
                if free.size:
                    tags[b][free] = groups.setdefault(str(name), len(groups) + 1)
        if groups:
            listed = [str(n) for n in sorted(sets, key=lambda n: auto[n]) if str(n) in groups]
            new_id = np.zeros(len(groups) + 1, dtype=np.int64)
            for i, name in enumerate(listed):
                new_id[groups[name]] = i + 1
            tags = [new_id[t] for t in tags]
            groups = {_set_name(name, file_type): i + 1 for i, name in enumerate(listed)}
            m.cell_data["group"] = tags
            m.field_data = {**m.field_data, **_set_dims(groups, tags, dims)}
    return m


_FLAC3D_KEY = re.compile(r"^(?:zone|face):(.+):\d+$")  # meshio's key of a FLAC3D group: zone:NAME:SLOT


def _set_name(name: str, file_type: str) -> str:
    """A set's name as the file gives it (FLAC3D's ZGROUP "matrix" SLOT 1, not meshio's key for it)."""
    m = _FLAC3D_KEY.match(name) if file_type == "flac3d" else None
    return m.group(1) if m else name


def _set_dims(groups: dict, tags: list, dims: list) -> dict:
    """field_data {name: [id, dim]}: each group's dimension that of the cells it holds."""
    out = {}
    for name, gid in groups.items():
        dim = next((d for t, d in zip(tags, dims, strict=True) if np.any(t == gid)), None)
        if dim is not None:
            out[name] = np.array([gid, dim])
    return out


def zero_on_elements(arrays: list, blocks: list, top: int) -> bool:
    """The tag array is 0 on every element (cell of the top dimension) while the boundary's cells
    carry others: a writer's "no group" for the elements (gmsh's SU2 export: su2:tag 0 on every
    volume cell, its markers on the faces), not one group 0 over the whole mesh."""
    elem = [np.asarray(arrays[i]) for i, _n, _v, tdim, data in blocks if tdim == top and len(data)]
    lower = [np.asarray(arrays[i]) for i, _n, _v, tdim, data in blocks if tdim < top and len(data)]
    return bool(elem) and not any(t.any() for t in elem) and any(t.any() for t in lower)
