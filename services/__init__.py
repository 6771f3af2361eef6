"""The processes of spikinglab, one folder each (brain, world, ev3_gateway, recorder), the bus they
share (bus/), and what more than one of them uses. The user's front is the `spikinglab` package."""
