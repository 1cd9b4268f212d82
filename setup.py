"""Build hook for the compiled modules (everything else is in pyproject.toml).

models/_fastmetrics.c holds compiled helpers of models/metrics.py (the 3D inscribed-ball search,
the 3D geometry, enclosing balls, partition statistics); models/_fastcuts.c those of the rtree
partitioner (the halving steps of its cuts, connected pieces). Both are optional: where they cannot
be compiled the install goes on and the numpy twins run (same results, slower).
"""

from setuptools import Extension, setup

setup(
    ext_modules=[
        Extension(
            "models._fastmetrics",
            ["models/_fastmetrics.c"],
            extra_compile_args=["-O3", "-fno-math-errno"],
            optional=True,
        ),
        Extension(
            "models._fastcuts",
            ["models/_fastcuts.c"],
            # no -ffast-math or contraction: the same float operations as the numpy twins, bit for bit
            extra_compile_args=["-O3", "-fno-math-errno", "-ffp-contract=off"],
            optional=True,
        ),
    ]
)
