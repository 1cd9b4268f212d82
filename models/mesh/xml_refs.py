"""The files an XML mesh file refers to, read as XML (Python's expat, streaming): a ParaView data
collection's data sets (.pvd: timestep, part, file), a parallel or multiblock VTK file's pieces
(<Piece Source=...>, <DataSet file=...>) and an XDMF file's data files (HDF and Binary DataItems,
xi:include). The parser decodes entities (&amp; in a file name) and skips comments, as VTK's
readers do; a pattern over the raw text did neither and read a commented-out time step, or missed
a file whose name holds an apostrophe or a space. None where the file is not well-formed XML (the
caller falls back to its patterns: the reader will say what is wrong)."""

from __future__ import annotations

import xml.etree.ElementTree as ET

_XINCLUDE = "{http://www.w3.org/2001/XInclude}include"


def _local(tag: str) -> str:
    return tag.rsplit("}", 1)[-1] if isinstance(tag, str) else ""


def _elements(path: str):
    """(local tag, attributes, element) of every element, each when its end is read (its text
    complete); elements are cleared once seen (an XDMF may hold its data inline, and be large)."""
    for _, el in ET.iterparse(path, events=("end",)):
        yield _local(el.tag), el.attrib, el
        el.clear()


def collection(path: str) -> list[tuple[str, str, str]] | None:
    """A .pvd's data sets: (timestep, part, file) as written (the attribute's text, '' where it has
    none), in file order; None where it is not well-formed XML."""
    try:
        return [
            (a.get("timestep", ""), a.get("part", ""), a["file"])
            for tag, a, _ in _elements(path)
            if tag == "DataSet" and "file" in a
        ]
    except (ET.ParseError, OSError, UnicodeError):
        return None


def piece_files(path: str) -> list[str] | None:
    """The files a parallel or multiblock VTK XML file (or a .pvd) names: each <Piece Source=...>
    and <DataSet file=...>, in file order, once each; None where it is not well-formed XML."""
    try:
        found = [
            a.get("Source") or a.get("file")
            for tag, a, _ in _elements(path)
            if tag in ("Piece", "DataSet") and (a.get("Source") or a.get("file"))
        ]
    except (ET.ParseError, OSError, UnicodeError):
        return None
    return list(dict.fromkeys(found))


def xdmf_files(path: str) -> list[str] | None:
    """The files an XDMF file's data lie in: HDF DataItems (file:/path), Binary ones (the file), and
    xi:include's href (before any '#'), in file order, once each; None where it is not well-formed
    XML (an undeclared xi: prefix, say)."""
    found = []
    try:
        for tag, a, el in _elements(path):
            if tag == "DataItem" and (a.get("Format") or "").lower() in ("hdf", "binary"):
                text = (el.text or "").strip()
                name = text.split(":/", 1)[0].strip() if a.get("Format", "").lower() == "hdf" else text
                if name:
                    found.append(name)
            elif el.tag == _XINCLUDE and a.get("href"):
                name = a["href"].split("#", 1)[0].strip()
                if name:
                    found.append(name)
    except (ET.ParseError, OSError, UnicodeError):
        return None
    return list(dict.fromkeys(found))
