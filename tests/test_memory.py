"""wdss.memory: an entry point started again under glibc's tunables faults no page in for a block freed and
allocated again, and changes nothing where it cannot or need not."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

from wdss import memory

# A command line that starts itself again: the tunables are read only when a process starts.
FAULTS = """
import json, resource, sys
from wdss.memory import memory_retained, restart_with_retained_memory

restart_with_retained_memory()
import torch

def faults():  # page faults of allocating 64 MB (above glibc's largest mmap threshold), writing it whole, freeing it
    before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    torch.ones(16 * 2**20)
    return resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before

print(json.dumps([memory_retained(), sys.argv[1:], [faults() for _ in range(6)]]))
"""


def run_faults(**env: str) -> list:
    """Whether the command ran under the tunables, its arguments, and the page faults of each allocation."""
    # Nothing else that changes how memory is allocated: a preloaded allocator, malloc's own variables, torch's huge
    # pages.
    mallocs = ("GLIBC_TUNABLES", memory.RESTARTED, "LD_PRELOAD", "THP_MEM_ALLOC_ENABLE")
    environ = {k: v for k, v in os.environ.items() if k not in mallocs and not k.startswith("MALLOC_")}
    command = [sys.executable, "-c", FAULTS, "an", "argument"]
    out = subprocess.run(command, capture_output=True, text=True, check=True, env={**environ, **env}).stdout
    return json.loads(out)


def huge_pages_always() -> bool:
    try:
        with open("/sys/kernel/mm/transparent_hugepage/enabled") as file:
            return "[always]" in file.read()
    except OSError:
        return False


@pytest.mark.skipif(not memory._glibc(), reason="glibc's malloc only")
def test_a_command_started_again_keeps_its_freed_memory_and_faults_no_page_in_again():
    retained, argv, counts_kept = run_faults()
    assert retained and argv == ["an", "argument"]  # the same command line
    assert max(counts_kept[1:]) <= 64  # the first allocation grows the heap; the next ones reuse it
    # Not started again (as if it had been, and glibc had ignored the tunables): every block is mapped afresh.
    retained, _, counts = run_faults(**{memory.RESTARTED: "1"})
    assert not retained
    if not huge_pages_always():  # transparent huge pages for every mapping: 512x fewer faults, but faults still
        assert min(counts) >= 2**26 // 4096 // 2  # about one fault per 4 KiB page
    assert min(counts) > max(counts_kept[1:])


def test_the_environment_keeps_other_tunables_and_sets_its_own():
    env = memory.retained_memory_environment(
        {"PATH": "/bin", "GLIBC_TUNABLES": "glibc.malloc.arena_max=2:glibc.malloc.mmap_max=9"}
    )
    assert env["PATH"] == "/bin"
    tunables = dict(item.split("=") for item in env["GLIBC_TUNABLES"].split(":"))
    assert tunables == {"glibc.malloc.arena_max": "2", **memory.TUNABLES}
    assert memory.memory_retained(env) == memory._glibc()


def test_nothing_starts_again_where_it_cannot_or_need_not(monkeypatch):
    def execve(*args):
        raise AssertionError("started again")

    monkeypatch.setattr(os, "execve", execve)
    monkeypatch.setattr(memory, "_glibc", lambda: False)  # macOS, Windows, musl
    memory.restart_with_retained_memory()
    monkeypatch.setattr(memory, "_glibc", lambda: True)
    monkeypatch.delenv("GLIBC_TUNABLES", raising=False)
    monkeypatch.delenv(memory.RESTARTED, raising=False)
    monkeypatch.setenv("LD_PRELOAD", "/usr/lib/x86_64-linux-gnu/libjemalloc.so.2")  # an allocator of its own
    memory.restart_with_retained_memory()
    monkeypatch.delenv("LD_PRELOAD")
    monkeypatch.setattr(sys, "argv", ["-"])  # a program read from standard input: consumed by now
    memory.restart_with_retained_memory()
    monkeypatch.setattr(sys, "argv", ["upscale.py"])
    monkeypatch.setenv(memory.RESTARTED, "1")  # started again once already: glibc ignored the tunables
    memory.restart_with_retained_memory()
    monkeypatch.delenv(memory.RESTARTED)
    monkeypatch.setenv("GLIBC_TUNABLES", memory.retained_memory_environment({})["GLIBC_TUNABLES"])
    memory.restart_with_retained_memory()  # already in effect
    monkeypatch.delenv("GLIBC_TUNABLES")
    with pytest.raises(AssertionError, match="started again"):  # and otherwise it does
        memory.restart_with_retained_memory()
