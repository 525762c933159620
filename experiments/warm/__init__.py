"""The warm server of ``ttc-bench``: commands run in a process forked from one that already
imported the stack, instead of a fresh interpreter importing it (≈ 1 s in the main process
and ≈ 1.1 s in each sweep worker on 2 cores).

* :mod:`.identity`: when a server may serve a command (code, libraries, environment), where
  its socket lives, the switch that turns it off;
* :mod:`.client`: the thin client in ``ttc-bench`` (argv, cwd, environment, stdin/stdout/
  stderr, Ctrl-C and the exit status forwarded);
* :mod:`.server`: the server (imports once, forks one process per command, idle timeout);
* :mod:`.forks`: a command's sweep workers forked from it by ``multiprocessing``'s fork server.
"""
