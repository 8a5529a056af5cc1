"""The paper's §6 benchmark suite (bunny in box, cylinder in cylinder, hourglass), measured against the reference."""
