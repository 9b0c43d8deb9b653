"""A plan as files and as evidence: plan.json and its schema, path measures, the
open-loop replay, and the socket protocol of `stepzoo plan --server`."""
