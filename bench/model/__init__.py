"""A model as the sweep sees it (TOML spec, CasADi source) and what is read off its
right-hand side and Jacobian: non-finite and non-smooth points, the frozen-Jacobian limits."""
