"""The ground floor: plumbing every layer may use (argument checks, seeding, atomic file writes, signal handling,
torch threads). Nothing here imports another module of this package outside ``utils``."""
