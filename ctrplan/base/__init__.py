"""The base layer: errors, YAML and CSV with line numbers, memory, the machine, worker pools.

Errors (`errors`), YAML with line numbers (`yamlio`), CSV
tables and atomic writes (`dataio`), memory sizing (`memory`), the machine and its cores (`machine`)
and worker pools (`parallel`)."""
