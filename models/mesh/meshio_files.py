"""meshio's readers, called directly for the formats meshio serves (docs/formats.md), with every
failure turned into one sentence of ours, and the table of meshio's cell type names we read."""

from __future__ import annotations

import contextlib
import io
import os
import re
import sys
import warnings

import numpy as np

from models.errors import MeshError
from models.mesh.container import (
    VTK_HEXAHEDRON,
    VTK_POLYGON,
    VTK_PYRAMID,
    VTK_QUAD,
    VTK_TETRA,
    VTK_TRIANGLE,
    VTK_WEDGE,
)

# meshio cell type name -> (VTK type, topological dimension, number of corner nodes kept)
MESHIO_TYPES: dict[str, tuple[int, int, int]] = {
    "vertex": (1, 0, 1),
    "line": (3, 1, 2),
    "line3": (3, 1, 2),
    "triangle": (VTK_TRIANGLE, 2, 3),
    "triangle6": (VTK_TRIANGLE, 2, 3),
    "triangle7": (VTK_TRIANGLE, 2, 3),
    "quad": (VTK_QUAD, 2, 4),
    "quad8": (VTK_QUAD, 2, 4),
    "quad9": (VTK_QUAD, 2, 4),
    "polygon": (VTK_POLYGON, 2, 0),
    "tetra": (VTK_TETRA, 3, 4),
    "tetra10": (VTK_TETRA, 3, 4),
    "hexahedron": (VTK_HEXAHEDRON, 3, 8),
    "hexahedron20": (VTK_HEXAHEDRON, 3, 8),
    "hexahedron27": (VTK_HEXAHEDRON, 3, 8),
    "wedge": (VTK_WEDGE, 3, 6),
    "wedge15": (VTK_WEDGE, 3, 6),
    "wedge18": (VTK_WEDGE, 3, 6),
    "pyramid": (VTK_PYRAMID, 3, 5),
    "pyramid13": (VTK_PYRAMID, 3, 5),
    "pyramid14": (VTK_PYRAMID, 3, 5),
}


def known_type(name: str) -> bool:
    """A meshio cell type we read: in MESHIO_TYPES, or a higher-order name of one of them (gmsh's elements
    of order 3 and up as meshio names them: triangle10, tetra20, hexahedron64, ...: the corner nodes
    come first), added to MESHIO_TYPES as its linear cell when first met."""
    if name in MESHIO_TYPES:
        return True
    base = name.rstrip("0123456789")
    if name != base and base in MESHIO_TYPES and base not in ("polygon", "vertex"):
        MESHIO_TYPES[name] = MESHIO_TYPES[base]
        return True
    return False


def read_meshio(path: str, file_type: str):
    """meshio's reader for `file_type` called directly (never meshio.read's guessing), with every
    failure (meshio raises many kinds, even SystemExit) turned into one sentence of ours."""
    import meshio
    from meshio._helpers import reader_map

    name = os.path.basename(path)
    if file_type not in reader_map:  # (a format meshio only writes, such as .svg: no mesh to read)
        from models.mesh.formats import extension, unknown_format

        raise MeshError(unknown_format(name, extension(path)).removeprefix(f"cannot read {name}: "))
    _meshio_dimensions()
    if file_type == "med":
        _med_families_without_groups()
    if file_type == "wkt":  # (meshio's pattern has no exponents: it backtracks for minutes on 1e-17)
        return _read_wkt(path)
    try:
        with (
            warnings.catch_warnings(),
            contextlib.redirect_stdout(io.StringIO()),
            contextlib.redirect_stderr(io.StringIO()),
        ):
            warnings.simplefilter("ignore")
            buffered = _BUFFER_READERS.get(file_type)
            if buffered is None:
                return reader_map[file_type](path)
            import importlib

            module, mode = buffered
            nastran = file_type == "nastran"
            with _open_guarded(
                path, mode, bulk=nastran and not found(path, _BEGIN_BULK), nastran=nastran
            ) as f:
                m = importlib.import_module(module).read_buffer(f)  # (a parse that no longer advances
                # ends, never hangs)
            card = (
                first_match(path, _LARGE_CARD) if nastran and not any(len(c.data) for c in m.cells) else None
            )
            if card:
                raise MeshError(
                    f"its element cards are in large-field form (such as {card}), which the Nastran reader "
                    "(meshio's) skips: write the elements in small or free field (the points may stay large)"
                )
            return m
    except MeshError:
        raise
    except (Exception, SystemExit) as exc:  # noqa: BLE001
        why = _why(exc, meshio)
        high = list(dict.fromkeys(_MEDIT_HIGH.findall(_head(path)))) if file_type == "medit" else None
        if high:  # (meshio's medit reader exits on any keyword it lacks: gmsh's order-2 export)
            why = (
                f"it holds {' and '.join(h.decode() for h in high)} elements (higher order), which this reader does not "
                "read: export the mesh at order 1, or as gmsh .msh, which keeps them (agglomerated on "
                "their corners)"
            )
        from models.mesh.formats import format_name

        if file_type == "cgns":  # (meshio's own layout: a node it reads missing, not an unknown type)
            from models.mesh.cgns_groups import meshio_layout_fault

            why = meshio_layout_fault(path) or why
        if file_type == "dolfin-xml":  # (its reader reads every <stem>_*.xml beside the file too)
            bad = _dolfin_sibling_at_fault(path)
            if bad:
                why = (
                    f"the file {bad} beside it, which DOLFIN's reader takes for its cell data "
                    f"(<name>_<data>.xml), is no DOLFIN mesh function: move it away, or rename it"
                )
        raise MeshError(
            f"cannot read {name} as {format_name(path)}: {why} (meshio's {file_type} reader)"
        ) from None


def _dolfin_sibling_at_fault(path: str) -> str | None:
    """The first `<stem>_*.xml` beside a DOLFIN XML file that its reader cannot read as a mesh
    function, where the file read alone (copied to a folder of its own) is a mesh; else None."""
    import shutil
    import tempfile

    from meshio.dolfin import read as read_dolfin

    folder, base = os.path.split(os.path.abspath(path))
    stem = os.path.splitext(base)[0]
    siblings = sorted(f for f in os.listdir(folder) if re.fullmatch(re.escape(stem) + r"_[^.]+\.xml", f))
    if not siblings:
        return None

    def reads(where: str) -> bool:
        try:
            with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
                read_dolfin(os.path.join(where, base))
        except (Exception, SystemExit):  # noqa: BLE001 (meshio raises many kinds)
            return False
        return True

    with tempfile.TemporaryDirectory(prefix="magnet-dolfin-") as alone:
        shutil.copy(path, os.path.join(alone, base))
        if not reads(alone):  # (the file itself is at fault)
            return None
        for f in siblings:  # a loop over the few files beside it
            shutil.copy(os.path.join(folder, f), os.path.join(alone, f))
            if not reads(alone):
                return f
            os.remove(os.path.join(alone, f))
    return None


_MEDIT_HIGH = re.compile(
    rb"^[ \t]*((?:Edges|Triangles|Quadrilaterals|Tetrahedra|Hexahedra|Prisms|Pyramids)[PQ][2-9])\b", re.M
)


def _head(path: str, size: int = 1 << 24) -> bytes:
    """The file's first `size` bytes (a keyword search's window)."""
    with open(path, "rb") as fh:
        return fh.read(size)


_WKT_RING = re.compile(r"\(\s*\(([^()]*)\)\s*\)")


def _read_wkt(path: str):
    """Well-known text surfaces (TIN, POLYHEDRALSURFACE, MULTIPOLYGON: each polygon's outer ring, the
    last point repeating the first) as a meshio.Mesh of triangles and quads, points merged where
    equal, as meshio's reader gives them. Linear in the file (meshio's regular expression has no
    exponents and backtracks for minutes on a coordinate like 6.1e-17)."""
    import meshio

    name = os.path.basename(path)
    with open(path, encoding="utf-8", errors="replace") as fh:
        rings = _WKT_RING.findall(fh.read())
    if not rings:
        raise MeshError(f"cannot read {name} as WKT: it holds no polygon")
    per = np.char.count(np.asarray(rings), ",") + 1  # points per ring
    dim = len(rings[0].split(",")[0].split())
    try:
        vals = np.asarray(",".join(rings).replace(",", " ").split(), dtype=np.float64)
    except ValueError:
        raise MeshError(f"cannot read {name} as WKT: a polygon's coordinates are not numbers") from None
    if dim not in (2, 3) or vals.size != int(per.sum()) * dim:
        raise MeshError(f"cannot read {name} as WKT: its points are not all of 2 or all of 3 coordinates")
    xyz = vals.reshape(-1, dim)
    first = np.cumsum(per) - per
    closed = np.all(xyz[first] == xyz[first + per - 1], axis=1)
    if not np.all(closed & ((per == 4) | (per == 5))):
        raise MeshError(
            f"cannot read {name} as WKT: {int(np.count_nonzero(~closed | ((per != 4) & (per != 5)))):,} "
            "polygons are not closed triangles or quadrilaterals (the last point repeating the first)"
        )
    keep = np.ones(xyz.shape[0], dtype=bool)
    keep[first + per - 1] = False  # (the repeated closing points)
    points, inverse = np.unique(xyz[keep], axis=0, return_inverse=True)
    node = inverse.ravel()
    corners = per - 1
    start = np.cumsum(corners) - corners
    cells = []
    for n, kind in ((3, "triangle"), (4, "quad")):
        at = start[corners == n]
        if at.size:
            cells.append((kind, node[at[:, None] + np.arange(n)]))
    return meshio.Mesh(points, cells)


def _med_families_without_groups() -> None:
    """meshio's MED reader takes every family to have groups (GRO): gmsh's MED export of a mesh without
    physical groups has families without, and every such file failed with KeyError('GRO'). Its family
    reader is replaced by one that gives such a family no group name (the rest as meshio reads it)."""
    from meshio.med import _med

    if getattr(_med._read_families, "_ours", False):
        return

    def read_families(fas_data):
        families = {}
        for _, node_set in fas_data.items():  # a loop over the families (a handful)
            if "GRO" not in node_set:
                families[node_set.attrs["NUM"]] = []
                continue
            nom = node_set["GRO"]["NOM"][()]
            families[node_set.attrs["NUM"]] = [
                bytes(np.asarray(row, dtype=np.int8).view(np.uint8)).decode("latin-1").strip().rstrip("\x00")
                for row in nom[: node_set["GRO"].attrs["NBR"]]
            ]
        return families

    read_families._ours = True
    _med._read_families = read_families


def _meshio_dimensions() -> None:
    """meshio's gmsh readers make cells named wedge15 and pyramid13 (gmsh's incomplete quadratic
    prism and pyramid) whose dimension meshio's own table lacks: every such file failed with
    KeyError('wedge15'). The names its readers make and the table misses get their dimension (from
    our cell table) before a read."""
    from meshio._mesh import topological_dimension

    for name in ("wedge15", "pyramid13"):
        if name not in topological_dimension and known_type(name):
            topological_dimension[name] = MESHIO_TYPES[name][1]


# meshio's text readers whose read(path) is open(path) + read_buffer(f): read here through a file
# that refuses to be read past its end again and again (meshio's PLY header loop, for one, asks
# for the next line forever on a truncated file)
_BUFFER_READERS = {
    "ply": ("meshio.ply._ply", "rb"),
    "nastran": ("meshio.nastran._nastran", "r"),
    "su2": ("meshio.su2._su2", "r"),
    "permas": ("meshio.permas._permas", "r"),
    "neuroglancer": ("meshio.neuroglancer._neuroglancer", "rb"),
}
_EOF_READS = 64  # consecutive reads at the end of the file: a parser that no longer advances


class _GuardedBinary(io.BufferedReader):
    """A binary file whose readline() raises EOFError when asked for a line at the end of the file
    _EOF_READS times in a row (a real file object: np.fromfile still reads from it)."""

    _at_eof = 0

    def readline(self, size=-1):
        line = super().readline(size)
        self._at_eof = 0 if line else self._at_eof + 1
        if self._at_eof > _EOF_READS:
            raise EOFError("end of file")
        return line


class _GuardedText(io.TextIOWrapper):
    """_GuardedBinary for text (_first: a line given before the file's own)."""

    _at_eof = 0
    _first = None
    _blank_goes_on = False  # Nastran: a line whose first field is blank continues the card before

    def readline(self, size=-1):
        if self._first is not None:
            line, self._first = self._first, None
            return line
        line = super().readline(size)
        self._at_eof = 0 if line else self._at_eof + 1
        if self._at_eof > _EOF_READS:
            raise EOFError("end of file")
        if self._blank_goes_on and line.startswith("        ") and line[8:].strip():
            # (gmsh's large-field export continues CHEXA so, after a card of 9 fields: meshio follows
            # only '+' or '*' there, or a 10th field left blank; a card never starts with a blank)
            line = "+" + line[1:]
        return line


def _open_guarded(path: str, mode: str, bulk: bool = False, nastran: bool = False):
    """bulk: a Nastran file of bulk data only (gmsh's export has no executive and case control
    sections, and no BEGIN BULK line, which meshio's reader looks for first): the line given first.
    nastran: a line whose first 8-character field is blank is a continuation (marked '+')."""
    raw = _GuardedBinary(io.FileIO(path, "rb"))
    if mode == "rb":
        return raw
    text = _GuardedText(raw)
    if bulk:
        text._first = "BEGIN BULK\n"
    text._blank_goes_on = nastran
    return text


_BEGIN_BULK = re.compile(rb"BEGIN BULK")
_LARGE_CARD = re.compile(rb"(?m)^C[A-Z0-9]+\*")  # a Nastran element card in large field (CTETRA*)


def first_match(path: str, pattern: re.Pattern) -> str | None:
    """The pattern's first match in the file, as text (one pass over its mapping), or None."""
    import mmap

    with open(path, "rb") as fh:
        if os.fstat(fh.fileno()).st_size == 0:
            return None
        with mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ) as mm:
            hit = pattern.search(mm)
            return None if hit is None else hit.group(0).decode("ascii", "replace")


def found(path: str, pattern: re.Pattern) -> bool:
    """The bytes pattern occurs in the file (one pass over its mapping; an empty file: no)."""
    return first_match(path, pattern) is not None


_LINE = re.compile(r"\bline\s+(\d+)", re.IGNORECASE)


def _why(exc: BaseException, meshio) -> str:
    """What was wrong, in our words (a library's text is never shown: it names its internals)."""
    text = str(exc)
    where = _LINE.search(text)
    at = f" (near line {int(where.group(1)):,})" if where else ""
    if isinstance(exc, UnicodeDecodeError):
        return f"it holds bytes that are not text where text was expected (byte offset {exc.start:,})"
    if isinstance(exc, ModuleNotFoundError):
        return f"this format needs the Python package {exc.name!r}, which is not installed"
    if isinstance(exc, KeyError):
        return "it holds an element type or a keyword that this reader does not know" + at
    if isinstance(exc, ValueError) and ("literal" in text or "could not convert" in text):
        return "a number in it is malformed" + at
    if isinstance(exc, IndexError):
        return "it refers to a node or an element that it does not define" + at
    if isinstance(exc, EOFError) or "end of file" in text.lower() or "truncat" in text.lower():
        return "the file ends before its data does (truncated?)" + at
    if "reshape" in text or "size" in text:
        return "a section holds fewer or more numbers than its header announces" + at
    return "it is corrupted or not in this format" + at


def whole_rows(name: str, data) -> None:
    """A block of a fixed-size meshio type lists that many nodes per cell (a reader that lost a
    card's continuation line gives hexahedra of 6 nodes). Blocks of meshio's readers only: where
    meshio is not loaded, our own readers made them, whole (and meshio stays unloaded)."""
    common = sys.modules.get("meshio._common")
    if common is None:
        return
    want = common.num_nodes_per_cell.get(name)
    got = np.shape(data)[1] if np.ndim(data) == 2 else None
    if want is not None and len(data) and got != want:
        raise MeshError(
            f"its {name} cells list {got if got is not None else 'differing numbers of'} nodes each, where a "
            f"{name} has {want}: the file is corrupted, or its element cards go on over lines in a way the "
            "reader does not follow"
        )
