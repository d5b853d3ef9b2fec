"""rvs-client: talk to an RVS server, interactively (line editing, history) or one-shot.

One-shot (``-c`` requests, or requests on a piped stdin) is for scripts and the GNC bench: each
request waits for its final line, and the exit status says whether any ended in ERROR.
Interactive is for operators: EVENTs and late job lines print while they type, and Ctrl-C stops
waiting for a long job without stopping it (``break`` does that).
"""

from __future__ import annotations

import argparse
import os
import sys
import threading
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path
from typing import Any, TextIO

from rvs_params.cli import ToolParser
from rvs_server.protocol import render_value

from .session import DEFAULT_HOST, DEFAULT_PORT, Line, Result, Session, SessionError, is_request, port_number

DEFAULT_TIMEOUT = 600.0
PROMPT = "rvs> "
HISTORY_FILE = ".rvs_client_history"


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    p = ToolParser(
        prog="rvs-client",
        description="Send requests to an RVS server and print its replies. Without -c, reads requests "
        "from stdin when it is piped, otherwise starts an interactive session (Ctrl-D leaves; "
        "note that 'quit' stops the server itself).",
    )
    p.add_argument("--host", default=DEFAULT_HOST, help=f"server address (default {DEFAULT_HOST})")
    p.add_argument("--port", type=port_number, default=DEFAULT_PORT, help=f"server port (default {DEFAULT_PORT})")
    p.add_argument("--token", help="send 'auth -token TOKEN' before anything else")
    p.add_argument("--format", choices=("text", "json"), default="text",
                   help="reply format: json sends 'format json' at connect and prints the greeting and every "
                        "line as JSON (default text)")
    p.add_argument("--json", action="store_const", dest="format", const="json", help="same as --format json")
    p.add_argument("--timeout", type=float, default=DEFAULT_TIMEOUT,
                   help=f"seconds to wait for each request's final line (default {DEFAULT_TIMEOUT:g}; 0: forever)")
    p.add_argument("-c", "--command", action="append", default=[], metavar="REQUEST",
                   help="send this request (repeatable, in order) and exit")
    p.add_argument("--progress", choices=("auto", "bar", "lines"), default="auto",
                   help="PROGRESS lines as a progress bar redrawn in place, or as lines (default: a bar when "
                        "the output is a terminal)")
    p.add_argument("-v", "--verbose", action="store_true",
                   help="one-shot: also print the greeting and the replies to --token and --format json")
    return p.parse_args(argv)


BAR_WIDTH = 24


def progress_bar(reply: Any) -> str:
    """One PROGRESS line as a bar: phase (and leg) first, because done/total count per phase."""
    f = reply.fields
    try:
        done, total = int(f["done"]), int(f["total"])
    except (KeyError, ValueError):
        return ""
    filled = BAR_WIDTH * min(done, total) // max(total, 1)
    where = " ".join(x for x in (f.get("phase", ""), f"leg {f['leg']}" if "leg" in f else "") if x)
    job = f"job {f['job']} " if "job" in f else ""
    return f"{job}{where + ' ' if where else ''}[{'#' * filled}{'.' * (BAR_WIDTH - filled)}] {done}/{total} " \
           f"{f.get('message', '')}"


class Printer:
    """Serialises output from the main and reader threads, and keeps the prompt intact.

    While the user is at the prompt, an asynchronous line is printed above it and the prompt
    and what they have typed so far are drawn again (the usual readline idiom). With ``bar``,
    a request's PROGRESS lines redraw one progress bar in place instead of scrolling by.
    """

    def __init__(self, out: TextIO, readline: Any = None, bar: bool = False) -> None:
        self.out = out
        self.readline = readline
        self.lock = threading.Lock()
        self.at_prompt = False
        self.bar = bar
        self.bar_shown = False

    def line(self, text: str) -> None:
        with self.lock:
            if self.bar_shown:  # the bar's line becomes this line
                self.out.write("\r\x1b[2K")
                self.bar_shown = False
            if self.at_prompt and self.readline is not None:
                buf = self.readline.get_line_buffer()
                self.out.write(f"\r\x1b[2K{text}\n{PROMPT}{buf}")
            elif self.at_prompt:
                self.out.write(f"\n{text}\n")
            else:
                self.out.write(text + "\n")
            self.out.flush()

    def reply(self, line: Line) -> None:
        if line.status == "PROGRESS" and self.at_prompt:
            # a job whose wait Ctrl-C stopped: its progress scrolling past the prompt (redrawn
            # under each line) would bury what is typed; its final line still prints, status
            # shows how far it is
            return
        if self.bar and line.status == "PROGRESS":
            text = progress_bar(line.reply)
            if text:
                with self.lock:
                    self.out.write("\r\x1b[2K" + text)
                    self.out.flush()
                    self.bar_shown = True
                return
        self.line(line.shown)


def _split(requests: Iterable[str]) -> Iterator[str]:
    """Requests, one per line, without the blank and comment lines the server never answers.

    Lazy, so requests piped in by a slow producer go out as they come.
    """
    for item in requests:
        yield from (part for part in item.splitlines() if is_request(part))


def _report(result: Result, timeout: float | None) -> None:
    if result.outcome == "timeout":
        print(f"rvs-client: no final reply within {timeout:g} s to: {result.request}", file=sys.stderr)
    elif result.outcome == "closed":
        print(f"rvs-client: the server closed the connection before answering: {result.request}", file=sys.stderr)


def _setup(session: Session, args: argparse.Namespace, printer: Printer, verbose: bool, timeout: float | None) -> bool:
    """Authenticate and switch format as asked; False if the server said no."""
    steps: list[Callable[[], Result]] = []
    if args.token is not None:
        steps.append(lambda: session.request("auth -token=" + render_value(args.token), timeout=timeout))
    if args.format == "json":
        steps.append(lambda: session.set_format("json", timeout))
    for step in steps:
        result = step()
        if verbose or not result.ok:
            for line in result.own:
                printer.reply(line)
        if not result.ok:
            _report(result, timeout)
            return False
    return True


def run_batch(session: Session, requests: Iterable[str], printer: Printer, timeout: float | None) -> int:
    failed = False
    for request in requests:
        result = session.request(request, timeout=timeout, on_line=printer.reply)
        if result.outcome in ("timeout", "closed"):
            _report(result, timeout)
            return 1  # the connection is in no state for the next request
        failed |= not result.ok
    return 1 if failed else 0


def _history_path() -> Path:
    return Path(os.environ.get("RVS_CLIENT_HISTORY") or Path.home() / HISTORY_FILE)


def _load_readline() -> Any:
    try:
        import readline
    except ImportError:  # e.g. Windows without pyreadline: plain input() still works
        return None
    path = _history_path()
    try:
        if path.exists():
            readline.read_history_file(path)
    except OSError:
        pass
    readline.set_history_length(1000)
    return readline


def _save_history(readline: Any) -> None:
    if readline is None:
        return
    try:
        readline.write_history_file(_history_path())
    except OSError as exc:
        print(f"rvs-client: cannot save history: {exc}", file=sys.stderr)


def run_interactive(session: Session, printer: Printer, timeout: float | None) -> int:
    failed = False
    try:
        while not session.closed:
            printer.at_prompt = True
            try:
                text = input(PROMPT)
            except EOFError:
                printer.line("")
                break
            except KeyboardInterrupt:
                printer.at_prompt = False
                printer.line("")
                continue
            finally:
                printer.at_prompt = False
            if not is_request(text):
                continue
            if session.closed:
                break
            for request in _split([text]):
                try:
                    result = session.request(request, timeout=timeout, on_line=printer.reply)
                except KeyboardInterrupt:
                    printer.line("(stopped waiting; its final line prints when it comes, 'status' shows its progress, "
                                 "'break' stops it)")
                    continue
                _report(result, timeout)
                failed |= not result.ok
    finally:
        _save_history(printer.readline)
    return 1 if failed else 0


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    timeout = args.timeout if args.timeout > 0 else None
    interactive = not args.command and sys.stdin.isatty()
    readline = _load_readline() if interactive else None
    bar = args.progress == "bar" or (args.progress == "auto" and sys.stdout.isatty())
    printer = Printer(sys.stdout, readline, bar=bar)

    def closed() -> None:
        if interactive:
            printer.line("(the server closed the connection)")

    session = Session(args.host, args.port, on_async=printer.reply, on_close=closed)
    try:
        session.connect()
    except (OSError, OverflowError, SessionError) as exc:
        print(f"rvs-client: cannot talk to {args.host}:{args.port}: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:  # Ctrl-C while a slow host is looked up or answers
        session.close()
        return 130
    try:
        if not _setup(session, args, printer, args.verbose, timeout):
            return 1
        if (interactive or args.verbose) and session.greeting is not None:
            printer.line(session.greeting)  # after setup: in the format the session goes on in
        if interactive:
            return run_interactive(session, printer, timeout)
        requests = _split(args.command) if args.command else _split(sys.stdin)
        return run_batch(session, requests, printer, timeout)
    except KeyboardInterrupt:
        return 130
    finally:
        session.close()


if __name__ == "__main__":
    sys.exit(main())
