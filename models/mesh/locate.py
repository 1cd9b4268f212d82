"""Where a text mesh file goes wrong: the line, the section and what was expected there.

Run only after a reader refused a file (or its mesh failed a check) and said no place: a plain
scan of the file's structure, section by section, for the text formats whose layout is simple
enough to follow here: legacy VTK ASCII (unstructured grids), gmsh ASCII (2.2 and 4.x), AVS UCD
ASCII and Gambit neutral; for Fluent, its sections (binary ones too: models.mesh.fluent_sections). It returns a phrase such as "line 12 (section POINTS, from line 5): 'x' where a number is
expected", or None when it finds nothing wrong (the reader's own reason then stands alone).

A refusal path, not a hot one: a loop over tokens is fine here, files over LIMIT bytes are not
scanned.
"""

from __future__ import annotations

import os
import re

LIMIT = 64 << 20
_INT = re.compile(rb"[-+]?\d+\Z")
_FLOAT = re.compile(rb"[-+]?(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?\Z|[-+]?(nan|inf|infinity)\Z", re.IGNORECASE)
_FINITE = re.compile(rb"[-+]?(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?\Z")


class _Found(Exception):
    """The first problem: its phrase."""


def _show(tok: bytes) -> str:
    """A token as a user can read it, quoted; bytes that are not printable text are not shown."""
    if not tok:
        return "nothing"
    text = tok[:24].decode("ascii", "replace")
    if any(not (32 < ord(c) < 127) for c in text):
        return "bytes that are not text"
    return repr(text + ("..." if len(tok) > 24 else ""))


class _Tokens:
    """Whitespace-separated tokens with their line numbers (1-based), and the section being read."""

    def __init__(self, lines: list[bytes], first: int, stop: int | None = None):
        self.lines, self.i, self.toks, self.k = lines, first, [], 0
        self.stop = len(lines) if stop is None else stop  # a section's end line (0-based), or the file's
        self.section, self.since = "", 0

    def enter(self, name: str, since: int | None = None) -> None:
        """A section starts: on the line read last when tokens are left on it, else on the next."""
        if since is None:
            since = self.line if self.k < len(self.toks) else self.line + 1
        self.section, self.since = name, since

    @property
    def line(self) -> int:
        return self.i  # 1-based number of the line the last token came from

    def next(self, what: str) -> bytes:
        while self.k >= len(self.toks):
            if self.i >= self.stop:
                if self.stop < len(self.lines):
                    raise _Found(
                        f"line {self.stop + 1:,}: section {self.section} (from line {self.since}) "
                        f"ends where {what} is expected"
                    )
                where = f" in section {self.section} (from line {self.since})" if self.section else ""
                raise _Found(f"the file ends{where} where {what} is expected: it is truncated")
            self.toks, self.k = self.lines[self.i].split(), 0
            self.i += 1
        self.k += 1
        return self.toks[self.k - 1]

    def rest_of_line(self) -> list[bytes]:
        out, self.k = self.toks[self.k :], len(self.toks)
        return out

    def fail(self, tok: bytes, what: str) -> None:
        sec = f" (section {self.section}, from line {self.since})" if self.section else ""
        raise _Found(f"line {self.line:,}{sec}: {_show(tok)} where {what} is expected")

    def int(self, what: str = "an integer", lo: int | None = None, hi: int | None = None) -> int:
        tok = self.next(what)
        if not _INT.match(tok):
            self.fail(tok, what)
        v = int(tok)
        if (lo is not None and v < lo) or (hi is not None and v > hi):
            self.fail(tok, what)
        return v

    def number(self, what: str = "a number") -> None:
        tok = self.next(what)
        if not _FLOAT.match(tok):
            self.fail(tok, what)


def locate(path: str | os.PathLike, kind: str) -> str | None:
    """The first problem in `path` read as `kind` ("legacy", "gmsh" or "ucd"), or None."""
    try:
        if os.path.getsize(path) > LIMIT:
            return None
        with open(path, "rb") as fh:
            data = fh.read()
    except OSError:
        return None
    lines = data.split(b"\n")
    try:
        {"legacy": _legacy, "gmsh": _gmsh, "ucd": _ucd, "gambit": _gambit, "fluent": _fluent}[kind](lines)
    except _Found as found:
        return str(found)
    except (KeyError, ValueError, IndexError, OverflowError):
        return None
    return None


# ---- legacy VTK ASCII --------------------------------------------------------------------------

_VTK_STOP = (b"POINT_DATA", b"CELL_DATA", b"FIELD", b"METADATA")


def _legacy(lines: list[bytes]) -> None:
    if not lines[0].lower().startswith(b"# vtk datafile version"):
        raise _Found("line 1: the header '# vtk DataFile Version x.x' is expected")
    if len(lines) < 4:
        raise _Found("the file ends before its header does (4 lines: version, title, ASCII, DATASET)")
    if lines[2].strip().upper() != b"ASCII":
        return  # binary: not a text scan
    ds = lines[3].split()
    if len(ds) != 2 or ds[0].upper() != b"DATASET":
        raise _Found("line 4: 'DATASET UNSTRUCTURED_GRID' (or another dataset type) is expected")
    if ds[1].upper() != b"UNSTRUCTURED_GRID":
        return
    t = _Tokens(lines, 4)
    n_points = None
    while True:
        try:
            key = t.next("a section keyword").upper()
        except _Found:
            return  # the end of the file between sections
        if key in _VTK_STOP:
            return
        t.enter(key.decode("ascii", "replace"))
        if key == b"POINTS":
            n_points = t.int("the number of points", lo=0)
            t.next("the points' data type")
            for _ in range(3 * n_points):
                t.number("a coordinate")
        elif key == b"CELLS":
            n = t.int("the number of cells", lo=0)
            size = t.int("the size of the cell list", lo=0)
            ids = "a point id" + (f" in 0..{n_points - 1}" if n_points else "")
            hi = None if n_points is None else n_points - 1
            save = (t.i, t.toks, t.k)
            if t.next("the cell list").upper() == b"OFFSETS":  # the 5.x layout
                t.next("the offsets' data type")
                for _ in range(n):
                    t.int("an offset", lo=0, hi=size)
                if t.next("CONNECTIVITY").upper() != b"CONNECTIVITY":
                    t.fail(t.toks[t.k - 1], "the keyword CONNECTIVITY")
                t.next("the connectivity's data type")
                for _ in range(size):
                    t.int(ids, lo=0, hi=hi)
                continue
            t.i, t.toks, t.k = save
            used = 0
            for _ in range(n):
                k = t.int("a cell's number of points", lo=1)
                for _ in range(k):
                    t.int(ids, lo=0, hi=hi)
                used += k + 1
                if used > size:
                    raise _Found(
                        f"line {t.line:,} (section CELLS, from line {t.since}): the cells hold more "
                        f"numbers than the {size:,} the header announces"
                    )
        elif key == b"CELL_TYPES":
            n = t.int("the number of cell types", lo=0)
            for _ in range(n):
                t.int("a VTK cell type (1..81)", lo=1, hi=81)
        else:
            t.section = ""
            t.fail(key, "a section keyword (POINTS, CELLS, CELL_TYPES, POINT_DATA or CELL_DATA)")


# ---- gmsh ASCII ---------------------------------------------------------------------------------

# gmsh element type -> number of nodes
GMSH_NODES = {1: 2, 2: 3, 3: 4, 4: 4, 5: 8, 6: 6, 7: 5, 8: 3, 9: 6, 10: 9, 11: 10, 12: 27, 13: 18}
GMSH_NODES.update({14: 14, 15: 1, 16: 8, 17: 20, 18: 15, 19: 13, 20: 9, 21: 10, 22: 12, 23: 15})
GMSH_NODES.update({24: 15, 25: 21, 26: 4, 27: 5, 28: 6, 29: 20, 30: 35, 31: 56, 92: 64, 93: 125})


def _gmsh(lines: list[bytes]) -> None:
    version, nodes = None, set()
    i = 0
    while i < len(lines):
        head = lines[i].strip()
        i += 1
        if not head:
            continue
        if not head.startswith(b"$"):
            raise _Found(f"line {i:,}: {_show(head.split()[0])} where a section ('$Name') is expected")
        name = head[1:].decode("ascii", "replace")
        start = i
        end = next((j for j in range(i, len(lines)) if lines[j].strip().startswith(b"$")), len(lines))
        if end == len(lines) or lines[end].strip() != b"$End" + head[1:]:
            found = "the end of the file" if end == len(lines) else f"line {end + 1:,}"
            raise _Found(f"section ${name} (from line {start:,}) has no $End{name} before {found}")
        t = _Tokens(lines, i, stop=end)
        t.enter("$" + name, since=start)
        if name == "MeshFormat":
            v = t.next("the format version ('2.2' or '4.1')")
            if not _FLOAT.match(v):
                t.fail(v, "the format version ('2.2' or '4.1')")
            version = float(v)
            if t.int("the file type (0 ASCII, 1 binary)", lo=0, hi=1) == 1:
                return  # binary: not a text scan
        elif name == "Nodes" and version is not None:
            nodes = _gmsh_nodes(t, version)
        elif name == "Elements" and version is not None:
            _gmsh_elements(t, version, nodes)
        if name in ("Nodes", "Elements") and version is not None:
            left, at = t.rest_of_line(), t.line
            for j in range(t.i, end):
                if left:
                    break
                left, at = lines[j].split(), j + 1
            if left:
                raise _Found(
                    f"line {at:,} (section ${name}, from line {start:,}): {_show(left[0])} after the "
                    f"entries the section announces, where $End{name} is expected"
                )
        i = end + 1


def _gmsh_nodes(t: _Tokens, version: float) -> set:
    tags = set()
    if version < 4:
        for _ in range(t.int("the number of nodes", lo=0)):
            tags.add(t.int("a node tag", lo=1))
            for _ in range(3):
                t.number("a coordinate")
        return tags
    blocks = t.int("the number of entity blocks", lo=0)
    for _ in range(3):
        t.int("a node count or tag", lo=0)
    for _ in range(blocks):
        dim = t.int("an entity dimension (0..3)", lo=0, hi=3)
        t.int("an entity tag")
        param = t.int("the parametric flag (0 or 1)", lo=0, hi=1)
        n = t.int("the number of nodes in the block", lo=0)
        block = [t.int("a node tag", lo=1) for _ in range(n)]
        tags.update(block)
        if param and version < 4.1:
            return tags  # (MSH 4.0's parametric layout: not followed here)
        # x y z per node, then (Mesh.SaveParametric) as many parametric coordinates as the entity has
        # dimensions: u on a curve, u v on a surface, u v w in a volume
        for _ in range(n * (3 + (dim if param else 0))):
            t.number("a coordinate")
    return tags


def _gmsh_elements(t: _Tokens, version: float, nodes: set) -> None:
    def node():
        v = t.int("a node tag", lo=1)
        if nodes and v not in nodes:
            t.fail(str(v).encode(), "a node tag that $Nodes defines")

    if version < 4:
        for _ in range(t.int("the number of elements", lo=0)):
            t.int("an element tag", lo=1)
            etype = t.int("an element type")
            if etype not in GMSH_NODES:
                t.fail(str(etype).encode(), "an element type gmsh defines")
            for _ in range(t.int("the number of tags", lo=0)):
                t.int("a tag")
            for _ in range(GMSH_NODES[etype]):
                node()
        return
    blocks = t.int("the number of entity blocks", lo=0)
    for _ in range(3):
        t.int("an element count or tag", lo=0)
    for _ in range(blocks):
        t.int("an entity dimension (0..3)", lo=0, hi=3)
        t.int("an entity tag")
        etype = t.int("an element type")
        if etype not in GMSH_NODES:
            t.fail(str(etype).encode(), "an element type gmsh defines")
        for _ in range(t.int("the number of elements in the block", lo=0)):
            t.int("an element tag", lo=1)
            for _ in range(GMSH_NODES[etype]):
                node()


# ---- AVS UCD ASCII -----------------------------------------------------------------------------

_UCD_NODES = {b"pt": 1, b"line": 2, b"tri": 3, b"quad": 4, b"tet": 4, b"pyr": 5, b"prism": 6, b"hex": 8}


def _ucd(lines: list[bytes]) -> None:
    first = next((j for j, ln in enumerate(lines) if ln.strip() and not ln.lstrip().startswith(b"#")), None)
    if first is None:
        raise _Found("the file holds only comments where the header 'n_points n_cells 0 0 0' is expected")
    t = _Tokens(lines, first)
    t.enter("header")
    n_pts = t.int("the number of points", lo=0)
    n_cells = t.int("the number of cells", lo=0)
    for what in ("node data", "cell data", "model data"):  # (their sections follow the cells)
        t.int(f"the number of {what} components", lo=0)
    t.enter("points")
    ids = set()
    for _ in range(n_pts):
        i = t.int("a point id")
        if i in ids:
            t.fail(str(i).encode(), "a point id no earlier point has")
        ids.add(i)
        if len(t.toks) != 4:
            raise _Found(f"line {t.line:,} (section points, from line {t.since}): 'id x y z' is expected")
        for _ in range(3):
            t.number("a coordinate")
    t.enter("cells")
    for _ in range(n_cells):
        t.int("a cell id")
        t.int("a material id")
        kind = t.next("a cell type (pt line tri quad tet pyr prism hex)")
        if kind.lower() not in _UCD_NODES:
            t.fail(kind, "a cell type (pt line tri quad tet pyr prism hex)")
        for _ in range(_UCD_NODES[kind.lower()]):
            v = t.int("a point id")
            if v not in ids:
                t.fail(str(v).encode(), "a point id that the points section defines")
        if t.k != len(t.toks):
            t.fail(
                t.toks[t.k], f"the end of the line (a {kind.decode()} has {_UCD_NODES[kind.lower()]} points)"
            )


# ---- Gambit neutral ---------------------------------------------------------------------------

_GAMBIT_NODES = {
    1: (2, 3),
    2: (4, 8, 9),
    3: (3, 6, 7),
    4: (8, 20, 27),
    5: (6, 15, 18),
    6: (4, 10),
    7: (5, 13, 14),
}


def _gambit_section(lines: list[bytes], start: int, name: bytes) -> tuple[int, int]:
    """(the section's first line after its title, its ENDOFSECTION line or len(lines)), 0-based;
    _Found where no such section follows `start`."""
    title = next((j for j in range(start, len(lines)) if lines[j].strip().startswith(name)), None)
    if title is None:
        raise _Found(f"the file ends before its {name.decode()} section")
    end = next((j for j in range(title + 1, len(lines)) if lines[j].strip() == b"ENDOFSECTION"), len(lines))
    return title + 1, end


def _gambit_count(
    t: _Tokens, end: int, n_lines: int, i: int, n: int, what: str, key: str, first: str
) -> None:
    """Before record i of n: a section that has ended (no token left before its ENDOFSECTION) holds
    fewer records than the header declares: say how many."""
    if t.k < len(t.toks) or any(ln.strip() for ln in t.lines[t.i : end]):
        return
    if end < n_lines:
        raise _Found(
            f"line {end + 1:,}: section {t.section} (from line {t.since}) holds {i:,} {what}, fewer than "
            f"the {n:,} the header declares ({key})"
        )
    raise _Found(
        f"the file ends in section {t.section} (from line {t.since}) after {i:,} of its {n:,} {what}: it is truncated"
    )


def _gambit(lines: list[bytes]) -> None:
    if lines[0].split()[:2] != [b"CONTROL", b"INFO"]:
        raise _Found("line 1: the title 'CONTROL INFO' is expected")
    head = next((j for j, ln in enumerate(lines[:12]) if ln.split()[:2] == [b"NUMNP", b"NELEM"]), None)
    if head is None:
        raise _Found("the header's 'NUMNP NELEM NGRPS NBSETS NDFCD NDFVL' line is missing")
    t = _Tokens(lines, head + 1)
    t.enter("CONTROL INFO")
    n_pts = t.int("the number of nodes (NUMNP)", lo=0)
    n_cells = t.int("the number of elements (NELEM)", lo=0)
    t.int("the number of element groups", lo=0)
    t.int("the number of boundary sets", lo=0)
    dims = t.int("the number of coordinate directions (2 or 3)", lo=2, hi=3)
    extra = t.rest_of_line()  # (NDFVL, which some writers leave out)
    if len(extra) > 1:  # (VTK's reader takes the row in fixed columns: a seventh number shifts them)
        raise _Found(
            f"line {t.line:,} (section CONTROL INFO): {5 + len(extra)} numbers where the row "
            "NUMNP NELEM NGRPS NBSETS NDFCD NDFVL has 6"
        )
    first, end = _gambit_section(lines, head + 2, b"NODAL COORDINATES")
    t = _Tokens(lines, first, end)
    t.enter("NODAL COORDINATES", first)
    for i in range(n_pts):
        _gambit_count(t, end, len(lines), i, n_pts, "nodes", "NUMNP", "a node id")
        t.int("a node id", lo=1)
        for _ in range(dims):
            t.number("a coordinate")
            if not _FINITE.match(t.toks[t.k - 1]):
                t.fail(t.toks[t.k - 1], "a finite coordinate")
    if end < len(lines) and t.i < end and any(ln.strip() for ln in lines[t.i : end]):
        raise _Found(
            f"line {t.i + 1:,} (section NODAL COORDINATES, from line {first}): more nodes than the "
            f"{n_pts:,} the header declares (NUMNP)"
        )
    first, end = _gambit_section(lines, end, b"ELEMENTS/CELLS")
    t = _Tokens(lines, first, end)
    t.enter("ELEMENTS/CELLS", first)
    for i in range(n_cells):
        _gambit_count(t, end, len(lines), i, n_cells, "elements", "NELEM", "an element id")
        t.int("an element id", lo=1)
        kind = t.int("an element type (1 to 7)", lo=1, hi=7)
        t.int(
            f"a number of nodes for element type {kind}",
            lo=min(_GAMBIT_NODES[kind]),
            hi=max(_GAMBIT_NODES[kind]),
        )
        for _ in range(int(t.toks[t.k - 1])):
            t.int(f"a node id in 1..{n_pts:,}", lo=1, hi=n_pts)
    if end < len(lines) and t.i < end and any(ln.strip() for ln in lines[t.i : end]):
        raise _Found(
            f"line {t.i + 1:,} (section ELEMENTS/CELLS, from line {first}): more elements than the "
            f"{n_cells:,} the header declares (NELEM)"
        )
    if end == len(lines):
        raise _Found(f"the file ends inside its ELEMENTS/CELLS section (from line {first}): it is truncated")


# ---- Fluent (ASCII and binary sections) -------------------------------------------------------


def _fluent(lines: list[bytes]) -> None:
    """Every Fluent section is a parenthesised list, the file a sequence of them; a binary section's
    body holds what its header declares and ends with its marker (models.mesh.fluent_sections)."""
    from models.mesh.fluent_sections import fault

    found = fault(b"\n".join(lines))
    if found:
        raise _Found(found)


__all__ = ["locate", "LIMIT"]
