"""How well a run tracks: scoring against the emulator's truth, families of random lines,
and the baseline tracker every number stands beside."""
