"""``python -m bench`` and the ``bench`` console script (``bench.__main__:entry``).

The stop signals (SIGINT, SIGTERM, SIGHUP) are handled before anything else is imported
(:mod:`bench.startup_signals`): a Ctrl-C or SIGTERM in the first moments gives one line and exit
code 1, not a traceback. ``bench.cli.main`` gives other commands Python's own handling back.
"""

import sys


def entry() -> int:
    """Run the ``bench`` command line with the start-up signal handler installed first."""
    from bench.startup_signals import StartupSignals, StoppedDuringStartup, stop_within

    guard = StartupSignals.install()
    try:
        try:
            from bench.cli import main, stdout_gone
        except ImportError as exc:  # a pybind11 module turns a stop landing in its import into this
            if (stop := stop_within(exc)) is None:
                raise
            raise stop from exc

        try:
            code = main()
            sys.stdout.flush()  # here, not at exit: a reader that went away is handled like one during the command
        except BrokenPipeError:
            return stdout_gone()
        return code
    except StoppedDuringStartup as exc:
        print(f"bench: {exc}", file=sys.stderr)
        return 1  # bench.errors.EXIT_FAILED, not imported: this may be the import that was stopped
    finally:
        guard.uninstall()


if __name__ == "__main__":
    sys.exit(entry())
