"""Formats whose file names other files, checked before a reader opens any: an OpenFOAM case
(its folder, .foam file or system/controlDict; reconstructed or decomposed) and an EnSight case
(its geometry and variable files, never outside its folder)."""

from __future__ import annotations

import os
import re

from models.errors import MeshError

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
