"""A child of ``covswarm run`` dies with it, however the launcher dies (even SIGKILL).

The launcher puts its pid in the child's environment; the child's entry point asks the
kernel for SIGKILL when its parent dies (PR_SET_PDEATHSIG), then checks that its parent
is still that launcher, since the launcher may have died before the request took effect.
Done in the child, not in a ``preexec_fn``, which is unsafe in the threaded launcher.
"""

from __future__ import annotations

import ctypes
import os
import signal

PARENT_ENV = "COVSWARM_PARENT_PID"
NICE_ENV = "COVSWARM_NICE"  # niceness the child adds to its own (deploy.processes.spawn)
PR_SET_PDEATHSIG = 1  # linux/prctl.h


def hold() -> None:
    """Die with the launcher that started this process, if one did (no-op otherwise), and
    lower this process's priority by what the launcher asked (NICE_ENV)."""
    parent = os.environ.pop(PARENT_ENV, None)
    if parent is None:
        return
    ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, signal.SIGKILL)
    if os.getppid() != int(parent):  # the launcher died before prctl took effect
        os._exit(1)
    if (nice := os.environ.pop(NICE_ENV, None)) is not None:
        os.nice(int(nice))
