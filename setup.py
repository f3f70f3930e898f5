"""The compiled kernels of fe_contact, Cython built at install (the rest of the
metadata is in pyproject.toml).  ``-ffp-contract=off``: no fused multiply-add, so
that results do not depend on the CPU (the numba kernels these replace did not
contract either)."""

import sys

from Cython.Build import cythonize
from setuptools import Extension, setup

FLAGS = [] if sys.platform == "win32" else ["-ffp-contract=off"]
KERNELS = [Extension(f"fe_contact.{layer}._kernels", [f"fe_contact/{layer}/_kernels.pyx"], extra_compile_args=FLAGS)
           for layer in ("linalg", "fem", "contact")]

setup(ext_modules=cythonize(KERNELS, language_level=3))
