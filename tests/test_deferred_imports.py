"""A module whose import is costly is imported where first used (rvs_params/deferred.py): the
server's start and the CLIs' command lines never load scipy, and a deferred module is the module
once read."""

from __future__ import annotations

import json
import subprocess
import sys
import threading

from rvs_params.deferred import deferred


def _loaded(code: str) -> list[str]:
    out = subprocess.run([sys.executable, "-c", code + "\nimport json\nprint(json.dumps(sorted({m.split('.')[0] "
                          "for m in sys.modules})))"], capture_output=True, text=True, timeout=120, check=True).stdout
    return json.loads(out.strip().splitlines()[-1])


def test_the_server_and_the_clis_start_without_scipy() -> None:
    # everything `rvs-server --help` and a refused command line import: the command table, the
    # devices, the workflows' steps and the telemetry
    loaded = _loaded("import sys\nimport rvs_server.main, rvs_server.app, prox_workflows.cli.prox, "
                     "prox_workflows.cli.dem_import, prox_workflows.cli.path_planner, drivers.tof.console")
    assert "rvs_server" in loaded and "numpy" in loaded
    assert "scipy" not in loaded, loaded


def test_a_deferred_module_is_the_module_once_read_from_any_thread() -> None:
    ndimage = deferred("scipy.ndimage")
    import scipy.ndimage as real

    got: list[object] = []
    threads = [threading.Thread(target=lambda: got.append(ndimage.distance_transform_edt)) for _ in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert got == [real.distance_transform_edt] * 4
    assert "scipy.ndimage" in repr(ndimage)
