"""`stepzoo sweep CONFIG --out DIR`: the stability/accuracy sweep of a config into a results
folder (tables in Parquet, summaries in CSV), resumable chunk by chunk."""
from stepzoo.workflows.sweep import show, sweep


def add_arguments(p):
    p.add_argument("config", metavar="CONFIG", help="sweep TOML (see bench/configs/)")
    p.add_argument("--out", required=True, metavar="DIR", help="results folder")
    p.add_argument("--resume", action="store_true",
                   help="skip the chunks DIR already holds (same config only)")
    p.add_argument("--overwrite", action="store_true", help="discard what DIR holds first")
    p.add_argument("--scheduler", metavar="ADDRESS", help="compute the chunks on a Dask "
                   "cluster: tcp://HOST:8786, or local:N worker processes here (needs "
                   "stepzoo[distributed])")
    p.add_argument("--format", choices=["text", "json"], default="text")


def main(args) -> int:
    manifest = sweep(args.config, args.out, resume=args.resume, overwrite=args.overwrite,
                     progress=args.progress, scheduler=args.scheduler)
    show(manifest, args.out, args.format)
    return 0
