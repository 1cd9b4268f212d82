"""Build hook for the one compiled module (everything else is in pyproject.toml).

models/_fastmetrics.c holds compiled helpers of models/metrics.py (the 3D inscribed-ball search,
the 3D geometry, enclosing balls, partition statistics). It is optional: where it cannot be
compiled the install goes on and metrics.py runs its numpy twins (same results, ~10x slower in 3D).
"""

from setuptools import Extension, setup

setup(
    ext_modules=[
        Extension(
            "models._fastmetrics",
            ["models/_fastmetrics.c"],
            extra_compile_args=["-O3", "-fno-math-errno"],
            optional=True,
        )
    ]
)
