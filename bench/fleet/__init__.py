"""``bench fleet``: one command over many run files, fanned out over dask.distributed workers
(processes: HDF5 serialises the threads of one process). docs/fleet.md.

* :mod:`bench.fleet.files`: which run files (a directory, or rows of the catalogue), the name each
  is known by, and where its output goes (always inside the output directory).
* :mod:`bench.fleet.tasks`: what a worker does with one file: the library function the serial
  command calls, and a small picklable :class:`~bench.fleet.tasks.FileResult`.
* :mod:`bench.fleet.cluster`: the embedded ``LocalCluster`` (127.0.0.1, processes, one thread
  each) or a connection to an existing scheduler, each with a timeout.
* :mod:`bench.fleet.fanout`: the files submitted to the workers and their results collected as
  they finish, with a timeout on each wait.

Light at import: dask and the analyses are imported when used.
"""
