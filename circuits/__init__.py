"""The circuit files shipped with spikinglab (package data): insect, conditioning, association, two_actions."""
