"""Waiting for a job: progress as Python users expect it, and Ctrl-C.

A job runs on a native thread; this waits on it a tenth of a second at a
time with the GIL released, so that the interpreter hears Ctrl-C (a
``KeyboardInterrupt``) between waits. On Ctrl-C the job is cancelled and
waited for, so that no process or shared memory outlives it, and the
``KeyboardInterrupt`` goes on up.
"""

import sys
from typing import Any, Optional


def _in_notebook() -> bool:
    shell = sys.modules.get("IPython")
    if shell is None:
        return False
    try:
        ip = shell.get_ipython()  # type: ignore[attr-defined]
    except AttributeError:
        return False
    return ip is not None and type(ip).__name__ == "ZMQInteractiveShell"


def _wanted(progress: Optional[bool]) -> bool:
    """Shown on a terminal; quiet in a notebook or a log unless asked."""
    if progress is not None:
        return progress
    return bool(getattr(sys.stderr, "isatty", lambda: False)()) and not _in_notebook()


class _Line:
    """A one-line bar on stderr, when tqdm is not installed."""

    def __init__(self, desc: str) -> None:
        self.desc = desc
        self.last = ""

    def show(self, done: int, total: int, unit: str, message: str) -> None:
        width = 30
        filled = int(width * done / total) if total else 0
        line = f"\r{self.desc} [{'#' * filled}{'.' * (width - filled)}] {done}/{total} {unit} {message}"
        if line != self.last:
            sys.stderr.write(line[:200].ljust(len(self.last)))
            sys.stderr.flush()
            self.last = line

    def close(self) -> None:
        if self.last:
            sys.stderr.write("\n")
            sys.stderr.flush()


class _Tqdm:
    """tqdm's bar (its notebook widget in a notebook), new when the unit changes."""

    def __init__(self, desc: str) -> None:
        from tqdm.auto import tqdm

        self.tqdm = tqdm
        self.desc = desc
        self.bar: Any = None
        self.unit = ""

    def show(self, done: int, total: int, unit: str, message: str) -> None:
        if self.bar is None or unit != self.unit:
            if self.bar is not None:
                self.bar.close()
            self.bar = self.tqdm(total=total or None, desc=self.desc, unit=f" {unit}", leave=True)
            self.unit = unit
        self.bar.total = total or None
        self.bar.n = done
        if message:
            self.bar.set_postfix_str(message, refresh=False)
        self.bar.refresh()

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


def _bar(desc: str) -> Any:
    try:
        return _Tqdm(desc)
    except ImportError:
        return _Line(desc)


def follow(job: Any, progress: Optional[bool], desc: str) -> str:
    """Waits for ``job``, drawing its progress if wanted; returns its
    outcome (JSON text) or raises its error. Ctrl-C cancels it, waits for
    it to clean up, and raises ``KeyboardInterrupt``."""
    bar = _bar(desc) if _wanted(progress) else None
    try:
        while not job.wait(0.1):
            if bar is not None:
                bar.show(*job.progress())
        if bar is not None:
            bar.show(*job.progress())
    except KeyboardInterrupt:
        job.cancel()
        _wait_through_interrupts(job)
        raise
    finally:
        if bar is not None:
            bar.close()
    return job.result()


def _wait_through_interrupts(job: Any) -> None:
    """Waits for a cancelled job to stop and clean up; another Ctrl-C
    meanwhile does not leave its processes behind."""
    while True:
        try:
            if job.wait(0.2):
                return
        except KeyboardInterrupt:
            continue
