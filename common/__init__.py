"""Messages, configuration and the pieces every service shares."""

from common.numba_cache import use_versioned_cache

use_versioned_cache()
