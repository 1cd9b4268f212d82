"""Build hook for the one compiled module (everything else is in pyproject.toml).

models/_inscribed3d.c is the 3D inscribed-ball search of models/metrics.py. It is optional: where
it cannot be compiled the install goes on and metrics.py falls back to its numpy search (same
guarantee, several times slower).
"""

from setuptools import Extension, setup

setup(
    ext_modules=[
        Extension(
            "models._inscribed3d",
            ["models/_inscribed3d.c"],
            extra_compile_args=["-O3", "-fno-math-errno"],
            optional=True,
        )
    ]
)
