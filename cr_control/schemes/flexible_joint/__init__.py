"""Chapter 6: constrained flexible-joint robots."""
