"""The mesh formats we read, by file extension: one list for the CLI, the service and the web page.

Imports nothing (no numpy, no VTK, no meshio): the service imports it for its upload checks and
must not pull in the readers. `models.mesh.read.read_mesh` is the one dispatch that reads them.
"""

from __future__ import annotations

import os

# extension -> name of the format (as a user knows it; which library reads it is no user's concern)
FORMATS: dict[str, str] = {
    ".vtu": "VTK XML (VTU)",
    ".vtk": "legacy VTK",
    ".msh": "gmsh",
    ".exo": "Exodus II",
    ".e": "Exodus II",
    ".xdmf": "XDMF",
    ".xmf": "XDMF",
    ".cgns": "CGNS",
    ".cas": "Fluent case",
    ".neu": "Gambit neutral",
    ".inp": "Abaqus or AVS UCD",
    ".ucd": "AVS UCD",
    ".avs": "AVS UCD",
    ".mesh": "Medit",
    ".med": "MED",
    ".obj": "Wavefront OBJ",
    ".off": "OFF",
    ".ply": "PLY",
    ".stl": "STL",
    ".h5m": "MOAB",
    ".su2": "SU2",
    ".nas": "Nastran",
    ".bdf": "Nastran",
    ".f3grid": "FLAC3D",
    ".dat": "Tecplot",
    ".tec": "Tecplot",
    ".tp": "Tecplot",
    ".plt": "Tecplot",
    ".szplt": "Tecplot",
    ".ugrid": "UGRID",
    ".foam": "OpenFOAM case",  # an empty file in the case's folder, as ParaView opens a case
    ".case": "EnSight case",
    ".encas": "EnSight case",
    ".xyz": "PLOT3D grid",
    ".xy": "PLOT3D grid",
    ".p3d": "PLOT3D grid",
    # VTK's other XML datasets and parallel / multiblock files (these name their pieces' files)
    ".vtp": "VTK XML polydata",
    ".vti": "VTK XML image data",
    ".vts": "VTK XML structured grid",
    ".vtr": "VTK XML rectilinear grid",
    ".pvtu": "VTK XML parallel unstructured grid",
    ".pvtp": "VTK XML parallel polydata",
    ".pvti": "VTK XML parallel image data",
    ".pvts": "VTK XML parallel structured grid",
    ".pvtr": "VTK XML parallel rectilinear grid",
    ".vtm": "VTK XML multiblock",
    ".vtpc": "VTK XML partitioned dataset collection",
    ".vtpd": "VTK XML partitioned dataset",
    ".pvd": "ParaView data collection",
    ".pvtk": "VTK parallel legacy",
    ".vtkhdf": "VTKHDF",
    ".ex2": "Exodus II",
    ".exii": "Exodus II",
    ".g": "Exodus II",
    ".gen": "Exodus II",
    # the rest of what meshio reads well
    ".meshb": "Medit",
    ".fem": "Nastran",
    ".mdpa": "Kratos",
    ".vol": "Netgen",
    ".post": "PERMAS",
    ".dato": "PERMAS",
    ".xml": "DOLFIN XML",
    ".wkt": "Well-known text (triangles)",
    ".ele": "Triangle / TetGen",
    ".node": "Triangle / TetGen",
}
# a mesh file that needs other files beside it (XDMF's heavy data in .h5, a parallel VTK file's
# pieces, TetGen's .node beside its .ele): uploaded in an archive holding them all
MULTI_FILE = (
    ".xdmf",
    ".xmf",
    ".pvtu",
    ".pvtp",
    ".pvti",
    ".pvts",
    ".pvtr",
    ".vtm",
    ".vtpc",
    ".vtpd",
    ".pvd",
    ".pvtk",
    ".ele",
    ".node",
    ".foam",
    ".case",
    ".encas",
)
# of those, files that may hold all their data themselves (an XDMF with its DataItems inline, as
# Format="XML"): taken alone over HTTP, the reader naming any data file that is not beside them
MAY_STAND_ALONE = (".xdmf", ".xmf")
# compound extensions first: "case.cas.h5" is a Fluent case, not an HDF5 file
COMPOUND = {
    ".cas.h5": "Fluent case (HDF5)",
    ".vol.gz": "Netgen",
    ".post.gz": "PERMAS",
    ".dato.gz": "PERMAS",
}
# every extension a mesh file may have (the one list: read.py's dispatch, the CLI's help, the page)
MESH_EXTENSIONS = tuple(sorted({*FORMATS, *COMPOUND}))
ARCHIVES = (".zip", ".tar.gz", ".tgz", ".tar")
# what is asked for in an archive when uploaded alone
ARCHIVE_ONLY = tuple(e for e in MULTI_FILE if e not in MAY_STAND_ALONE)
# what the HTTP API and the web page accept: every single-file format, and archives holding the rest
UPLOAD_EXTENSIONS = tuple(e for e in FORMATS if e not in ARCHIVE_ONLY) + tuple(COMPOUND) + ARCHIVES


def extension(path: str | os.PathLike) -> str:
    """The lower-case format extension of `path` ('.cas.h5', '.tar.gz' included), or ''."""
    name = os.path.basename(os.fspath(path)).lower()
    for ext in (*COMPOUND, ".tar.gz"):
        if name.endswith(ext) and len(name) > len(ext):
            return ext
    return os.path.splitext(name)[1]


_COMPRESSORS = {".gz": "gunzip", ".bz2": "bunzip2", ".xz": "unxz", ".zst": "unzstd", ".lz4": "unlz4"}


def not_found(path: str) -> str:
    """The refusal of a mesh path that does not lead to a file: missing, or a symbolic link to
    nothing (its target missing, or a loop of links)."""
    if os.path.islink(path):
        return f"mesh file not found: {path} is a symbolic link that leads to no file (its target is missing, or the links loop)"
    return f"mesh file not found: {path}"


def unknown_format(name: str, ext: str) -> str:
    """The one sentence for a file whose extension no reader takes (the CLI's, the API's and the
    upload check's alike): the formats a file can be alone, then the archives for those that need
    the files beside them."""
    shown = f"'{ext}'" if ext else "(no extension)"
    alone = [e for e in FORMATS if e not in ARCHIVE_ONLY] + list(COMPOUND)
    return (
        f"cannot read {name}: unknown mesh format {shown}; use one of: {', '.join(alone)}; or "
        f"{' / '.join(ARCHIVES)} holding a mesh and the files beside it ({' '.join(ARCHIVE_ONLY)} go in one)"
    )


def compressed_hint(path: str | os.PathLike) -> str:
    """For a name such as mesh.vtu.gz (a mesh file compressed whole, which no reader takes): what to
    do, as a sentence's tail; '' for any other name."""
    name = os.path.basename(os.fspath(path))
    stem, ext = os.path.splitext(name)
    tool = _COMPRESSORS.get(ext.lower())
    if tool is None or extension(stem) not in FORMATS:
        return ""
    return f" ({name} is a {extension(stem)} file compressed whole: decompress it first, e.g. {tool} {name})"


def format_name(path: str | os.PathLike, file_format: str | None = None) -> str:
    """The format a file is read as ('Exodus II', 'legacy VTK', ...): from file_format when given."""
    if file_format:
        key = "." + file_format.lower().lstrip(".")
        return FORMATS.get(key, COMPOUND.get(key, file_format))
    ext = extension(path)
    if ext == ".msh" and _first_byte(path) == b"(":  # .msh is gmsh's and Fluent's extension
        return "Fluent case"
    if ext in (".inp", ".ucd", ".avs") and _first_byte(path) == b"\x07":  # AVS's binary magic byte
        return "binary AVS UCD"
    if ext == ".inp":
        return _inp_format(path)
    return FORMATS.get(ext) or COMPOUND.get(ext) or "mesh"


def _inp_format(path) -> str:
    """An ASCII .inp file's format by its first line that is not a '#' comment (pick_reader's
    choice, read.py, by the same lines): Abaqus keywords start with '*', AVS UCD with its header's
    five integers; "Abaqus or AVS UCD" where the file does not say (unreadable, empty, neither)."""
    try:
        with open(path, "rb") as f:
            head = f.read(4096)
    except OSError:
        return FORMATS[".inp"]
    for line in head.lstrip(b"\xef\xbb\xbf").splitlines()[:-1] or head.splitlines()[:1]:
        words = line.split()
        if not words or line.lstrip().startswith(b"#"):
            continue
        if line.lstrip().startswith(b"*"):
            return "Abaqus"
        if len(words) == 5 and all(w.lstrip(b"-").isdigit() for w in words):
            return "AVS UCD"
        break
    return FORMATS[".inp"]


def _first_byte(path) -> bytes:
    try:
        with open(path, "rb") as f:
            return f.read(1)
    except OSError:
        return b""


__all__ = [
    "FORMATS",
    "MESH_EXTENSIONS",
    "MULTI_FILE",
    "MAY_STAND_ALONE",
    "ARCHIVE_ONLY",
    "ARCHIVES",
    "UPLOAD_EXTENSIONS",
    "extension",
    "format_name",
]
