import os

# numba's on-disk cache (cache=True kernels) needs a writable directory
os.environ.setdefault("NUMBA_CACHE_DIR", "/tmp/numba_cache")
