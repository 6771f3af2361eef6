"""numba's cache of compiled kernels: one folder per version of the sources (services/kernel_cache.py)."""

import os
import shutil
import subprocess
import sys
import tempfile
import textwrap
import time
from pathlib import Path

from numba.core import config

from services.kernel_cache import cache_roots, kernel_sources, prune, sources_digest, use_cache_folder

REPO = Path(__file__).parents[1]
INLINED = "from numba import njit\n\n@njit(inline='always')\ndef value():\n    return {}\n"
CACHED = textwrap.dedent(
    """
    from numba import njit
    from pkg.a import value

    @njit(cache=True)
    def read():
        return value()

    print(read())
    """
)
FOLDER_PER_VERSION = textwrap.dedent(
    """
    import os
    from pathlib import Path
    from services.kernel_cache import cache_roots, sources_digest
    os.environ["NUMBA_CACHE_DIR"] = str(cache_roots(None)[0] / sources_digest(Path(__file__).parent))
    """
)
NUMBA_ALONE = "import services  # its own folder, which pkg's sources do not name\n"


def numba_cache_dir() -> str:
    return config.CACHE_DIR  # pyright: ignore[reportAttributeAccessIssue] (from the environment)


def run_package(tmp_path) -> str:
    env = os.environ | {"XDG_CACHE_HOME": str(tmp_path / "cache"), "PYTHONPATH": f"{tmp_path}:{REPO}"}
    env.pop("NUMBA_CACHE_DIR", None)
    done = subprocess.run([sys.executable, "-m", "pkg.b"], cwd=tmp_path, env=env, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    return done.stdout.strip()


def value_after_a_change(tmp_path, init: str) -> str:
    """pkg.b's kernel inlines pkg.a's value(): run it, change value() from 1 to 2, run it again."""
    (tmp_path / "pkg").mkdir()
    (tmp_path / "pkg" / "__init__.py").write_text(init)
    (tmp_path / "pkg" / "b.py").write_text(CACHED)
    (tmp_path / "pkg" / "a.py").write_text(INLINED.format(1))
    assert run_package(tmp_path) == "1"
    (tmp_path / "pkg" / "a.py").write_text(INLINED.format(2))
    return run_package(tmp_path)


def test_numba_alone_loads_a_kernel_compiled_against_an_inlined_functions_old_source(tmp_path):
    """What services/kernel_cache.py is for: numba checks b.py only. (Should numba ever check the
    inlined function's file too, this fails, and the folder per version is no longer needed.)"""
    assert value_after_a_change(tmp_path, NUMBA_ALONE) == "1"


def test_a_folder_per_version_compiles_again_when_only_an_inlined_function_changes(tmp_path):
    assert value_after_a_change(tmp_path, FOLDER_PER_VERSION) == "2"
    folders = {p.name for p in (tmp_path / "cache" / "spikinglab" / "numba").iterdir()} - {sources_digest()}
    assert len(folders) == 2  # one per version of pkg (services, imported by pkg, has its own)


def test_the_digest_follows_names_and_contents_of_what_kernels_can_depend_on(tmp_path):
    (tmp_path / "a.py").write_text("import numba\nfrom .b import x\n")
    (tmp_path / "b.py").write_text("x = 1\n")  # a constant a kernel would freeze
    (tmp_path / "c.py").write_text("y = 1\n")  # as a service's options: no kernel's module imports it
    first = sources_digest(tmp_path)
    assert sources_digest(tmp_path) == first
    (tmp_path / "c.py").write_text("y = 2\n")
    assert sources_digest(tmp_path) == first
    (tmp_path / "b.py").write_text("x = 2\n")
    changed = sources_digest(tmp_path)
    (tmp_path / "a.py").rename(tmp_path / "d.py")
    assert len({first, changed, sources_digest(tmp_path)}) == 3


def test_the_kernels_depend_on_the_engine_and_the_world_not_on_the_services_around_them():
    sources = set(kernel_sources(REPO / "services"))
    assert {Path("brain/engine.py"), Path("brain/stdp.py"), Path("loop.py"), Path("world/world.py")} <= sources
    assert {Path("params.py"), Path("vocabulary.py"), Path("brain/__init__.py")} <= sources  # imported by them
    assert not {Path("options.py"), Path("run.py"), Path("bus/transport.py"), Path("brain/service.py")} & sources


def test_the_roots_in_order(tmp_path, monkeypatch):
    temp = Path(tempfile.gettempdir()) / f"spikinglab-numba-{os.getuid()}"
    assert cache_roots(str(tmp_path)) == [tmp_path / "spikinglab", temp]
    inherited = tmp_path / "spikinglab" / "0123456789abcdef"  # a version's folder: its root
    assert cache_roots(str(inherited)) == [tmp_path / "spikinglab", temp]
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert cache_roots(None) == [tmp_path / "xdg" / "spikinglab" / "numba", temp]


def test_an_unwritable_root_falls_back_to_the_temporary_folder(tmp_path, monkeypatch):
    blocked = tmp_path / "a-file"
    blocked.write_text("")
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(blocked))  # restored after the test
    monkeypatch.setattr(config, "CACHE_DIR", numba_cache_dir())
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path / "tmp"))
    folder = use_cache_folder()
    assert folder == tmp_path / "tmp" / f"spikinglab-numba-{os.getuid()}" / sources_digest()
    assert folder is not None and folder.is_dir() and numba_cache_dir() == os.environ["NUMBA_CACHE_DIR"] == str(folder)


def test_hidden_and_unreadable_files_do_not_stop_the_digest(tmp_path):
    (tmp_path / "a.py").write_text("x = 1\n")
    first = sources_digest(tmp_path)
    (tmp_path / ".#a.py").symlink_to(tmp_path / "gone")  # an editor's lock file, dangling
    assert sources_digest(tmp_path) == first
    (tmp_path / "b.py").symlink_to(tmp_path / "gone-too")
    assert sources_digest(tmp_path) != first


def test_services_compile_into_this_versions_folder():
    """Here, and in a child process (which inherits the setting) that imports numba first."""
    import services.brain.engine as engine

    folder = numba_cache_dir()
    assert os.path.basename(folder) == sources_digest() and os.environ["NUMBA_CACHE_DIR"] == folder
    kernel_cache = engine._netlogo_serial._cache  # pyright: ignore[reportAttributeAccessIssue] (numba's)
    assert kernel_cache._cache_path.startswith(folder)
    child = subprocess.run(
        [sys.executable, "-c", "import numba, services; print(numba.config.CACHE_DIR)"],
        capture_output=True,
        text=True,
        check=True,
    )
    assert child.stdout.strip() == folder


def test_prune_deletes_only_other_versions_unused_for_days(tmp_path):
    old, recent, other = tmp_path / "00000000000000aa", tmp_path / "00000000000000bb", tmp_path / "not-a-version"
    for folder in (old, recent, other):
        folder.mkdir()
    ten_days_ago = time.time() - 10 * 86400
    for folder in (old, other):
        os.utime(folder, (ten_days_ago, ten_days_ago))
    prune(tmp_path, 7)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["00000000000000bb", "not-a-version"]


def test_every_kernel_a_large_world_and_brain_use_is_cached():
    """numba refuses to cache a kernel that reads a global such as get_num_threads() (a warning,
    once); every world process then compiled its kernels anew, about 3 s each start."""
    import importlib
    import pkgutil

    import numpy as np
    from numba.core.caching import NullCache
    from numba.core.registry import CPUDispatcher

    import services
    from services.brain.circuit import load_circuit
    from services.brain.engine import Engine
    from services.params import PARALLEL_FROM
    from services.world.world import ACTIONS, World

    world = World(seed=1, agents=PARALLEL_FROM)
    world.sense()
    world.act(np.zeros((PARALLEL_FROM, len(ACTIONS)), np.uint8))
    Engine(load_circuit("insect"), agents=PARALLEL_FROM, semantics="netlogo").step()
    used = {}
    for info in pkgutil.walk_packages(services.__path__, "services."):
        if info.name.startswith(("services.gpu", "services.ev3_gateway")) or info.name.endswith("__main__"):
            continue  # the device's kernels; the robot's optional packages; a process's start
        module = importlib.import_module(info.name)
        for name, value in vars(module).items():
            cache = getattr(value, "_cache", None)  # numba's
            if isinstance(value, CPUDispatcher) and value.overloads and not isinstance(cache, NullCache):
                used[f"{info.name}.{name}"] = cache._cache_file._index_path  # pyright: ignore[reportOptionalMemberAccess]
    assert "services.world.world._sense_parallel" in used and "services.brain.engine._netlogo_parallel" in used
    assert [name for name, index in used.items() if not os.path.exists(index)] == []
    by_place = Path(numba_cache_dir()) / f"services-numpy{np.__version__}"  # services/kernel_locator.py
    assert [name for name, index in used.items() if not Path(index).is_relative_to(by_place)] == []


TWO_KERNELS = textwrap.dedent(
    """
    import services.kernels  # what the engine and the world import
    from numba import njit

    @njit(cache=True)
    def double(n):
        return 2 * n

    @njit(cache=True)
    def half(n):
        return n / 2

    @njit  # never cached: compiled in every run, and nothing said of it
    def third(n):
        return n / 3

    print(third(3), double(3), half(3))
    """
)


def test_a_process_says_once_that_it_compiles_and_nothing_when_the_cache_holds_its_kernels(tmp_path):
    (tmp_path / "two.py").write_text(TWO_KERNELS)
    env = os.environ | {"NUMBA_CACHE_DIR": str(tmp_path / "cache"), "PYTHONPATH": str(REPO)}

    def stderr_of_a_run() -> str:
        done = subprocess.run(
            [sys.executable, "two.py"], cwd=tmp_path, env=env, capture_output=True, text=True, timeout=120
        )
        assert done.returncode == 0 and done.stdout == "1.0 6 1.5\n", done.stderr
        return done.stderr

    first = stderr_of_a_run()
    assert first.count("compiling numba kernels: minutes the first time this version") == 1, first
    assert str(tmp_path / "cache" / "spikinglab") in first  # where they are kept
    assert stderr_of_a_run() == ""  # both loaded from the cache; the third compiled again, unsaid


def test_a_copy_of_the_sources_elsewhere_loads_the_kernels_this_checkout_compiled(tmp_path):
    """numba keyed a kernel's cache files by the absolute path of its source folder: a second clone,
    a CI checkout or an installed wheel compiled every kernel again (minutes) into the same folder."""
    copy = tmp_path / "elsewhere"
    shutil.copytree(  # files of new times, as in a clone
        REPO / "services",
        copy / "services",
        ignore=shutil.ignore_patterns("__pycache__", ".*"),
        copy_function=shutil.copy,
    )
    env = os.environ | {"NUMBA_CACHE_DIR": str(tmp_path / "cache")}
    draw = "import services, numpy as np; from services.brain.engine import order_draw; "
    draw += "print(services.__file__, order_draw(np.uint64(12345), 8))"

    def run_from(root: Path) -> subprocess.CompletedProcess:
        done = subprocess.run(
            [sys.executable, "-c", draw], cwd=root, env=env | {"PYTHONPATH": str(root)}, capture_output=True, text=True
        )
        assert done.returncode == 0, done.stderr
        return done

    here, there = run_from(REPO), run_from(copy)
    assert "compiling numba kernels" in here.stderr  # an empty cache
    assert there.stdout.split()[0] == str(copy / "services" / "__init__.py")
    assert there.stdout.split()[1:] == here.stdout.split()[1:]
    assert there.stderr == ""  # loaded what the checkout compiled
