"""Formats whose file names other files, checked before a reader opens any: an OpenFOAM case
(its folder, .foam file or system/controlDict; reconstructed or decomposed), an EnSight case
(its geometry and variable files, never outside its folder), VTK's parallel and multiblock files
(their pieces) and XDMF (its data files)."""

from __future__ import annotations

import os
import re

from models.errors import MeshError
from models.mesh.formats import format_name

_ENSIGHT_FILE = re.compile(
    rb"^\s*(?:model|measured|[a-z ]+per (?:node|element|case))\s*:\s*(?:[\d\s]*?)(\S+)\s*$",
    re.MULTILINE | re.IGNORECASE,
)


def ensight_files(path: str) -> None:
    """An EnSight case names its geometry (and variable) files: one outside the case's folder (an
    absolute path, or up with '..': an upload naming a file of the server) is refused before VTK's
    reader opens it; a missing geometry file is named."""
    try:
        with open(path, "rb") as fh:
            text = fh.read(1 << 20)
    except OSError:
        return
    name = os.path.basename(path)
    folder = os.path.dirname(os.path.abspath(path))
    if b"FORMAT" not in text.upper():
        raise MeshError(f"cannot read {name} as an EnSight case: it has no FORMAT section")
    for m in _ENSIGHT_FILE.finditer(text):
        ref = m.group(1).decode("utf-8", "replace")
        where = os.path.normpath(os.path.join(folder, ref))
        if os.path.isabs(ref) or os.path.commonpath([folder, where]) != folder:
            raise MeshError(
                f"cannot read {name} as an EnSight case: its file {ref} lies outside the case's folder; keep "
                "the case's files beside it or below it"
            )
        if m.group(0).lstrip().lower().startswith(b"model") and "*" not in ref and not os.path.exists(where):
            raise MeshError(
                f"cannot read {name} as an EnSight case: its geometry file {ref} is missing (keep it beside "
                "the case file, or upload them all in one .zip or .tar.gz)"
            )


def _polymesh(folder: str) -> bool:
    mesh = os.path.join(folder, "constant", "polyMesh")
    return any(os.path.exists(os.path.join(mesh, f)) for f in ("faces", "faces.gz"))


def openfoam_case(path: str) -> str:
    """The reader of the OpenFOAM case the .foam file or system/controlDict `path` names (its
    folder): "openfoam" for a case with constant/polyMesh, "openfoam-decomposed" for one whose mesh
    is only in processor*/constant/polyMesh (decomposePar's); MeshError for neither (VTK's reader
    would only say it read nothing)."""
    folder = os.path.dirname(os.path.abspath(path))
    if os.path.basename(path) == "controlDict":
        folder = os.path.dirname(folder)
    if _polymesh(folder):
        return "openfoam"
    if any(d.startswith("processor") and _polymesh(os.path.join(folder, d)) for d in os.listdir(folder)):
        return "openfoam-decomposed"
    raise MeshError(
        f"cannot read {os.path.basename(path)} as an OpenFOAM case: its folder has no constant/polyMesh/faces "
        "(nor processor*/constant/polyMesh/faces of a decomposed case); keep the file in the case's folder, "
        "or upload the case's folder in one .zip or .tar.gz"
    )


def openfoam_file(folder: str) -> str | None:
    """The file that opens an OpenFOAM case given as its folder: its system/controlDict (a .foam
    file beside it where there is one); None when the folder is no case."""
    if not os.path.isdir(os.path.join(folder, "constant", "polyMesh")) and not any(
        d.startswith("processor") and os.path.isdir(os.path.join(folder, d, "constant", "polyMesh"))
        for d in os.listdir(folder)
    ):
        return None
    foams = sorted(f for f in os.listdir(folder) if f.endswith(".foam"))
    if foams:
        return os.path.join(folder, foams[0])
    control = os.path.join(folder, "system", "controlDict")
    return control if os.path.isfile(control) else None


_PIECE = re.compile(rb"""<(?:Piece|DataSet)\b[^>]*?\b(?:Source|file)\s*=\s*["']([^"']+)["']""")
_HEAVY = re.compile(rb"""(?:>|\s)([^\s<>"':]+\.(?:h5|hdf5|hdf|he5)):/""")  # XDMF's heavy data: file.h5:/path
_XI_HREF = re.compile(rb"""<xi:include\b[^>]*?\bhref\s*=\s*["']([^"'#]+)""")  # XDMF's included files
# XDMF's data items that name a file: Binary (the file) and HDF (file:/path), whatever the file's name
_XDMF_FILE_ITEM = re.compile(
    rb"""<DataItem\b[^>]*?\bFormat\s*=\s*["'](?:Binary|HDF)["'][^>]*>\s*([^<\s][^<]*?)\s*<""", re.IGNORECASE
)


_PVTK_PIECE = re.compile(rb"""<Piece\b[^>]*?\bfileName\s*=\s*["']([^"']+)["']""")


def legacy_pieces(path: str, text: bytes) -> list[str]:
    """The piece files of a .pvtk (vtkPDataSetWriter), as paths to open: a relative name below the
    file's folder; an absolute one (the writer writes the path it was given) where it lies in
    that folder, else the file of its name beside the .pvtk (the pieces moved, or uploaded in an
    archive, with it). A piece found in neither place, or outside the folder, is refused."""
    folder = os.path.dirname(os.path.realpath(path))
    out = []
    for raw in dict.fromkeys(_PVTK_PIECE.findall(text)):
        piece = raw.decode("utf-8", "replace").strip()
        where = os.path.realpath(os.path.join(folder, piece))
        if os.path.commonpath([folder, where]) != folder or not os.path.isfile(where):
            beside = os.path.join(folder, os.path.basename(piece))
            if os.path.isabs(piece) and os.path.isfile(beside):
                where = beside
            elif os.path.commonpath([folder, where]) != folder:
                raise MeshError(
                    f"cannot read {os.path.basename(path)} as VTK parallel legacy: its piece file {piece} "
                    "lies outside the file's folder, and no file of its name is beside it"
                )
            else:
                raise MeshError(
                    f"cannot read {os.path.basename(path)} as VTK parallel legacy: its piece file {piece} is "
                    "missing (keep the piece files beside it, or upload them all in one .zip or .tar.gz)"
                )
        out.append(where)
    return out


def pieces_present(path: str, ext: str) -> None:
    """A parallel or multiblock VTK XML file names its pieces' files (XDMF its data files): say
    which one is missing (VTK's reader only fails), relative to the file's folder as VTK resolves
    them; a piece outside that folder (an absolute path elsewhere, or up with '..') is refused: an upload never
    makes the reader open another file of the server. An XDMF is scanned whole (its data may be
    inline, and large): its HDF5 files, its Binary data files and its xi:include files."""
    import mmap

    from models.mesh import xml_refs

    xdmf = ext in (".xdmf", ".xmf")
    if ext == ".pvtk":
        with open(path, "rb") as fh:
            legacy_pieces(path, fh.read(16 << 20))
        return
    if not xdmf and os.path.isfile(path) and os.path.getsize(path) > (16 << 20):  # (a header file is small)
        return
    named = xml_refs.xdmf_files(path) if xdmf else xml_refs.piece_files(path)  # (as XML: entities, comments)
    if named is not None:
        return _present(path, named, "data file" if xdmf else "piece file")
    try:  # not well-formed XML: its file names by patterns (the reader will say what is wrong)
        with open(path, "rb") as fh:
            if os.fstat(fh.fileno()).st_size == 0:
                return
            text = mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ)
    except (OSError, ValueError):
        return
    try:
        if xdmf:
            found = [m.group(1) for m in _HEAVY.finditer(text)]
            found += [m.group(1) for m in _XI_HREF.finditer(text)]
            found += [m.group(1).split(b":/", 1)[0] for m in _XDMF_FILE_ITEM.finditer(text)]
        else:
            found = [m.group(1) for m in _PIECE.finditer(text)]
    finally:
        text.close()
    _present(
        path, [raw.decode("utf-8", "replace").strip() for raw in found], "data file" if xdmf else "piece file"
    )


def _present(path: str, named: list[str], what: str) -> None:
    """pieces_present's verdict on the files a file names (relative to its folder)."""
    folder = os.path.dirname(os.path.abspath(path))
    for piece in dict.fromkeys(named):
        # (an absolute path inside the folder is fine: meshio writes its Binary data files so)
        where = os.path.realpath(os.path.join(folder, piece))
        if os.path.commonpath([os.path.realpath(folder), where]) != os.path.realpath(folder):
            raise MeshError(  # (an upload naming files of the server: never read)
                f"cannot read {os.path.basename(path)} as {format_name(path)}: its {what} {piece} "
                f"lies outside the file's folder; keep the {what}s beside it or below it"
            )
        if not os.path.exists(where):
            raise MeshError(
                f"cannot read {os.path.basename(path)} as {format_name(path)}: its {what} {piece} is "
                f"missing (keep the {what}s beside it, or upload them all in one .zip or .tar.gz)"
            )
