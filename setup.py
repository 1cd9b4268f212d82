"""Build hook for the compiled modules (everything else is in pyproject.toml).

models/quality/_fastmetrics.c holds compiled helpers of models/quality/ (the 3D inscribed-ball search,
and in the same module _fastcircle.c the 2D one; the 3D geometry, enclosing balls, partition statistics); models/graph/_fastgraph.c graph helpers of the
rtree partitioner and the 2D merge (the halving steps of the cuts, connected pieces, coarse-graph
edges, boundary loops); models/mesh/_fastmesh.c the read stage's validation (measures of fixed-size
cells and polygons, the orientation check; in the same module, _fastfaces.c its face check, _fastascii.c
its ASCII number parser and _fastpoly.c its polyhedra).
Both are optional: where they cannot be compiled the install goes on and the numpy twins run (same
results, slower; models/native.py finds them).
"""

from setuptools import Extension, setup

setup(
    ext_modules=[
        Extension(
            "models.quality._fastmetrics",
            ["models/quality/_fastmetrics.c", "models/quality/_fastcircle.c"],
            depends=["models/_buffers.h", "models/quality/_fastheap.h"],
            include_dirs=["models"],
            extra_compile_args=["-O3", "-fno-math-errno"],
            optional=True,
        ),
        Extension(
            "models.graph._fastgraph",
            ["models/graph/_fastgraph.c"],
            depends=["models/_buffers.h"],
            include_dirs=["models"],
            # no -ffast-math or contraction: the same float operations as the numpy twins, bit for bit
            extra_compile_args=["-O3", "-fno-math-errno", "-ffp-contract=off"],
            optional=True,
        ),
        Extension(
            "models.mesh._fastmesh",
            [
                "models/mesh/_fastmesh.c",
                "models/mesh/_fastfaces.c",
                "models/mesh/_fastascii.c",
                "models/mesh/_fastpoly.c",
            ],
            depends=["models/_buffers.h", "models/mesh/_fastmesh.h"],
            include_dirs=["models"],
            # the same float operations as the numpy twins in geometry.py, bit for bit
            extra_compile_args=["-O3", "-fno-math-errno", "-ffp-contract=off"],
            optional=True,
        ),
    ]
)
