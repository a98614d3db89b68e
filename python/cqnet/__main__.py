"""The ``cqnet`` command as the package installs it (``python -m cqnet``
too). The actors of a run start through ``_api._actor_command``."""

import signal
import sys


def main() -> int:
    """``cqnet …`` on the command line: the same program as the Rust binary."""
    from ._api import _actor_command
    from ._cqnet import cli_main, set_actor_program

    # Ctrl-C is the program's to handle, as in the binary: a `run` stops
    # its network and reaps it.
    signal.signal(signal.SIGINT, signal.SIG_DFL)
    set_actor_program(*_actor_command())
    return cli_main(["cqnet", *sys.argv[1:]])


if __name__ == "__main__":
    sys.exit(main())
