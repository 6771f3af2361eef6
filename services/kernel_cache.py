"""Where numba keeps compiled kernels on disk: a folder of their own for each version of the sources.

numba checks a cached kernel against the source file of the function it compiled, not against the
files of the functions inlined into it. services/loop.py's fused loop inlines the engine of
services/brain/engine.py, so after a change to engine.py alone numba would load a loop compiled
against the old engine, with the old engine's results. Kernels are therefore cached in a folder
named after a hash of every source file of services/ (under $NUMBA_CACHE_DIR when that is set,
else ~/.cache/spikinglab/numba), and any change to the sources starts an empty one."""

from __future__ import annotations

import os
import shutil
import sys
import time
from hashlib import blake2b
from pathlib import Path

SOURCES = Path(__file__).parent
KEEP_DAYS = 7  # other versions' folders unused this long are deleted when a new one is made


def sources_digest(root: Path = SOURCES) -> str:
    """A hash of the names and contents of every .py file under `root`."""
    digest = blake2b(digest_size=8)
    for path in sorted(root.rglob("*.py")):
        digest.update(path.relative_to(root).as_posix().encode() + b"\0" + path.read_bytes())
    return digest.hexdigest()


def cache_folder(base: str | None, digest: str) -> Path:
    """The folder for these sources' kernels under `base` ($NUMBA_CACHE_DIR or None); `base` is
    the folder itself when it already is one (a child process inherits its parent's setting)."""
    root = (
        Path(base)
        if base
        else Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "spikinglab" / "numba"
    )
    return root if root.name == digest else root / digest


def use_cache_folder() -> Path:
    """Point numba's cache at this version's folder: through the environment before numba is
    imported (child processes inherit it), or through numba's config after."""
    folder = cache_folder(os.environ.get("NUMBA_CACHE_DIR"), sources_digest())
    if not folder.exists():
        prune(folder.parent, KEEP_DAYS)
    try:
        folder.mkdir(parents=True, exist_ok=True)
        os.utime(folder)  # in use: not pruned
    except OSError:  # numba then keeps its kernels beside the sources, or compiles them each time
        return folder
    os.environ["NUMBA_CACHE_DIR"] = str(folder)
    if "numba" in sys.modules:  # numba read its environment when it was imported
        from numba.core import config

        config.CACHE_DIR = str(folder)
    return folder


def prune(root: Path, days: float) -> None:
    """Delete the folders of other source versions under `root` unused for `days`."""
    if not root.is_dir():
        return
    cutoff = time.time() - days * 86400
    for old in root.iterdir():
        try:
            named = len(old.name) == 16 and set(old.name) <= set("0123456789abcdef")  # sources_digest()'s
            if named and old.is_dir() and old.stat().st_mtime < cutoff:
                shutil.rmtree(old, ignore_errors=True)
        except OSError:
            pass
