"""Chapter 2: a robot constrained by an object carried by another manipulator (closed chain)."""
