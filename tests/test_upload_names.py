"""The service's check of an upload's file name (service/mesh_check.extension_of) words a mesh file
compressed whole as the CLI does: what it is and what to do (outside sweep U: `.vtu.gz` and
`.msh.gz` were "no mesh format extension we read" with the list of all extensions)."""

from __future__ import annotations

import pytest

from service.mesh_check import UploadRejected, extension_of


@pytest.mark.parametrize(
    "name, tool", [("m.vtu.gz", "gunzip"), ("m.msh.xz", "unxz"), ("m.exo.bz2", "bunzip2")]
)
def test_a_compressed_mesh_is_told_to_be_decompressed(name, tool):
    with pytest.raises(UploadRejected) as err:
        extension_of(name)
    assert err.value.status == 422
    assert (
        f"{name} is a .{name.split('.')[1]} file compressed whole: decompress it first, e.g. {tool} {name}"
        in (err.value.message)
    )


def test_other_names_keep_their_answer():
    assert extension_of("m.vtu") == "vtu"
    with pytest.raises(UploadRejected):
        extension_of("notes.txt.gz")  # (not a mesh inside: the list of extensions, as before)
