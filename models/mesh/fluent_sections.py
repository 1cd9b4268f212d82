"""Where a Fluent mesh or case file (.msh, .cas) goes wrong, section by section, its binary sections
included: a refusal path (models.mesh.locate calls it after VTK's reader refused or crashed on the
file), never a gate before the reader.

A Fluent file is a sequence of parenthesised sections, "(index (header) (body))". ASCII sections
are followed by their parentheses (outside quoted text). Binary sections (index 20xx: float32
values, 30xx: float64; integers are 32-bit little-endian in both) hold raw bytes between "(" and
")" and end with "End of Binary Section index)". For the mesh's own sections the header says how
many bytes the body holds:

- x010 nodes (zone first last type [dim]): (last - first + 1) * dim values;
- x012 cells (zone first last type element-type): one int32 per cell where the zone is mixed
  (element type 0), no body otherwise;
- x013 faces (zone first last bc-type face-type): per face its nodes, c0 and c1 as int32; a
  face of a mixed zone (face type 0 or 5) starts with its number of nodes.

A body that is shorter, or not followed by its end marker, is named with its section, the ids its
header gives and the byte where it starts. Other binary sections (face and cell trees, interface
parents) are found by their end marker.
"""

from __future__ import annotations

import re

import numpy as np

_HEAD = re.compile(rb"\((\d{1,5})")
_HEX_HEADER = re.compile(rb"\s*\(([0-9a-fA-F\s]*)\)")
_WHAT = {10: "nodes", 12: "cells", 13: "faces"}
_FACE_NODES = {2: 2, 3: 3, 4: 4}  # Fluent's face types with a fixed number of nodes


class _Fault(Exception):
    pass


def faults(data: bytes) -> tuple[str | None, str | None]:
    """(the first place where `data`, a whole Fluent file, breaks Fluent's section structure, the
    first face whose node or cell ids are out of range), each in words or None. A broken structure
    makes VTK's reader crash, run on, or read garbage: a refusal. A face id out of range often
    leaves VTK's cells right (a hexahedron is built from two of its six faces): a warning where VTK
    reads the file, the place where it does not."""
    seen = {"nodes": 0, "cells": 0, "ids": None}
    try:
        _walk(data, seen)
    except _Fault as found:
        return str(found), seen["ids"]
    return None, seen["ids"]


def fault(data: bytes) -> str | None:
    """faults' first answer, else its second: the place for a refusal."""
    structure, ids = faults(data)
    return structure or ids


def _walk(data: bytes, seen: dict) -> None:
    pos, n, dim = 0, len(data), 3  # seen: the largest node and cell ids declared so far
    while True:
        while pos < n and data[pos] in b" \t\r\n\0":
            pos += 1
        if pos >= n:
            return
        m = _HEAD.match(data, pos)
        if m is None:
            raise _Fault(f"byte {pos:,}: {_shown(data[pos : pos + 12])} where a section '(index' is expected")
        index, start = int(m.group(1)), pos
        if index % 1000 in _WHAT and index // 1000 in (2, 3):
            pos = _binary(data, m.end(), index, start, dim, seen)
        elif index // 1000 in (2, 3):
            end = re.compile(rb"\)\s*End of Binary Section\s+%d\s*\)" % index).search(data, m.end())
            if end is None:
                raise _Fault(f"the file ends inside section {index} (from byte {start:,}): it is truncated")
            pos = end.end()
        elif index in _WHAT:  # an ASCII mesh section: its header, then its body's characters
            pos = _ascii_mesh(data, m.end(), index, start, dim, seen)
        else:
            pos = _ascii(data, start, index)
            if index == 2:
                found = re.match(rb"\(2\s+(\d)\s*\)", data[start:pos])
                dim = int(found.group(1)) if found else dim


def _ascii_header(data: bytes, at: int, index: int, start: int) -> list[int]:
    """An ASCII section 10, 12 or 13 starts with '(zone first last type ...)' in hexadecimal; a
    cell zone's element type (12, zone > 0) is one Fluent has (0 mixed to 7 polyhedral)."""
    head = re.compile(rb"\s*\(([^()]{0,200})\)").match(data, at)
    fields = head.group(1).split() if head else []
    if not head or not 3 <= len(fields) <= 6 or not all(re.fullmatch(rb"[0-9a-fA-F]+", f) for f in fields):
        shown = _shown(data[at : at + 24].strip())
        shown = "(bytes that are not text)" if shown == "bytes that are not text" else shown
        raise _Fault(
            f"section {index} (from byte {start:,}): its header {shown} is not '(zone first last type ...)' "
            "in hexadecimal numbers"
        )
    if index == 12 and len(fields) >= 5 and int(fields[0], 16) > 0 and int(fields[4], 16) > 7:
        raise _Fault(
            f"section 12 (cells, from byte {start:,}): its element type is {int(fields[4], 16)}, which "
            "Fluent does not have (0 mixed, 1 triangle, 2 tetrahedron, 3 quadrilateral, 4 hexahedron, "
            "5 pyramid, 6 wedge, 7 polyhedron)"
        )
    return [int(f, 16) for f in fields]


_NOT_HEX = re.compile(rb"[^0-9a-fA-F\s]")
_NOT_REAL = re.compile(rb"[^0-9eEdD+\-.nNaAiIfFtTyY\s]")  # (nan, inf, infinity: left to the reader)


def _ascii_mesh(data: bytes, at: int, index: int, start: int, dim: int, seen: dict) -> int:
    """The byte after an ASCII section 10, 12 or 13: its header (_ascii_header; the largest node and
    cell ids declared, into seen), then its body, if any: numbers only (hexadecimal ids in 12 and
    13, reals in 10) up to the ')' that closes it, and as many as the header declares where their
    count is fixed."""
    fields = _ascii_header(data, at, index, start)
    if index in (10, 12):
        key = "nodes" if index == 10 else "cells"
        seen[key] = max(seen[key], fields[2])
    pos = _HEX_HEADER.match(data, at).end()
    while pos < len(data) and data[pos] in b" \t\r\n":
        pos += 1
    if data[pos : pos + 1] == b")":
        return pos + 1
    if data[pos : pos + 1] != b"(":
        return _ascii(data, start, index)  # (another layout: its parentheses only)
    close = data.find(b")", pos + 1)
    if close < 0:
        raise _Fault(
            f"the file ends inside section {index} (from line {_line(data, start):,}): it is truncated"
        )
    body = data[pos + 1 : close]
    bad = (_NOT_REAL if index == 10 else _NOT_HEX).search(body)
    if bad is not None:
        at_byte = pos + 1 + bad.start()
        kind = "a real number" if index == 10 else "a hexadecimal number"
        raise _Fault(
            f"line {_line(data, at_byte):,} (section {index}, {_WHAT[index]} {fields[1]:,} to {fields[2]:,}, "
            f"from line {_line(data, start):,}): {_char(body[bad.start()])} at byte {at_byte:,} where {kind} "
            "is expected"
        )
    per = {
        10: fields[4] if len(fields) > 4 else dim,
        13: _FACE_NODES.get(fields[4] if len(fields) > 4 else 0),
    }
    width = per.get(index)
    if width is not None and len(body) < (8 << 20):
        need = (fields[2] - fields[1] + 1) * (width + (2 if index == 13 else 0))
        held = len(body.split())
        if held != need:
            raise _Fault(
                f"section {index} ({_WHAT[index]} {fields[1]:,} to {fields[2]:,}, from line {_line(data, start):,}) "
                f"holds {held:,} numbers where its header declares {need:,}"
            )
    end = data.find(b")", close + 1)
    if end < 0:
        raise _Fault(
            f"the file ends inside section {index} (from line {_line(data, start):,}): it is truncated"
        )
    return end + 1


def _line(data: bytes, at: int) -> int:
    return data.count(b"\n", 0, at) + 1


def _ascii(data: bytes, start: int, index: int) -> int:
    """The byte after the ')' that closes the ASCII section starting at `start`."""
    depth, quoted = 0, False
    for m in re.compile(rb'\\.|[()"]', re.DOTALL).finditer(data, start):
        c = m.group()
        if c[:1] == b"\\":  # (an escaped character in a quoted string: \" among them)
            continue
        if c == b'"':
            quoted = not quoted
        elif quoted:
            continue
        elif c == b"(":
            depth += 1
        else:
            depth -= 1
            if depth == 0:
                return m.end()
    raise _Fault(
        f"the file ends inside section {index} (from byte {start:,}; {depth} '(' not closed): it is truncated"
    )


def _binary(data: bytes, at: int, index: int, start: int, dim: int, seen: dict) -> int:
    """The byte after a mesh section x010, x012 or x013 (its header, its binary body and its end
    marker), checked against what its header declares; a face's node and cell ids against the
    largest ones declared before it (seen: updated here)."""
    kind = _WHAT[index % 1000]
    head = _HEX_HEADER.match(data, at)
    if head is None:
        raise _Fault(
            f"section {index} (from byte {start:,}): its header '(zone first last ...)' cannot be read"
        )
    try:
        fields = [int(t, 16) for t in head.group(1).split()]
    except ValueError:
        fields = []
    if len(fields) < 4:
        raise _Fault(
            f"section {index} (from byte {start:,}): its header has {len(fields)} numbers, not 4 or 5"
        )
    first, last = fields[1], fields[2]
    if kind in seen:
        seen[kind] = max(seen[kind], last)
    count = last - first + 1
    what = f"section {index} ({kind} {first:,} to {last:,}, from byte {start:,})"
    if count < 0 or count > len(data):
        raise _Fault(f"{what}: its header declares {count:,} {kind}, which the file cannot hold")
    pos = head.end()
    while pos < len(data) and data[pos] in b" \t\r\n":
        pos += 1
    if pos < len(data) and data[pos : pos + 1] == b")":  # no body (a cell zone of one element type)
        return pos + 1
    if data[pos : pos + 1] != b"(":
        if pos >= len(data):
            raise _Fault(f"the file ends inside {what}: it is truncated")
        raise _Fault(
            f"{what}: {_shown(data[pos : pos + 12])} at byte {pos:,} where its data's '(' is expected"
        )
    body = pos + 1
    if kind == "nodes":
        nd = fields[4] if len(fields) > 4 else dim
        size = count * nd * (4 if index // 1000 == 2 else 8)
        end = body + size
    elif kind == "cells":
        end = body + (4 * count if len(fields) > 4 and fields[4] == 0 else 0)
    else:
        end = _faces_end(data, body, count, fields[4] if len(fields) > 4 else 0, what, seen)
    if end > len(data):
        raise _Fault(
            f"the file ends inside {what}: its binary data needs {end - body:,} bytes from byte {body:,}, "
            f"the file holds {len(data) - body:,} of them: it is truncated"
        )
    close = re.compile(rb"\)\s*End of Binary Section\s+%d\s*\)" % index).match(data, end)
    if close is None:
        later = re.compile(rb"\)\s*End of Binary Section\s+%d\s*\)" % index).search(data, body)
        said = f", not at byte {later.start():,} where it is" if later else ""
        raise _Fault(
            f"{what}: its binary data ({end - body:,} bytes for the {count:,} {kind} its header declares) "
            f"should be followed by ')End of Binary Section {index})' at byte {end:,}{said}"
        )
    return close.end()


def _faces_end(data: bytes, body: int, count: int, face_type: int, what: str, seen: dict) -> int:
    """Where the body of a face section ends: fixed-size faces by arithmetic; a mixed zone (face
    type 0 or 5) face by face, each led by its number of nodes. Each face's node ids (1 to the
    largest declared) and cell ids c0 (from 1) and c1 (0 on the boundary) are checked where the
    body is whole (VTK's reader indexes its arrays with them: it crashes, or fails 'parsing')."""
    room = (len(data) - body) // 4
    ints = np.frombuffer(data, dtype="<i4", count=room, offset=body)
    if face_type in _FACE_NODES:
        k = _FACE_NODES[face_type]
        if count * (k + 2) <= room:
            rows = ints[: count * (k + 2)].reshape(count, k + 2)
            _ids(rows[:, :k], rows[:, k], rows[:, k + 1], body, k + 2, what, seen)
        return body + 4 * count * (k + 2)
    if face_type not in (0, 5):
        raise _Fault(f"{what}: its face type is {face_type}, which Fluent does not have (0, 2, 3, 4 or 5)")
    at = 0
    for face in range(count):
        if at >= len(ints):
            return body + 4 * (at + 1)  # past the end: said as truncated by the caller
        k = int(ints[at])
        if k < 2 or k > 1024:
            raise _Fault(
                f"{what}: face {face + 1:,} of the section (at byte {body + 4 * at:,}) says it has {k:,} nodes"
            )
        if at + k + 3 <= len(ints):
            row = ints[at + 1 : at + k + 3]
            _ids(row[None, :k], row[k : k + 1], row[k + 1 :], body + 4 * at, 0, what, seen, face)
        at += k + 3
    return body + 4 * at


def _ids(nodes, c0, c1, at: int, stride: int, what: str, seen: dict, first: int = 0) -> None:
    """The first face (rows of nodes, c0, c1; row r at byte at + 4 * stride * r) whose node or cell
    ids are out of range, named in seen["ids"] (the walk goes on); nothing where no such ids were
    declared before the section."""
    n_nodes, n_cells = seen["nodes"], seen["cells"]
    bad_node = ((nodes < 1) | (nodes > n_nodes)).any(axis=1) if n_nodes else np.zeros(len(nodes), bool)
    bad_cell = ((c0 < 1) | (c0 > n_cells) | (c1 < 0) | (c1 > n_cells)) if n_cells else np.zeros(len(c0), bool)
    bad = np.flatnonzero(bad_node | bad_cell)
    if not bad.size:
        return
    fatal = np.flatnonzero(bad_cell | ((nodes < 1).any(axis=1) if n_nodes else bad_cell))
    r = int(fatal[0]) if fatal.size else int(bad[0])
    where = f"face {first + r + 1:,} of the section (at byte {at + 4 * stride * r:,})"
    if bad_cell[r]:  # (VTK's reader crashed, ran on, or refused on 37 of 44 such mutants: a refusal)
        raise _Fault(
            f"{what}: {where} lies between cells {int(c0[r]):,} and {int(c1[r]):,}; the cells are 1 to "
            f"{n_cells:,} (0: none, on the boundary)"
        )
    node = int(nodes[r][(nodes[r] < 1) | (nodes[r] > n_nodes)][0])
    said = f"{what}: {where} refers to node {node:,}; the nodes are 1 to {n_nodes:,}"
    if node < 1:  # (a crash on 7 of 13)
        raise _Fault(said)
    if seen["ids"] is None:  # a node id past the nodes: VTK read 42 of 76 such mutants right (a
        seen["ids"] = said  # hexahedron is built from two of its faces): said, not refused


def _char(c: int) -> str:
    return repr(chr(c)) if 32 < c < 127 else f"a byte that is not text (0x{c:02x})"


def _shown(raw: bytes) -> str:
    text = raw.decode("ascii", "replace")
    if not text or any(not (32 <= ord(c) < 127) for c in text):
        return "bytes that are not text"
    return repr(text)
