"""A malformed XML file read by VTK (XDMF, and the VTK XML files VTK's readers take) is refused
with the place of its fault, found by Python's expat when VTK says none (before: "it is
corrupted or not an XDMF file", with no place)."""

from __future__ import annotations

import meshio
import pytest
import vtk_corpus as vc

from models.errors import MeshError
from models.mesh.sandbox import read_mesh_safe


def _xdmf(tmp_path):
    p, h = vc.grid(3, 3, 3)
    path = tmp_path / "good.xdmf"
    meshio.write(str(path), meshio.Mesh(p, [("hexahedron", h)]), data_format="XML")
    return path.read_text()


def _line_of(text: str, needle: str) -> int:
    return text[: text.index(needle)].count("\n") + 1


@pytest.mark.parametrize(
    "fault, what",
    [
        (lambda s: s.replace("</Topology>", "</Topolgy>"), "a closing tag does not match the tag it closes"),
        (lambda s: s[: len(s) // 2], "the file ends before its XML does"),
        (lambda s: s.replace("<Geometry", "<Geo&metry", 1), "a character that XML does not allow"),
    ],
)
def test_a_malformed_xdmf_is_refused_at_its_fault(tmp_path, fault, what):
    text = fault(_xdmf(tmp_path))
    path = tmp_path / "bad.xdmf"
    path.write_text(text)
    with pytest.raises(MeshError) as err:
        read_mesh_safe(str(path))
    msg = str(err.value)
    assert msg.startswith("cannot read bad.xdmf as XDMF: its XML is malformed: " + what), msg
    if "Topolgy" in text:
        assert f"(at line {_line_of(text, '</Topolgy>'):,}, column" in msg


@pytest.mark.parametrize(
    "name, text, said",
    [
        (
            "page.vtu",
            "<!DOCTYPE html>\n<html><head><title>404</title></head><body>Not found</body></html>\n",
            "cannot read page.vtu as VTK XML (VTU): it is a web page (HTML), not a VTK XML file: "
            "was a download page saved instead of the mesh?",
        ),
        (
            "page2.vtu",  # HTML that is not well-formed XML (an unclosed <meta>, <br>)
            '<!DOCTYPE html>\n<html><head><meta charset="utf-8"></head><body><br>Not found</body></html>\n',
            "cannot read page2.vtu as VTK XML (VTU): it is a web page (HTML), not a VTK XML file: "
            "was a download page saved instead of the mesh?",
        ),
        (
            "other.vtu",
            '<?xml version="1.0"?>\n<Foo><Bar/></Foo>\n',
            "cannot read other.vtu as VTK XML (VTU): its root element is <Foo>, not <VTKFile>: "
            "it is not a VTK XML file",
        ),
        (
            "other.xdmf",
            '<?xml version="1.0"?>\n<Foo><Bar/></Foo>\n',
            "cannot read other.xdmf as XDMF: its root element is <Foo>, not <Xdmf>: it is not an XDMF file",
        ),
    ],
)
def test_well_formed_xml_of_another_kind_is_said_to_be_what_it_is(tmp_path, name, text, said):
    """A web page saved under a mesh's name (a download that kept the page), or XML of another
    root: said as such, not as "corrupted" (before: 'the file is corrupted or not VTK XML (VTU)')."""
    path = tmp_path / name
    path.write_text(text)
    with pytest.raises(MeshError) as err:
        read_mesh_safe(str(path))
    assert str(err.value) == said


def test_a_parser_error_of_a_format_that_is_no_xml_is_not_called_xml():
    """Fluent's reader says 'parsing' too: that is its text, not XML (mutation sweep Z)."""
    from models.mesh.vtk_readers import explain

    assert explain("vtkFLUENTReader (0x55d0): error parsing a section", "Fluent case") == (
        "its text cannot be parsed"
    )
    assert explain("vtkXMLParser (0x55d0): error parsing XML", "VTK XML unstructured grid") == (
        "its XML cannot be parsed"
    )
