"""The ``cqnet`` command as the package installs it, and the entry point
of each actor process a ``cqnet.run`` starts."""

import signal
import sys


def main() -> int:
    """``cqnet …`` on the command line: the same program as the Rust binary."""
    from ._cqnet import cli_main

    # Ctrl-C is the program's to handle, as in the binary: a `run` stops
    # its network and reaps it, and an actor dies of it.
    signal.signal(signal.SIGINT, signal.SIG_DFL)
    return cli_main(["cqnet", *sys.argv[1:]])


if __name__ == "__main__":
    sys.exit(main())
