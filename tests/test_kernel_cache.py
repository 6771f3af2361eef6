"""numba's cache of compiled kernels: one folder per version of the sources (services/kernel_cache.py)."""

import os
import subprocess
import sys
import textwrap
import time

import numba

from services.kernel_cache import cache_folder, prune, sources_digest

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
INIT = textwrap.dedent(
    """
    import os
    from pathlib import Path
    from services.kernel_cache import cache_folder, sources_digest
    folder = cache_folder(None, sources_digest(Path(__file__).parent))
    os.environ["NUMBA_CACHE_DIR"] = str(folder)
    """
)


def run_package(tmp_path) -> str:
    env = os.environ | {"XDG_CACHE_HOME": str(tmp_path / "cache"), "PYTHONPATH": f"{tmp_path}:{os.getcwd()}"}
    env.pop("NUMBA_CACHE_DIR", None)
    done = subprocess.run([sys.executable, "-m", "pkg.b"], cwd=tmp_path, env=env, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    return done.stdout.strip()


def test_a_kernel_is_compiled_again_when_only_a_function_it_inlines_changes(tmp_path):
    """numba alone would load b's kernel compiled against a's old value (it checks b.py only)."""
    (tmp_path / "pkg").mkdir()
    (tmp_path / "pkg" / "__init__.py").write_text(INIT)
    (tmp_path / "pkg" / "b.py").write_text(CACHED)
    (tmp_path / "pkg" / "a.py").write_text(INLINED.format(1))
    assert run_package(tmp_path) == "1"
    (tmp_path / "pkg" / "a.py").write_text(INLINED.format(2))
    assert run_package(tmp_path) == "2"
    folders = {p.name for p in (tmp_path / "cache" / "spikinglab" / "numba").iterdir()} - {sources_digest()}
    assert len(folders) == 2  # one per version of pkg (services, imported by pkg, has its own)


def test_the_digest_follows_names_and_contents(tmp_path):
    (tmp_path / "a.py").write_text("x = 1\n")
    first = sources_digest(tmp_path)
    assert sources_digest(tmp_path) == first
    (tmp_path / "a.py").write_text("x = 2\n")
    changed = sources_digest(tmp_path)
    (tmp_path / "a.py").rename(tmp_path / "b.py")
    assert len({first, changed, sources_digest(tmp_path)}) == 3


def test_the_folder_is_under_numba_cache_dir_once(tmp_path):
    assert cache_folder(str(tmp_path), "0123456789abcdef") == tmp_path / "0123456789abcdef"
    inherited = tmp_path / "0123456789abcdef"
    assert cache_folder(str(inherited), "0123456789abcdef") == inherited  # a child process's setting


def test_services_compile_into_this_versions_folder():
    """In this process (numba imported before services) and in a fresh one (after)."""
    import services.brain.engine as engine

    folder = numba.config.CACHE_DIR
    assert os.path.basename(folder) == sources_digest()
    assert engine._netlogo_serial._cache._cache_path.startswith(folder)
    fresh = subprocess.run(
        [sys.executable, "-c", "import services, numba; print(numba.config.CACHE_DIR)"],
        capture_output=True,
        text=True,
        check=True,
    )
    assert fresh.stdout.strip() == folder


def test_prune_deletes_only_other_versions_unused_for_days(tmp_path):
    old, recent, other = tmp_path / "00000000000000aa", tmp_path / "00000000000000bb", tmp_path / "not-a-version"
    for folder in (old, recent, other):
        folder.mkdir()
    ten_days_ago = time.time() - 10 * 86400
    for folder in (old, other):
        os.utime(folder, (ten_days_ago, ten_days_ago))
    prune(tmp_path, 7)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["00000000000000bb", "not-a-version"]
