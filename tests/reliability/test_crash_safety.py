"""Crash safety: ``rvs_server`` in a child process killed with SIGKILL while it
writes products.

The same products are written twice under one name and the server is killed during the second
write, at the moment the k-th temporary file (``.NAME.*.tmp*``, a dotfile beside its product)
appears. Every product under its final name must then be complete and readable: either the
previous version byte for byte, or the new one whole (each file is written to a temporary file,
fsynced and renamed). A DEM's layers must still share one grid. On restart, ``status`` reports the
last complete recovery set, a break killed mid-way leaves none half-written, and ``--recover
last`` loads the set back (pose and maps).
"""

from __future__ import annotations

import hashlib
import random
import re
import signal
import time
from pathlib import Path

import cv2
import pytest
import tifffile
import yaml
from support.marks import LONG, long_test
from support.reliability_figures import record
from support.server import FAST, LineClient

from prox_workflows.grid import read_geotiff
from prox_workflows.pointcloud import read_ply
from rvs_server.client.session import ServerProcess

DEM_LINE = "dem-full-tof -range -60,60,-50,-20 -name site"
STEREO_LINE = "grab-stereo -output pair -resolution {res}"
TEMP = re.compile(r"^\..+\.tmp")


def finals(folder: Path) -> dict[str, str]:
    """sha256 of every product under its final name (dotfiles are temporaries)."""
    out = {}
    for p in sorted(folder.rglob("*")):
        if p.is_file() and not any(part.startswith(".") for part in p.relative_to(folder).parts):
            out[p.relative_to(folder).as_posix()] = hashlib.sha256(p.read_bytes()).hexdigest()
    return out


def temporaries(folder: Path) -> list[Path]:
    return [p for p in folder.rglob(".*") if TEMP.match(p.name)]


def readable(path: Path) -> None:
    """Open a product the way its users would; raises if it is partial."""
    suffix = path.suffix
    if suffix == ".tif":
        image = tifffile.imread(path)
        assert image.size > 0
    elif suffix == ".png":
        assert cv2.imread(str(path), cv2.IMREAD_UNCHANGED) is not None, path
    elif suffix in (".yaml", ".cal"):
        assert yaml.safe_load(path.read_text()) is not None, path
    elif suffix == ".ply":
        cloud = read_ply(path)
        assert len(next(iter(cloud.values()))) > 0
    elif suffix == ".csv":
        lines = path.read_text().splitlines()
        assert len(lines) >= 2 and all(line.count(",") == lines[0].count(",") for line in lines), path
    else:
        assert path.stat().st_size > 0, path


@pytest.fixture
def data(tmp_path: Path) -> Path:
    return tmp_path / "data"


def start(data: Path, *extra: str) -> tuple[ServerProcess, LineClient]:
    srv = ServerProcess(data, extra_args=[*FAST, *extra])
    srv.start()
    return srv, LineClient(srv.port, timeout=120)


def kill_at_temp(srv: ServerProcess, c: LineClient, line: str, watch: Path, k: int, timeout: float = 120) -> int:
    """Send ``line`` and SIGKILL the server when the k-th distinct temporary file shows up under
    ``watch``; returns how many it saw (fewer than k: the job ended first and was killed after)."""
    seen: set[str] = set()
    c.send(line)
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        for p in temporaries(watch) if watch.exists() else []:
            seen.add(p.name)
        if len(seen) >= k:
            break
        time.sleep(0.0005)
    srv.proc.send_signal(signal.SIGKILL)
    srv.proc.wait(10)
    srv.proc = None
    return len(seen)


def check_products(before: dict[str, str], folder: Path) -> dict[str, int]:
    after = finals(folder)
    missing = set(before) - set(after)
    assert not missing, f"products gone after the kill: {sorted(missing)[:5]}"
    replaced = kept = 0
    for rel, digest in after.items():
        readable(folder / rel)
        if before.get(rel) == digest:
            kept += 1
        else:
            replaced += 1
    return {"kept": kept, "replaced": replaced, "temporaries": len(temporaries(folder))}


def kill_points(n_long: int, n_short: int, hi: int) -> list[int]:
    """Which temporary file to kill at: the first, the last and some between (short suite: one
    in the middle, among the products rather than the views)."""
    if not LONG:
        return [hi * 2 // 3][:n_short]
    rng = random.Random(8)
    return sorted({1, hi, *(rng.randint(2, hi - 1) for _ in range(n_long - 2))})


@long_test  # the default run kills a rewrite of one DEM in test_sigkill_mid_rewrite_leaves_one_whole_dem
@pytest.mark.parametrize("k", kill_points(10, 1, 30))
def test_sigkill_while_writing_a_dem_keeps_the_previous_products(data: Path, k: int) -> None:
    srv, c = start(data)
    try:
        assert c.request(DEM_LINE, timeout=300).status == "OK"
        before = finals(data / "dem")
        assert any(p.endswith("site_dem.tif") for p in before)
        seen = kill_at_temp(srv, c, DEM_LINE, data / "dem", k)
    finally:
        srv.stop()
    figures = check_products(before, data / "dem")
    record("crash_dem", k=k, seen=seen, **figures)
    assert seen >= k, f"the job ended before its temporary file {k}"


@pytest.mark.long
@pytest.mark.parametrize("when", ["writing", "renaming"] if LONG else ["renaming"])
def test_sigkill_mid_rewrite_leaves_one_whole_dem(data: Path, when: str) -> None:
    """A DEM rewritten under the same name on another grid, killed while its files are written
    (the previous set stays) or while they are renamed into place (the next start finishes the
    set): after a restart every layer of the DEM is on one grid, with no temporary left."""
    first, second = (f"dem-full-tof -range {r},-50,-30 -name site" for r in ("-20,20", "-40,40"))
    srv, c = start(data)
    try:
        assert c.request(first, timeout=300).status == "OK"
        dem = data / "dem" / "site_dem.tif"
        before = {p.name: read_geotiff(p)[1] for p in (data / "dem").glob("site_*.tif")}
        inode = dem.stat().st_ino
        if when == "writing":
            kill_at_temp(srv, c, second, data / "dem", 5)
        else:
            c.send(second)  # same name, another extent: another grid
            deadline = time.monotonic() + 120
            while dem.stat().st_ino == inode and time.monotonic() < deadline:
                time.sleep(0.0002)
            srv.proc.send_signal(signal.SIGKILL)  # the new dem.tif is in place, maybe not all the others
            srv.proc.wait(10)
            srv.proc = None
    finally:
        srv.stop()
    srv, c = start(data)  # the start finishes a set whose commit was cut short, and sweeps temporaries
    try:
        assert c.request("status").status == "OK"
    finally:
        srv.stop()
    grids = {p.name: read_geotiff(p)[1] for p in (data / "dem").glob("site_*.tif")}
    assert set(grids) == set(before)
    assert len(set(grids.values())) == 1, grids
    assert (set(grids.values()) == set(before.values())) == (when == "writing")
    assert not temporaries(data / "dem") and not list((data / "dem").glob(".products-*"))


@long_test  # the default run kills while a DEM's products are written (the same product_set commit)
@pytest.mark.parametrize("res", ["highest", "high"])
def test_sigkill_while_writing_a_stereo_pair_keeps_the_previous_pair(data: Path, res: str) -> None:
    srv, c = start(data)
    line = STEREO_LINE.format(res=res)
    try:
        assert c.request(line, timeout=300).status == "OK"
        before = finals(data / "stereo")
        seen = kill_at_temp(srv, c, line, data / "stereo", 1)
    finally:
        srv.stop()
    figures = check_products(before, data / "stereo")
    record("crash_stereo", res=res, seen=seen, **figures)
    left = tifffile.imread(data / "stereo/pair_left.tif")
    assert left.shape[:2] == tifffile.imread(data / "stereo/pair_right.tif").shape[:2]


@long_test  # the default run kills a DEM job (the whole-DEM test) and loads a recovery set back (test_dem_tof)
def test_after_a_kill_the_last_complete_recovery_set_is_reported_and_loads_back(data: Path) -> None:
    """A server made a DEM, broke (a recovery set with the maps), continued, moved on, and was
    killed during a second break while it copied the maps. After a restart, status reports the
    last complete set, nothing half-written counts, and --recover last loads it back."""
    srv, c = start(data)
    try:
        assert c.request("pose -x 0.5 -y 0.25 -heading 10").status == "OK"
        assert c.request(DEM_LINE, timeout=300).status == "OK"
        r = c.request("break")
        assert r.status == "OK" and (data / r.fields["recovery"] / "maps" / "site_dem.tif").is_file()
        assert c.request("continue").status == "OK"
        c.request("pose -x 3 -y 3 -heading 90")
        kill_at_temp(srv, c, "break", data / "recovery", 1, timeout=30)
    finally:
        srv.stop()
    sets = [p for p in (data / "recovery").iterdir() if not p.name.startswith(".")]
    for folder in sets:  # whatever the kill left visible is complete
        manifest = yaml.safe_load((folder / "manifest.yaml").read_text())
        for rel in manifest["maps"].values():
            readable(folder / rel)
    last = f"recovery/{sorted(p.name for p in sets)[-1]}"
    srv, c = start(data)
    try:
        st = c.request("status")
        assert st.fields["recovery"] == last and st.fields["mode"] == "ready"
        assert c.request("check-move -dx 0.2").fields["code"] == "E_DATA"  # no maps until recovered
    finally:
        srv.stop()
    srv, c = start(data, "--recover", "last")
    try:
        st = c.request("status")
        assert st.fields["recovery"] == last
        p = yaml.safe_load((data / last / "manifest.yaml").read_text())["pose"]
        assert st.fields["pose"] == f"{p['x']:.3f},{p['y']:.3f},{p['heading']:.2f}"
        r = c.request("check-move -dx 0.2")  # the maps are back: the safety gate has a verdict
        assert r.status == "OK" and r.fields["verdict"] in ("ok", "not_traversable", "unknown"), r
    finally:
        srv.stop()
    record("crash_recovery", sets=len(sets), half_written=len(temporaries(data / "recovery")))
