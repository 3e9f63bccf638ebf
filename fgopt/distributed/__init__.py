"""Beyond one process: many independent problems on Dask (``fgopt[distributed]``).

``solve_many(problems)`` solves ``(graph, initial)`` pairs or problem-building callables on a
Dask cluster (an embedded ``LocalCluster`` by default); ``solve_files`` is ``fgopt solve-many``.
"""

from .files import solve_files as solve_files
from .files import summary_table as summary_table
from .many import solve_many as solve_many
