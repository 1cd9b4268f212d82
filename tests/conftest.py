import os
import sys

import pytest

HERE = os.path.dirname(__file__)
sys.path.insert(0, HERE)
os.environ.setdefault("MPLBACKEND", "Agg")

DATA = os.path.join(HERE, "data")
BRAIN = os.path.join(DATA, "BrainCoronalNoHoles.vtu")
EMILIA = os.path.join(DATA, "MeshEmilia.vtk")


@pytest.fixture
def brain_path():
    return BRAIN


@pytest.fixture
def emilia_path():
    return EMILIA
