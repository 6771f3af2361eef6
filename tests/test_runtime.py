"""services/runtime.py: what every service process does at its start and end."""

from .processes import endpoint, finish, start


def test_a_service_traced_by_python_says_at_its_end_what_its_python_objects_hold(tmp_path, monkeypatch):
    """PYTHONTRACEMALLOC=1 splits a process's memory: what Python objects (numpy's arrays among
    them) hold, and by difference from its RSS, what native code does (docs/results.md, Soak)."""
    monkeypatch.setenv("PYTHONTRACEMALLOC", "1")  # the services inherit it
    world_ep, brain_ep = endpoint(tmp_path, "world"), endpoint(tmp_path, "brain")
    world = start("world", "--listen", world_ep, "--ticks", "300", log=tmp_path / "world.log")
    brain = start("brain", "--listen", brain_ep, "--connect", world_ep, "--once", log=tmp_path / "brain.log")
    assert finish(world, 180, tmp_path / "world.log") == 0
    assert finish(brain, 60, tmp_path / "brain.log") == 0
    for name in ("world", "brain"):
        log = (tmp_path / f"{name}.log").read_text()
        assert f"{name} INFO Python heap at the end: " in log and " MB held (peak " in log, log[-2000:]
