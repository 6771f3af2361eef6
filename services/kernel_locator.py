"""numba's cache locator for the CPU kernels of services/: their cache files named by their place in
the package, not by the folder the package lies in, so every copy of one version of the sources (a
second clone, a CI checkout, an installed wheel) loads the kernels another copy compiled, where
numba's own locator keys them by the source folder's absolute path and compiles again for minutes.
A cached kernel is checked against a hash of its source file's contents, as numba 0.68 checks it
(0.62 to 0.65 check the file's time, which a copy does not share); the folder is this version's
(services/kernel_cache.py) and the numpy it was compiled against. numba-cuda's kernels keep its own
locators (by path)."""

from __future__ import annotations

import functools
import hashlib
import os
from pathlib import Path

import numpy as np
from numba.core import caching

from services.kernel_cache import SOURCES

PACKAGE = SOURCES.resolve()


def register() -> None:
    """First in numba's list of locators for this process: before the modules of services/ define
    their kernels (services/kernels.py, which they import, calls this). A list the user gives in
    NUMBA_CACHE_LOCATOR_CLASSES replaces numba's and this one."""
    if SourcesLocator not in caching.CacheImpl._locator_classes:
        caching.CacheImpl._locator_classes.insert(0, SourcesLocator)


class SourcesLocator(caching.UserProvidedCacheLocator):
    """A function of services/ caches in <numba's cache folder>/services-numpy<version>/<its
    subpackage>; for any other function, or where that folder cannot be written, numba tries its
    own locators after this one."""

    @classmethod
    def get_suitable_cache_subpath(cls, py_file):  # numba's __init__ puts it under its cache folder
        place = Path(py_file).resolve().parent.relative_to(PACKAGE)
        return os.path.join(f"{PACKAGE.name}-numpy{np.__version__}", *place.parts)

    def get_source_stamp(self):
        st = os.stat(self._py_file)
        return _contents_hash(self._py_file, st.st_mtime, st.st_size)

    @classmethod
    def from_function(cls, py_func, py_file):  # numba's: None without a cache folder, or one not writable
        if Path(py_file).resolve().is_relative_to(PACKAGE):
            return super().from_function(py_func, py_file)
        return None


@functools.cache
def _contents_hash(path: str, mtime: float, size: int) -> bytes:
    """Read again where the file changed (its time and size are in the key)."""
    return hashlib.sha256(Path(path).read_bytes()).digest()
