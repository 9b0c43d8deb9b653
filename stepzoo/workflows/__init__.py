"""Workflows that combine the library's parts for the command line: the pipeline,
report assembly, tune for plans and the pipeline's second process."""
