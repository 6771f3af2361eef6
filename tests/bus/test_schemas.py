"""Message schemas: round trips, and strict rejection of everything malformed."""

import msgspec
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from services.bus import keys
from services.bus.schemas import (
    VERSION,
    Array,
    BusError,
    Control,
    Sensors,
    decode,
    encode,
)
from spikinglab.bench.fuzz import examples

GOOD = examples()


@pytest.mark.parametrize("message", GOOD, ids=lambda m: type(m).__name__)
def test_round_trip(message):
    back = decode(encode(message), type(message))
    assert back == message and back.version == VERSION


def test_arrays_come_back_exactly():
    values = np.array([[0.2, np.nan, 3.0000000000000004]])
    m = decode(encode(Sensors(tick=0, names=("a", "b", "c"), values=Array.of(values))), Sensors)
    assert isinstance(m, Sensors)
    np.testing.assert_array_equal(m.values.numpy("values", "<f8", 2), values)


raw = msgspec.msgpack.Encoder().encode
sensors_dict = {
    "kind": "sensors",
    "tick": 1,
    "version": VERSION,
    "names": ["a"],
    "values": {"dtype": "<f8", "shape": [1, 1], "data": np.zeros(1).tobytes()},
}


@pytest.mark.parametrize(
    "payload,reason",
    [
        (encode(GOOD[0])[:-5], "not a message: Input data was truncated"),
        (b"\x00\x01garbage", "invalid message"),
        (raw({**sensors_dict, "version": VERSION + 1}), f"schema version {VERSION + 1}, this program speaks {VERSION}"),
        (raw({**sensors_dict, "kind": "teleport"}), "invalid message"),
        (raw({k: v for k, v in sensors_dict.items() if k != "values"}), "missing required field `values`"),
        (raw({**sensors_dict, "tick": "soon"}), "Expected `int`, got `str` - at `$.tick`"),
        (
            raw({**sensors_dict, "values": {"dtype": "<f4", "shape": [1, 1], "data": b"1234"}}),
            "values: dtype '<f4', expected '<f8'",
        ),
        (
            raw({**sensors_dict, "values": {"dtype": "<f8", "shape": [1, 1], "data": b"1234"}}),
            "values: 4 bytes do not hold shape [1, 1]",
        ),
        (
            raw({**sensors_dict, "values": {"dtype": "<f8", "shape": [1, 2], "data": np.zeros(2).tobytes()}}),
            "values has 2 columns for 1 sensor names",
        ),
        (encode(GOOD[1]), "a Motor message where Sensors/Control was expected"),
        (encode(Control(tick=1, command="dance")), "unknown control command 'dance'"),
    ],
)
def test_malformed_messages_are_rejected_with_the_reason(payload, reason):
    with pytest.raises(BusError) as err:
        decode(payload, (Sensors, Control))
    assert reason in str(err.value)


def test_a_message_of_another_version_is_named_so_even_when_its_fields_do_not_decode():
    """A version-7 sensors message lacks fields this version requires: the version is the reason,
    not the first missing field; a message of this version missing the same field keeps that reason."""
    old = {k: v for k, v in sensors_dict.items() if k != "names"}
    with pytest.raises(BusError, match=f"^schema version 7, this program speaks {VERSION}$"):
        decode(raw({**old, "version": 7}), (Sensors, Control))
    with pytest.raises(BusError, match="^invalid message: Object missing required field `names`$"):
        decode(raw(old), (Sensors, Control))


def test_keys():
    assert keys.sensors("insect") == "spikinglab/insect/sensors"
    assert keys.alive("pop7", "brain") == "spikinglab/pop7/alive/brain"
    for bad in ("a/b", "*", "", "x y"):
        with pytest.raises(ValueError, match="one key segment"):
            keys.motor(bad)


SENSED = st.one_of(st.just(np.nan), st.floats(allow_nan=False), st.sampled_from([0.0, -0.0, 2.0**31, 2.0**31 - 1]))


@settings(max_examples=200, deadline=None)
@given(st.lists(SENSED, min_size=5, max_size=5), st.integers(1, 3))
def test_sensor_values_are_checked_alike_for_few_agents_and_many(row, agents):
    """A reading of a few agents is range-checked in plain Python, one of many with numpy (the
    lock-step tick's reading is small): both take exactly the values in [0, 2**31) or NaN."""
    ok = all(np.isnan(x) or 0 <= x < 2**31 for x in row)
    for n in (agents, 100 * agents):  # below and above the plain-Python path's size
        message = Sensors(tick=1, names=tuple("abcde"), values=Array.of(np.array([row] * n)))
        if ok:
            assert decode(encode(message), Sensors) == message
        else:
            with pytest.raises(BusError, match="a sensor value outside"):
                decode(encode(message), Sensors)


def test_an_array_viewed_encodes_as_one_copied():
    """Array.view (the lock-step sensors, not copied) puts the same bytes on the bus as Array.of,
    for an array in place, a strided slice and a big-endian one (those two copied), and reads the
    array's memory as it is when encoded."""
    values = np.arange(20, dtype="<f8").reshape(4, 5)
    for a in (values, values[:, 1:3], values.astype(">f8"), values[1:3]):
        assert encode(Sensors(tick=1, names=("a",), values=Array.view(a))) == encode(
            Sensors(tick=1, names=("a",), values=Array.of(a))
        )
    viewed = Array.view(values)
    values[0, 0] = 99.0
    back = decode(encode(Sensors(tick=1, names=tuple("abcde"), values=viewed)), Sensors)
    assert isinstance(back, Sensors) and back.values.numpy("values", "<f8", 2)[0, 0] == 99.0
