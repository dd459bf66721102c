"""One BLAS thread in the project's node executables, unless the user set it.

Imported first by the entry points (``planner``, ``tracker``, ``recorder``, ``replay``),
before numpy and CasADi load their BLAS: the solves factor small banded and sparse
matrices, where BLAS threads only cost (docs/speed.md, "BLAS threads"). A Python process of
a user's own that imports the package is not touched.
"""

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
