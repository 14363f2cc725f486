"""The pipeline's services, each a pure core and a thin bus shell."""

import common  # noqa: F401  (points numba's cache at this version of the kernels: common/numba_cache.py)
