"""Procedural worlds: seeded, batched generators that write ``World`` tensors directly."""
