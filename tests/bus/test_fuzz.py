"""No payload, however malformed, gets past a decoder as anything but a rejection, and what decodes,
the service code that takes it takes or refuses without an exception (Hypothesis; the generators
are spikinglab.bench.mutants', which `spikinglab bench fuzz` runs longer, counting the outcomes per key)."""

from __future__ import annotations

import sys

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from spikinglab import cli
from spikinglab.bench.fuzz import KINDS, SOURCES, Services
from spikinglab.bench.mutants import HEALTH_CHECKS, payloads

FUZZ = settings(max_examples=150, deadline=None, suppress_health_check=HEALTH_CHECKS)
SERVICES = Services()


def throw(batch: list[bytes]) -> None:
    for payload in batch:
        assert set(SERVICES.outcomes(payload)) <= {"rejected", "refused", "taken"}


@FUZZ
@given(st.binary(max_size=256))
def test_arbitrary_bytes(payload):
    throw([payload])


@FUZZ
@given(st.sampled_from(KINDS).flatmap(lambda kind: payloads("byte", kind)))
def test_byte_mutants_of_every_schema(batch):
    throw(batch)


@FUZZ
@given(st.sampled_from(KINDS).flatmap(lambda kind: payloads("structure", kind)))
def test_structure_mutants_of_every_schema(batch):
    throw(batch)


@FUZZ
@given(st.sampled_from(KINDS).flatmap(lambda kind: payloads("any-shape", kind)))
def test_well_formed_messages_of_any_shape_and_value(batch):
    throw(batch)


def test_the_nine_byte_message_that_killed_three_services():
    """A msgpack map whose `kind` is not valid UTF-8 (issue 12)."""
    assert set(SERVICES.outcomes(b"\x81\xa4kind\xa2\xff\xfe")) == {"rejected"}


def test_the_sources_reach_the_services():
    """The generators are worth running: real messages of each kind are taken, and the bench's
    sources are the ones tested here."""
    from services.bus.schemas import encode
    from spikinglab.bench.fuzz import examples

    assert SOURCES == ("bytes", "byte", "structure", "any-shape")
    services = Services()  # not the fuzzed ones: a forged tick 0 of another run may have restarted their brain
    for message in examples():
        assert "taken" in services.outcomes(encode(message)), type(message).__name__


def test_bench_fuzz_without_hypothesis_names_the_extra_to_install(monkeypatch, capsys):
    """On a plain install (no hypothesis) the bench says in one line what to install, and the soak
    bench, which throws the same real messages mutated, still imports."""
    monkeypatch.setitem(sys.modules, "hypothesis", None)  # `import hypothesis` fails, as where it is not installed
    for name in [n for n in sys.modules if n.startswith(("hypothesis.", "spikinglab.bench."))]:
        monkeypatch.delitem(sys.modules, name)  # imported afresh, without it
    with pytest.raises(SystemExit) as ended:
        cli.main(["bench", "fuzz", "--examples", "1"])
    assert ended.value.code == 2
    assert capsys.readouterr().err == (
        "spikinglab bench fuzz: needs hypothesis, which a plain install leaves out: pip install 'spikinglab[fuzz]'\n"
    )
    __import__("spikinglab.bench.soak")
