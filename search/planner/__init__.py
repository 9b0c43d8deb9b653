"""The planner core of the paper: PathFinder's best-first tree growth, expansion by
shooting towards selected points, the connection (its OCP), termination and status."""
