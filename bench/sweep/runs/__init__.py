"""The runs a sweep chunk makes: a method's batched accuracy runs, the stability
test's runs, and the figure runs (trajectories at fractions of the limit)."""
