"""rvs-replay --mcap: a recorded run (``record -start``) run again through the real server on
replay backends, its replies compared with the recorded ones.

The server starts in this process on a free port (the same code path as rvs-server), with the
configuration the recorded run had and every device on its ``replay`` backend reading the file
(drivers/replay.py), recording the replay itself to ``<data>/recordings/replay.mcap``. It
starts from the state the recorded server had at ``record -start``: the current maps (their
cells the latched Grids the recording begins with, their grid the metadata's), the pose and
its estimate (the replayed rover). The recorded requests are sent over TCP in their recorded
order, each on a connection of its own recorded connection, and each waits for what the
recorded run had seen of the request before it (its final line, its ACK, or nothing: a
``break`` sent during a job is sent during it), for the frames recorded before the recorded
server answered it while a job or a monitor runs (a monitor's calls are served in their
recorded turn, so it stops after as many cycles as it made, those made while its stop was on
its way included), and with ``--timing recorded`` for its recorded time.

Each request's ACK and final line (OK or ERROR) must equal the recorded ones, but for the
fields that legitimately differ (:data:`IGNORED_FIELDS`: job numbers, times) and product names
made from the time of day; PROGRESS and EVENT lines are not compared. Replies about the server
itself (:data:`STATUS_ONLY`: status, version, config, logbook, events) are compared by their
status word only. Requests that manage the run rather than belong to it (:data:`SKIPPED`:
record, quit, sim, auth) are not sent. ``--products``: every map layer the replay published
(the /map/* Grids of both recordings, those made after the first request) equal, cell for
cell; a run that made none compares none. A ``ros2``-profile recording (a rosbag2 directory or
its MCAP file) does not replay: one line says so, exit status 2.

    rvs-replay --mcap data/recordings/run1.mcap [--products] [--timing recorded] [--data DIR]
"""

from __future__ import annotations

import argparse
import contextlib
import json
import re
import socket
import sys
import tempfile
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from drivers.base import DeviceError
from drivers.registry import DEVICE_KINDS, registry
from drivers.replay import TIMINGS, Replay, decoder, load, running
from prox_workflows.grid import GridGeometry, Layers
from rvs_params.cli import ToolParser

from ..protocol import Reply, parse_reply
from ..telemetry.messages import DTYPES
from ..telemetry.outlet import MAP_PREFIX
from ..telemetry.recording import read_messages
from .session import ServerThread

IGNORED_FIELDS = frozenset({"job", "seconds", "elapsed", "duration", "time", "started", "uptime", "source"})
STATUS_ONLY = frozenset({"status", "version", "config", "logbook", "events"})
SKIPPED = frozenset({"record", "quit", "sim", "auth", "exit", "bye"})
FINAL = ("OK", "ERROR")
DURATION = re.compile(r"_m?s(_|$)")  # a time it took (cycle_ms, cycle_ms_max, drive_s): the machine's, not the run's
WALL_STAMP = re.compile(r"\d{8}T\d{6}(_\d{3})?")  # default product names: the UTC time of day
NOT_REPLAYED_CONFIG = ("server",)  # where it listens and keeps its data is the replay's own
DEFAULT_TIMEOUT = 600.0


@dataclass
class Exchange:
    """A request and the reply lines that answer it (ACK, PROGRESS, OK/ERROR)."""

    conn: Any
    request: str
    t_ns: int = 0
    lines: list[tuple[int, Reply]] = field(default_factory=list)
    job: str | None = None
    done: threading.Event = field(default_factory=threading.Event)

    @property
    def command(self) -> str:
        words = self.request.split()
        words = words[1:] if words and words[0].startswith("@") else words
        return words[0].lower() if words else ""

    @property
    def answered_ns(self) -> int:
        """When the recorded server had acted on it: its first reply line, or the request's own
        time when nothing came back. A monitor's stop answers once the monitor has ended, so
        the frames recorded between the request and that answer are cycles the monitor made
        before the stop reached it (on a loaded machine, a cycle or more)."""
        return self.lines[0][0] if self.lines else self.t_ns

    def compared(self) -> list[Reply]:
        return [r for _, r in self.lines if r.status in ("ACK", *FINAL)]

    def seen_by(self, t_ns: int) -> str:
        """What had come back by ``t_ns``: final, ack or nothing."""
        got = [r.status for t, r in self.lines if t <= t_ns]
        return "final" if any(s in FINAL for s in got) else "ack" if "ACK" in got else "nothing"


class Grouper:
    """Assigns a connection's reply lines to its requests: the first ACK/OK/ERROR after a
    request is its own, and the lines of a job carry its number."""

    def __init__(self) -> None:
        self.waiting: list[Exchange] = []  # sent, nothing back yet
        self.jobs: dict[str, Exchange] = {}
        self.lock = threading.Lock()

    def sent(self, ex: Exchange) -> None:
        with self.lock:
            self.waiting.append(ex)

    def reply(self, t_ns: int, reply: Reply) -> None:
        with self.lock:
            job = str(reply.fields.get("job")) if "job" in reply.fields else None
            ex = self.jobs.get(job) if job is not None else None
            if ex is None and reply.status in ("ACK", *FINAL) and self.waiting:
                ex = self.waiting.pop(0)
                if reply.status == "ACK" and job is not None:
                    ex.job = job
                    self.jobs[job] = ex
            if ex is None:
                return
            ex.lines.append((t_ns, reply))
            if reply.status in FINAL:
                ex.done.set()
                if ex.job is not None:
                    self.jobs.pop(ex.job, None)


def recorded_exchanges(path: Path) -> list[Exchange]:
    """The recorded requests in order, with their reply lines."""
    exchanges: list[Exchange] = []
    groupers: dict[Any, Grouper] = {}
    for _, channel, message in read_messages(path):
        if channel.topic != "/rvs/wire":
            continue
        wire = json.loads(message.data)
        grouper = groupers.setdefault(wire["conn"], Grouper())
        if wire["dir"] == "request":
            ex = Exchange(wire["conn"], wire["line"], message.log_time)
            exchanges.append(ex)
            grouper.sent(ex)
        elif wire["dir"] == "reply":
            try:
                grouper.reply(message.log_time, parse_reply(wire["line"]))
            except Exception:  # noqa: BLE001 - a line that is no reply (an echo) answers nothing
                continue
    return exchanges


class Connection:
    """One TCP connection of the replay; a reader thread files its lines with the grouper."""

    def __init__(self, port: int) -> None:
        self.sock = socket.create_connection(("127.0.0.1", port), timeout=30)
        self.sock.settimeout(None)
        self.grouper = Grouper()
        self.file = self.sock.makefile("r", encoding="utf-8", newline="\n")
        self.hello = self.file.readline()
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self) -> None:
        for line in self.file:
            try:
                reply = parse_reply(line)
            except Exception:  # noqa: BLE001 - not a reply line
                continue
            if reply.status != "EVENT":
                self.grouper.reply(time.time_ns(), reply)

    def send(self, ex: Exchange) -> None:
        self.grouper.sent(ex)
        self.sock.sendall(ex.request.encode() + b"\n")

    def close(self) -> None:
        self.sock.close()


def normalised(reply: Reply, command: str) -> tuple[Any, ...]:
    if command in STATUS_ONLY:
        return reply.module, reply.status
    fields = {k: WALL_STAMP.sub("<time>", str(v)) for k, v in reply.fields.items()
              if k not in IGNORED_FIELDS and not DURATION.search(k)}
    return reply.module, reply.status, reply.tag, fields


def compare(recorded: list[Exchange], replayed: list[Exchange]) -> list[str]:
    problems = []
    for rec, rep in zip(recorded, replayed, strict=True):
        want = [normalised(r, rec.command) for r in rec.compared()]
        got = [normalised(r, rec.command) for r in rep.compared()]
        if not rec.done.is_set():
            continue  # unanswered when the recording stopped: nothing to hold the replay to
        if want != got:
            problems.append(f"> {rec.request}\n  recorded: {want}\n  replayed: {got}")
    return problems


def grids(path: Path, after_ns: int) -> dict[str, list[bytes]]:
    """Per map layer, the Grids published after ``after_ns`` (their encoded cells and geometry)."""
    out: dict[str, list[bytes]] = {}
    for _, channel, message in read_messages(path):
        if channel.topic.startswith("/map/") and message.log_time >= after_ns:
            out.setdefault(channel.topic, []).append(_cells(message.data))
    return out


def _cells(data: bytes) -> bytes:
    """A Grid without its timestamp (protobuf field 1), the one part that differs between runs."""
    out, i = bytearray(), 0
    while i < len(data):
        key, j = _varint(data, i)
        wire = key & 7
        if wire == 0:
            end = _varint(data, j)[1]
        elif wire == 2:
            size, k = _varint(data, j)
            end = k + size
        else:
            end = j + (8 if wire == 1 else 4)
        if key >> 3 != 1:
            out += data[i:end]
        i = end
    return bytes(out)


def _varint(data: bytes, i: int) -> tuple[int, int]:
    value = shift = 0
    while True:
        b = data[i]
        value |= (b & 0x7F) << shift
        i += 1
        if b < 0x80:
            return value, i
        shift += 7


def compare_products(recorded: Path, replayed: Path, rec_start: int, rep_start: int) -> tuple[list[str], int]:
    """The mismatches, and how many maps (a layer each) were compared."""
    want, got = grids(recorded, rec_start), grids(replayed, rep_start)
    problems = []
    for topic in sorted(set(want) | set(got)):
        a, b = want.get(topic, []), got.get(topic, [])
        if len(a) != len(b):
            problems.append(f"{topic}: {len(a)} maps recorded, {len(b)} replayed")
        problems += [f"{topic}: map {i + 1} differs" for i, (x, y) in enumerate(zip(a, b, strict=False)) if x != y]
    return problems, sum(min(len(want.get(t, [])), len(got.get(t, []))) for t in want)


def start_maps(path: Path, metadata: dict[str, Any], before_ns: int) -> tuple[Layers, str | None, dict[str, str]] | None:
    """The maps the server had when the recording started (a recording started after a DEM):
    their grid, name and files from the metadata, their cells from the latched /map/* Grids the
    recording begins with (the last of each layer before the first request), as they were."""
    info = metadata.get("maps")
    if not isinstance(info, dict):
        return None
    cell, xmin, ymax, width, height, crs = info["geometry"]
    geometry = GridGeometry(float(cell), float(xmin), float(ymax), int(width), int(height), crs)
    layers = Layers(geometry)
    parsers: dict[int, Any] = {}
    for schema, channel, message in read_messages(path):
        if not channel.topic.startswith(MAP_PREFIX) or message.log_time >= before_ns:
            continue
        grid = decoder(parsers, schema)(message.data)
        if grid.column_count != width or len(grid.data) != height * grid.row_stride:
            continue  # another grid than the current maps'
        cells = np.frombuffer(grid.data, np.uint8).reshape(height, width, grid.cell_stride)
        for f in grid.fields:
            dtype = np.dtype(DTYPES[f.type])
            column = cells[..., f.offset:f.offset + dtype.itemsize].copy().view(dtype)
            layers[f.name] = np.flipud(column.reshape(height, width))  # the Grid's rows run south first
    if "dem" not in layers:
        return None
    return layers, info.get("name"), {str(k): str(v) for k, v in (info.get("files") or {}).items()}


def config_dir(metadata: dict[str, Any], where: Path) -> Path | None:
    """The recorded configuration as config files (the replay's --config overlay): the values
    that differ from this server's defaults (a default need not pass its own option's check)."""
    config = metadata.get("config")
    if not isinstance(config, dict):
        return None
    from ..main import build_config

    defaults = build_config()
    where.mkdir(parents=True, exist_ok=True)
    for old in where.glob("*.yaml"):  # a data directory used for a replay before
        old.unlink()
    for module, values in config.items():
        if module in NOT_REPLAYED_CONFIG or module not in defaults.module_names():
            continue
        now = defaults.get(module).as_dict()
        changed = {k: v for k, v in values.items() if k in now and json.dumps(v) != json.dumps(now[k])}
        if changed:
            (where / f"{module}.yaml").write_text(yaml.safe_dump(changed), "utf-8")
    return where


def replay_sets(path: Path, data: Path, timing: str) -> list[str]:
    """Every device kind that has a replay backend on it (one without keeps its recorded backend)."""
    sets = [f"server.data={data}", "server.port=0", "server.warm_up=false", "server.record=false"]
    for kind in replayed_kinds():
        sets += [f"drivers.{kind}.backend=replay", f"drivers.{kind}.replay_file={path}",
                 f"drivers.{kind}.replay_timing={timing}"]
    return sets


def replayed_kinds() -> list[str]:
    return [kind for kind in DEVICE_KINDS if "replay" in registry(kind).names()]


@dataclass
class Outcome:
    sent: int
    skipped: list[str]
    problems: list[str]
    recording: Path  # the replay's own
    maps: int = 0  # map layers compared cell for cell


def replay(path: Path, data: Path, *, products: bool = False, timing: str = "fast",
           timeout: float = DEFAULT_TIMEOUT) -> Outcome:
    """Run the recording at ``path`` again on a server of replay backends in ``data``."""
    path = path.resolve()
    recording = load(path)
    recorded = recorded_exchanges(path)
    chosen = [ex for ex in recorded if ex.command not in SKIPPED]
    skipped = [ex.request for ex in recorded if ex.command in SKIPPED]
    overlay = config_dir(recording.metadata, data / "config")
    server = ServerThread(replay_sets(path, data, timing), str(overlay) if overlay is not None else None)
    server.start()
    conns: dict[Any, Connection] = {}
    replayed: list[Exchange] = []
    maps = 0
    try:
        first_ns = chosen[0].t_ns if chosen else recording.start_ns or 0
        start = start_maps(path, recording.metadata, first_ns)
        if start is not None:  # the state the recorded run started from
            server.app.maps.replace(*start)
        run = running(path)
        if run is not None:
            run.allow(chosen[0].answered_ns if chosen else None)
        client = Connection(server.port)
        ok = _request(client, "record -start -name replay", timeout)
        if ok.status != "OK":
            raise RuntimeError(f"the replay server would not record: {ok}")
        rep_start = time.time_ns()
        for i, ex in enumerate(chosen):
            conn = conns.get(ex.conn) or conns.setdefault(ex.conn, Connection(server.port))
            mine = Exchange(ex.conn, ex.request)
            replayed.append(mine)
            _hold(server.app, run, ex, timing, timeout)
            if run is not None:  # the calls the recorded run made before its next request took effect
                run.allow((chosen[i + 1] if i + 1 < len(chosen) else ex).answered_ns)
            conn.send(mine)
            _await(ex, mine, chosen[i + 1].t_ns if i + 1 < len(chosen) else None, timeout)
        if run is not None:
            run.allow(None)
        for mine in replayed:
            mine.done.wait(timeout)
        _request(client, "record -stop", timeout)
        problems = compare(chosen, replayed)
        if products:
            rec_start = chosen[0].t_ns if chosen else 0
            mismatches, maps = compare_products(path, data / "recordings" / "replay.mcap", rec_start, rep_start)
            problems += mismatches
    finally:
        for conn in conns.values():
            conn.close()
        server.stop()
    return Outcome(len(replayed), skipped, problems, data / "recordings" / "replay.mcap", maps)


def _hold(app: Any, run: Replay | None, ex: Exchange, timing: str, timeout: float) -> None:
    """Send a request no earlier than the recorded run did: with recorded timing at its recorded
    time after the start; always not before the replay served the frames recorded before it took
    effect (:attr:`Exchange.answered_ns`) while a job or a monitor (hazard-start, track3d-start)
    may still ask for them. With the gate of :meth:`Replay.allow` (no call the recorded run made
    after that is served before the request is sent, nor after the last request before it is
    answered), a hazard-stop ends a monitor that made as many cycles as the recorded one, however
    slow either machine was."""
    if run is None:
        return
    run.pace(ex.t_ns, timing)
    deadline = time.monotonic() + timeout
    due = ex.answered_ns
    while run.behind(due) and (app.jobs.current is not None or len(app.monitors)) and time.monotonic() < deadline:
        time.sleep(0.01)


def _await(rec: Exchange, mine: Exchange, next_ns: int | None, timeout: float) -> None:
    """Hold the next request back until the replay has seen of this one what the recorded run
    had seen of it when the next was sent."""
    seen = rec.seen_by(next_ns) if next_ns is not None else "final"
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        now = mine.seen_by(time.time_ns())
        if seen == "nothing" or now == "final" or (seen == "ack" and now == "ack"):
            return
        mine.done.wait(0.01)


def _request(conn: Connection, line: str, timeout: float) -> Reply:
    ex = Exchange(None, line)
    conn.send(ex)
    ex.done.wait(timeout)
    return ex.compared()[-1] if ex.compared() else Reply("?", "ERROR", {"message": "no reply"})


def parse_args(argv: list[str]) -> argparse.Namespace:
    p = ToolParser(prog="rvs-replay --mcap", description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--mcap", type=Path, required=True, metavar="FILE", help="the recording (record -start) to replay")
    p.add_argument("--products", action="store_true", help="also compare every map layer made, cell for cell")
    p.add_argument("--timing", choices=TIMINGS, default="fast",
                   help="frames at once (fast) or not before their recorded time (recorded)")
    p.add_argument("--data", type=Path, help="the replay server's data directory (default: a temporary one, "
                   "removed after; give one to keep the replay's products and its recording)")
    p.add_argument("--timeout", type=float, default=DEFAULT_TIMEOUT,
                   help=f"seconds to wait for each request's final line (default {DEFAULT_TIMEOUT:g})")
    return p.parse_args(argv)


def main(argv: list[str]) -> int:
    args = parse_args(argv)
    if not args.mcap.exists():
        print(f"rvs-replay: --mcap {args.mcap}: no such file", file=sys.stderr)
        return 2
    with _data_dir(args.data) as data:
        try:
            outcome = replay(args.mcap, data, products=args.products, timing=args.timing, timeout=args.timeout)
        except (OSError, RuntimeError, ValueError, DeviceError) as exc:
            print(f"rvs-replay: {exc.message if isinstance(exc, DeviceError) else exc}", file=sys.stderr)
            return 2
    for problem in outcome.problems:
        print(f"MISMATCH {problem}")
    if outcome.skipped:
        print(f"not sent ({', '.join(sorted(SKIPPED))}): {len(outcome.skipped)}")
    what = f"replies and {outcome.maps} map layers" if args.products else "replies"
    print(f"{outcome.sent} requests replayed from {args.mcap}: {what} "
          f"{'differ' if outcome.problems else 'match'} ({len(outcome.problems)} mismatches)")
    return 1 if outcome.problems else 0


@contextlib.contextmanager
def _data_dir(given: Path | None) -> Iterator[Path]:
    if given is not None:
        given.mkdir(parents=True, exist_ok=True)
        yield given
        return
    with tempfile.TemporaryDirectory(prefix="rvs-replay-") as tmp:
        yield Path(tmp)
