"""The world a plan lives in: occupancy maps, the car's footprint, the validity
checker, the built-in scenarios and the query files (with their data folders)."""
