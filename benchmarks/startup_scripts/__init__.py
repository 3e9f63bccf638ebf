"""Scripts that ``benchmarks/startup.py`` runs in new processes (each is also a plain example)."""
