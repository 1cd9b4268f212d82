"""VTU (VTK XML UnstructuredGrid) reading: mixed and polyhedral cells, and a fast path for simple
single-piece files."""

from __future__ import annotations

import base64
import binascii
import math
import os
import re
import sys

import numpy as np

from models.errors import MeshError
from models.mesh.mapped import file_bytes, owned

# meshio's VTU reader refuses polyhedra mixed with other cells, which is what write_vtu writes for
# a 3D result with boundary groups; this reads such files (inline ascii or uncompressed base64
# binary DataArrays, as write_vtu and VTK's own writer without compression produce).
_NP_TYPES = {
    "Float64": np.float64,
    "Float32": np.float32,
    "Int64": np.int64,
    "Int32": np.int32,
    "UInt64": np.uint64,
    "UInt32": np.uint32,
    "Int8": np.int8,
    "UInt8": np.uint8,
    "Int16": np.int16,
    "UInt16": np.uint16,
}
_MESHIO_NAMES = {
    3: "line",
    5: "triangle",
    7: "polygon",
    9: "quad",
    10: "tetra",
    12: "hexahedron",
    13: "wedge",
    14: "pyramid",
}


def _decode(el, header: type) -> np.ndarray:
    kind = _NP_TYPES.get(el.get("type", ""))
    if kind is None:
        raise MeshError(f"unsupported VTU data type {el.get('type')!r}")
    fmt = el.get("format", "ascii")
    text = (el.text or "").strip()
    if fmt == "ascii":
        return np.array(text.split(), dtype=np.float64).astype(kind) if text else np.zeros(0, kind)
    if fmt != "binary":
        raise MeshError(f"unsupported VTU data format {fmt!r} (inline ascii or binary only)")
    hsize = np.dtype(header).itemsize
    raw = base64.b64decode(text)
    n = int(np.frombuffer(raw[:hsize], dtype=header)[0])
    if len(raw) < hsize + n:  # header and data encoded separately
        hlen = 4 * ((hsize + 2) // 3)
        raw = base64.b64decode(text[:hlen])[:hsize] + base64.b64decode(text[hlen:])
    return np.frombuffer(raw[hsize : hsize + n], dtype=kind).copy()


def read_vtu_mixed(path: str | os.PathLike):
    """A VTU with VTK_POLYHEDRON cells next to other cells, as a meshio-like object
    (points, cells [.type, .data], cell_data {name: [array per block]}, field_data)."""
    import xml.etree.ElementTree as ET
    from types import SimpleNamespace

    root = ET.parse(os.fspath(path)).getroot()
    if root.get("compressor"):
        raise MeshError("compressed VTU files with polyhedra mixed with other cells are not supported")
    header = np.uint64 if root.get("header_type") == "UInt64" else np.uint32
    piece = root.find("UnstructuredGrid/Piece")
    if piece is None:
        raise MeshError("not a VTU UnstructuredGrid file")

    def arrays(section: str) -> dict:
        node = piece.find(section)
        return (
            {}
            if node is None
            else {
                el.get("Name"): (_decode(el, header), int(el.get("NumberOfComponents", 1)))
                for el in node.findall("DataArray")
            }
        )

    pts, ncomp = next(iter(arrays("Points").values()))
    cells = {k: v[0].astype(np.int64) for k, v in arrays("Cells").items()}
    conn, offs, types = cells["connectivity"], cells["offsets"], cells["types"]
    start = np.r_[0, offs[:-1]]
    cuts = np.flatnonzero(types[1:] != types[:-1]) + 1
    bounds = np.r_[0, cuts, types.size]
    blocks, sel = [], []
    for b0, b1 in zip(bounds[:-1], bounds[1:], strict=True):  # a loop over blocks of one type
        t = int(types[b0])
        if t == 42:
            fs, fo = cells["faces"], cells["faceoffsets"]
            # a cell's stream starts where the last earlier stream ended (faceoffsets = ends, -1 = none)
            begins = np.r_[0, np.maximum.accumulate(np.where(fo >= 0, fo, 0))[:-1]]
            data = []
            for c in range(b0, b1):  # polyhedra are parsed one by one (their faces are lists)
                begin = int(begins[c])
                n_faces = int(fs[begin])
                k, faces = begin + 1, []
                for _ in range(n_faces):
                    m = int(fs[k])
                    faces.append(fs[k + 1 : k + 1 + m])
                    k += m + 1
                data.append(faces)
            blocks.append(SimpleNamespace(type="polyhedron", data=data))
            sel.append(np.arange(b0, b1))
            continue
        if t not in _MESHIO_NAMES:
            raise MeshError(f"unsupported VTK cell type {t} in the VTU file")
        size = offs[b0:b1] - start[b0:b1]
        for s in np.unique(size):  # polygons of different sizes go to different blocks
            ids = np.arange(b0, b1)[size == s]
            data = conn[start[ids][:, None] + np.arange(s)[None, :]]
            name = _MESHIO_NAMES[t] if t != 7 else {3: "triangle", 4: "quad"}.get(int(s), "polygon")
            blocks.append(SimpleNamespace(type=name, data=data))
            sel.append(ids)
    cell_data = {
        name: [a.reshape(-1, nc)[ids].reshape(-1) if nc == 1 else a.reshape(-1, nc)[ids] for ids in sel]
        for name, (a, nc) in arrays("CellData").items()
    }
    fd = root.find("UnstructuredGrid/FieldData")
    field_data = {} if fd is None else {el.get("Name"): _decode(el, header) for el in fd.findall("DataArray")}
    return SimpleNamespace(
        points=pts.reshape(-1, ncomp).astype(np.float64),
        cells=blocks,
        cell_data=cell_data,
        field_data=field_data,
    )


# The common VTU layout, read without meshio's XML tree (what meshio.read of a large file spends
# beside decoding): one Piece, inline base64 "binary" DataArrays, zlib-compressed or not, cells of
# fixed-size types that meshio keeps in VTK's node order (in runs of one type: meshio's blocks), no
# point or field data. Any other file (or anything unexpected) gives None, and meshio reads it. The
# arrays are those meshio.read gives.
_SIMPLE_CELLS = {5: ("triangle", 3), 9: ("quad", 4), 10: ("tetra", 4), 12: ("hexahedron", 8)}
_ATTR = re.compile(rb'([A-Za-z_][-\w.:]*)\s*=\s*"([^"<&]*)"')
_SECTIONS = {b"Points", b"Cells", b"CellData", b"PointData"}


def read_vtu_simple(path: str | os.PathLike):
    """meshio.read of a VTU of the common layout above (a meshio-like object: points, cells
    [.type, .data], cell_data {name: [array]}, field_data), or None for any other file."""
    if sys.byteorder != "little":
        return None
    try:
        return _simple_vtu(file_bytes(path))  # mapped: what it returns is copied (models.mesh.mapped)
    except Exception:  # noqa: BLE001  (anything unexpected: meshio reads it, and says what is wrong)
        return None


_PIECE = re.compile(rb"<Piece\b([^>]*)>")
_COUNT = re.compile(rb'\bNumberOf(Points|Cells)\s*=\s*"\s*(\d+)\s*"')
_ZLIB_RATIO = 1100  # zlib inflates at most ~1032 bytes per byte


def impossible_counts(path: str | os.PathLike, head_bytes: int = 1 << 16) -> str | None:
    """What is wrong when a Piece in the head of a VTU announces more points or cells than the
    whole file can hold (each needs at least a byte, zlib's ratio aside), else None. VTK's reader
    believes such a number and runs for minutes (a seeded mutant: NumberOfCells="999999999")."""
    size = os.path.getsize(path)
    with open(os.fspath(path), "rb") as fh:
        head = fh.read(head_bytes)
    end = head.find(b"<AppendedData")
    held = room(size, b"compressor=" in head[: max(end, 0) or len(head)])
    for piece in _PIECE.finditer(head, 0, end if end >= 0 else len(head)):
        for what, number in _COUNT.findall(piece.group(1)):
            n = int(number)
            if n > held:
                return more_than_held(n, what.decode().lower(), size)
    return None


def more_than_held(n: int, what: str, size: int) -> str:
    """impossible_counts' sentence: a Piece announcing n points or cells its size bytes cannot hold."""
    return f"its Piece announces {n:,} {what}, more than its {size:,} bytes can hold"


def room(size: int, compressed: bool) -> int:
    """The most values a file of `size` bytes can hold (each needs at least a byte, zlib's ratio aside)."""
    return size * (_ZLIB_RATIO if compressed else 1)


def layout(root: dict, dataset: str) -> tuple[str | None, np.dtype] | None:
    """(compressor or None, header dtype) of a VTKFile tag's attributes (scan_xml) when the file is
    `dataset` ("UnstructuredGrid", "ImageData", ...) in a layout our numpy readers read:
    little-endian, UInt32 or UInt64 headers, zlib-compressed or not; None for any other."""
    a = {k.decode(): v.decode() for k, v in root.items()}
    if a.get("type") != dataset or a.get("version", "0.1") not in ("0.1", "1.0"):
        return None
    if a.get("byte_order", "LittleEndian") != "LittleEndian":
        return None
    compressor = a.get("compressor")
    if compressor not in (None, "vtkZLibDataCompressor"):
        return None
    header = {"UInt32": np.dtype("<u4"), "UInt64": np.dtype("<u8")}.get(a.get("header_type", "UInt32"))
    return None if header is None else (compressor, header)


def array_reader(compressor: str | None, header: np.dtype, appended: dict):
    """array(attrs, text): a DataArray's values (scan_xml's (attrs, text); text None: appended, its
    bytes in `appended` (_appended) at its offset), reshaped to (-1, NumberOfComponents) when the
    tag says it. Inline: binary (base64) only; zlib blocks in base64 or raw bytes. ValueError (or
    any other exception) for a layout or data not read here: the caller declines the file."""
    decode = _decode_zlib if compressor else _decode_raw
    decode_raw = _decode_appended_zlib if compressor else _decode_appended_raw

    def array(attrs: dict, text: bytes | None) -> np.ndarray:
        kind = np.dtype(_NP_TYPES[attrs[b"type"].decode()]).newbyteorder("<")
        if text is None:  # appended: its slice of AppendedData
            text, raw = appended[int(attrs[b"offset"])]
            out = decode_raw(text, kind, header) if raw else decode(text, kind, header)
        elif attrs.get(b"format") != b"binary":
            raise ValueError("not inline binary")
        else:
            out = decode(text.strip(), kind, header)
        if b"NumberOfComponents" in attrs:
            out = out.reshape(-1, int(attrs[b"NumberOfComponents"]))
        return out

    return array


def _simple_vtu(data: bytes):
    from types import SimpleNamespace

    scanned = scan_xml(data)
    if scanned is None:
        return None
    root, _, piece, sections = scanned
    file_layout = layout(root, "UnstructuredGrid")
    if file_layout is None:
        return None
    compressor, header = file_layout
    n_points, n_cells = int(piece[b"NumberOfPoints"]), int(piece[b"NumberOfCells"])
    appended = _appended(sections.pop(b"appended", None), sections)
    if sections.get(b"PointData") or set(sections) - _SECTIONS or len(sections.get(b"Points", ())) != 1:
        return None
    if compressor and any(raw for _, raw in appended.values()):
        return None  # zlib blocks in raw appended data: left to the other readers
    array = array_reader(compressor, header, appended)

    cells = {attrs[b"Name"]: (attrs, text) for attrs, text in sections.get(b"Cells", ())}
    if set(cells) != {b"connectivity", b"offsets", b"types"}:
        return None
    types = array(*cells[b"types"])  # first: a file of other cells is declined before the big arrays
    offsets = array(*cells[b"offsets"])
    if types.shape != (n_cells,) or offsets.shape != (n_cells,) or n_cells == 0:
        return None
    runs = _runs(types)  # (start, end, VTK type) of each run of one type, as meshio's blocks
    if runs is None:
        return None
    p_attrs, p_text = sections[b"Points"][0]
    points = array(p_attrs, p_text).reshape(n_points, int(p_attrs[b"NumberOfComponents"]))
    conn = array(*cells[b"connectivity"])
    if len(runs) == 1:  # (one type: the offsets are a range, no sizes array)
        k = _SIMPLE_CELLS[runs[0][2]][1]
        if conn.shape != (k * n_cells,) or not np.array_equal(offsets, np.arange(k, k * n_cells + 1, k)):
            return None
    else:
        widths = np.repeat([_SIMPLE_CELLS[t][1] for _, _, t in runs], [e - s for s, e, _ in runs])
        if conn.shape != (int(widths.sum()),) or not np.array_equal(offsets, np.cumsum(widths)):
            return None
    cell_data = {}
    if any(a.get(b"Name") == b"vtkGhostType" for a, _ in sections.get(b"CellData", ())):
        return None  # ghost cells (a parallel writer's piece): VTK's path leaves them out
    for attrs, text in sections.get(b"CellData", ()):
        d = array(attrs, text)
        if d.shape[0] != n_cells:
            return None
        # a copy per block, as meshio's d[start + items]
        cell_data[attrs[b"Name"].decode()] = [d[np.arange(s, e)] for s, e, _ in runs]
    # meshio adds the piece's point offset (a numpy int64 0): the same dtype promotion and values
    # in a new array (inflated blocks already are one: kept as they are when int64)
    conn = conn if compressor and conn.dtype == np.int64 else conn + np.cumsum([0])[0]
    blocks, at = [], 0
    for s, e, t in runs:
        name, k = _SIMPLE_CELLS[t]
        blocks.append(SimpleNamespace(type=name, data=conn[at : at + (e - s) * k].reshape(e - s, k)))
        at += (e - s) * k
    return SimpleNamespace(points=owned(points), cells=blocks, cell_data=cell_data, field_data={})


_MAX_RUNS = 64  # runs of one cell type read here (more: a file of interleaved types, VTK's CSR path)


def _runs(types: np.ndarray) -> list[tuple[int, int, int]] | None:
    """(start, end, VTK type) of each run of cells of one type (meshio's cell blocks), where every
    type is one of _SIMPLE_CELLS and there are at most _MAX_RUNS runs; None otherwise."""
    breaks = np.flatnonzero(types[1:] != types[:-1]) + 1
    if breaks.size + 1 > _MAX_RUNS:
        return None
    starts = [0, *breaks.tolist()]
    ends = [*breaks.tolist(), int(types.size)]
    kinds = [int(types[s]) for s in starts]
    if any(t not in _SIMPLE_CELLS for t in kinds):
        return None
    return list(zip(starts, ends, kinds, strict=True))


def _appended(section, sections: dict) -> dict:
    """{offset: (its bytes, raw?)} of the appended DataArrays: AppendedData from its '_' on, cut
    at the offsets (each array's bytes run to the next array's offset). Raw bytes: uncompressed
    only (ValueError otherwise, as for any other layout not read here)."""
    offsets = sorted({int(a[b"offset"]) for items in sections.values() for a, t in items if t is None})
    if not offsets:
        return {}
    if section is None:
        raise ValueError("appended arrays without AppendedData")
    attrs, body = section[0]
    raw = attrs.get(b"encoding") == b"raw"
    if not raw and attrs.get(b"encoding") != b"base64":
        raise ValueError("unknown AppendedData encoding")
    start = bytes(body[:4096]).index(b"_") + 1
    if bytes(body[: start - 1]).strip():
        raise ValueError("AppendedData does not start with '_'")
    stop = len(body)
    while not raw and stop > start and body[stop - 1] in b" \t\r\n":
        stop -= 1
    blob = body[start:stop]  # memoryview slices: the arrays' bytes are not copied
    ends = [*offsets[1:], len(blob)]
    if offsets[0] < 0 or ends[-1] < offsets[-1]:
        raise ValueError("an appended array's offset is past the end of the data")
    return {o: (blob[o:e], raw) for o, e in zip(offsets, ends, strict=True)}


def _decode_appended_raw(data: bytes, dtype: np.dtype, header: np.dtype) -> np.ndarray:
    """An uncompressed appended array in raw encoding: its byte count, then its bytes."""
    h = header.itemsize
    total = int(np.frombuffer(data[:h], header)[0])
    if len(data) < h + total or total % dtype.itemsize:
        raise ValueError("an appended array is shorter than its header says")
    return np.frombuffer(data, dtype=dtype, count=total // dtype.itemsize, offset=h)


def scan_xml(data: bytes, dataset: bytes = b"UnstructuredGrid"):
    """A VTK XML file of one Piece, walking its tags with bytes.find (the base64 text between them
    is never parsed): (VTKFile's attributes, the `dataset` element's, the Piece's, and
    {section: [(attrs, text)]} of the DataArrays: the Piece's sections by name, the dataset's
    FieldData as b"FieldData", AppendedData as b"appended"). None for any other layout than
    VTKFile/dataset/Piece/section/DataArray and VTKFile/dataset/FieldData/DataArray (DataArrays with
    the InformationKey/Value children VTK writes: an array's norm range; a string array is an
    <Array>), for a section given twice, and for what VTK's XML parser would refuse or read otherwise
    than this scan: characters XML does not allow, text between the tags, an XML declaration not
    first, an attribute not name="value"."""
    stack: list[bytes] = []
    root = grid = piece = None
    sections: dict[bytes, list] = {}
    values: list[int] = []  # the Value children of the open InformationKey
    pos = 0
    while True:
        lt = data.find(b"<", pos)
        between = data[pos:] if lt < 0 else data[pos:lt]  # (an inline array's text is not here)
        if stack and stack[-1] == b"Value":
            if plain_number(between.strip()) is None:
                return None
        elif between.strip():
            return None  # text where VTK's XML has none
        if lt < 0:
            break
        if data.startswith(b"<?", lt):
            pos = data.index(b"?>", lt) + 2
            if lt != 0 or not _XML_DECLARATION.fullmatch(data[lt:pos]):
                return None
            continue
        if data.startswith(b"<!--", lt):
            end = data.index(b"-->", lt)
            if b"<" in data[lt + 4 : end] or not _xml_chars(data[lt:end]):
                return None
            pos = end + 3
            continue
        if data.startswith(b"<!", lt):
            return None  # CDATA, DOCTYPE
        gt = data.index(b">", lt)
        tag = data[lt + 1 : gt]
        if b"<" in tag or b"&" in tag or not _xml_chars(tag):
            return None
        if tag.startswith(b"/"):
            if not stack or stack.pop() != tag[1:].strip():
                return None
            if tag[1:].strip() == b"InformationKey" and values.pop() != 2:
                return None  # fewer Values than its length
            pos = gt + 1
            continue
        closed = tag.endswith(b"/")
        name = tag.rstrip(b"/").split(None, 1)[0]
        pairs = _ATTR.findall(tag)
        attrs = dict(pairs)
        if len(attrs) != len(pairs) or _ATTR.sub(b"", tag.rstrip(b"/")).split() != [name]:
            return None  # a repeated attribute, or one not in name="value" form
        depth = len(stack)
        if depth == 1 and name == b"AppendedData" and not closed and b"appended" not in sections:
            end = data.rfind(b"</AppendedData>")  # raw bytes may hold '<': the last closing tag
            if end < gt:
                return None
            sections[b"appended"] = [(attrs, memoryview(data)[gt + 1 : end])]  # a view, not a copy
            pos = end + len(b"</AppendedData>")
            continue
        if depth > 2 and stack[2] == b"FieldData":
            expected = (b"VTKFile", dataset, b"FieldData", b"DataArray", b"InformationKey", b"Value")
        else:
            expected = (b"VTKFile", dataset, None, None, b"DataArray", b"InformationKey", b"Value")
        role = b"DataArray" if name == b"Array" else name  # VTK writes a string array as <Array>
        if depth >= len(expected) or (expected[depth] is not None and role != expected[depth]):
            return None
        if depth == 0:
            if root is not None:
                return None
            root = attrs
        elif depth == 1:
            grid = attrs
        elif depth == 2 and name == b"Piece":
            if piece is not None:
                return None  # more than one Piece
            piece = attrs
        elif depth == 2 and name != b"FieldData":
            return None
        elif depth == 2 or expected[depth] is None:  # a section: the dataset's FieldData, a Piece's
            if name in sections or (depth == 3 and name == b"FieldData"):
                return None
            sections[name] = []
        elif role == b"DataArray" and attrs.get(b"format") == b"appended":
            sections[stack[-1]].append((attrs, None))  # its bytes in AppendedData, at its offset
        elif role == b"DataArray":  # its text runs to the next tag (VTK may add InformationKey children)
            end = data.find(b"<", gt + 1)
            if closed or end < 0:
                return None
            sections[stack[-1]].append((attrs, data[gt + 1 : end]))
            gt = end - 1  # the scan goes on after its text
        elif name == b"InformationKey":
            if (
                closed
                or attrs.get(b"name") not in _NORM_RANGES
                or {**attrs, b"name": None} != _NORM_RANGE_KEY
            ):
                return None
            values.append(0)
        elif closed or values[-1] >= 2 or attrs != {b"index": b"%d" % values[-1]}:
            return None  # a Value: the next index, its text a number (above)
        else:
            values[-1] += 1
        if not closed:
            stack.append(name)
        pos = gt + 1
    if stack or root is None or grid is None or piece is None:
        return None
    return root, grid, piece, sections


# the XML declaration VTK's writers write, and the one InformationKey they write under an array
_XML_DECLARATION = re.compile(
    rb"""<\?xml\s+version\s*=\s*(["'])1\.0\1(?:\s+encoding\s*=\s*(["'])(?i:utf-8)\2)?\s*\?>"""
)
_NORM_RANGES = (b"L2_NORM_RANGE", b"L2_NORM_FINITE_RANGE")
_NORM_RANGE_KEY = {b"name": None, b"location": b"vtkDataArray", b"length": b"2"}  # two Values
_NUMBER = re.compile(rb"[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?")


def plain_number(token: bytes) -> float | None:
    """A number written as VTK writes one, read as every correctly rounded parser reads it (C++
    streams, Python): a plain decimal, finite, neither overflowing nor underflowing; else None."""
    if not _NUMBER.fullmatch(token):
        return None
    value = float(token)
    if value == 0:  # (a zero written with a non-zero digit before its exponent underflowed)
        return None if _NONZERO.search(_EXPONENT.split(token, 1)[0]) else value
    return value if math.isfinite(value) and abs(value) >= sys.float_info.min else None


_NONZERO = re.compile(rb"[1-9]")
_EXPONENT = re.compile(rb"[eE]")


_NOT_XML = re.compile(rb"[\x00-\x08\x0b\x0c\x0e-\x1f]")


def _xml_chars(text: bytes) -> bool:
    """Text an XML parser (VTK's) takes: UTF-8, no control character but tab, newline, return."""
    try:
        text.decode("utf-8")
    except UnicodeDecodeError:
        return False
    return _NOT_XML.search(text) is None


def _decode_raw(text: bytes, dtype: np.dtype, header: np.dtype) -> np.ndarray:
    """meshio's read_uncompressed_binary (base64.b64decode is binascii.a2b_base64 on a copy of a
    memoryview: called directly, an appended array is decoded from the file's bytes)."""
    raw = binascii.a2b_base64(text)
    h = header.itemsize
    total = int(np.frombuffer(raw[:h], header)[0])
    if len(raw) == h:  # header and data encoded separately
        if len(text) != _b64_chars(h) + _b64_chars(total):
            raise ValueError("base64 text of another length than its header says")
        raw = binascii.a2b_base64(text[_b64_chars(h) :])
    else:
        if len(text) != _b64_chars(h + total):
            raise ValueError("base64 text of another length than its header says")
        raw = memoryview(raw)[h:]  # (not a copy)
    return np.frombuffer(raw[:total], dtype=dtype)


def _b64_chars(n: int) -> int:
    """The length of n bytes in base64: a text of another length (a character lost, added, or
    one the decoder skips) is not decoded as VTK's reader would decode it."""
    return -(-n // 3) * 4


def _decode_zlib(text: bytes, dtype: np.dtype, header: np.dtype) -> np.ndarray:
    """meshio's read_compressed_binary (zlib): a header of block sizes, then the blocks (base64)."""
    h = header.itemsize
    n_blocks = int(np.frombuffer(base64.b64decode(text[: -(-h // 3) * 4])[:h], header)[0])
    n_chars = -(-(h * (3 + n_blocks)) // 3) * 4
    head = np.frombuffer(base64.b64decode(text[:n_chars]), header)
    if len(text) != n_chars + _b64_chars(int(head[3 : 3 + n_blocks].sum())):
        raise ValueError("base64 text of another length than its header says")
    return _inflate(head, memoryview(binascii.a2b_base64(text[n_chars:])), dtype)


def _decode_appended_zlib(data: bytes, dtype: np.dtype, header: np.dtype) -> np.ndarray:
    """A zlib-compressed appended array in raw encoding: _decode_zlib's header and blocks, as bytes."""
    h = header.itemsize
    n_blocks = int(np.frombuffer(data[:h], header)[0])
    head = np.frombuffer(data, header, count=3 + n_blocks)
    return _inflate(head, memoryview(data)[h * (3 + n_blocks) :], dtype)


def _inflate(head: np.ndarray, raw: memoryview, dtype: np.dtype) -> np.ndarray:
    """The zlib blocks after a header (number of blocks, block size, last block's size, the blocks'
    compressed sizes) inflated into one array of dtype."""
    import zlib

    n_blocks = int(head[0])
    sizes = head[3 : 3 + n_blocks].astype(np.int64)
    ends = np.cumsum(sizes).tolist()
    starts = [0, *ends[:-1]]
    if n_blocks:  # the blocks inflated straight into the array the header announces
        full, last = int(head[1]), int(head[2])
        out = _inflate_into(raw, starts, ends, (n_blocks - 1) * full + (last or full), dtype.itemsize)
        if out is not None:
            return out.view(dtype)
    seen: dict[bytes, bytes] = {}  # equal blocks (a types array of one cell type) are inflated once
    blocks = []
    for s, e in zip(starts, ends, strict=True):
        b = raw[s:e].tobytes()
        out = seen.get(b)
        if out is None:
            out = seen[b] = zlib.decompress(b)
        blocks.append(out)
    if any(len(b) % dtype.itemsize for b in blocks):
        raise ValueError("a block does not hold whole items")
    return np.frombuffer(bytearray().join(blocks), dtype=dtype)  # writable, as meshio's concatenate


def _inflate_into(raw: memoryview, starts: list, ends: list, total: int, itemsize: int) -> np.ndarray | None:
    """The zlib blocks raw[start:end] inflated one after the other into one new (total,) uint8 array
    (no list of inflated blocks joined into a copy: half the memory), or None when they do not fill
    exactly `total` bytes (the caller then concatenates them as meshio does). Equal compressed blocks
    are inflated once. ValueError when a block does not hold whole items (meshio's frombuffer)."""
    import zlib

    out = np.empty(total, dtype=np.uint8)
    seen: dict[memoryview, tuple[int, int]] = {}  # compressed block -> where its bytes went
    pos = 0
    for s, e in zip(starts, ends, strict=True):
        b = raw[s:e]
        done = seen.get(b)
        n = done[1] - done[0] if done is not None else None
        if done is None:
            d = zlib.decompress(b)
            n = len(d)
            if n % itemsize:
                raise ValueError("a block does not hold whole items")
            if pos + n > total:
                return None
            out[pos : pos + n] = np.frombuffer(d, dtype=np.uint8)
            seen[b] = (pos, pos + n)
        else:
            if pos + n > total:
                return None
            out[pos : pos + n] = out[done[0] : done[1]]
        pos += n
    return out if pos == total else None
