"""The RVS wire protocol (PROTOCOL.md): request parsing and reply formatting, pure and without I/O.

Kept free of sockets and state so that the server, the client, the replay tool and the property
tests all share one definition of the grammar.
"""

from __future__ import annotations

import json
import math
import numbers
import re
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any, ClassVar

from rvs_params import STEM_RE, is_number, valid_stem  # noqa: F401 - the one file-stem rule, shared with settings

MAX_LINE = 4096
DASHES = ("--", "-", "\u2013")  # longest first; the en dash is how the thesis prints "-output"
TAG_RE = re.compile(r"[A-Za-z0-9_.:\-]{1,32}")
NAME_RE = re.compile(r"[A-Za-z][A-Za-z0-9_\-]*")
KEY_RE = re.compile(r"[a-z][a-z0-9_]*")
BARE_VALUE_RE = re.compile(r"[^\s\"=]+")
STATUSES = ("ACK", "PROGRESS", "OK", "ERROR", "EVENT")


class ProtocolError(Exception):
    """A request the server must answer with an ERROR line; carries the protocol's error code."""

    def __init__(self, code: str, message: str) -> None:
        super().__init__(message)
        self.code = code
        self.message = message


@dataclass
class Request:
    """One parsed request line.

    ``options`` keeps the order and repeats of the line (``config -set a=1 -set b=2``); option
    names are lower case with ``-`` folded to ``_`` so they match config field names. A flag's
    value is ``True``. ``positional`` holds bare words that follow the command before any option
    (``help grab-tof``, ``events off``). ``sent`` is the command word as the client wrote it
    (``command`` is its lower-case lookup key), for replies that quote it back.
    """

    command: str
    tag: str | None = None
    options: list[tuple[str, str | bool]] = field(default_factory=list)
    positional: list[str] = field(default_factory=list)
    sent: str = ""

    def __post_init__(self) -> None:
        self.sent = self.sent or self.command


@dataclass
class Reply:
    """One reply line: ``module status key=value...``; ``tag`` is rendered as the first key."""

    module: str
    status: str
    fields: dict[str, Any] = field(default_factory=dict)
    tag: str | None = None


class Fixed(float):
    """A float that keeps its number of decimals on the wire (``pan=-30.000``).

    A float subclass so JSON still renders it as a number.
    """

    decimals: int

    def __new__(cls, value: float, decimals: int = 3) -> Fixed:
        obj = super().__new__(cls, value)
        obj.decimals = decimals
        return obj


class Rows(list[tuple[Any, ...]]):
    """Records of one width (waypoints as x, y, heading).

    The text grammar has only flat comma lists, so text runs the records together
    (``x1,y1,h1,x2,...``) and the reader splits them by the width the protocol page gives; JSON
    keeps each record an array (``[[x1, y1, h1], ...]``) so a JSON client needs no such knowledge.
    """


class Group(dict[str, Any]):
    """Keys that belong to one thing rather than to the reply (a module's settings in ``config``).

    Their names and types are the module's, not the protocol's, and clash with reply keys
    (``height`` is a flag in one module and a length in a reply), so JSON nests them in one object
    under the group's key; text, which has no nesting, spreads them into the line as before
    (a nested mapping's keys joined with ``_``: ``ptu_backend=sim``).
    """


# Keys whose value is a number or a word (``worst=0.850`` or ``worst=unknown``): JSON carries
# their text, so that the key keeps one type.
TEXT_VALUED_KEYS = frozenset({"worst"})


# --------------------------------------------------------------------------------------------
# requests


def _tokenize(line: str) -> list[tuple[str, bool, int | None]]:
    """Split a request into tokens: (text, started_quoted, index of the first unquoted '=').

    Quoted sections may be glued to bare text (``-name="a b"``), as in a shell.
    """
    tokens: list[tuple[str, bool, int | None]] = []
    i, n = 0, len(line)
    while i < n:
        while i < n and line[i] in " \t\r":
            i += 1
        if i >= n:
            break
        buf: list[str] = []
        started_quoted = line[i] == '"'
        eq: int | None = None
        while i < n and line[i] not in " \t\r":
            c = line[i]
            if c == '"':
                i += 1
                while True:
                    if i >= n:
                        raise ProtocolError("E_SYNTAX", "unbalanced double quote; close it with \"")
                    c = line[i]
                    if c == "\\":
                        if i + 1 >= n:
                            raise ProtocolError("E_SYNTAX", "backslash at end of line inside a quoted value")
                        e = line[i + 1]
                        if e in '"\\':
                            buf.append(e)
                        elif e == "n":
                            buf.append("\n")
                        else:
                            raise ProtocolError(
                                "E_SYNTAX", f"unknown escape \\{e} in a quoted value; use \\\" or \\\\"
                            )
                        i += 2
                    elif c == '"':
                        i += 1
                        break
                    else:
                        buf.append(c)
                        i += 1
            else:
                if c == "=" and eq is None:
                    eq = len(buf)
                buf.append(c)
                i += 1
        tokens.append(("".join(buf), started_quoted, eq))
    return tokens


def _option_name(text: str, quoted: bool) -> str | None:
    """The option name if the token is an option: dashes followed by a letter."""
    if quoted:
        return None
    for dash in DASHES:
        if text.startswith(dash):
            rest = text[len(dash) :]
            if rest[:1].isascii() and rest[:1].isalpha():
                return rest
            return None
    return None


BLANKS = " \t\r"  # around a request; telnet clients may send CR CR LF


def is_silent(line: bytes) -> bool:
    """Blank and comment lines get no reply, whatever bytes follow the ``#``: decided on the
    bytes, before any UTF-8 check, so a comment in another encoding is still a comment."""
    stripped = line.strip(BLANKS.encode())
    return not stripped or stripped.startswith(b"#")


def parse_request(line: str) -> Request | None:
    """Parse one request line (already stripped of CR/LF and telnet bytes).

    Returns None for blank and comment lines, which get no reply.
    """
    stripped = line.strip(BLANKS)
    if not stripped or stripped.startswith("#"):
        return None
    tokens = _tokenize(stripped)
    tag: str | None = None
    text, quoted, _ = tokens[0]
    if text.startswith("@") and not quoted:
        tag = text[1:]
        if not TAG_RE.fullmatch(tag):
            raise ProtocolError(
                "E_SYNTAX", "bad tag: use @ followed by 1-32 of letters, digits, '_', '.', ':', '-'"
            )
        tokens = tokens[1:]
        if not tokens:
            raise _tagged_error(tag, "E_SYNTAX", "a tag must be followed by a command")
    text, quoted, _ = tokens[0]
    if quoted or not text or _option_name(text, quoted) is not None:
        raise _tagged_error(tag, "E_SYNTAX", "a request starts with a command name; try help")
    req = Request(command=text.lower(), tag=tag, sent=text)
    i = 1
    while i < len(tokens):
        text, quoted, eq = tokens[i]
        name = _option_name(text, quoted)
        if name is None:
            if req.options:
                raise _tagged_error(
                    tag, "E_ARG", f"value '{_clip(text)}' does not follow an option; write -option value"
                )
            req.positional.append(text)
            i += 1
            continue
        value: str | bool
        if eq is not None:
            # eq counts characters of the token's text; the dash prefix is part of it
            dash_len = len(text) - len(name)
            name, value = text[dash_len:eq], text[eq + 1 :]
        elif i + 1 < len(tokens) and _is_value(*tokens[i + 1][:2]):
            value = tokens[i + 1][0]
            i += 1
        else:
            value = True
        if not NAME_RE.fullmatch(name):
            raise _tagged_error(tag, "E_ARG", f"bad option name '-{_clip(name)}'; names are letters, digits, '-', '_'")
        req.options.append((name.lower().replace("-", "_"), value))
        i += 1
    return req


def _is_value(text: str, quoted: bool) -> bool:
    """Whether a token after an option is its value: anything but an option, and a number or a
    list of them even where a letter follows the dash (``-tilt -inf``, ``-range -Infinity,0,1,2``),
    so that the option's own check judges it; no option is named like a number."""
    return _option_name(text, quoted) is None or all(is_number(part) for part in text.split(","))


def _tagged_error(tag: str | None, code: str, message: str) -> ProtocolError:
    err = ProtocolError(code, message)
    err.tag = tag  # type: ignore[attr-defined]
    return err


def _clip(text: str, n: int = 40) -> str:
    return text if len(text) <= n else text[: n - 3] + "..."


def tag_of(line: str) -> str | None:
    """Best-effort tag of a line that failed to parse, so its ERROR still carries it."""
    m = re.match(r"\s*@([A-Za-z0-9_.:\-]{1,32})(\s|$)", line)
    return m.group(1) if m else None


# --------------------------------------------------------------------------------------------
# replies


def _scalar(value: Any) -> Any:
    """A numpy scalar (a count summed over an array, a comparison) as its Python twin, so both
    formats give it the type of a plain number or flag."""
    item = getattr(value, "item", None)
    return item() if callable(item) and getattr(value, "shape", None) == () else value


# Characters a terminal acts on rather than shows (BEL, Ctrl-L, ESC sequences, a CR that
# rewrites the line, NUL...): C0 but tab and LF (which quoting writes as \n), DEL and C1.
CONTROLS = re.compile("[\x00-\x08\x0b-\x1f\x7f-\x9f]")


def _caret(char: str) -> str:
    code = ord(char)
    if code >= 0x80:
        return "M-" + _caret(chr(code - 0x80))
    return "^" + chr(code ^ 0x40)  # ^@ NUL, ^G BEL, ^L form feed, ^[ ESC, ^? DEL


def show_controls(text: str) -> str:
    """Control characters in caret notation, as ``cat -v`` shows them (Ctrl-L is ``^L``, C1
    ``M-^[``): a value that quotes what a client sent (an unknown command's name, a bad value)
    then cannot ring, clear or drive an operator's terminal. The reply grammar's quoted strings
    have no escape for them, so text shows them (lossily); JSON escapes them exactly."""
    return CONTROLS.sub(lambda m: _caret(m.group()), text)


def render_value(value: Any) -> str:
    """A value as it appears on a text line: bare when it can be, quoted otherwise."""
    value = _scalar(value)
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, numbers.Integral):
        return str(int(value))
    if isinstance(value, Fixed):
        return f"{float(value):.{value.decimals}f}" if math.isfinite(value) else "nan"
    if isinstance(value, numbers.Real):
        return format(float(value), ".6g") if math.isfinite(value) else "nan"
    if value is None:
        return "none"
    if isinstance(value, list | tuple):
        value = ",".join(render_value(v) for v in value)
    text = show_controls(str(value))
    if text and BARE_VALUE_RE.fullmatch(text):
        return text
    return '"' + text.replace("\\", "\\\\").replace('"', '\\"').replace("\n", "\\n") + '"'


def format_reply(reply: Reply) -> str:
    """The text line of a reply, without its line end."""
    parts = [reply.module, reply.status]
    if reply.tag is not None:
        parts.append(f"tag={reply.tag}")
    parts.extend(_text_pairs(reply.fields))
    return " ".join(parts)


def _text_pairs(fields: dict[str, Any], prefix: str = "", settings: bool = False) -> Iterator[str]:
    for key, value in fields.items():
        if isinstance(value, Group):
            yield from _text_pairs(value, prefix, True)
        elif isinstance(value, dict):
            yield from _text_pairs(value, f"{prefix}{key}_", settings)
        elif settings and isinstance(value, float) and math.isnan(value):
            # A setting holds NaN only as its declared "not set" default (a value given is
            # always finite): none, as PROTOCOL says absent values read, and as JSON's null.
            yield f"{prefix}{key}=none"
        else:
            yield f"{prefix}{key}={render_value(value)}"


def _json_value(value: Any) -> Any:
    """The JSON twin of :func:`render_value`: a number is the figure text prints (so both
    formats carry the same digits), absent (None) and undefined (NaN) values are null."""
    value = _scalar(value)
    if isinstance(value, bool | str) or value is None:
        return value
    if isinstance(value, numbers.Integral):
        return int(value)
    if isinstance(value, numbers.Real):
        return float(render_value(value)) if math.isfinite(value) else None
    if isinstance(value, dict):
        return {key: _json_value(v) for key, v in value.items()}
    if isinstance(value, list | tuple):
        return [_json_value(v) for v in value]
    return str(value)


def format_reply_json(reply: Reply) -> str:
    """The JSON line of a reply: the same content, numbers as JSON numbers."""
    obj: dict[str, Any] = {"module": reply.module, "status": reply.status}
    if reply.tag is not None:
        obj["tag"] = reply.tag
    for key, value in reply.fields.items():
        # a field never overwrites the line's own module, status or tag
        name = key + "_" if key in ("module", "status", "tag") else key
        text_valued = key in TEXT_VALUED_KEYS and not isinstance(value, str)
        obj[name] = render_value(value) if text_valued else _json_value(value)
    # json escapes C0 itself; DEL and C1 too, so the line is as safe to show as a text one
    return _JSON_RAW_CONTROLS.sub(lambda m: f"\\u{ord(m.group()):04x}",
                                  json.dumps(obj, separators=(",", ":"), ensure_ascii=False))


_JSON_RAW_CONTROLS = re.compile("[\x7f-\x9f]")


def parse_reply(line: str) -> Reply:
    """Parse a text reply line (for clients, replays and tests); values come back as strings."""
    line = line.rstrip("\r\n")
    if line.startswith("{"):
        try:
            obj = json.loads(line)
            module, status = obj.pop("module"), obj.pop("status")
        except (ValueError, KeyError, AttributeError) as exc:
            raise ProtocolError("E_SYNTAX", f"bad JSON reply: {exc}") from None
        tag = obj.pop("tag", None)
        return Reply(module, status, obj, tag)
    head = line.split(" ", 2)
    if len(head) < 2 or head[1] not in STATUSES:
        raise ProtocolError("E_SYNTAX", f"not a reply line: {_clip(line)!r}")
    module, status = head[0], head[1]
    rest = head[2] if len(head) == 3 else ""
    fields: dict[str, Any] = {}
    tag: str | None = None
    i, n = 0, len(rest)
    while i < n:
        if rest[i] == " ":
            i += 1
            continue
        eq = rest.find("=", i)
        if eq < 0:
            raise ProtocolError("E_SYNTAX", f"key without value in reply: {_clip(rest[i:])!r}")
        key = rest[i:eq]
        i = eq + 1
        if i < n and rest[i] == '"':
            i += 1
            buf: list[str] = []
            while True:
                if i >= n:
                    raise ProtocolError("E_SYNTAX", "unbalanced quote in reply")
                c = rest[i]
                if c == "\\" and i + 1 < n:
                    e = rest[i + 1]
                    buf.append("\n" if e == "n" else e)
                    i += 2
                elif c == '"':
                    i += 1
                    break
                else:
                    buf.append(c)
                    i += 1
            value = "".join(buf)
        else:
            end = rest.find(" ", i)
            end = n if end < 0 else end
            value = rest[i:end]
            i = end
        if key == "tag" and tag is None and not fields:
            tag = value
        else:
            fields[key] = value
    return Reply(module, status, fields, tag)


# --------------------------------------------------------------------------------------------
# bytes to lines


class Telnet:
    """A telnet command that means something to the server, in order among the lines.

    Telnet's Ctrl-C sends IAC IP and then IAC DO TIMING-MARK, and discards all output until
    the server answers the mark: a server that ignores the mark leaves the operator blind.
    """

    def __init__(self, name: str) -> None:
        self.name = name

    def __repr__(self) -> str:
        return f"Telnet({self.name})"


@dataclass(frozen=True)
class TooLong:
    """A request line over the limit, discarded but for its tag: a line that starts with ``@tag ``
    gets its E_TOOLONG with ``tag=``, so a GNC matching replies by tag is not left waiting."""

    tag: str | None = None

    HEAD: ClassVar[int] = 34  # bytes kept to find it in: "@", 32 of the tag, a blank
    _TAG: ClassVar[re.Pattern[bytes]] = re.compile(rb"@([A-Za-z0-9_.:\-]{1,32})[ \t\r]")

    @classmethod
    def of(cls, head: bytes) -> TooLong:
        """From the first bytes of the discarded line."""
        m = cls._TAG.match(head[: cls.HEAD])
        return cls(m.group(1).decode("ascii") if m else None)


INTERRUPT = Telnet("interrupt")  # IAC IP
TIMING_MARK = Telnet("timing-mark")  # IAC DO TIMING-MARK
WILL_TIMING_MARK = bytes([255, 251, 6])  # the answer to DO TIMING-MARK (RFC 860)


class LineSplitter:
    """Turns the byte stream of one connection into request lines.

    Strips telnet IAC sequences (answering only the timing mark, see :class:`Telnet`), drops
    the CR of CRLF, and enforces the line limit: an over-long line yields a :class:`TooLong`
    (with its tag) once and the rest up to the next LF is discarded, so one runaway client line
    costs nothing but itself.
    """

    IAC, IP, DO, TM = 0xFF, 244, 253, 6

    def __init__(self, max_line: int = MAX_LINE) -> None:
        self.max_line = max_line
        self._buf = bytearray()
        self._discarding = False
        self._iac_pending = 0  # bytes of a telnet command still to drop after a chunk boundary
        self._iac_need_cmd = False
        self._iac_do = False  # the pending byte is the option of a DO
        self._cr_pending = False

    def _strip_iac(self, data: bytes) -> list[bytes | Telnet]:
        """The data without telnet commands, split where an interrupt or a timing mark was."""
        if self.IAC not in data and not self._iac_pending and not self._iac_need_cmd:
            return [data]
        pieces: list[bytes | Telnet] = []
        out = bytearray()
        for b in data:
            if self._iac_need_cmd:
                self._iac_need_cmd = False
                self._iac_pending = 1 if 251 <= b <= 254 else 0  # WILL/WONT/DO/DONT take an option byte
                self._iac_do = b == self.DO
                if b == self.IP:
                    pieces += [bytes(out), INTERRUPT]
                    out.clear()
                continue
            if self._iac_pending:
                self._iac_pending -= 1
                if self._iac_do and b == self.TM:
                    pieces += [bytes(out), TIMING_MARK]
                    out.clear()
                self._iac_do = False
                continue
            if b == self.IAC:
                self._iac_need_cmd = True
                continue
            out.append(b)
        pieces.append(bytes(out))
        return pieces

    def feed(self, data: bytes) -> list[bytes | TooLong | Telnet]:
        """Feed received bytes; returns complete lines (bytes), a :class:`TooLong` for each
        too-long line and the telnet commands the server acts on, in the order they came."""
        out: list[bytes | TooLong | Telnet] = []
        for piece in self._strip_iac(data):
            if isinstance(piece, Telnet):
                out.append(piece)
            elif piece:
                self._lines(piece, out)
        return out

    def _lines(self, data: bytes, out: list[bytes | TooLong | Telnet]) -> None:
        if self._cr_pending and data[:1] == b"\x00":
            data = data[1:]
            self._cr_pending = False  # that NUL was the CR's; a second one is a byte of the line
        if data:  # a CR whose NUL is already here is not pending
            self._cr_pending = data.endswith(b"\r")
        data = data.replace(b"\r\x00", b"\r")  # telnet's CR NUL is a bare CR, also across chunks
        start = 0
        while True:
            nl = data.find(b"\n", start)
            chunk = data[start:] if nl < 0 else data[start:nl]
            if self._discarding:
                if nl >= 0:
                    self._discarding = False
            else:
                self._buf += chunk
                if nl >= 0:
                    line = bytes(self._buf)
                    self._buf.clear()
                    if line.endswith(b"\r"):
                        line = line[:-1]
                    # the tag is read from the bytes a line is judged on, however TCP cut them:
                    # the same line then gets the same tag whether its LF came with it or later
                    if len(line) > self.max_line:
                        out.append(TooLong.of(line[: self.max_line + 2]))
                    else:
                        out.append(line)
                elif len(self._buf) > self.max_line + 1:  # +1: a CR may still precede the LF
                    out.append(TooLong.of(bytes(self._buf[: self.max_line + 2])))
                    self._buf.clear()
                    self._discarding = True
            if nl < 0:
                break
            start = nl + 1
