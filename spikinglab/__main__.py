"""`python -m spikinglab <command>`, the same as the `spikinglab` console script."""

from spikinglab.cli import main

main()
