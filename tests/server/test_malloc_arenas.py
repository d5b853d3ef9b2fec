"""The server bounds glibc's malloc arenas (``server.malloc_arenas``): every thread that allocates
would otherwise get an arena of its own that keeps what it freed, and a rover's server would grow
in steps as job threads take turns at the renders. Counted with glibc's own ``malloc_info`` in a
fresh interpreter, whose threads would each take a new arena."""

from __future__ import annotations

import subprocess
import sys
import textwrap

import pytest

COUNT_ARENAS = textwrap.dedent("""
    import ctypes, sys, threading
    import numpy as np
    from rvs_server.heap import bound_malloc_arenas

    arenas = int(sys.argv[1])
    print(bound_malloc_arenas(arenas))
    hold = threading.Barrier(8)

    def work():
        a = np.ones(4096)  # through malloc, not Python's own small-object pool
        hold.wait()  # eight threads allocating at once
        del a

    threads = [threading.Thread(target=work) for _ in range(8)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    libc = ctypes.CDLL(None)
    libc.fopen.restype = ctypes.c_void_p
    fh = libc.fopen(sys.argv[2].encode(), b"w")
    libc.malloc_info(0, ctypes.c_void_p(fh))
    libc.fclose(ctypes.c_void_p(fh))
""")


def arenas_used(tmp_path, arenas: int) -> tuple[str, int]:
    info = tmp_path / f"info{arenas}.xml"
    out = subprocess.run([sys.executable, "-c", COUNT_ARENAS, str(arenas), str(info)], capture_output=True,
                         text=True, timeout=60, check=True)
    return out.stdout.strip(), info.read_text().count("<heap nr=")


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's mallopt and malloc_info")
def test_the_servers_threads_share_the_declared_arenas(tmp_path) -> None:
    said, bounded = arenas_used(tmp_path, 2)
    assert said == "True" and bounded == 2
    said, default = arenas_used(tmp_path, 0)  # 0: glibc's default, an arena a thread
    assert said == "False" and default > 2


def test_the_bound_is_set_at_start_and_not_at_run_time(server_factory) -> None:
    """Arenas made before the call stay, so the bound only means something before the server's
    threads allocate: --set and YAML take it, config -set refuses it."""
    c = server_factory(["server.malloc_arenas=3"]).client()
    assert c.request("config -module server").fields["malloc_arenas"] == "3"
    r = c.request("config -module server -set malloc_arenas=8")
    assert r.status == "ERROR" and "malloc_arenas" in r.fields["message"], r
