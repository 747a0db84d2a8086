"""Throughput benchmarks: each module is run from the repository root as ``python -m bench.<name>`` (``make bench``
runs every ``bench_*`` module) and writes ``bench/results*.json``. Speed is measured here, never asserted in tests;
the fidelity studies are in ``studies/``."""
