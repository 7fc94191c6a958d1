"""``python stop_while_compiling.py <overrides>``: ``python -m experiments.run <overrides>`` that sends itself the
signal ``$STOP_SIGNAL`` from inside the callback LLVM makes into Python once numba has compiled a kernel, the first
time that happens after the run folder ``$STOP_RUN_DIR`` has its ``status.json``.

C code calls that callback and ignores any exception raised in it: the handler's exception is lost there, as it is
when a signal lands while numba compiles. ``$NUMBA_CACHE_DIR`` should be empty, so that the run compiles.
"""

import os
import runpy
import signal
import sys
from pathlib import Path

from numba.core import codegen

SIGNUM = getattr(signal, os.environ["STOP_SIGNAL"])
STATUS = Path(os.environ["STOP_RUN_DIR"]) / "status.json"
HOOK = codegen.JITCodeLibrary._object_compiled_hook.__func__
_sent = []


def _compiled(cls, ll_module, buf):
    if not _sent and STATUS.is_file():
        _sent.append(True)
        print("signal sent from the compiler's callback", file=sys.stderr, flush=True)
        os.kill(os.getpid(), SIGNUM)
    return HOOK(cls, ll_module, buf)


codegen.JITCodeLibrary._object_compiled_hook = classmethod(_compiled)
sys.argv = ["experiments/run.py", *sys.argv[1:]]
runpy.run_module("experiments.run", run_name="__main__", alter_sys=True)
