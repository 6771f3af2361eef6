"""Where numba keeps compiled kernels on disk: a folder of their own for each version of the sources
they are compiled from.

numba checks a cached kernel against the source file of the function it compiled, not against the
files of the functions inlined into it. services/loop.py's fused loop inlines the engine of
services/brain/engine.py, so after a change to engine.py alone numba would load a loop compiled
against the old engine, with the old engine's results. Kernels are therefore cached in a folder
named after a hash of the source files they can depend on: those of services/ that import numba
and every file of services/ these import, directly or through others (a kernel sees only what its
module imports: the functions it calls and the constants frozen into it); a change to any other
file (a service's options, the bus) keeps the kernels. The folder is `<root>/<hash>`, where the
root is $NUMBA_CACHE_DIR/spikinglab when that is set, else $XDG_CACHE_HOME/spikinglab/numba (by
default ~/.cache/spikinglab/numba), else, where neither can be written, one in the temporary
folder. Inside it, a CPU kernel's files are named by its module's place in services/
(services/kernel_locator.py), so every copy of the same sources shares them. Setting numba's cache
folder is process-wide: other numba code in the same process caches there too. A process that
starts to compile a kernel for this cache says so (say_when_compiling)."""

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
NUMBA = re.compile(rb"^[ \t]*(?:import|from)[ \t]+numba\b", re.MULTILINE)
# an import statement: from SOURCE import LISTED (a line, or a parenthesised list), or import PLAIN
IMPORT = re.compile(rb"^[ \t]*(?:from[ \t]+([.\w]+)[ \t]+import[ \t]+(\([^)]*\)|[^\n]*)|import[ \t]+([^\n]*))", re.M)


def sources_digest(root: Path = SOURCES) -> str:
    """A hash of the names and contents of the .py files under `root` that kernels can depend on
    (kernel_sources; hidden ones, such as an editor's lock files, left out; an unreadable one
    counts by its name)."""
    digest = blake2b(digest_size=8)
    for relative, content in sorted(kernel_sources(root).items()):
        digest.update(relative.as_posix().encode() + b"\0" + (b"unreadable" if content is None else content))
    return digest.hexdigest()


def kernel_sources(root: Path) -> dict[Path, bytes | None]:
    """The files under `root` (a package) that import numba, and those of `root` they import,
    directly or through others, with the packages above each: {path under root: content, or None
    where unreadable (kept, as it may be either)}."""
    files: dict[Path, bytes | None] = {}
    for path in root.rglob("*.py"):
        relative = path.relative_to(root)
        if any(part.startswith(".") for part in relative.parts):
            continue
        try:
            files[relative] = path.read_bytes()
        except OSError:
            files[relative] = None
    modules = {module_name(root.name, relative): relative for relative in files}
    wanted = [
        relative
        for relative, content in files.items()
        if content is None or (b"numba" in content and NUMBA.search(content))
    ]
    kept: dict[Path, bytes | None] = {}
    while wanted:
        relative = wanted.pop()
        if relative not in kept:
            kept[relative] = files[relative]
            module = module_name(root.name, relative)
            wanted += [modules[name] for name in imported(files[relative], module, relative) if name in modules]
    return kept


def module_name(package: str, relative: Path) -> str:
    parts = [package, *relative.with_suffix("").parts]
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def imported(content: bytes | None, module: str, relative: Path) -> set[str]:
    """The modules a source imports, anywhere in it, with the packages above each (their
    __init__ runs first). Read from its import statements by pattern, not parsed: every process
    that imports services computes this, and parsing would take it 80 ms longer; a statement's
    like in a string adds a file at most."""
    package = module if relative.name == "__init__.py" else module.rpartition(".")[0]
    names: set[str] = {package}
    for source, listed, plain in IMPORT.findall(content or b""):
        if plain:
            names.update(_words(plain))
            continue
        dots = len(source) - len(source.lstrip(b"."))
        base = package.split(".")[: len(package.split(".")) - dots + 1] if dots else []
        source = ".".join([*base, *filter(None, [source.lstrip(b".").decode()])])
        names.add(source)
        names.update(f"{source}.{name}" for name in _words(listed))  # a module, or a name in one
    return {".".join(name.split(".")[:i]) for name in names for i in range(1, name.count(".") + 2)}


def _words(listed: bytes) -> list[str]:
    """The names of an import statement's list: "a.b as c, d" and "(a,\n b)" alike."""
    text = re.sub(rb"#[^\n]*", b"", listed).strip(b"()").decode(errors="replace")
    return [item.split()[0] for item in text.split(",") if item.split()]


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


def say_when_compiling() -> None:
    """Say on stderr, once, as this process begins to compile a kernel that is to be cached: numba's
    "numba:compile" event comes for such a kernel only where its cache lacks it, and the first command
    of a version of the kernels' sources on a machine compiles for minutes before its first tick.
    Kernels that are never cached (a benchmark's no-op) compile every time and say nothing."""
    from numba.core import event

    class FirstCompile(event.Listener):
        said = False

        def on_start(self, compile_event) -> None:
            details = compile_event.data or {}
            cache = getattr(details.get("dispatcher"), "_cache", None)  # numba's NullCache where it never caches
            cached = cache is not None and type(cache).__name__ != "NullCache"
            if cached and not self.said:
                self.said = True
                print(
                    ("\n" if sys.stderr.isatty() else "")  # past a progress bar's line
                    + "compiling numba kernels: minutes the first time this version of their sources runs here, "
                    + f"then kept in {os.environ.get('NUMBA_CACHE_DIR', 'the __pycache__ folders beside them')}",
                    file=sys.stderr,
                    flush=True,
                )

        def on_end(self, data) -> None:
            pass

    event.register("numba:compile", FirstCompile())


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
