"""No payload, however malformed, gets past a decoder as anything but a rejection, and what decodes,
the service code that takes it takes or refuses without an exception (Hypothesis; the generators
are spikinglab.bench.fuzz's, whose bench runs them longer and counts the outcomes per key)."""

from __future__ import annotations

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from spikinglab.bench.fuzz import KINDS, SOURCES, Services, payloads

FUZZ = settings(max_examples=150, deadline=None, suppress_health_check=list(HealthCheck))
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
    from spikinglab.bench.fuzz import EXAMPLES, encode

    assert SOURCES == ("bytes", "byte", "structure", "any-shape")
    services = Services()  # not the fuzzed ones: a forged tick 0 of another run may have restarted their brain
    for message in EXAMPLES:
        assert "taken" in services.outcomes(encode(message)), type(message).__name__
