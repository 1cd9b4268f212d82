"""Multi-file meshes (XDMF + its .h5) in one .zip, .tar.gz or .tar: checked before anything is
unpacked (number of members, total unpacked size, no absolute path or `..`, no link or device),
then unpacked into a folder; the mesh file inside is picked by its extension (models.mesh.formats).
"""

from __future__ import annotations

import os
import re
import shutil
import stat
import tarfile
import zipfile
from pathlib import Path, PurePosixPath

from models.errors import MeshError
from models.mesh.formats import COMPOUND, FORMATS, MULTI_FILE, extension

MAX_MEMBERS = 64
MAX_UNPACKED_BYTES = 4 << 30


def _members(path: Path, name: str) -> list[tuple[str, int, str]]:
    """(member name, unpacked size, kind: 'file' | 'dir' | 'link' | 'other') of every member."""
    try:
        if extension(path) == ".zip":
            with zipfile.ZipFile(path) as zf:
                out = []
                for info in zf.infolist():
                    mode = info.external_attr >> 16
                    kind = (
                        "dir"
                        if info.is_dir()
                        else "link"
                        if stat.S_ISLNK(mode)
                        else "file"
                        if stat.S_IFMT(mode) == 0 or stat.S_ISREG(mode)  # no type bits: a plain file
                        else "other"
                    )
                    out.append((info.filename, info.file_size, kind))
                return out
        with tarfile.open(path, "r:*") as tf:
            return [
                (
                    m.name,
                    m.size,
                    "file"
                    if m.isfile()
                    else "dir"
                    if m.isdir()
                    else "link"
                    if m.issym() or m.islnk()
                    else "other",
                )
                for m in tf.getmembers()
            ]
    except (OSError, EOFError, zipfile.BadZipFile, tarfile.TarError, ValueError):
        raise MeshError(f"cannot read {name}: it is not a valid {extension(path)} archive") from None


def check_archive(
    path: str | os.PathLike, max_members: int = MAX_MEMBERS, max_bytes: int = MAX_UNPACKED_BYTES
) -> str:
    """The mesh file inside the archive `path` (its member name), after every check; MeshError else."""
    path = Path(path)
    name = path.name
    members = _members(path, name)
    if len(members) > max_members:
        raise MeshError(
            f"cannot read {name}: the archive holds {len(members)} members; at most {max_members}"
        )
    total = sum(size for _, size, _ in members)
    if total > max_bytes:
        raise MeshError(
            f"cannot read {name}: the archive unpacks to {total / 2**20:.0f} MiB; at most {max_bytes / 2**20:.0f} MiB"
        )
    for member, _, kind in members:
        parts = PurePosixPath(member.replace("\\", "/")).parts
        if member.startswith(("/", "\\")) or (parts and ":" in parts[0]) or ".." in parts:
            raise MeshError(
                f"cannot read {name}: the archive member {member[:100]} points outside the archive"
            )
        if kind in ("link", "other"):
            raise MeshError(
                f"cannot read {name}: the archive member {member[:100]} is a link or a device; only files are accepted"
            )
    meshes = [
        m
        for m, _, kind in members
        if kind == "file" and (extension(m) in FORMATS or extension(m) in COMPOUND)
    ]
    foam = [m for m in meshes if extension(m) == ".foam"] or _control_dicts(members)
    if len(foam) == 1:
        return foam[0]
    if not meshes:
        raise MeshError(
            f"cannot read {name}: the archive holds no mesh file (one of {', '.join(FORMATS)} with its data files)"
        )
    eles = {m[: -len(".ele")] for m in meshes if extension(m) == ".ele"}
    meshes = [m for m in meshes if not (extension(m) == ".node" and m[: -len(".node")] in eles)]  # (its .ele)
    if len(meshes) > 1 and all(extension(m) == ".inp" for m in meshes):
        meshes = _not_included(path, meshes)  # an Abaqus file and the files it *INCLUDEs
    if len(meshes) > 1:  # a file naming its pieces (.pvtu, .pvd, .pvtk, .vtm, ...) with them
        headers = [m for m in meshes if extension(m) in MULTI_FILE and extension(m) not in (".ele", ".node")]
        if len(headers) > 1:
            headers = _unnamed(path, headers)  # (a .pvd naming .pvtu files: the .pvd)
        if len(headers) == 1:
            return headers[0]
    if len(meshes) > 1:
        raise MeshError(
            f"cannot read {name}: the archive holds {len(meshes)} mesh files ({', '.join(meshes[:5])}); send one"
        )
    return meshes[0]


def unpack(path: str | os.PathLike, dest: str | os.PathLike, max_bytes: int = MAX_UNPACKED_BYTES) -> Path:
    """Check the archive, unpack its files into `dest` (sizes enforced while writing, not only as
    declared) and return the mesh file's path there."""
    path, dest = Path(path), Path(dest)
    inner = check_archive(path, max_bytes=max_bytes)
    written = 0

    def copy(src, target: Path) -> None:
        nonlocal written
        target.parent.mkdir(parents=True, exist_ok=True)
        with open(target, "wb") as out:
            while chunk := src.read(1 << 20):
                written += len(chunk)
                if written > max_bytes:
                    raise MeshError(f"cannot read {path.name}: the archive unpacks to more than it declares")
                out.write(chunk)

    try:
        if extension(path) == ".zip":
            with zipfile.ZipFile(path) as zf:
                for info in zf.infolist():
                    if not info.is_dir():
                        with zf.open(info) as src:
                            copy(src, dest / info.filename)
        else:
            with tarfile.open(path, "r:*") as tf:
                for m in tf.getmembers():
                    if m.isfile():
                        copy(tf.extractfile(m), dest / m.name)
    except (OSError, EOFError, zipfile.BadZipFile, tarfile.TarError, ValueError, RuntimeError):
        shutil.rmtree(dest, ignore_errors=True)
        raise MeshError(f"cannot read {path.name}: the archive is corrupted") from None
    return dest / inner


__all__ = ["check_archive", "unpack", "MAX_MEMBERS", "MAX_UNPACKED_BYTES"]


_INCLUDE = re.compile(rb"^[ \t]*\*[ \t]*[A-Za-z][^\n]*?\bINPUT[ \t]*=[ \t]*\"?([^\",\r\n]+)", re.I | re.M)


def _not_included(path: Path, meshes: list[str], limit: int = 64 << 20) -> list[str]:
    """The members that no other member names in an INPUT= parameter (Abaqus *INCLUDE, *NODE,
    INPUT=...): the main file of a model split over several .inp files."""
    named = set()
    try:
        for m in meshes:
            if extension(path) == ".zip":
                with zipfile.ZipFile(path) as zf, zf.open(m) as fh:
                    head = fh.read(limit)
            else:
                with tarfile.open(path, "r:*") as tf:
                    head = tf.extractfile(m).read(limit)
            folder = PurePosixPath(m.replace("\\", "/")).parent
            for ref in _INCLUDE.findall(head):
                named.add(str(folder / ref.decode("utf-8", "replace").strip()))
    except (OSError, EOFError, zipfile.BadZipFile, tarfile.TarError, ValueError, AttributeError):
        return meshes
    return [m for m in meshes if str(PurePosixPath(m.replace("\\", "/"))) not in named] or meshes


def _unnamed(path: Path, headers: list[str], limit: int = 16 << 20) -> list[str]:
    """The header files that no other header among them names (by file name, in its first
    `limit` bytes)."""
    named = set()
    try:
        for m in headers:
            if extension(path) == ".zip":
                with zipfile.ZipFile(path) as zf, zf.open(m) as fh:
                    head = fh.read(limit)
            else:
                with tarfile.open(path, "r:*") as tf:
                    head = tf.extractfile(m).read(limit)
            for other in headers:
                if other != m and PurePosixPath(other).name.encode() in head:
                    named.add(other)
    except (OSError, EOFError, zipfile.BadZipFile, tarfile.TarError, ValueError, AttributeError):
        return headers
    return [m for m in headers if m not in named] or headers


def _control_dicts(members) -> list[str]:
    """The system/controlDict of each OpenFOAM case among the members: one whose folder holds a
    constant/polyMesh/faces, its own or a processor's (a decomposed case). A case's other files may
    carry mesh extensions (constant/triSurface/*.stl); its controlDict, or its .foam file, opens it."""
    files = [m for m, _, kind in members if kind == "file"]
    names = [m.replace("\\", "/") for m in files]
    faces = [n for n in names if n.endswith(("constant/polyMesh/faces", "constant/polyMesh/faces.gz"))]
    out = []
    for m, n in zip(files, names, strict=True):
        if n.endswith("system/controlDict"):
            root = n[: -len("system/controlDict")]
            tops = {f[len(root) :].split("/")[0] for f in faces if f.startswith(root)}
            if any(t == "constant" or t.startswith("processor") for t in tops):
                out.append(m)
    return out
