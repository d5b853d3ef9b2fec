"""What the device consoles (``rvs-ptu``, ``rvs-tof``, ``rvs-cam``) share.

A bench console must outlive whatever the hardware does, so every command's error is caught and
printed, and a one-shot run (``-c``) reports through its exit status whether any line failed.
The consoles differ in which errors are worth a bare message, what Ctrl-C means and how a ``-c``
line is echoed; those are class attributes or small overrides here, so each tool keeps its exact
output while the scaffolding lives once.

A one-shot run's stdout holds the commands' results and nothing else (``rvs-cam -c calibration >
calib.yaml`` must be YAML a program reads): the echo of a ``-c`` line, what the start-up command
(``open``, ``init``) prints, warnings and errors are *notes*, which go to stderr there. At the
prompt a person reads both in one place, so notes go to the console's stdout.
"""

from __future__ import annotations

import cmd
import contextlib
import json
import math
import shlex
import sys
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any, TextIO

import yaml

from drivers.base import DeviceError

DEFAULT_CONFIG = Path(__file__).resolve().parents[1] / "config" / "drivers.yaml"


def default_data_dir() -> Path:
    """The server's default data directory (``data`` in config/server.yaml), so bench images land
    beside the server's own products rather than wherever the console was started."""
    server_yaml = DEFAULT_CONFIG.with_name("server.yaml")
    data = (yaml.safe_load(server_yaml.read_text()) or {}).get("data") if server_yaml.is_file() else None
    return Path(data or "data")


def split_words(arg: str, n_min: int, n_max: int, usage: str) -> list[str]:
    """Shell-style words of a command's argument, so a wrong count answers with the usage line."""
    words = shlex.split(arg)
    if not n_min <= len(words) <= n_max:
        raise ValueError(f"usage: {usage}")
    return words


def numbers(arg: str, n_min: int, n_max: int, usage: str, kind: type = float) -> list[Any]:
    """The command's words as numbers of ``kind``: a word that is not one answers with the usage
    line, where Python's conversion message would not say which command or what to type."""
    words = split_words(arg, n_min, n_max, usage)
    try:
        values = [kind(w) for w in words]
    except ValueError:
        raise ValueError(f"{'whole ' if kind is int else ''}numbers expected; usage: {usage}") from None
    if not all(math.isfinite(v) for v in values):
        raise ValueError(f"finite numbers expected; usage: {usage}")
    return values


def read_config(path: str | Path | None = None) -> dict[str, Any] | None:
    """The whole drivers YAML, or None when none was named and the default file is absent.

    A named file that is missing raises OSError: the user asked for it, so silently falling back to
    built-in defaults would hide a typo.
    """
    source = Path(path) if path else (DEFAULT_CONFIG if DEFAULT_CONFIG.exists() else None)
    if source is None:
        return None
    try:
        data = yaml.safe_load(source.read_text()) or {}
    except yaml.MarkedYAMLError as exc:
        if exc.problem_mark is not None:
            exc.problem_mark.name = str(source)  # so the message names the file, not "<unicode string>"
        raise
    if not isinstance(data, dict):
        raise ValueError(f"{source}: not a drivers config (want a mapping of device sections such as 'tof:')")
    return data


#: What a console's start-up (config file, option values, scene, backend) may raise on bad input:
#: each is reported as one line and exit status 2, never as a traceback.
SETUP_ERRORS: tuple[type[Exception], ...] = (OSError, ValueError, TypeError, DeviceError, yaml.YAMLError)


def one_line(exc: BaseException) -> str:
    """An exception as one line for ``tool: message``: YAML's errors span several lines (the
    quoted source and a caret), so they become their position and problem."""
    if isinstance(exc, yaml.MarkedYAMLError) and exc.problem_mark is not None:
        mark = exc.problem_mark
        where = f"{mark.name}: " if mark.name and not mark.name.startswith("<") else ""
        return f"{where}not valid YAML: {exc.problem} (line {mark.line + 1}, column {mark.column + 1})"
    if isinstance(exc, FileNotFoundError) and exc.filename:
        return f"{exc.filename}: no such file"
    return " ".join(str(exc).split()) or type(exc).__name__


def load_section(section: str, defaults: dict[str, Any], path: str | Path | None = None) -> dict[str, Any]:
    """A device's section of drivers.yaml over its defaults, so a console runs with no config at all."""
    config = dict(defaults)
    data = read_config(path)
    if data is not None:
        config.update(data.get(section, {}) or {})
    return config


class DeviceConsole(cmd.Cmd):
    """A bench session must outlive whatever a command raises: errors are printed, never fatal.

    A one-shot run's lines are checked before anything runs, as a program's options are: a
    command that does not exist, or arguments its ``check_<command>`` refuses, is one ``tool:
    message`` line and exit status 2, with the device untouched (half a script run against the
    hardware, then a typo, helps nobody)."""

    #: The program's name, which starts its one-line usage errors.
    tool = "rvs-console"
    #: Commands that answer without an open device: a one-shot run of only these goes on when the
    #: start-up command fails (what is on the bus, what the driver state is), any other stops there.
    offline: frozenset[str] = frozenset({"help", "status", "quit", "exit"})

    #: Errors the message of which is self-explanatory; anything else is printed with its type.
    plain_errors: tuple[type[Exception], ...] = (DeviceError, ValueError)
    #: False lets Ctrl-C during a command end the session instead of returning to the prompt.
    catch_interrupts = True
    #: Tail of the unknown-command message. Not named help_*: cmd.Cmd would list that as a help topic.
    unknown_hint = "'help' lists the commands"

    def __init__(self, stdout: TextIO | None = None, notes: TextIO | None = None) -> None:
        super().__init__(stdout=stdout or sys.stdout)
        self.failed: bool | int = False
        self._notes = notes

    @property
    def notes(self) -> TextIO:
        """Where notes go (see the module's docstring): stdout unless :func:`run` says otherwise."""
        return self._notes if self._notes is not None else self.stdout

    @notes.setter
    def notes(self, stream: TextIO | None) -> None:
        self._notes = stream

    def say(self, text: str) -> None:
        """A result, flushed at once, so a long command's progress shows while it runs."""
        self.stdout.write(text + "\n")
        self.stdout.flush()

    def note(self, text: str) -> None:
        """Anything that is not a command's result: kept apart so a one-shot stdout stays parseable."""
        self.notes.write(text + "\n")
        self.notes.flush()

    @contextlib.contextmanager
    def results_as_notes(self) -> Iterator[None]:
        """A command run for its side effect (the start-up ``open``): what it prints is a note."""
        stdout = self.stdout
        self.stdout = self.notes
        try:
            yield
        finally:
            self.stdout = stdout

    def dump(self, data: Any) -> None:
        """Device structures as indented JSON, readable and still parseable by scripts."""
        self.say(json.dumps(data, indent=2, default=str))

    def fail(self, message: str) -> None:
        """Every failure passes here so a one-shot run can report it in its exit status."""
        self.failed = True
        self.note(message)

    def interrupted(self) -> None:
        """Ctrl-C stops only the running command; a console whose device keeps moving overrides this."""
        self.note("interrupted")

    def onecmd(self, line: str) -> bool:
        try:
            return bool(super().onecmd(line))
        except KeyboardInterrupt:
            if not self.catch_interrupts:
                raise
            self.interrupted()
        except self.plain_errors as exc:
            self.fail(f"error: {exc}")
        except Exception as exc:  # noqa: BLE001 - a console reports everything and carries on
            self.fail(f"error: {type(exc).__name__}: {exc}")
        return False

    def emptyline(self) -> bool:
        return False  # never repeat the last command (it may be a move or a grab)

    def default(self, line: str) -> bool:
        self.fail(f"error: unknown command {line.split()[0]!r}; {self.unknown_hint}")
        return False

    def commands_in(self, line: str) -> list[str]:
        """The commands of one ``-c`` argument: ``;`` separates them, so a script needs one
        argument per step."""
        return [c for c in (part.strip() for part in line.split(";")) if c]

    def run_line(self, line: str) -> bool:
        """One ``-c`` argument; True once a command asks to leave, like ``cmdloop`` would stop."""
        return any(self.onecmd(self.precmd(command)) for command in self.commands_in(line))

    def usage_problem(self, lines: Sequence[str]) -> str | None:
        """What is wrong with a one-shot run's commands as typed, before any runs: an unknown
        command, or arguments its ``check_<command>(arg)`` refuses (ValueError); None if nothing."""
        for line in lines:
            for command in self.commands_in(line):
                name, arg, _ = self.parseline(self.precmd(command))
                if not name or not hasattr(self, f"do_{name}"):
                    return f"unknown command {command.split()[0]!r}; {self.unknown_hint}"
                check = getattr(self, f"check_{name}", None)
                if check is not None:
                    try:
                        check(arg or "")
                    except ValueError as exc:
                        return f"{name}: {exc}"
        return None

    def all_offline(self, lines: Sequence[str]) -> bool:
        """Whether every command of a one-shot run answers without an open device."""
        return all((self.parseline(self.precmd(c))[0] or "") in self.offline
                   for line in lines for c in self.commands_in(line))

    def start_up(self, line: str) -> str | None:
        """A one-shot run's start-up command (``open``): None once it ran, else why it failed, as
        one line (a device that cannot be opened is the run's set-up failing, like a bad option)."""
        try:
            super().onecmd(self.precmd(line))
        except Exception as exc:  # noqa: BLE001 - whatever the device says, said once
            return one_line(exc)
        return None

    def do_quit(self, arg: str) -> bool:
        """quit: leave the console."""
        return True

    do_exit = do_quit

    def do_EOF(self, arg: str) -> bool:  # noqa: N802 - cmd.Cmd's name for end of input
        self.say("")
        return True


def run(
    console: DeviceConsole,
    lines: Sequence[str],
    *,
    start: str | None = None,
    close: Callable[[], object] | None = None,
    prompt_status: bool = False,
    notes: TextIO | None = None,
) -> int:
    """The console's session: ``lines`` one-shot if any, else the interactive prompt.

    ``start`` (e.g. ``open``) runs first so the device is ready; ``close`` runs however the session
    ends and its errors are swallowed, since leaving must never trace back. One-shot runs exit 2
    when a line does not parse or ``start`` fails (one line on ``notes``), 1 if any command failed; the prompt exits 0 unless ``prompt_status``, as a person saw the errors.
    One-shot, notes (``start``'s output among them) go to ``notes``, by default stderr.
    """
    if lines:
        console.notes = notes or sys.stderr
        problem = console.usage_problem(lines)
        if problem is not None:
            console.notes.write(f"{console.tool}: {problem}\n")
            return 2
    try:
        if start is not None:
            if lines and console.all_offline(lines):
                with console.results_as_notes():
                    console.onecmd(start)  # a failure is reported and the commands still answer
            elif lines:
                with console.results_as_notes():
                    failure = console.start_up(start)
                if failure is not None:
                    console.notes.write(f"{console.tool}: {failure}\n")
                    return 2
            else:
                console.onecmd(start)
        if lines:
            for line in lines:
                if console.run_line(line):
                    break
            return 1 if console.failed else 0
        console.cmdloop()
        return (1 if console.failed else 0) if prompt_status else 0
    finally:
        if close is not None:
            try:
                close()
            except Exception:  # noqa: BLE001 - leaving the console must not trace back
                pass
