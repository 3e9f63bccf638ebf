"""Beyond one process: many independent problems on Dask (``fgopt[distributed]``).

``solve_many(problems)`` solves ``(graph, initial)`` pairs or problem-building callables on a
Dask cluster (an embedded ``LocalCluster`` by default); ``solve_files`` is ``fgopt solve-many``.
"""

from .files import solve_files as solve_files
from .files import summary_table as summary_table
from .many import solve_many as solve_many

#: The public names (each has an entry in the API reference: tests/test_docs_reference.py).
__all__ = ["solve_files", "summary_table", "solve_many"]
