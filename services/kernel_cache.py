"""Where numba keeps compiled kernels on disk: a folder of their own for each version of the sources.

numba checks a cached kernel against the source file of the function it compiled, not against the
files of the functions inlined into it. services/loop.py's fused loop inlines the engine of
services/brain/engine.py, so after a change to engine.py alone numba would load a loop compiled
against the old engine, with the old engine's results. Kernels are therefore cached in a folder
named after a hash of every source file of services/: `<root>/<hash>`, where the root is
$NUMBA_CACHE_DIR/spikinglab when that is set, else $XDG_CACHE_HOME/spikinglab/numba (by default
~/.cache/spikinglab/numba), else, where neither can be written, one in the temporary folder. Any
change to the sources starts an empty folder. Setting numba's cache folder is process-wide: other
numba code in the same process caches there too."""

from __future__ import annotations

import os
import re
import shutil
import sys
import tempfile
import time
from hashlib import blake2b
from pathlib import Path

SOURCES = Path(__file__).parent
KEEP_DAYS = 7  # other versions' folders unused this long are deleted when a new one is made
DIGEST = re.compile(r"[0-9a-f]{16}")  # sources_digest()'s names


def sources_digest(root: Path = SOURCES) -> str:
    """A hash of the names and contents of the .py files under `root` (hidden ones, such as an
    editor's lock files, left out; an unreadable one counts by its name)."""
    digest = blake2b(digest_size=8)
    for path in sorted(root.rglob("*.py")):
        relative = path.relative_to(root)
        if any(part.startswith(".") for part in relative.parts):
            continue
        try:
            content = path.read_bytes()
        except OSError:
            content = b"unreadable"
        digest.update(relative.as_posix().encode() + b"\0" + content)
    return digest.hexdigest()


def cache_roots(numba_cache_dir: str | None) -> list[Path]:
    """Where the folders of all versions go, in order of preference. A $NUMBA_CACHE_DIR that is
    already a version's folder (a child process inherits its parent's setting) names its root."""
    roots = []
    if numba_cache_dir:
        given = Path(numba_cache_dir).absolute()
        roots.append(given.parent if DIGEST.fullmatch(given.name) else given / "spikinglab")
    else:
        try:
            home_cache = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
            roots.append(home_cache / "spikinglab" / "numba")
        except RuntimeError:  # no home folder
            pass
    return roots + [Path(tempfile.gettempdir()) / f"spikinglab-numba-{os.getuid()}"]


def use_cache_folder() -> Path | None:
    """Point numba's cache at this version's folder in the first root that can be written:
    through the environment before numba is imported (child processes inherit it), or through
    numba's config after. None where no root can be written; numba then caches beside the sources,
    where a change to an inlined function alone goes unseen."""
    digest = sources_digest()
    for root in cache_roots(os.environ.get("NUMBA_CACHE_DIR")):
        folder = root / digest
        try:
            if not folder.exists():
                prune(root, KEEP_DAYS)
            folder.mkdir(parents=True, exist_ok=True)
            os.utime(folder)  # in use: not pruned
        except OSError:
            continue
        os.environ["NUMBA_CACHE_DIR"] = str(folder)
        if "numba" in sys.modules:  # numba read its environment when it was imported
            from numba.core import config

            config.CACHE_DIR = str(folder)  # pyright: ignore[reportAttributeAccessIssue] (from the environment)
        return folder
    return None


def prune(root: Path, days: float) -> None:
    """Delete the folders of other source versions under `root` unused for `days`."""
    if not root.is_dir():
        return
    cutoff = time.time() - days * 86400
    for old in root.iterdir():
        try:
            if DIGEST.fullmatch(old.name) and old.is_dir() and old.stat().st_mtime < cutoff:
                shutil.rmtree(old, ignore_errors=True)
        except OSError:
            pass
