"""What every PoseidonSLAM service shares: messages, codec, bus, event-time ordering,
configuration and MCAP recordings."""
import os as _os
from pathlib import Path as _Path

# numba's on-disk cache needs a writable folder; the package folder may not be one.
_os.environ.setdefault("NUMBA_CACHE_DIR", str(_Path.home() / ".cache" / "poseidonslam" / "numba"))
