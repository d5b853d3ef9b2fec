"""rvs-replay: scripted regression replays against a running (or freshly started) RVS server.

A script is the conversation a GNC engineer would have by hand, written down once::

    # comments and blank lines are ignored
    > sleep -seconds 0.1
    < EGP-RVS-SLEEP ACK job=\\d+
    < EGP-RVS-SLEEP OK job=\\d+ slept=[0-9.]+

``> request`` lines are sent one at a time; each ``< regex`` must fullmatch the request's reply
lines in order (with the tag the replay added removed, so scripts read like a telnet session).
PROGRESS and EVENT lines, and lines about other requests, may be skipped; an ACK, OK or ERROR
that matches no expectation fails the request, as does the final line arriving early.
``--record`` writes such a script from a live run, with volatile values turned into patterns.

The server is always named: ``--server`` starts a fresh simulated one per script, ``--host`` /
``--port`` replay against a running one (whose pose, PTU and mode the replay changes); the
server's address and hello line go to stderr.
"""

from __future__ import annotations

import argparse
import json
import re
import sys
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from rvs_params.cli import ToolParser
from rvs_server.protocol import render_value

from .session import (
    DEFAULT_HOST,
    DEFAULT_PORT,
    Line,
    Result,
    ServerProcess,
    Session,
    SessionError,
    is_request,
    port_number,
    try_parse,
)

DEFAULT_TIMEOUT = 120.0
SKIPPABLE = ("PROGRESS", "EVENT")


class ScriptError(Exception):
    """A script that cannot be read; names the file and line."""


@dataclass
class Step:
    """One request of a script with the patterns its reply lines must match."""

    request: str
    expect: list[str] = field(default_factory=list)
    source: str = "<script>"
    lineno: int = 0
    compiled: list[re.Pattern[str]] = field(default_factory=list, repr=False)

    @property
    def where(self) -> str:
        return f"{self.source}:{self.lineno}"


# A script as items in file order: Steps, and the comment/blank lines kept for --record.
Item = Step | str


# ---------------------------------------------------------------------- reading scripts


def looks_like_script(text: str) -> bool:
    """Scripts have '>' request lines; anything else is a plain file of requests."""
    return any(line.startswith(">") for line in text.splitlines())


def parse_script(text: str, source: str = "<script>") -> list[Item]:
    """Steps (and comment lines) of a script; requests the server never answers are dropped."""
    items: list[Item] = []
    step: Step | None = None
    seen_request = False
    for n, raw in enumerate(text.splitlines(), 1):
        line = raw.rstrip()
        if line.startswith(">"):
            seen_request = True
            request = line[1:].strip()
            step = Step(request, [], source, n) if is_request(request) else None
            if step is not None:
                items.append(step)
        elif line.startswith("<"):
            if not seen_request:
                raise ScriptError(f"{source}:{n}: expectation before any '>' request")
            pattern = line[2:] if line.startswith("< ") else line[1:]
            try:
                compiled = re.compile(pattern)
            except re.error as exc:
                raise ScriptError(f"{source}:{n}: bad regex {pattern!r}: {exc}") from None
            if step is not None:  # expectations of a dropped (blank/comment) request go with it
                step.expect.append(pattern)
                step.compiled.append(compiled)
        elif not line.strip() or line.lstrip().startswith("#"):
            items.append(line)
        else:
            raise ScriptError(f"{source}:{n}: expected '> request', '< regex', '#' comment or blank line")
    return items


def parse_requests(text: str, source: str = "<requests>") -> list[Item]:
    """A plain file of requests, one per line, as items (for --record)."""
    items: list[Item] = []
    for n, raw in enumerate(text.splitlines(), 1):
        line = raw.rstrip()
        items.append(Step(line.strip(), [], source, n) if is_request(line) else line)
    return items


def load(path: Path) -> list[Item]:
    try:
        text = path.read_text("utf-8")
    except OSError as exc:
        raise ScriptError(f"{path}: {exc.strerror or exc}") from None
    return parse_script(text, str(path)) if looks_like_script(text) else parse_requests(text, str(path))


# ---------------------------------------------------------------------- matching


def check(patterns: Sequence[re.Pattern[str]], lines: Sequence[Line], outcome: str = "ok") -> str | None:
    """Why the reply lines fail the expectations, or None if they pass.

    ``lines`` are everything that arrived while the request was waited for; ``outcome`` is the
    session's (ok/error: the final line came; timeout; closed).
    """
    i = 0
    for line in lines if patterns else ():  # no expectations: any final line will do
        # another request's line is matched as it came, tag and all (shown may have its tag taken
        # off for people to read), so the late OK of a timed-out step never passes for the next one
        if i < len(patterns) and patterns[i].fullmatch(line.shown if line.mine else line.text):
            i += 1
            continue
        if not line.mine or line.status in SKIPPABLE:
            continue
        if i < len(patterns):
            return f"expectation {i + 1} does not match: {line.shown}"
        return f"unexpected line, no expectation left for it: {line.shown}"
    if outcome == "timeout":
        return "timeout: no final line"
    if outcome == "closed":
        return "the server closed the connection"
    if i < len(patterns):
        return f"final line arrived with {len(patterns) - i} expectation(s) left"
    return None


# ---------------------------------------------------------------------- recording

_ISO = r"\d{4}-\d{2}-\d{2}T\d{2}:\d{2}:\d{2}(?:\.\d+)?(?:Z|[+-]\d{2}:?\d{2})?"
_COMPACT = r"\d{8}T\d{6}(?:_\d+)?Z?"
_JOB_IN_TEXT = r"\d+"
_VOLATILE_TEXT = re.compile(rf"(?P<iso>{_ISO})|(?P<compact>{_COMPACT})|(?<=\bjob )(?P<job>\d+)")
_NUM = r"[0-9.]+"
_INT = r"\d+"
# Values that differ from run to run or from build to build, by key.
VOLATILE_KEYS: dict[str, str] = {
    "job": _INT,
    "interrupted": _INT,
    "clients": _INT,
    "uptime": _NUM,
    "slept": _NUM,
    "elapsed": _NUM,
    "duration": _NUM,
    "seconds_taken": _NUM,
    "python": r"\S+",
    "devices": r"\S+",
    "checked": r"\S+",
    "progress": r"\d+/\d+",
}
_JSON_VOLATILE: dict[str, str] = {
    "job": _INT,
    "interrupted": _INT,
    "clients": _INT,
    "uptime": r"[0-9.eE+-]+",
    "slept": r"[0-9.eE+-]+",
    "elapsed": r"[0-9.eE+-]+",
    "duration": r"[0-9.eE+-]+",
    "seconds_taken": r"[0-9.eE+-]+",
    "python": r'"[^"]*"',
    "devices": r'(?:"[^"]*"|\[[^\]]*\])',
    "checked": r'(?:"[^"]*"|\[[^\]]*\])',
    "progress": r'"\d+/\d+"',
}
_TEXT_LINE = re.compile(r'(\S+ (?:ACK|PROGRESS|OK|ERROR|EVENT))((?: [a-z_][a-z0-9_]*=(?:"(?:[^"\\]|\\.)*"|[^ "]*))*)')
_TEXT_PAIR = re.compile(r' ([a-z_][a-z0-9_]*)=("(?:[^"\\]|\\.)*"|[^ "]*)')


def escape(text: str) -> str:
    """Like re.escape but leaves spaces, '-', '=', '/', ',' and quotes alone, so recorded
    expectations stay readable."""
    return re.sub(r"([.^$*+?{}\[\]\\|()])", r"\\\1", text)


def _generic(text: str) -> str:
    """Escaped text with timestamps (ISO and file-name style) and 'job N' turned into patterns."""
    out: list[str] = []
    pos = 0
    for m in _VOLATILE_TEXT.finditer(text):
        out.append(escape(text[pos : m.start()]))
        out.append(_ISO if m.group("iso") else _COMPACT if m.group("compact") else _JOB_IN_TEXT)
        pos = m.end()
    out.append(escape(text[pos:]))
    return "".join(out)


def _text_value(key: str, raw: str) -> str:
    pattern = VOLATILE_KEYS.get(key)
    if pattern is not None and re.fullmatch(pattern, raw):
        return pattern
    if raw.startswith('"'):
        return '"' + _generic(raw[1:-1]) + '"'
    return _generic(raw)


def _json_pattern(line: str) -> str | None:
    try:
        obj: Any = json.loads(line)
    except ValueError:
        return None
    if not isinstance(obj, dict):
        return None
    parts: list[str] = []
    for key, value in obj.items():
        literal = json.dumps(value, ensure_ascii=False, separators=(",", ":"))
        pattern = _JSON_VOLATILE.get(key)
        value_re = pattern if pattern is not None and re.fullmatch(pattern, literal) else _generic(literal)
        parts.append(escape(json.dumps(key, ensure_ascii=False)) + ":" + value_re)
    pattern = r"\{" + ",".join(parts) + r"\}"
    return pattern if re.fullmatch(pattern, line) else None


def pattern_for(line: str) -> str:
    """A regex that fullmatches ``line`` and the same reply from another run."""
    if line.startswith("{"):
        pattern = _json_pattern(line)
        if pattern is not None:
            return pattern
        return _generic(line)
    m = _TEXT_LINE.fullmatch(line)
    if m is None:
        return _generic(line)
    head = escape(m.group(1))
    pairs = "".join(f" {key}={_text_value(key, raw)}" for key, raw in _TEXT_PAIR.findall(m.group(2)))
    return head + pairs


def recorded(result: Result) -> list[str]:
    """Expectations for a live result: the request's own ACK, OK and ERROR lines."""
    return [pattern_for(line.shown) for line in result.own if line.status not in SKIPPABLE]


def render_script(items: Sequence[Item], results: dict[int, Result]) -> str:
    out: list[str] = []
    for item in items:
        if isinstance(item, str):
            out.append(item)
            continue
        out.append(f"> {item.request}")
        result = results.get(id(item))
        if result is not None:
            out.extend(f"< {p}" for p in recorded(result))
    return "\n".join(out) + "\n"


# ---------------------------------------------------------------------- running


@dataclass
class Outcome:
    step: Step
    result: Result
    failure: str | None


def run_steps(session: Session, steps: Sequence[Step], timeout: float | None) -> list[Outcome]:
    outcomes: list[Outcome] = []
    for step in steps:
        result = session.request(step.request, timeout=timeout)
        outcomes.append(Outcome(step, result, check(step.compiled, result.lines, result.outcome)))
    return outcomes


def report_failure(outcome: Outcome, out: Any) -> None:
    step, result = outcome.step, outcome.result
    print(f"FAIL {step.where}: > {step.request}", file=out)
    print(f"  {outcome.failure}", file=out)
    print("  expected:", file=out)
    for pattern in step.expect or ["(nothing but a final line)"]:
        print(f"    < {pattern}", file=out)
    print("  actual:", file=out)
    for line in result.lines or []:
        print(f"    {line.shown}" + ("" if line.mine else "    (not about this request)"), file=out)
    if not result.lines:
        print("    (no lines)", file=out)


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    p = ToolParser(
        prog="rvs-replay",
        description="Replay scripts of '> request' / '< regex' lines against an RVS server and check its replies. "
                    "rvs-replay --mcap FILE [--products] replays a recording instead (rvs-replay --mcap X --help).",
    )
    p.add_argument("scripts", nargs="+", type=Path, metavar="SCRIPT", help="replay script(s); with --record, "
                   "one script or plain file of requests")
    p.add_argument("--host", help=f"address of a running server to replay against (default {DEFAULT_HOST} "
                   "when --port is given); replays change its state")
    p.add_argument("--port", type=port_number, help=f"port of a running server (default {DEFAULT_PORT} when --host is given)")
    p.add_argument("--token", help="send 'auth -token TOKEN' before each script")
    p.add_argument("--timeout", type=float, default=DEFAULT_TIMEOUT,
                   help=f"seconds to wait for each request's final line (default {DEFAULT_TIMEOUT:g})")
    p.add_argument("--server", action="store_true",
                   help="start a fresh simulated server (python -m rvs_server --port 0) for each script")
    p.add_argument("--server-arg", action="append", default=[], metavar="ARG",
                   help="extra argument for --server's command line (repeatable), e.g. --server-arg=--scene=quarry")
    p.add_argument("--record", type=Path, metavar="FILE",
                   help="run the requests live and write a script with their replies as expectations")
    p.add_argument("-v", "--verbose", action="store_true", help="also list the requests that pass")
    args = p.parse_args(argv)
    # A replay moves the PTU, sets the pose, breaks jobs: it must never land on whatever server
    # happens to listen on the default port, so the target is always named.
    running = args.host is not None or args.port is not None
    if args.server and running:
        p.error("--server starts a fresh server of its own; drop --host/--port (or --server to use a running one)")
    if not args.server and not running:
        p.error("say which server to replay against: --server for a fresh simulated one, or --host/--port "
                f"for a running one (e.g. --port {DEFAULT_PORT}; the replay changes its state)")
    if running:
        args.host = args.host if args.host is not None else DEFAULT_HOST
        args.port = args.port if args.port is not None else DEFAULT_PORT
    return args


def _session(args: argparse.Namespace, host: str, port: int, retry_for: float, what: str) -> Session:
    session = Session(host, port, tag_prefix="r")
    session.connect(retry_for=retry_for)
    print(f"rvs-replay: replaying against {what} {host}:{port} ({_server_name(session.greeting)})", file=sys.stderr)
    hello = try_parse(session.greeting or "")
    mode = hello.fields.get("mode") if hello is not None else None
    if mode not in (None, "ready"):
        # the scripts start from ready (their jobs are refused in break, standby and fault mode):
        # say so once, rather than leave the operator to read it out of every failure
        print(f"rvs-replay: the server is in {mode} mode, not ready; scripts that run jobs will fail "
              "(send continue or reset first)", file=sys.stderr)
    if args.token is not None:
        result = session.request("auth -token=" + render_value(args.token), timeout=args.timeout)
        if not result.ok:
            session.close()
            final = result.final.shown if result.final else result.outcome
            raise SessionError(f"auth refused: {final}")
    return session


def _server_name(greeting: str | None) -> str:
    """``rvs/0.1.0, protocol 1, mode ready`` from the hello line, so an operator sees what it hit."""
    reply = try_parse(greeting or "")
    fields = reply.fields if reply is not None else {}
    return f"{fields.get('server', '?')}, protocol {fields.get('protocol', '?')}, mode {fields.get('mode', '?')}"


def run_file(args: argparse.Namespace, items: list[Item]) -> list[Outcome]:
    steps = [item for item in items if isinstance(item, Step)]
    timeout = args.timeout if args.timeout > 0 else None
    server: ServerProcess | None = None
    try:
        host, port, what = args.host, args.port, "the running server at"
        if args.server:
            server = ServerProcess(extra_args=args.server_arg)
            host, port, what = DEFAULT_HOST, server.start(), "a fresh simulated server at"
        try:
            session = _session(args, host, port, retry_for=30.0 if server else 0.0, what=what)
        except (OSError, SessionError) as exc:
            where = f"{host}:{port}"
            tail = f"\n{server.log_tail()}" if server is not None else ""
            raise SessionError(f"cannot talk to {where}: {exc}{tail}") from None
        with session:
            return run_steps(session, steps, timeout)
    finally:
        if server is not None:
            server.stop()


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if any(a == "--mcap" or a.startswith("--mcap=") for a in argv):  # a recording, not a script
        from .recording_replay import main as replay_recording

        return replay_recording(argv)
    args = parse_args(argv)
    if args.record is not None and len(args.scripts) != 1:
        print("rvs-replay: --record takes exactly one input file", file=sys.stderr)
        return 2
    if args.record is not None and not args.record.absolute().parent.is_dir():
        # found out before the replay runs (and changes the server), not after
        print(f"rvs-replay: --record {args.record}: no folder {args.record.absolute().parent}", file=sys.stderr)
        return 2
    try:
        loaded = [(path, load(path)) for path in args.scripts]
    except ScriptError as exc:
        print(f"rvs-replay: {exc}", file=sys.stderr)
        return 2
    outcomes: list[Outcome] = []
    for _path, items in loaded:
        try:
            file_outcomes = run_file(args, items)
        except SessionError as exc:
            print(f"rvs-replay: {exc}", file=sys.stderr)
            return 2
        except KeyboardInterrupt:
            print(f"\nrvs-replay: interrupted in {_path}", file=sys.stderr)
            return 130
        outcomes.extend(file_outcomes)
        if args.record is not None:
            results = {id(o.step): o.result for o in file_outcomes}
            try:
                args.record.write_text(render_script(items, results), "utf-8")
            except OSError as exc:
                print(f"rvs-replay: cannot write {args.record}: {exc.strerror or exc}", file=sys.stderr)
                return 2
    passed = failed = 0
    for outcome in outcomes:
        # When recording there is nothing to expect yet: a request passes once it is answered.
        failure = outcome.failure
        if args.record is not None:
            failure = None if outcome.result.final is not None else f"no final line ({outcome.result.outcome})"
            outcome.failure = failure
        if failure is None:
            passed += 1
            if args.verbose:
                print(f"ok   {outcome.step.where}: > {outcome.step.request}")
        else:
            failed += 1
            report_failure(outcome, sys.stdout)
    if args.record is not None:
        print(f"recorded {len(outcomes)} requests to {args.record}")
    print(f"{passed} passed, {failed} failed")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
