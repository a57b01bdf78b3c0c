"""The compiled inner loops, each with a numpy twin that gives the same results (the rest of the build is
in pyproject.toml; ext-modules are declared here because setuptools' pyproject form is still experimental
and warns on every install).

`optional=True` keeps the install working where no C compiler is: the numpy path runs then. The install
itself stays quiet either way; `python -m courtloc.native_report` (run by `make`) says which path runs.
"""
from setuptools import Extension, setup

setup(ext_modules=[
    Extension("courtloc.scan._scan_kernel", ["scan/scan_kernel.c"], optional=True),
    # C99 without FMA contraction: the kernel follows the numpy fit operation by operation (tested against it).
    Extension("courtloc.localizer._fit_kernel", ["localizer/fit_kernel.c"],
              extra_compile_args=["-O2", "-std=c99", "-ffp-contract=off"], optional=True),
    # -O3 vectorises the row adds (across cells, so no cell's sum is reordered: bit-identical to numpy).
    Extension("courtloc.localizer._search_kernel", ["localizer/search_kernel.c"],
              extra_compile_args=["-O3", "-std=c99"], optional=True),
])
