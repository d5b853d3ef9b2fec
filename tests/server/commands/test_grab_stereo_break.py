"""break during grab-stereo, through sockets: the grab does no further stage once the break is
answered (no frame finished, no file written), ends E_INTERRUPTED, and the products of an
earlier grab of the same name stay as they were."""

from __future__ import annotations

import threading
from typing import Any

import pytest

import drivers.stereo.imaging as imaging
from rvs_server.commands import hardware


def _break_inside(server: Any, monkeypatch: pytest.MonkeyPatch, module: Any, name: str) -> list[str]:
    """Patch ``module.name`` so that its first call answers a ``break`` (sent on a second
    connection, its OK read) before it returns; returns the log of calls after that break."""
    real = getattr(module, name)
    ctl = server.client()
    after: list[str] = []
    state = {"break": "to send"}  # then "sent", then "answered"
    lock = threading.Lock()  # the two cameras render in two threads

    def wrapped(*args: Any, **kw: Any) -> Any:
        with lock:
            first, answered = state["break"] == "to send", state["break"] == "answered"
            state["break"] = "sent" if first else state["break"]
        if answered:  # a call that starts once the break is answered
            after.append(name)
        out = real(*args, **kw)
        if first:
            r = ctl.request("break")
            assert r.status == "OK" and r.fields["interrupted"] != "none", r
            with lock:
                state["break"] = "answered"
        return out

    monkeypatch.setattr(module, name, wrapped)
    return after


def _calls_of(monkeypatch: pytest.MonkeyPatch, module: Any, name: str, log: list[str]) -> None:
    real = getattr(module, name)

    def wrapped(*args: Any, **kw: Any) -> Any:
        log.append(name)
        return real(*args, **kw)

    monkeypatch.setattr(module, name, wrapped)


@pytest.mark.parametrize("resolution", ["low", "highest"])
def test_a_break_during_the_exposure_finishes_no_frame(server, monkeypatch, resolution: str) -> None:
    c = server.client()
    assert c.request("grab-stereo -output brk -resolution low").status == "OK"
    before = {p.name: p.read_bytes() for p in (server.data / "stereo").glob("brk_*")}
    after = _break_inside(server, monkeypatch, imaging, "expose")
    _calls_of(monkeypatch, imaging, "jpeg", after)
    r = c.request(f"grab-stereo -output brk -resolution {resolution}")
    assert (r.status, r.fields["code"]) == ("ERROR", "E_INTERRUPTED"), r
    assert "jpeg" not in after, after  # the frame whose exposure the break caught is not finished
    assert {p.name: p.read_bytes() for p in (server.data / "stereo").glob("brk_*")} == before


def test_a_break_during_the_writes_keeps_the_earlier_pair(server, monkeypatch) -> None:
    c = server.client()
    assert c.request("grab-stereo -output brk -resolution low").status == "OK"
    before = {p.name: p.read_bytes() for p in (server.data / "stereo").glob("brk_*")}
    assert {"brk_left.tif", "brk_right.tif", "brk_left.png", "brk_right.png"} <= set(before)
    after = _break_inside(server, monkeypatch, hardware, "write_tiff")
    _calls_of(monkeypatch, hardware, "write_png", after)
    r = c.request("grab-stereo -output brk -resolution low")
    assert (r.status, r.fields["code"]) == ("ERROR", "E_INTERRUPTED"), r
    assert after == [], after  # no further file written once the break is answered
    assert {p.name: p.read_bytes() for p in (server.data / "stereo").glob("brk_*")} == before
    assert not [p for p in (server.data / "stereo").iterdir() if p.name.startswith(".")]  # no temp left


def test_a_break_while_the_distortion_map_is_made_stops_it_and_keeps_no_part(server, monkeypatch) -> None:
    """The first grab at a resolution inverts the lens distortion for every pixel (seconds at
    the highest): a break stops it between bands of rows, and the next grab makes it whole."""
    monkeypatch.setattr(imaging, "_MAPS", {}, raising=False)
    c = server.client()
    after = _break_inside(server, monkeypatch, imaging, "_undistort_pixels")
    pixels: list[int] = []
    counted = imaging._undistort_pixels

    def counting(pts: Any, *args: Any) -> Any:
        pixels.append(len(pts))
        return counted(pts, *args)

    monkeypatch.setattr(imaging, "_undistort_pixels", counting)
    r = c.request("grab-stereo -output brk -resolution highest")
    assert (r.status, r.fields["code"]) == ("ERROR", "E_INTERRUPTED"), r
    assert after == [], len(after)  # no band after the break
    assert sum(pixels) < 2 * 1920 * 1080 // 2, pixels  # the two cameras' maps: most of them never made
    assert imaging._MAPS == {}
    assert c.request("continue").status == "OK"
    r = c.request("grab-stereo -output brk -resolution medium")
    assert r.status == "OK", r
    assert imaging._MAPS and all(m.map_x.shape == (768, 1024) for m in imaging._MAPS.values())
