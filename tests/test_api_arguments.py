"""The Python API with bad or unusual arguments (an outside sweep of session 43: 95 of 601 calls
gave a raw TypeError / ValueError / IndexError / KeyError, or cut arrays without a word): each is
now worked or refused with our own error in one sentence."""

from __future__ import annotations

import numpy as np
import pytest

from models import agglomerate
from models.agglomeration import build_hierarchy, read_mesh
from models.errors import MagnetError, ParameterError


def _square(n: int = 10):
    i, j = np.meshgrid(np.arange(n + 1.0), np.arange(n + 1.0), indexing="ij")
    p = np.c_[i.ravel(), j.ravel()]
    a = (np.arange(n)[:, None] * (n + 1) + np.arange(n)[None, :]).ravel()
    b = a + n + 1
    t = np.concatenate([np.c_[a, b, b + 1], np.c_[a, b + 1, a + 1]])
    return p, t


P, T = _square()


@pytest.mark.parametrize(
    "kwargs, said",
    [
        ({"cells": [("triangle", np.c_[T, T[:, :1]])]}, "a triangle has 3 nodes, but its cells here have 4"),
        ({"cells": [("triangle", T + 0.5)]}, "point ids must be whole numbers"),
        ({"points": np.c_[P, P]}, "points must be an (n, 2) or (n, 3) array, got shape (121, 4)"),
        ({"points": P + 1j}, "points must be real numbers"),
        ({"points": np.full(P.shape, "a")}, "points must be real numbers"),
        ({"points": [[0, 0], [1, 0, 0]]}, "its rows differ in length"),
        ({"tags": [np.full(len(T), np.nan)]}, "tags must be whole numbers"),
        ({"tags": [np.full(len(T), 1.5)]}, "tags must be whole numbers"),
        ({"tags": [np.array(["a"] * len(T))]}, "tags must be whole numbers"),
        ({"tags": 3}, "tags must hold one array per cell block"),
        ({"tags": [np.zeros(5)]}, "tags must hold one number per triangle cell"),
        ({"cells": [("tri", T)]}, "unknown cell type 'tri' in cells=: use meshio's names"),
        ({"cells": [(None, T)]}, "unknown cell type 'None'"),
    ],
)
def test_bad_arrays_are_refused_in_one_sentence(kwargs, said):
    args = {"points": P, "cells": [("triangle", T)], **kwargs}
    with pytest.raises(ParameterError) as e:
        read_mesh(**args)
    assert said in str(e.value) and "np." not in str(e.value), str(e.value)


def test_numpy_scalars_are_numbers():
    res = agglomerate(
        points=P, cells=[("triangle", T)], k=np.int64(4), seed=np.int32(1), allow_extra=np.False_
    )
    assert res.n_elements == 4
    h = build_hierarchy(points=P, cells=[("triangle", T)], coarsest=np.int64(3))
    assert int(h.levels[0].max()) + 1 <= 3


@pytest.mark.parametrize(
    "call, said",
    [
        (lambda: agglomerate(points=P, cells=[("triangle", T)], subset=[[0, 1], [2]], k=2), "subset must be"),
        (
            lambda: build_hierarchy(points=P, cells=[("triangle", T)], coarsest=None),
            "coarsest must be a whole",
        ),
        (lambda: build_hierarchy(points=P, cells=[("triangle", T)], kappa=5), "kappa must be"),
        (lambda: build_hierarchy(points=P, cells=[("triangle", T)], kappa=["x", 1]), "kappa must be"),
    ],
)
def test_bad_parameters_are_refused_in_one_sentence(call, said):
    with pytest.raises(ParameterError) as e:
        call()
    assert said in str(e.value)


def test_cells_left_out_keep_one_input_label_each_and_are_said():
    bad = T.copy()
    bad[0, 0] = -1  # (a missing point: one cell of 200 left out, a few bad among many)
    said = []
    res = agglomerate(points=P, cells=[("triangle", bad)], k=4, warn=said.append)
    assert res.labels.shape == (len(T) - 1,) and res.input_labels.shape == (len(T),)
    assert res.input_labels[0] == -1 and np.array_equal(res.input_labels[1:], res.labels)
    assert len(said) == 1 and "input_labels one per cell given" in said[0]


def test_writes_and_element_numbers_are_checked(tmp_path):
    res = agglomerate(points=P, cells=[("triangle", T)], k=6)
    for path, said in (
        (tmp_path / "no" / "a.vtu", "folder"),
        (None, "give the path of a file"),
        (tmp_path, "use .vtu"),
    ):
        with pytest.raises(ParameterError) as e:
            res.write(path)
        assert said in str(e.value)
    assert res.write(str(tmp_path / "b.vtu").encode()) == str(tmp_path / "b.vtu")
    for tag in (-1, "x"):  # (as agglomerate(boundary_tag=...) takes it: 0 to 2^31 - 1)
        with pytest.raises(ParameterError):
            res.write(tmp_path / "c.vtu", boundary_tag=tag)
    for e in (6, -1, "a", 1.0):
        with pytest.raises(ParameterError):
            res.polygon(e)
    assert len(res.polygon(5)) >= 3
    h = build_hierarchy(points=P, cells=[("triangle", T)])
    (tmp_path / "file").write_text("x")
    with pytest.raises(ParameterError) as e:
        h.write(tmp_path / "file")
    assert "it is a file, not a folder" in str(e.value)
    with pytest.raises(MagnetError):
        h.write(None)


def test_python_callers_get_their_own_argument_names():
    for call, said in (
        (lambda: build_hierarchy(points=P, cells=[("triangle", T)], ratio=1), "ratio must be >= 2"),
        (lambda: agglomerate(points=P, cells=[("triangle", T)], k=4, seed=-1), "seed must be"),
        (
            lambda: agglomerate(points=P, cells=[("triangle", T)], k=4, progress="x"),
            "progress must be a function",
        ),
        (
            lambda: agglomerate(points=P, cells=[("triangle", T)], k=4, metrics="no"),
            "metrics must be True or False",
        ),
        (lambda: agglomerate(5, k=3), "cannot read an int as a mesh"),
    ):
        with pytest.raises(ParameterError) as e:
            call()
        assert said in str(e.value) and "options." not in str(e.value), str(e.value)
