"""Build the compiled cores (`routine_gym/_native/`: Sequitur, the MinAtar games, CompILE's
masked GRU); all other metadata lives in pyproject.toml.

Every core is optional: each has a Python twin (`routine_gym._native`'s doc), so an extension
that fails to build (no C++17 compiler, `CC=false CXX=false`) is skipped, the install goes on,
and the build ends by saying which cores it skipped. `docs/native.md` says what each one buys.
"""

import sys

from setuptools import Extension, setup
from setuptools.command.build_ext import build_ext


class OptionalBuildExt(build_ext):
    """`build_ext` that skips an extension it cannot build and names the skipped ones at the end.

    setuptools' own `optional=True` also skips a failed extension, but its one line of warning
    is lost in pip's output; this says which cores the Python twins stand in for.
    """

    def run(self) -> None:
        self.skipped: list[str] = []
        try:
            super().run()
        except Exception as error:  # noqa: BLE001 (no compiler at all: every core is skipped)
            self.skipped = [ext.name for ext in self.extensions]
            self._report(error)
            return
        self._report(None)

    def build_extension(self, ext: Extension) -> None:
        try:
            super().build_extension(ext)
        except Exception as error:  # noqa: BLE001 (a compiler error of any kind)
            self.skipped.append(ext.name)
            print(f"routine-gym: could not build {ext.name} ({error})", file=sys.stderr)

    def _report(self, error: Exception | None) -> None:
        if not self.skipped:
            return
        names = ", ".join(name.rsplit(".", 1)[-1].lstrip("_") for name in self.skipped)
        reason = f" ({error})" if error is not None else ""
        print(f"routine-gym: skipped the compiled cores {names}{reason}; their Python twins "
              "run instead (a C++17 compiler builds them; docs/native.md)", file=sys.stderr)


def core(name: str, depends: tuple[str, ...] = (), args: tuple[str, ...] = ("-O2",)) -> Extension:
    """The extension `routine_gym._native._NAME` from `routine_gym/_native/_NAME.cpp`."""
    return Extension(
        f"routine_gym._native._{name}",
        [f"routine_gym/_native/_{name}.cpp"],
        depends=[f"routine_gym/_native/{header}" for header in depends],
        extra_compile_args=[*args, "-std=c++17"],
        language="c++",
        optional=True,
    )


setup(
    ext_modules=[
        core("sequitur"),
        core("minatar_core", depends=("_pybuffers.h",)),
        # -O3, contracted multiply-adds and no FP traps: the loops are meant to vectorize
        # (FMA on AVX2; the σ and tanh loops' selects need -fno-trapping-math for that).
        core("masked_gru", depends=("_pybuffers.h", "_masked_gru_kernel.h"),
             args=("-O3", "-ffp-contract=fast", "-fno-trapping-math", "-Wno-psabi")),
    ],
    cmdclass={"build_ext": OptionalBuildExt},
)
