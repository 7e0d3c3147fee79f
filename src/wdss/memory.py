"""Keep the memory a process frees, so that a loop over large frames stops page-faulting.

glibc's malloc serves every block above its mmap threshold (at most 32 MiB) with a fresh ``mmap`` and unmaps it
when freed. A 1080p feature map (64 channels at 960x540: 133 MB) is such a block, so every frame maps its tensors
anew and the kernel faults in and zeroes each 4 KiB page on first touch: on a CPU that was a large share of an
eager forward's time at 1080p, and with the memory kept no page faults after the first frame, resident memory
steady (docs/performance.md). Engines, onnxruntime's arena and PyTorch's CUDA allocator all keep the memory they free.

glibc is told so by its tunables, which it reads only when a process starts (:data:`TUNABLES`, glibc 2.26 on): no
block from ``mmap``, the heap never trimmed, and no per-thread cache or fast bins. The last two matter: the few
bytes ``posix_memalign`` (PyTorch's CPU allocator) splits off a block sit in those caches as if in use, so the
freed block cannot merge with its neighbours and the next one of the same size grows the heap instead, on every
frame, without end. ``mallopt`` can set all but the per-thread cache at run time; hence an entry
point starts itself again under the tunables (:func:`restart_with_retained_memory`), whose values replace a user's
own for the same four and are inherited by the processes it starts (torch.compile's workers among them).
PyTorch's CPU tuning guide recommends preloading jemalloc or tcmalloc for the same reason; this needs neither, and
leaves a process that preloads an allocator of its own as it is.
"""

from __future__ import annotations

import ctypes
import os
import sys

__all__ = ["TUNABLES", "memory_retained", "restart_with_retained_memory", "retained_memory_environment"]

TUNABLES = {
    "glibc.malloc.mmap_max": "0",
    "glibc.malloc.trim_threshold": str(2**62),
    "glibc.malloc.tcache_count": "0",
    "glibc.malloc.mxfast": "0",
}
RESTARTED = "WDSS_RETAINED_MEMORY"  # set in the restarted process: never restart twice


def _glibc() -> bool:
    """Whether this process's C library is glibc 2.26 or later (the first with these tunables)."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        version = ctypes.CDLL(None).gnu_get_libc_version  # musl has no such function
    except (OSError, AttributeError):
        return False
    version.restype = ctypes.c_char_p
    major, minor = (int(part) for part in version().decode().split(".")[:2])
    return (major, minor) >= (2, 26)


def _preloads_allocator(environ) -> bool:
    """Whether an allocator of its own (jemalloc, tcmalloc, mimalloc) is preloaded: glibc's tunables do not reach it."""
    return "malloc" in environ.get("LD_PRELOAD", "")


def _tunables(value: str) -> dict[str, str]:
    return dict(item.split("=", 1) for item in value.split(":") if "=" in item)


def _holds_tunables(environ) -> bool:
    held = _tunables(environ.get("GLIBC_TUNABLES", ""))
    return all(held.get(k) == v for k, v in TUNABLES.items())


def memory_retained(environ: dict | None = None) -> bool:
    """Whether this process (or one started with ``environ``) was started with ``GLIBC_TUNABLES`` holding
    :data:`TUNABLES`, on a glibc that reads them and no allocator of its own preloaded."""
    environ = os.environ if environ is None else environ
    return _glibc() and not _preloads_allocator(environ) and _holds_tunables(environ)


def retained_memory_environment(environ: dict | None = None) -> dict[str, str]:
    """``environ`` (default: this process's) with :data:`TUNABLES` added to its ``GLIBC_TUNABLES``: its other tunables
    are kept, its own values of these four replaced."""
    env = dict(os.environ if environ is None else environ)
    merged = {**_tunables(env.get("GLIBC_TUNABLES", "")), **TUNABLES}
    env["GLIBC_TUNABLES"] = ":".join(f"{k}={v}" for k, v in merged.items())
    return env


def restart_with_retained_memory() -> None:
    """Start this process's command line again, in place (``exec``: the same process id), under :data:`TUNABLES`.

    For a command-line entry point that loops over frames, called before it does anything else. Returns, leaving
    everything as it is, when the tunables are already in effect, where the C library is not glibc (macOS,
    Windows, musl, glibc before 2.26), with an allocator of its own preloaded, in a process this already restarted
    (glibc ignored them there), and where the command line cannot be run again: a program read from standard input
    (``python -``, consumed by now), or an embedded interpreter without ``sys.executable``.
    """
    if os.environ.get(RESTARTED) or _holds_tunables(os.environ) or _preloads_allocator(os.environ) or not _glibc():
        return
    if not sys.executable or not sys.orig_argv or sys.argv[0] in ("", "-"):
        return
    env = retained_memory_environment()
    env[RESTARTED] = "1"
    sys.stdout.flush()
    sys.stderr.flush()
    os.execve(sys.executable, [sys.executable, *sys.orig_argv[1:]], env)
