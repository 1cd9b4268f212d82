"""Gambit neutral (.neu) files: what VTK's reader (vtkGAMBITReader) leaves out or dies on.

- Element groups as physical groups. A Gambit file puts every element in an ELEMENT GROUP (its
  zone: a material, a fluid or solid region; gmsh writes one per physical group), named on the
  line after the group's header. VTK's reader keeps only each group's MATERIAL number ("Material
  Type"), 0 in every group gmsh writes, so the groups and their names were lost.
- Repeated ENDOFSECTION lines. gmsh writes one or more ENDOFSECTION too many after the element
  groups of a file with boundary conditions; VTK's reader then frees memory twice and dies, so the
  file is read from a copy without them (vtk_readers).

Element ids: a group lists Gambit element ids; VTK's reader keeps the elements in the file's order
and ignores their ids, so the k-th element is taken to be id k (as every writer we know numbers
them: Gambit, gmsh, ICEM). A group listing an id past the elements, or an element in no group,
is said in a note rather than guessed at.
"""

from __future__ import annotations

import re

import numpy as np

# the header line of an element group: GROUP: g ELEMENTS: n MATERIAL: m NFLAGS: f
_GROUP = re.compile(
    rb"ELEMENT GROUP[^\n]*\n\s*GROUP:\s*(\d+)\s+ELEMENTS:\s*(\d+)\s+MATERIAL:\s*(\d+)\s+NFLAGS:\s*(\d+)[^\n]*\n"
    rb"([^\n]*)\n"
)
_END = re.compile(rb"^[ \t]*ENDOFSECTION[ \t\r]*$", re.M)
REPEATED_END = re.compile(rb"(ENDOFSECTION[ \t\r]*\n)(?:[ \t\r]*ENDOFSECTION[ \t\r]*\n)+")


def element_groups(data: bytes, n_cells: int, dim: int) -> tuple[np.ndarray | None, dict, str | None] | None:
    """(tags (n_cells,) int64: each element's group number, 0 for none; {name: [number, dim]} as
    gmsh's field data; a note or None) from a Gambit file's bytes; None where it has no element
    group. Groups that cannot be trusted (a count that does not match its ids, an id past the
    elements) give (None, {}, a note saying so): no group is used."""
    tags = np.zeros(n_cells, dtype=np.int64)
    sizes = np.zeros(n_cells, dtype=np.int64)  # the size of the group a cell is in (smallest wins)
    names: dict[str, list[int]] = {}
    twice = 0
    found = False
    for m in _GROUP.finditer(data):
        found = True
        number, count, nflags = int(m.group(1)), int(m.group(2)), int(m.group(4))
        end = _END.search(data, m.end())
        body = data[m.end() : end.start() if end else len(data)].split()
        if len(body) != nflags + count or number < 1:
            return (
                None,
                {},
                (
                    f"element group {number} lists {max(len(body) - nflags, 0):,} ids where its header says "
                    f"{count:,}: the element groups are not used"
                ),
            )
        try:
            ids = np.array(body[nflags:], dtype=np.int64) - 1
        except ValueError:
            return (
                None,
                {},
                f"element group {number} holds a word that is not an element id: the element groups are not used",
            )
        if ids.size and (ids.min() < 0 or ids.max() >= n_cells):
            return (
                None,
                {},
                (
                    f"element group {number} lists element {int(ids.max()) + 1:,}, past the {n_cells:,} elements "
                    "of the file: the element groups are not used"
                ),
            )
        name = m.group(5).decode("utf-8", "replace").strip() or f"group {number}"
        name = name if name not in names else f"{name} (group {number})"
        names[name] = [number, dim]
        taken = sizes[ids] > 0
        twice += int(np.count_nonzero(taken))
        better = ~taken | (sizes[ids] > count)  # a cell in two groups: kept in the smaller one
        tags[ids[better]] = number
        sizes[ids[better]] = count
    if not found:
        return None
    notes = []
    if twice:
        notes.append(
            f"{twice:,} element{'s' if twice > 1 else ''} listed in two element groups: "
            f"{'each' if twice > 1 else 'it is'} kept in the smaller group"
        )
    loose = int(np.count_nonzero(sizes == 0))
    if loose:
        notes.append(f"{loose:,} element{'s' if loose > 1 else ''} in no element group: group 0")
    return tags, names, "; ".join(notes) or None
