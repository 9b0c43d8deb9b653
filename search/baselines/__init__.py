"""Planners that stepzoo's PathFinder is compared with, on the same map, car and collision
check: Hybrid A* (hybrid_astar)."""
