"""Ctrl-C and SIGTERM at any moment, XLA compilation included: flush what is finished, exit 130.

Python runs a signal handler in the main thread between bytecodes; during an XLA compilation or
a jitted call that moment is a callback from C++ into Python, where a raised KeyboardInterrupt
crashes the process (a segfault) or is swallowed. So `HardStop` never raises: its handler only
records the signal, while the C-level handler writes the signal number to a pipe
(`signal.set_wakeup_fd`) that a watcher thread reads at once, whatever the main thread is doing.
The watcher takes `HardStop.lock` (held by the main thread around every file write, so that no
write is cut), runs `flush()` (e.g. rebuild the results from the finished cells), flushes stdout
and stderr and ends the process with `os._exit(130)`: no Python unwinding, no C++ callback.
"""

from __future__ import annotations

import os
import signal
import sys
import threading
from collections.abc import Callable

EXIT_CODE = 130  # 128 + SIGINT, as a shell reports a Ctrl-C


class HardStop:
    """`with HardStop(flush):` makes SIGINT and SIGTERM end the process with exit code 130
    after `flush()` (under `lock`). Outside the block the previous handlers are back; entered
    from another thread than the main one (where signals never arrive) it does nothing."""

    def __init__(self, flush: Callable[[], None] | None = None, code: int = EXIT_CODE):
        self.flush, self.code = flush, code
        self.lock = threading.RLock()
        self.signum: int | None = None
        self._closing = False

    def _record(self, signum, frame) -> None:
        self.signum = signum

    def _watch(self) -> None:
        try:
            data = os.read(self._r, 1)
        except OSError:
            return
        if not data or self._closing:
            return
        with self.lock:
            try:
                print(f"\n{signal.Signals(data[0]).name}: stopping", file=sys.stderr, flush=True)
                if self.flush is not None:
                    self.flush()
            except BaseException as e:  # noqa: BLE001 (the exit below must happen)
                print(f"while stopping: {type(e).__name__}: {e}", file=sys.stderr)
            finally:
                for stream in (sys.stdout, sys.stderr):
                    try:
                        stream.flush()
                    except Exception:  # noqa: BLE001, S110
                        pass
                os._exit(self.code)

    def __enter__(self) -> HardStop:
        self._active = threading.current_thread() is threading.main_thread()
        if not self._active:  # signals reach the main thread only: nothing to install
            return self
        self._r, self._w = os.pipe()
        os.set_blocking(self._w, False)
        self._old_fd = signal.set_wakeup_fd(self._w, warn_on_full_buffer=False)
        self._old = {s: signal.signal(s, self._record) for s in (signal.SIGINT, signal.SIGTERM)}
        self._thread = threading.Thread(target=self._watch, name="hard-stop", daemon=True)
        self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        if not self._active:
            return
        self._closing = True
        for s, h in self._old.items():
            signal.signal(s, h)
        signal.set_wakeup_fd(self._old_fd)
        os.write(self._w, b"\0")  # wakes the watcher, which sees _closing and returns
        self._thread.join()
        os.close(self._r)
        os.close(self._w)
