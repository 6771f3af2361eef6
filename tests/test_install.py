"""spikinglab as a user installs it: a wheel built from this repository in a fresh venv, used from
another directory (no checkout on the path). The venv's packages come from the registry, or
pip's cache after the suite's own install."""

import shutil
import subprocess
import sys
import tomllib
import venv

import pytest

from .processes import ROOT


@pytest.mark.timeout(1800)  # a fresh machine downloads the dependencies (pip's own limit is 900 s)
def test_the_wheel_installs_and_runs_from_any_directory(tmp_path):
    source, dist = tmp_path / "source", tmp_path / "dist"  # a copy: the build writes build/ beside the sources
    shutil.copytree(
        ROOT,
        source,
        ignore=shutil.ignore_patterns(".*", "runs", "build", "dist", "*.egg-info", "__pycache__", "bench-results"),
    )
    subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w", dist, source],
        check=True,
        capture_output=True,
        timeout=300,
    )
    (wheel,) = dist.glob("spikinglab-*.whl")
    venv.create(tmp_path / "venv", with_pip=True)
    bin_dir = tmp_path / "venv" / "bin"
    install = subprocess.run([bin_dir / "pip", "install", "-q", wheel], capture_output=True, text=True, timeout=900)
    assert install.returncode == 0, install.stderr
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()

    def spikinglab(*args):
        done = subprocess.run(
            [bin_dir / "spikinglab", *map(str, args)], cwd=elsewhere, capture_output=True, text=True, timeout=300
        )
        assert done.returncode == 0, done.stderr
        return done

    release = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["version"]
    assert spikinglab("--version").stdout.strip() == f"spikinglab {release}"
    located = subprocess.run(
        [bin_dir / "python", "-c", "import spikinglab; print(spikinglab.__file__)"],
        cwd=elsewhere,
        capture_output=True,
        text=True,
        check=True,
    ).stdout
    assert str(tmp_path / "venv") in located  # the installed package, not the checkout
    done = spikinglab("run", "--ticks", 2000, "--quiet", "--id", "r")  # the circuit comes from the package
    run = elsewhere / "runs" / "r"
    assert (run / "summary.json").exists() and (run / "recording.rrd").exists()
    assert "learning time" in done.stdout
    spikinglab("conditioning", "--out", elsewhere / "figs")
    assert (elsewhere / "figs" / "fig2.png").exists()
    spikinglab("bench", "engine", "--help")
    spikinglab("gateway", "--help")
    fuzz = subprocess.run(  # its generators need hypothesis, which a plain install leaves out
        [bin_dir / "spikinglab", "bench", "fuzz", "--examples", "1"], cwd=elsewhere, capture_output=True, text=True
    )
    assert (fuzz.returncode, fuzz.stderr) == (
        2,
        "spikinglab bench fuzz: needs hypothesis, which a plain install leaves out: pip install 'spikinglab[fuzz]'\n",
    )
    shipped = spikinglab("launch", "--list").stdout  # the launch files come from the package too
    assert all(name in shipped for name in ("simulation", "robot", "remote-world", "remote-brain"))
    assert str(tmp_path / "venv") in shipped
