"""Plan-bench: a query set planned with several integrators (engine), its results
folder, the integrators compared, OMPL's log format and the fastest faithful choice."""
