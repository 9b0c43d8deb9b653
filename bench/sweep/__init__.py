"""The sweep engine: a config's (method, h, operating point) grid in chunks, its
references, runs, limit search and tables, and the results folder it writes."""
