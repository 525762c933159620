"""This machine and this process: where the folders are (:mod:`.paths`), what produced a
result (:mod:`.provenance`: code version, machine, package versions), and the process's heap
between long steps (:mod:`.heap`). The lowest layer of :mod:`experiments`: it imports nothing
else of the project."""
