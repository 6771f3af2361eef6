"""`spikinglab bench robot`'s estimate of how long it takes, said before its runs start."""

from spikinglab.bench.robot import in_words


def test_a_wait_under_a_minute_is_said_in_seconds_and_longer_ones_in_minutes():
    assert in_words(20) == "20 seconds"  # --seconds 10 --seeds 1: two rounds of 10 s, not "0 minutes"
    assert in_words(1) == "1 second"
    assert in_words(59.4) == "59 seconds"
    assert in_words(60) == "1 minute"
    assert in_words(2 * 120) == "4 minutes"  # the default: six runs of 120 s, two at a time
