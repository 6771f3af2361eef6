"""The launch files shipped with spikinglab (package data): `spikinglab launch simulation` (or robot,
remote-world, remote-brain) runs one; `spikinglab launch --list` names them."""
