"""The default envelope sweep, split as its manifest reports it (compile per method,
reference, integration, stability, metrics), and the raw driver time of the same
integrations: every accuracy call the sweep makes is recorded and replayed, compiled."""
import sys
from pathlib import Path
from time import perf_counter

import jax

from stepzoo import integrators
from stepzoo.bench import sweep, sweep_config

ENVELOPE = Path(sweep.__file__).parent / "configs" / "envelope.toml"


def test_envelope_sweep(benchmark, tmp_path, monkeypatch):
    calls = []
    plain = integrators.integrate_batch

    def recording(*args, **kwargs):
        # Only the accuracy runs are charged to the sweep's integration_s.
        if sys._getframe(2).f_code.co_name == "_accuracy_runs":
            calls.append((args, kwargs))
        return plain(*args, **kwargs)

    monkeypatch.setattr(integrators, "integrate_batch", recording)
    cfg = sweep_config.load(ENVELOPE)
    manifest = benchmark.pedantic(
        lambda: sweep.run_sweep(cfg, tmp_path / "sweep", overwrite=True, progress=False),
        rounds=1)
    driver_s = 0.0
    for args, kwargs in calls:
        t0 = perf_counter()
        jax.block_until_ready(plain(*args, **kwargs).x)
        driver_s += perf_counter() - t0
    benchmark.extra_info.update(kind="sweep", timing=manifest["timing"], calls=len(calls),
                                driver_s=driver_s)
