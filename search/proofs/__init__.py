"""Proofs about a forward-only car that need no search: it cannot leave a pose, and
the obstacle-blind bounds (Dubins, Reeds-Shepp) on any path's length."""
