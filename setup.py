"""Build the compiled cores (Sequitur, MinAtar Breakout, TensorBoard record framing, CompILE's
masked GRU, RoutineActionWrapper's step); all other metadata lives in pyproject.toml."""

import numpy
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
            depends=["routine_gym/_pybuffers.h"],
            extra_compile_args=["-O2", "-std=c++17"],
            language="c++",
        ),
        Extension(
            "routine_gym._records",
            ["routine_gym/_records.cpp"],
            extra_compile_args=["-O2", "-std=c++17"],
            language="c++",
        ),
        Extension(
            "routine_gym._masked_gru",
            ["routine_gym/_masked_gru.cpp"],
            depends=["routine_gym/_pybuffers.h", "routine_gym/_masked_gru_kernel.h"],
            # -O3, contracted multiply-adds and no FP traps: the loops are meant to vectorize
            # (FMA on AVX2; the σ and tanh loops' selects need -fno-trapping-math for that).
            extra_compile_args=["-O3", "-std=c++17", "-ffp-contract=fast", "-fno-trapping-math",
                                "-Wno-psabi"],
            language="c++",
            # masked_gru.py runs the torch loop without it (a compiler without GCC's vector
            # extensions, such as MSVC, skips it instead of failing the install).
            optional=True,
        ),
        Extension(
            "routine_gym._wrapper_core",
            ["routine_gym/_wrapper_core.cpp"],
            include_dirs=[numpy.get_include()],
            extra_compile_args=["-O2", "-std=c++17"],
            language="c++",
            # wrapper.py steps in Python without it.
            optional=True,
        ),
    ]
)
