"""Build the compiled cores (Sequitur, MinAtar Breakout, TensorBoard record framing); all other
metadata lives in pyproject.toml."""

from setuptools import Extension, setup

setup(
    ext_modules=[
        Extension(
            "routine_gym._sequitur",
            ["routine_gym/_sequitur.cpp"],
            extra_compile_args=["-O2", "-std=c++17"],
            language="c++",
        ),
        Extension(
            "routine_gym._minatar_core",
            ["routine_gym/_minatar_core.cpp"],
            extra_compile_args=["-O2", "-std=c++17"],
            language="c++",
        ),
        Extension(
            "routine_gym._records",
            ["routine_gym/_records.cpp"],
            extra_compile_args=["-O2", "-std=c++17"],
            language="c++",
        ),
    ]
)
