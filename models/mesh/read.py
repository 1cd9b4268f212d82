"""Mesh input: one dispatch (pick_reader) picks one reader per file, whose arrays become one `Mesh`.

Format quirks stay here. Everything returned is validated: finite coordinates, cell indices in
range, no degenerate cells, cells oriented consistently with their neighbours and each connected
piece positively (2D counter-clockwise, 3D outward): see orientation.py. A folded cell (negative
signed measure once its neighbours agree) is kept and reported in mesh.meta["orientation"].
"""

from __future__ import annotations

import os
import re
import stat
import struct
import sys
from itertools import chain

import numpy as np

from models.errors import MeshError
from models.mesh import case_files, lookalikes
from models.mesh.build import MIRROR, _bounds, mesh_from_cells, weld_points  # noqa: F401 (MIRROR, weld_points: API)
from models.mesh.cells import BOUNDARY_TAG_NAME, distinct_nodes, find_tag_key, higher_order_line
from models.mesh.container import (
    CELL_TYPE_NAMES,
    VTK_POLYGON,
    VTK_POLYHEDRON,
    VTK_QUAD,
    VTK_TRIANGLE,
    Mesh,
)
from models.mesh.formats import (
    MESH_EXTENSIONS,
    MULTI_FILE,
    compressed_hint,
    extension,
    format_name,
    not_found,
)
from models.mesh.meshio_files import MESHIO_TYPES as _TYPES
from models.mesh.meshio_files import found as _found
from models.mesh.meshio_files import known_type as _known
from models.mesh.meshio_files import read_meshio as _read_meshio
from models.mesh.meshio_files import whole_rows
from models.mesh.meshio_groups import zero_on_elements

# extension -> the reader family that serves it (docs/formats.md); any other meshio extension: meshio
_VTK_XML = (
    ".vtu",
    ".pvtu",
    ".vtp",
    ".pvtp",
    ".vti",
    ".pvti",
    ".vts",
    ".pvts",
    ".vtr",
    ".pvtr",
    ".vtm",
    ".vtpc",
    ".vtpd",
    ".pvd",
)
_EXODUS = (".exo", ".e", ".ex2", ".exii", ".g", ".gen")
_VTK_OTHER = {
    ".xdmf": "xdmf",
    ".xmf": "xdmf",
    ".cgns": "cgns",
    ".cas": "fluent",
    ".neu": "gambit",
    ".vtkhdf": "vtkhdf",
    ".foam": "openfoam",
    ".case": "ensight",
    ".encas": "ensight",
    ".xyz": "plot3d",
    ".xy": "plot3d",
    ".p3d": "plot3d",
    ".dat": "tecplot",
    ".tec": "tecplot",
    ".tp": "tecplot",
    ".plt": "tecplot",
    ".szplt": "tecplot",
}
_SURFACES = (".stl", ".obj", ".ply", ".off")
XML_GRIDS = (".vts", ".vtr", ".vti")  # VTK XML structured files: our numpy path first (xml_grid.py)
SUPPORTED_EXTENSIONS = MESH_EXTENSIONS  # the one list, in models/mesh/formats.py


def _extension(path: str) -> str:
    return extension(path)


_VTKTYPE = re.compile(rb"vtktype(?!u?int64\b)[a-z0-9]+")


def _other_vtktypes(path: str) -> bool:
    """A legacy VTK file naming a vtktype* data type other than (u)int64 (one regex pass, mmap)."""
    return _found(path, _VTKTYPE)


def pick_reader(path: str, file_format: str | None = None) -> tuple[str, str]:
    """One reader per file, by extension and a look at its first bytes: (family, detail) with
    family "vtu" (our fast VTU path, VTK's reader for any other VTU), "vtk" (detail: a key of
    vtk_readers.READERS), "ucd" (our AVS UCD reader) or "meshio" (detail: meshio's file type)."""
    name = os.path.basename(path)
    ext = _extension(path)
    with open(path, "rb") as fh:
        head = fh.read(4096)
    if head[:4] in (b"\x89HDF", b"CDF\x01", b"CDF\x02", b"CDF\x05"):
        from models.mesh.containers import truncated

        why = truncated(path, head)  # (before a native reader opens it: they crash on such files)
        if why:
            raise MeshError(f"cannot read {name} as {format_name(path, file_format)}: {why}")
    text = head.lstrip(b"\xef\xbb\xbf \t\r\n")
    legacy = text[:14].lower() == b"# vtk datafile"
    xml = text[:1] == b"<"
    fmt = (file_format or "").lower()
    if fmt:
        if fmt in ("ucd", "avsucd"):
            return ("vtk", "avs-binary") if head[:1] == b"\x07" else ("ucd", "")
        if fmt == "vtu":
            return ("vtu", "")
        if fmt in ("vtk", "legacy"):
            return ("vtk", "legacy") if legacy else ("vtk", "xml")
        if fmt == "exodus":
            return ("vtk", "exodus")
        if fmt in ("xdmf", "cgns", "fluent", "gambit", "tecplot"):
            return ("vtk", fmt)
        return ("meshio", fmt)
    if ext == ".vtk" or (legacy and ext in _VTK_XML):
        if legacy:
            # VTK's legacy reader knows vtktypeint64/uint64 only; meshio writes e.g. vtktypeuint8 too
            return ("meshio", "vtk") if _other_vtktypes(path) else ("vtk", "legacy")
        if xml and b"<VTKFile" in head:
            return ("vtk", "xml")
        raise MeshError(
            f"cannot read {name} as legacy VTK: its first line must be '# vtk DataFile Version x.x'"
        )
    if ext in _VTK_XML:
        if not xml:
            raise MeshError(f"cannot read {name} as VTK XML ({ext}): the file does not start with an XML tag")
        if ext in MULTI_FILE:
            case_files.pieces_present(path, ext)
        return ("vtu", "") if ext == ".vtu" else ("vtk", ext)
    if ext in _EXODUS:
        if head[:3] == b"CDF" or head[:4] == b"\x89HDF":
            from models.mesh.containers import exodus_fault

            why = exodus_fault(path)  # (netCDF classic: its blocks' header, before VTK's reader crashes;
            # netCDF-4: read_vtk checks them in the reading child)
            if why:
                raise MeshError(f"cannot read {name} as Exodus II: {why}")
            return ("vtk", "exodus")
        raise MeshError(
            f"cannot read {name} as Exodus II: the file is neither netCDF nor HDF5 (byte 0)"
            + (f"; {lookalikes.byu_surface(text)}" if ext == ".g" else "")
        )
    if ext == ".cas.h5":
        return ("vtk", "fluent-h5")
    if ext == ".pvtk":  # vtkPDataSetWriter's list of legacy pieces
        if not xml:
            raise MeshError(
                f"cannot read {name} as VTK parallel legacy: the file does not start with an XML tag"
            )
        case_files.pieces_present(path, ext)
        return ("vtk", ".pvtk")
    if ext in (".case", ".encas"):
        case_files.ensight_files(path)
    if ext == ".foam" or name == "controlDict":
        return ("vtk", case_files.openfoam_case(path))
    if ext in _VTK_OTHER:
        if ext in (".xdmf", ".xmf") and not xml:
            raise MeshError(f"cannot read {name} as XDMF: the file does not start with an XML tag")
        if ext in (".xdmf", ".xmf"):
            case_files.pieces_present(path, ext)
        if ext == ".vtkhdf" and head[:4] != b"\x89HDF":
            raise MeshError(f"cannot read {name} as VTKHDF: the file is not HDF5 (byte 0)")
        if ext == ".cas" and not text.startswith(b"("):
            raise MeshError(f"cannot read {name} as a Fluent case: a Fluent case starts with '(' (byte 0)")
        if _VTK_OTHER[ext] == "plot3d" and lookalikes.xyz_molecule(text):
            raise MeshError(f"cannot read {name} as PLOT3D grid: {lookalikes.xyz_molecule(text)}")
        if _VTK_OTHER[ext] == "tecplot":
            _tecplot_ascii(name, ext, head, text)
        if ext == ".neu" and not re.search(rb"CONTROL[ \t]+INFO", head.upper()):  # (or a tab between)
            raise MeshError(
                f"cannot read {name} as Gambit neutral: no 'CONTROL INFO' section at the start of the file"
            )
        if ext == ".cgns" and head[:4] == b"\x89HDF":
            from models.mesh.cgns_groups import meshio_layout

            if meshio_layout(path):  # (meshio's writer: plain HDF5 groups, which VTK's reader refuses)
                return ("meshio", "cgns")
        return ("vtk", _VTK_OTHER[ext])
    if ext == ".msh":
        if text.startswith(b"$"):
            return ("meshio", "gmsh")
        if text.startswith(b"("):
            return ("vtk", "fluent")
        raise MeshError(
            f"cannot read {name}: a .msh file is gmsh (starts with '$MeshFormat') or Fluent (starts with '('), and this one is neither"
        )
    if ext in (".ucd", ".avs", ".inp"):
        from models.mesh.ucd import is_ucd

        if head[:1] == b"\x07":
            _binary_ucd_whole(path, head, name)
            return ("vtk", "avs-binary")
        if ext != ".inp" or is_ucd(path):
            return ("ucd", "")
        return ("meshio", "abaqus")
    if ext == ".ply":
        from models.mesh.ply import check_header

        check_header(path, name, head)
    import meshio

    types = meshio.extension_to_filetypes.get(ext)
    if not types:
        hint = compressed_hint(path)
        if hint:
            raise MeshError(f"cannot read {name}: unknown mesh format {ext!r}{hint}")
        from models.mesh.formats import unknown_format

        raise MeshError(unknown_format(name, ext))
    return ("meshio", types[0])


def _binary_ucd_whole(path: str, head: bytes, name: str) -> None:
    """A binary AVS UCD file shorter than its header's counts need (magic byte 7; nodes, cells,
    node / cell / model data components, connectivity length as int32; then 16 bytes a
    cell, 4 a connectivity entry, 12 a node) is refused as truncated before VTK's reader reads past
    its end."""
    if len(head) < 25:
        raise MeshError(
            f"cannot read {name} as binary AVS UCD: the file ends inside its header: it is truncated"
        )
    size = os.path.getsize(path)
    for order in "<>":  # (the writer's byte order: little on every machine of today, big on old ones)
        n_nodes, n_cells, _, _, _, n_list = struct.unpack(order + "6i", head[1:25])
        if min(n_nodes, n_cells, n_list) >= 0 and max(n_nodes, n_cells, n_list) <= size:
            break
    else:
        return  # (counts that fit no byte order: VTK's reader speaks)
    need = 25 + 16 * n_cells + 4 * n_list + 12 * n_nodes
    if size < need:
        raise MeshError(
            f"cannot read {name} as binary AVS UCD: the file is truncated: it holds {size:,} bytes of the "
            f"{need:,} its header's {n_nodes:,} nodes and {n_cells:,} cells need (copy or upload it again)"
        )


def _tecplot_ascii(name: str, ext: str, head: bytes, text: bytes) -> None:
    """Refuses what VTK's Tecplot reader (ASCII only, as ParaView's) cannot read, in our words: a
    binary Tecplot file (.plt's '#!TDV' header, SZL's .szplt) or a file with no Tecplot record."""
    if head[:5] == b"#!TDV" or ext == ".szplt" or head[:8] == b"#!SZPLT":
        raise MeshError(
            f"cannot read {name} as Tecplot: it is a binary Tecplot file, and only Tecplot's ASCII "
            "format is read; save it from Tecplot as ASCII data (.dat), or convert it with Tecplot's "
            "preplot/szl tools"
        )
    upper = text[:4096].upper()
    if not any(word in upper for word in (b"ZONE", b"VARIABLES", b"TITLE")):
        raise MeshError(
            f"cannot read {name} as Tecplot: no TITLE, VARIABLES or ZONE record at the start of the "
            "file (is it a Tecplot ASCII data file?)"
        )


class NativeReaderNeeded(MeshError):
    """read_mesh(native=False) met a file that only a native reader (VTK's, gmsh's library) reads."""


def read_mesh(
    path: str | os.PathLike,
    physical_tag: str | None = None,
    file_format: str | None = None,
    weld: float | None = None,
    *,
    native: bool = True,
) -> Mesh:
    """Read a mesh file and return a validated, positively oriented `Mesh`: one reader per file
    (pick_reader), which hands its arrays to build.mesh_from_cells.

    weld: merge points closer than this distance first (coincident duplicates that split a mesh).
    native=False: a VTU, .vts, .vtr or .vti that our numpy paths (models/mesh/vtu.py, xml_grid.py)
    do not read raises NativeReaderNeeded instead of going to VTK's reader (the CLI then reads it in
    the sandbox: models.mesh.sandbox)."""
    path = os.fspath(path)
    if not os.path.exists(path):
        raise MeshError(not_found(path))
    if os.path.isdir(path):  # an OpenFOAM case given as its folder
        path = case_files.openfoam_file(path) or path
    special_file(path)
    if os.path.getsize(path) == 0 and _extension(path) != ".foam":  # (a .foam file is empty)
        raise MeshError(f"{os.path.basename(path)}: the file is empty (0 bytes)")
    try:
        return _read(path, physical_tag, file_format, weld, native)
    except NativeReaderNeeded:
        raise
    except MeshError as exc:
        raise MeshError(refusal(str(exc), path, file_format)) from None


_SPECIAL = ((stat.S_ISFIFO, "a named pipe"), (stat.S_ISSOCK, "a socket"), (stat.S_ISCHR, "a device"),
            (stat.S_ISBLK, "a device"))  # fmt: skip


def special_file(path: str) -> None:
    """Refuse a path that is no regular file (a pipe or a device has no size and may never end:
    the readers seek and map their files)."""
    mode = os.stat(path).st_mode
    for test, what in _SPECIAL:
        if test(mode):
            raise MeshError(
                f"{os.path.basename(path)} is {what}, not a mesh file: save the mesh to a file and give that"
            )


def refusal(msg: str, path: str, file_format: str | None) -> str:
    """A reader's or a check's refusal as one sentence naming the file, the format tried and,
    where it can be known, the place."""
    name, fmt = os.path.basename(path), format_name(path, file_format)
    msg = _with_place(msg, path, file_format)
    if (name in msg and fmt in msg) or msg.startswith(f"cannot read {name} as "):  # (said already)
        return msg
    for prefix in (f"cannot read {name}: ", f"{name}: "):
        if msg.startswith(prefix):
            msg = msg[len(prefix) :]
    if fmt == "mesh":  # (no format known by its extension: the message says what is wrong)
        return f"cannot read {name}: {msg}"
    return f"cannot read {name} as {fmt}: {msg}"


# the text formats whose structure models.mesh.locate follows: pick_reader's answer -> its kind
_LOCATABLE = {
    ("vtk", "legacy"): "legacy",
    ("meshio", "vtk"): "legacy",
    ("meshio", "gmsh"): "gmsh",
    ("ucd", ""): "ucd",
    ("vtk", "gambit"): "gambit",
    ("vtk", "fluent"): "fluent",
}
PLACE = re.compile(r"\b(?:line|byte offset|byte|offset) \d|\bsection [$A-Z]")


def _with_place(msg: str, path: str, file_format: str | None) -> str:
    """A refusal of a text file that says no place gets the place where the file goes wrong, when
    a scan of its structure finds one (models.mesh.locate): the line, the section, what was expected."""
    if PLACE.search(msg):
        return msg
    try:
        kind = _LOCATABLE.get(pick_reader(path, file_format))
    except (MeshError, OSError):
        return msg
    if kind is None:
        return msg
    from models.mesh.locate import locate

    where = locate(path, kind)
    if not where:
        return msg
    vague = _VAGUE.search(msg)  # "it is corrupted or not X": the place says more, and replaces it
    return msg[: vague.start()] + where if vague else f"{msg.rstrip('.')}; {where}"


_VAGUE = re.compile(
    r"(?:(?:the file is|it is) corrupted or not [^;:]*|its text cannot be parsed|its cells cannot be read"
    r"|the file ends before its data does \(truncated\?\))$"
)


def _read(path: str, physical_tag, file_format, weld, native: bool = True) -> Mesh:
    if file_format is None and _extension(path) == ".vtk":
        from models.mesh import deferred
        from models.mesh.legacy import read_legacy_raw, read_legacy_simple

        if deferred.DEFER and weld is None and physical_tag is None:  # the reading child: the
            raw = read_legacy_raw(path, mapped=True)  # file's arrays as they are (mapped), widened
            # and built by the caller
            if raw is not None:
                from models.mesh.boundary import group_names

                groups, bounds = group_names(None, deferred.FIXED_DIM[raw[3]])
                meta = {"group_names": groups, "boundary_names": bounds}
                meta.update(reader="numpy (models/mesh/legacy.py)", format="legacy VTK")
                return deferred.fixed(*raw, meta)
        simple = read_legacy_simple(path)  # the common binary layout, numpy on the file's bytes; else None
        if simple is not None:
            mesh = mesh_from_meshio(simple, physical_tag=physical_tag, weld=weld, owned=True)
            mesh.meta.update(reader="numpy (models/mesh/legacy.py)", format="legacy VTK")
            return mesh
    family, detail = pick_reader(path, file_format)
    if family == "vtu":
        from models.mesh.vtu import impossible_counts, read_vtu_simple

        simple = read_vtu_simple(path)  # the common layout, faster than any XML reader; else None
        if simple is not None:
            mesh = mesh_from_meshio(simple, physical_tag=physical_tag, weld=weld, owned=True)
            mesh.meta.update(reader="numpy (models/mesh/vtu.py)", format="VTK XML unstructured grid")
            return mesh
        why = impossible_counts(path)
        if why:  # VTK's reader would believe the number (and run for minutes)
            raise MeshError(f"the file is corrupted: {why}")
        if not native:
            raise NativeReaderNeeded(f"{os.path.basename(path)} needs VTK's VTU reader")
        family, detail = "vtk", ".vtu"
    if family == "vtk" and detail in XML_GRIDS:
        from models.mesh.xml_grid import read_xml_grid

        # the common layout, numpy on the file's bytes; else None. In-process (native=False): a
        # lattice beyond the sandbox's memory limit is left to the sandbox
        limit = None if native else default_memory()
        mesh = read_xml_grid(path, physical_tag, weld, memory_bytes=limit)
        if mesh is not None:
            return mesh
        if not native:
            raise NativeReaderNeeded(f"{os.path.basename(path)} needs VTK's XML reader")
    if family == "ucd":
        from models.mesh.ucd import read_ucd

        return mesh_from_meshio(read_ucd(path), physical_tag=physical_tag, weld=weld, owned=True)
    if family == "vtk":
        from models.mesh.vtk_readers import read_vtk

        return read_vtk(
            path, detail, physical_tag=physical_tag, weld=weld, fmt=format_name(path, file_format)
        )
    if (family, detail) == ("meshio", "gmsh"):
        return _read_gmsh(path, physical_tag, weld, native)
    if (family, detail) == ("meshio", "ply"):
        return _read_ply(path, physical_tag, weld, native, format_name(path, file_format))
    if family == "meshio" and detail in ("obj", "off"):  # (meshio refuses OFF polygons, OBJ's v/vt/vn)
        from models.mesh import surface_text

        try:
            faces = surface_text.READERS["." + detail](path)
        except MeshError as exc:
            raise MeshError(
                f"cannot read {os.path.basename(path)} as {format_name(path, file_format)}: {exc}"
            ) from None
        return mesh_from_meshio(
            surface_text.as_meshio(*faces), physical_tag=physical_tag, weld=weld, owned=True
        )
    from models.mesh.meshio_groups import named_groups

    if detail in ("abaqus", "tetgen"):  # (ours: mesh/abaqus.py, mesh/tetgen.py)
        from models.mesh.abaqus import read_abaqus
        from models.mesh.tetgen import read_tetgen

        what = "Abaqus" if detail == "abaqus" else "Triangle / TetGen"
        try:
            m = (read_abaqus if detail == "abaqus" else read_tetgen)(path)
        except MeshError as exc:
            raise MeshError(f"cannot read {os.path.basename(path)} as {what}: {exc}") from None
    else:
        m = _read_meshio(path, detail)
    m = named_groups(m, detail, path, [_TYPES[c.type][1] if _known(c.type) else 3 for c in m.cells])
    return mesh_from_meshio(m, physical_tag=physical_tag, weld=weld, owned=True)


def _read_ply(path: str, physical_tag, weld, native: bool, fmt: str) -> Mesh:
    """A PLY file by meshio's reader (its points as written: VTK's vtkPLYReader makes doubles
    float32); one that meshio refuses (big-endian, extra face properties, colours in odd places) by
    VTK's reader, ParaView's, which is native code: with native=False NativeReaderNeeded (the caller
    reads it in the sandbox). A file VTK cannot read either keeps meshio's refusal."""
    try:
        m = _read_meshio(path, "ply")
    except MeshError as refused:
        from models.mesh.ply import planar_copy

        with planar_copy(path) as copy:  # (x and y without z: meshio's writer given 2D points)
            if copy:
                return mesh_from_meshio(
                    _read_meshio(copy, "ply"), physical_tag=physical_tag, weld=weld, owned=True
                )
        if not native:
            raise NativeReaderNeeded(f"{os.path.basename(path)} needs VTK's PLY reader") from None
        from models.mesh.vtk_readers import read_vtk

        try:
            return read_vtk(path, "ply", physical_tag=physical_tag, weld=weld, fmt=fmt)
        except MeshError as exc:
            if "cannot be opened" in str(exc) or "corrupted" in str(exc):
                raise refused from None
            raise  # (VTK read it: what is wrong with the mesh, a curved surface say)
    return mesh_from_meshio(m, physical_tag=physical_tag, weld=weld, owned=True)


def _read_gmsh(path: str, physical_tag, weld, native: bool) -> Mesh:
    """A gmsh file by meshio's reader; one that meshio refuses but that looks sound (partitioned,
    MSH 4.0, saved with SaveAll: models.mesh.gmsh_native) by gmsh's own library, which is native
    code: with native=False NativeReaderNeeded (the caller reads it in the sandbox). A file gmsh
    cannot read either keeps meshio's refusal (it says where the file goes wrong)."""
    try:
        m = _read_meshio(path, "gmsh")
    except MeshError as refused:
        from models.mesh import gmsh_native

        open_section = _unclosed_gmsh_section(path)
        if open_section:  # (a cut file: said as such, whatever the parser met first)
            raise MeshError(
                f"cannot read {os.path.basename(path)} as gmsh: the file ends inside its ${open_section} "
                f"section (no $End{open_section}): it is truncated"
            ) from None

        if not gmsh_native.worth_trying(path):
            raise
        if not native:
            raise NativeReaderNeeded(f"{os.path.basename(path)} needs gmsh's library") from None
        try:
            m = gmsh_native.read_gmsh(path)
        except MeshError:
            raise refused from None
        if physical_tag is None:  # (Mesh.SaveAll: what lies in no physical group is tagged 0 there too)
            from models.mesh.gmsh_groups import zero_is_no_group

            zero_is_no_group(m)
        mesh = mesh_from_meshio(m, physical_tag=physical_tag, weld=weld, owned=True)
        mesh.meta.update(reader="gmsh's library (models/mesh/gmsh_native.py)", format="gmsh")
        return mesh
    from models.mesh.gmsh_groups import resolve_overlaps, zero_is_no_group

    note = None
    if physical_tag is None:
        zero_is_no_group(m)
        note = resolve_overlaps(m)  # (cells in two physical groups)
    mesh = mesh_from_meshio(m, physical_tag=physical_tag, weld=weld, owned=True)
    if note:
        mesh.meta["overlapping_groups"] = note
    return mesh


_GMSH_MARK = re.compile(rb"^\$(End)?([A-Za-z]+)\r?$", re.MULTILINE | re.IGNORECASE)  # (MSH 1: $ENDNOD)


def _unclosed_gmsh_section(path: str) -> str | None:
    """The section a gmsh file ends in without closing it (a truncated file), or None: the last
    section mark of the file's last MiB, where it opens a section."""
    try:
        with open(path, "rb") as fh:
            fh.seek(max(0, os.path.getsize(path) - (1 << 20)))
            tail = fh.read()
    except OSError:
        return None
    marks = _GMSH_MARK.findall(tail)
    if not marks:
        return None
    end, name = marks[-1]
    return None if end else name.decode("ascii")


_ENV_SAID: set[str] = set()


def env_ignored(name: str, raw: str, wanted: str) -> None:
    """Say once per process, on stderr, that an environment variable's value was not understood."""
    if name not in _ENV_SAID:
        _ENV_SAID.add(name)
        print(f"magnet: warning: {name}={raw!r} is ignored: it must be {wanted}", file=sys.stderr)


def default_memory() -> int:
    """The default memory budget of a read (the sandbox's limit: models.mesh.sandbox): the
    environment's MAGNET_READ_MEMORY_MB, else the machine's physical memory."""
    mb = os.environ.get("MAGNET_READ_MEMORY_MB")
    if mb and mb.strip().isdigit() and int(mb) > 0:
        return int(mb) << 20
    if mb:
        env_ignored(
            "MAGNET_READ_MEMORY_MB", mb, "a whole number of megabytes > 0; the machine's memory it is"
        )
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):
        return 16 << 30


def mesh_from_meshio(
    m, physical_tag: str | None = None, weld: float | None = None, owned: bool = False
) -> Mesh:
    """Convert a meshio.Mesh (blocks of cells) into our CSR `Mesh`. owned: `m` is ours to consume
    (read here, dropped after): the mesh may keep and edit its arrays in place instead of a copy."""
    blocks = []
    for i, block in enumerate(m.cells):
        name = block.type
        if name.startswith("polyhedron"):
            blocks.append((i, name, VTK_POLYHEDRON, 3, block.data))
            continue
        if not _known(name):
            raise MeshError(
                f"it holds cells of a type that cannot be agglomerated ({name}, as meshio names it)"
            )
        vtk, tdim, _ = _TYPES[name]
        whole_rows(name, block.data)
        blocks.append((i, name, vtk, tdim, block.data))
    groups_key = find_tag_key(m.cell_data, physical_tag)
    top = max((b[3] for b in blocks if len(b[4])), default=0)
    bnd_key = BOUNDARY_TAG_NAME if BOUNDARY_TAG_NAME in m.cell_data else groups_key
    elem_key = groups_key
    if (
        groups_key is not None
        and physical_tag is None
        and zero_on_elements(m.cell_data[groups_key], blocks, top)
    ):
        elem_key = None  # (0 on every element: no groups, as gmsh's 0; the boundary's tags stay)
    cells = []
    for i, name, _vtk, tdim, data in blocks:
        key = elem_key if tdim == top else bnd_key
        tags = None if key is None else np.asarray(m.cell_data[key][i]).reshape(-1)
        cells.append((name, data, tags, tdim))
    mesh = mesh_from_blocks(
        np.asarray(m.points, dtype=np.float64), cells, tag_name=elem_key, weld=weld, owned=owned
    )
    from models.mesh.boundary import group_names

    mesh.meta["group_names"], mesh.meta["boundary_names"] = group_names(
        getattr(m, "field_data", None), mesh.dim
    )
    return mesh


def mesh_from_arrays(points, cells, tags=None) -> Mesh:
    """Build a `Mesh` from points and [(meshio type name, array)] blocks; tags is None or one array per block."""
    blocks = []
    for j, (name, data) in enumerate(cells):
        if name.startswith("polyhedron"):
            tdim = 3
        elif _known(name):
            tdim = _TYPES[name][1]
        else:
            raise MeshError(f"cells of a type that cannot be agglomerated ({name}, as meshio names it)")
        blocks.append((name, data, None if tags is None else np.asarray(tags[j]).reshape(-1), tdim))
    return mesh_from_blocks(
        np.asarray(points, dtype=np.float64), blocks, tag_name=None if tags is None else "tags"
    )


def _csr_from_blocks(blocks, owned: bool = False):
    """Concatenate blocks into CSR (a loop over blocks, not cells): fixed-width (n, w) arrays, or
    (sizes, nodes) pairs of variable-width cells (polyhedra). owned: the blocks are ours to keep, so
    one contiguous int64 (n, w) block becomes the connectivity as it is (no copy)."""
    if owned and len(blocks) == 1 and not isinstance(blocks[0], tuple):
        d = np.asarray(blocks[0], dtype=np.int64)
        if not d.flags.writeable:  # e.g. np.frombuffer of the file's bytes: orienting edits it in place
            d = d.copy()
        n, w = d.shape
        return np.arange(0, n * w + 1, w, dtype=np.int64) if w else np.zeros(n + 1, np.int64), d.reshape(-1)
    sizes = (
        np.concatenate(
            [d[0] if isinstance(d, tuple) else np.full(len(d), d.shape[1], dtype=np.int64) for d in blocks]
        )
        if blocks
        else np.zeros(0, np.int64)
    )
    conn = (
        np.concatenate(
            [d[1] if isinstance(d, tuple) else np.asarray(d, dtype=np.int64).reshape(-1) for d in blocks]
        )
        if blocks
        else np.zeros(0, np.int64)
    )
    offsets = np.zeros(len(sizes) + 1, dtype=np.int64)
    np.cumsum(sizes, out=offsets[1:])
    return offsets, conn


def mesh_from_blocks(
    points: np.ndarray, blocks, tag_name: str | None = None, weld: float | None = None, owned: bool = False
) -> Mesh:
    """Core builder: split elements from boundary cells, check, orient, project 2D meshes.

    weld: merge points closer than this (see weld_points) before anything else is checked.
    owned: the blocks' arrays are the caller's to give away (see mesh_from_meshio)."""
    if points.ndim != 2 or len(points) == 0:
        raise MeshError("the mesh has no points")
    nonempty = [b for b in blocks if len(b[1]) > 0]
    if not nonempty:
        raise MeshError("the mesh has no cells")
    dim = max(b[3] for b in nonempty)
    if dim < 2:
        held = "line/vertex" if dim == 1 else "vertex"
        raise MeshError(
            f"{'1D meshes' if dim == 1 else 'points alone'} are not supported: the file holds only {held} "
            "cells, no 2D or 3D elements"
        )

    elem, bnd = [], []
    for name, data, tags, tdim in nonempty:
        (elem if tdim == dim else bnd if tdim == dim - 1 else []).append((name, data, tags))
    lower: dict[str, int] = {}  # not agglomerated: reported by describe(), never silently dropped
    for name, data, _tags, tdim in nonempty:
        if tdim < dim:
            lower[name] = lower.get(name, 0) + len(data)

    types_list, data_list, tag_list = [], [], []
    higher: list = []  # (name, corner nodes, the other nodes) per higher-order block
    poly_faces = []  # per polyhedron block: (cell ids in elem order, faces per cell, face sizes, face nodes)
    n_so_far = 0
    for name, data, tags in elem:
        if name.startswith("polyhedron"):
            nfaces, fsizes, fnodes, sizes, nodes = _polyhedra(data)
            poly_faces.append((n_so_far + np.arange(len(data), dtype=np.int64), nfaces, fsizes, fnodes))
            data_list.append((sizes, nodes))
            types_list.append(np.full(len(data), VTK_POLYHEDRON, np.uint8))
            n_so_far += len(data)
        else:
            vtk, _, keep = _TYPES[name]
            arr = np.asarray(data, dtype=np.int64)
            if arr.ndim != 2:
                raise MeshError(f"malformed {name} block in the mesh")
            if keep and arr.shape[1] > keep:  # a higher-order cell: its corner nodes (listed first)
                higher.append((name, keep, arr[:, keep:]))
                arr = arr[:, :keep]
            if vtk == VTK_POLYGON and arr.shape[1] == 3:
                vtk = VTK_TRIANGLE
            elif vtk == VTK_POLYGON and arr.shape[1] == 4:
                vtk = VTK_QUAD
            data_list.append(arr)
            types_list.append(np.full(len(arr), vtk, np.uint8))
            n_so_far += len(arr)
        if tags is not None:
            tag_list.append(tags)
    offsets, conn = _csr_from_blocks(data_list, owned=owned)
    cell_types = np.concatenate(types_list)
    tags = np.concatenate(tag_list).astype(np.int64) if tag_list and len(tag_list) == len(elem) else None
    bnd_csr = None
    if bnd:
        b_data = [
            np.asarray(d, dtype=np.int64)[:, : (_TYPES[n][2] or None)]
            for n, d, _ in bnd
            if not n.startswith("polyhedron")
        ]
        b_off, b_conn = _csr_from_blocks(b_data)
        b_types = np.concatenate([np.full(len(d), _TYPES[n][0], np.uint8) for n, d, _ in bnd])
        b_tags = (
            np.concatenate([t for _, _, t in bnd]).astype(np.int64)
            if all(t is not None for _, _, t in bnd)
            else None
        )
        bnd_csr = (b_off, b_conn, b_types, b_tags)
    mesh = mesh_from_cells(
        points, offsets, conn, cell_types, tags, tag_name, poly_faces, bnd_csr, lower, dim, weld=weld
    )
    if higher:
        _note_higher(mesh, higher, conn, len(points))
    return mesh


# meshio's quadratic cell names (the others with more nodes than their corners are of higher order)
_QUADRATIC = {"triangle6", "triangle7", "quad8", "quad9", "tetra10", "hexahedron20", "hexahedron27"}
_QUADRATIC |= {"wedge15", "wedge18", "pyramid13", "pyramid14"}


def _note_higher(mesh: Mesh, higher: list, corners: np.ndarray, n_points: int) -> None:
    """The one line a higher-order mesh gets (as models.mesh.cells says it for VTK's cells): agglomerated
    on the corner nodes, so many nodes (used by no corner) unused; mesh.meta["higher_order"] and
    ["higher_order_unused_points"] (check and describe report those points so, not as stray ones)."""
    used = np.zeros(n_points, dtype=bool)
    for _, _, rest in higher:
        used[rest[(rest >= 0) & (rest < n_points)]] = True
    corner = np.zeros(n_points, dtype=bool)
    corner[corners[(corners >= 0) & (corners < n_points)]] = True
    unused = int(np.count_nonzero(used & ~corner))
    names = sorted({name for name, _, _ in higher})
    keep = "/".join(str(k) for k in sorted({k for _, k, _ in higher}))
    quadratic = all(name in _QUADRATIC for name in names)
    mesh.meta["higher_order"] = higher_order_line(quadratic, names, keep, unused)
    mesh.meta["higher_order_unused_points"] = unused


def _polyhedra(data) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """meshio's polyhedron cells (per cell a list of faces) as arrays, iterated at C level only:
    (faces per cell, face sizes, face nodes, distinct nodes per cell, those nodes ascending per cell)."""
    nfaces = np.fromiter(map(len, data), dtype=np.int64, count=len(data))
    faces = list(chain.from_iterable(data))
    fsizes = np.fromiter(map(len, faces), dtype=np.int64, count=len(faces))
    fnodes = np.concatenate(faces).astype(np.int64).reshape(-1) if faces else np.zeros(0, np.int64)
    return (nfaces, fsizes, fnodes, *distinct_nodes(nfaces, fsizes, fnodes))


def describe(mesh: Mesh) -> dict:
    """Summary used by the CLI and the service: counts, dimension, types, groups, bounding box."""
    from models.mesh.dropped import left_out_info

    p = mesh.points3d()
    return {
        "cells": mesh.n_cells,
        "points": mesh.n_points,
        "dim": mesh.dim,
        "cell_types": mesh.cell_type_counts(),
        "lower_dim_cells": dict(mesh.meta.get("lower_dim_cells", {})),
        "physical_groups": mesh.physical_groups(),
        "bbox": [x.tolist() for x in _bounds(p)],
        **_boundary_summary(mesh),
        # the few bad cells the read left out (file ids): subsets are the file's ids (models.params)
        **({"cells_left_out": left_out_info(mesh.meta)} if mesh.meta.get("dropped_cells") else {}),
    }


def _boundary_summary(mesh: Mesh) -> dict:
    from models.mesh.boundary import summary

    s = summary(mesh)
    return {"boundary_groups": [g["tag"] for g in s["groups"]], "boundary": s}


__all__ = [
    "read_mesh",
    "mesh_from_arrays",
    "mesh_from_meshio",
    "mesh_from_blocks",
    "describe",
    "CELL_TYPE_NAMES",
]
