"""The server through real TCP sockets: sessions, jobs, modes, limits, auth, shutdown."""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import yaml
from support.server import LineClient, wait_for

from rvs_server.protocol import parse_reply
from rvs_server.table import COMMANDS, command


def test_greeting_help_and_typo(client: LineClient) -> None:
    hello = parse_reply(client.greeting)
    assert (hello.module, hello.status) == ("RVS", "EVENT")
    assert hello.fields["kind"] == "hello" and hello.fields["protocol"] == "1"
    assert hello.fields["server"] == "rvs/0.1.0" and hello.fields["mode"] in ("ready", "fault")
    r = client.request("help")
    assert r.module == "EGP-RVS-HELP" and r.status == "OK"
    assert {"quit", "break", "sleep", "status", "logbook"} <= set(r.fields["commands"].split())
    r = client.request("frobnicate")
    assert (r.module, r.status, r.fields["code"]) == ("RVS", "ERROR", "E_UNKNOWN")
    assert "frobnicate" in r.fields["message"] and "help" in r.fields["message"]
    r = client.request("stauts")
    assert "did you mean status" in r.fields["message"]


def test_unknown_command_is_quoted_as_sent(client: LineClient) -> None:
    """The echo is what the client wrote, case and all (names are looked up case-insensitively)."""
    r = client.request("FOO -x 1")
    assert (r.fields["code"], r.fields["message"]) == ("E_UNKNOWN", "unknown command 'FOO'; try help")
    r = client.request("@t3 STAUTS")
    assert r.tag == "t3" and r.fields["message"] == "unknown command 'STAUTS'; did you mean status?"
    assert client.request("STATUS").module == "EGP-RVS-STATUS"


def test_help_for_a_command_comes_from_its_declaration(client: LineClient) -> None:
    r = client.request("help EGP-RVS-SLEEP")
    assert r.fields["command"] == "sleep" and r.fields["kind"] == "job"
    assert "-seconds" in r.fields["usage"]
    assert "[0, 86400] s" in r.fields["opt_seconds"] and "default 10" in r.fields["opt_seconds"]
    r = client.request("help nosuch")
    assert r.fields["code"] == "E_ARG"


def test_blank_and_comment_lines_get_no_reply(client: LineClient) -> None:
    client.send(b"\n   \n# just a note\r\n@t1 version\n")
    r = client.reply()
    assert r.module == "EGP-RVS-VERSION" and r.tag == "t1"


def test_argument_errors_name_the_option(client: LineClient) -> None:
    r = client.request("sleep -seconds abc")
    assert r.fields["code"] == "E_ARG" and "-seconds" in r.fields["message"]
    r = client.request("sleep -seconds 1e9")
    assert r.fields["code"] == "E_ARG" and "[0, 86400]" in r.fields["message"]
    r = client.request("sleep -sekonds 1")
    assert r.fields["code"] == "E_ARG" and "-sekonds" in r.fields["message"] and "-seconds" in r.fields["message"]
    r = client.request("sleep -seconds 1 -seconds 2")
    assert r.fields["code"] == "E_ARG"
    r = client.request("status -verbose")
    assert r.fields["code"] == "E_ARG"
    r = client.request('sleep -seconds "1')
    assert r.fields["code"] == "E_SYNTAX"
    client.send(b"status \xc3\x28\n")
    assert client.reply().fields["code"] == "E_SYNTAX"


def test_job_lines_carry_tag_and_status_answers_during_job(server, client: LineClient) -> None:
    other = server.client()
    client.send("@nap sleep -seconds 0.6")
    ack = client.reply()
    assert (ack.status, ack.tag) == ("ACK", "nap")
    job = ack.fields["job"]
    r = other.request("status")
    assert r.fields["mode"] == "sleep" and r.fields["job"] == job and r.fields["job_command"] == "sleep"
    lines = client.until_final(job=job)
    final = lines[-1]
    assert final.status == "OK" and final.tag == "nap" and final.fields["job"] == job
    assert 0.55 <= float(final.fields["slept"]) < 5
    assert all(line.tag == "nap" for line in lines if line.module == "EGP-RVS-SLEEP")
    assert other.request("status").fields["mode"] == "ready"
    other.close()


def test_busy_names_the_running_job(server, client: LineClient) -> None:
    client.send("sleep -seconds 60")
    job = client.reply().fields["job"]
    other = server.client()
    r = other.request("sleep -seconds 1")
    assert r.fields["code"] == "E_BUSY" and r.fields["job"] == job
    t0 = time.monotonic()
    r = other.request("break")
    assert r.status == "OK" and r.fields["interrupted"] == job
    final = client.until_final(job=job)[-1]
    # interrupted, not slept out: far less than the 60 s (how much less is the machine's speed)
    assert final.fields["code"] == "E_INTERRUPTED" and time.monotonic() - t0 < 30.0
    other.close()


def test_break_writes_a_recovery_set_and_continue_returns_to_ready(server, client: LineClient) -> None:
    client.send("pose -x 1.5 -y -2 -heading 30")
    assert client.reply().fields["x"] == "1.500"
    client.send("@s sleep -seconds 30")
    job = client.reply().fields["job"]
    breaker = server.client()
    r = breaker.request("break")
    rec = server.data / r.fields["recovery"]
    manifest = yaml.safe_load((rec / "manifest.yaml").read_text())
    assert manifest["job"]["command"] == "sleep" and manifest["job"]["parameters"] == {"seconds": 30.0}
    assert manifest["pose"] == {"x": 1.5, "y": -2.0, "heading": 30.0}
    assert not list((server.data / "recovery").glob(".*"))  # no half-written set left behind
    assert client.until_final(job=job)[-1].fields["code"] == "E_INTERRUPTED"
    st = breaker.request("status")
    assert st.fields["mode"] == "break" and st.fields["recovery"] == r.fields["recovery"]
    r = breaker.request("continue")
    assert r.status == "OK" and r.fields["mode"] == "ready"
    assert breaker.request("status").fields["mode"] == "ready"
    breaker.close()


def test_standby_refuses_jobs_until_a_mode_change(client: LineClient) -> None:
    assert client.request("standby").fields["mode"] == "standby"
    r = client.request("sleep -seconds 0")
    assert r.fields["code"] == "E_STATE" and "continue" in r.fields["message"]
    assert client.request("status").fields["mode"] == "standby"
    r = client.request("reinit")
    assert r.status == "OK" and r.fields["mode"] == "ready"
    assert client.request("sleep -seconds 0").status == "OK"


def test_too_long_line_is_refused_and_connection_survives(client: LineClient) -> None:
    client.send(b"status " + b"x" * 5000 + b"\n")
    r = client.reply()
    assert (r.module, r.fields["code"]) == ("RVS", "E_TOOLONG")
    client.sock.sendall(b"version -" + b"y" * 4200)  # arrives in pieces, no LF yet
    client.sock.sendall(b"zzz\nversion\n")
    assert client.reply().fields["code"] == "E_TOOLONG"
    assert client.reply().module == "EGP-RVS-VERSION"
    client.send(b"a" * 4096 + b"\r\n")  # exactly at the limit: parsed, unknown command
    assert client.reply().fields["code"] == "E_UNKNOWN"


def test_telnet_iac_bytes_are_stripped(client: LineClient) -> None:
    client.send(b"\xff\xfd\x03\xff\xfb\x18ver\xff\xf1sion\r\n")
    r = client.reply()
    assert r.module == "EGP-RVS-VERSION" and r.status == "OK"


def test_json_mode(client: LineClient) -> None:
    client.send("format json")
    obj = json.loads(client.line())
    assert obj == {"module": "EGP-RVS-FORMAT", "status": "OK", "format": "json"}
    client.send("@j1 sleep -seconds 0.05")
    lines = [json.loads(client.line()) for _ in range(2)]
    ack = next(o for o in lines if o["status"] == "ACK")
    assert ack["tag"] == "j1" and isinstance(ack["job"], int) and list(ack)[:3] == ["module", "status", "tag"]
    while True:
        obj = json.loads(client.line())
        if obj["module"] == "EGP-RVS-SLEEP" and obj["status"] == "OK":
            break
    assert isinstance(obj["slept"], float) and obj["tag"] == "j1"
    r = client.request("format text")
    assert (r.module, r.fields["format"]) == ("EGP-RVS-FORMAT", "text")


def test_events_off_silences_mode_events(server, client: LineClient) -> None:
    watcher = server.client()
    assert watcher.request("events off").fields["events"] == "off"
    assert client.request("sleep -seconds 0").status == "OK"
    watcher.send("version")
    assert watcher.reply().module == "EGP-RVS-VERSION"  # no EVENT line came first
    watcher.close()


def test_many_concurrent_clients(server_factory) -> None:
    server = server_factory(["server.max_clients=64"])
    errors: list[str] = []

    def worker(i: int) -> None:
        try:
            c = server.client()
            for k in range(10):
                r = c.request(f"@c{i}-{k} status")
                if r.tag != f"c{i}-{k}" or r.fields.get("mode") not in ("ready", "busy", "sleep"):
                    errors.append(f"{i}: {r}")
            c.close()
        except Exception as exc:  # noqa: BLE001
            errors.append(f"{i}: {exc!r}")

    threads = [threading.Thread(target=worker, args=(i,)) for i in range(50)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(30)
    assert errors == []


def test_max_clients(server_factory) -> None:
    srv = server_factory(["server.max_clients=3"])
    clients = [srv.client() for _ in range(3)]
    extra = socket.create_connection(("127.0.0.1", srv.port), timeout=5)
    data = b""
    while not data.endswith(b"\n"):
        chunk = extra.recv(1024)
        if not chunk:
            break
        data += chunk
    r = parse_reply(data.decode())
    assert r.fields["code"] == "E_BUSY" and "too many clients" in r.fields["message"]
    assert extra.recv(1024) == b""  # closed
    clients[0].close()
    assert wait_for(lambda: len(srv.app.connections) == 2)
    again = srv.client()
    assert again.request("version").status == "OK"


def test_auth_token(server_factory) -> None:
    srv = server_factory(["server.token=s3cret"])
    c = srv.client()
    assert c.request("version").status == "OK"
    assert c.request("help").status == "OK"
    r = c.request("status")
    assert r.fields["code"] == "E_AUTH"
    assert c.request("sleep -seconds 0").fields["code"] == "E_AUTH"
    assert c.request("auth -token wrong").fields["code"] == "E_AUTH"
    assert c.request("auth -token s3cret").fields["authenticated"] == "true"
    assert c.request("status").status == "OK"
    assert c.request("config -module server").fields["token"] == "***"


def test_config_show_set_and_protected(client: LineClient) -> None:
    r = client.request("config -module EGP-RVS-SLEEP")
    assert r.fields == {"module_name": "sleep", "seconds": "10"}
    assert client.request("config -module sleep -set seconds=0.25").fields["seconds"] == "0.25"
    ok = client.request("sleep")
    assert 0.2 <= float(ok.fields["slept"]) < 5
    r = client.request("config -module sleep -set seconds=-4")
    assert r.fields["code"] == "E_ARG" and "[0, 86400]" in r.fields["message"]
    for key in ("host=0.0.0.0", "port=1", "token=x"):
        r = client.request(f"config -module server -set {key}")
        assert r.fields["code"] == "E_ARG" and "protected" in r.fields["message"]
    r = client.request("config -module nosuch")
    assert r.fields["code"] == "E_ARG" and "sleep" in r.fields["message"]
    r = client.request("config -module drivers -set ptu.nosuchkey=1")
    assert r.fields["code"] == "E_ARG"
    assert {"drivers", "server", "sleep"} <= set(client.request("config").fields["modules"].split())


def test_config_dir_and_set_at_start(server_factory, tmp_path: Path) -> None:
    cfg = tmp_path / "cfg"
    cfg.mkdir()
    (cfg / "sleep.yaml").write_text("seconds: 3.5\n")
    srv = server_factory(["sleep.seconds=4.5"], config_dir=str(cfg))
    assert srv.client().request("config -module sleep").fields["seconds"] == "4.5"
    srv2 = server_factory(config_dir=str(cfg))
    assert srv2.client().request("config -module sleep").fields["seconds"] == "3.5"


def test_pose_and_logbook(server, client: LineClient) -> None:
    r = client.request("pose -x 2 -y 3.25 -heading 190")
    assert (r.fields["x"], r.fields["y"], r.fields["heading"]) == ("2.000", "3.250", "-170.00")
    assert client.request("pose").fields["y"] == "3.250"
    assert client.request("status").fields["pose"] == "2.000,3.250,-170.00"
    r = client.request("logbook")
    copy = server.data / r.fields["file"]
    assert r.fields["file"].startswith("shared/") and copy.is_file()
    assert "listening" in copy.read_text()
    r = client.request("logbook -name ../../etc/x")
    assert r.fields["code"] == "E_ARG"


def test_handler_bug_is_e_internal_and_server_keeps_serving(client: LineClient) -> None:
    @command("explode", help="test only")
    def explode(ctx, cfg):  # noqa: ANN001, ANN202
        raise ZeroDivisionError("boom")

    try:
        r = client.request("explode")
        assert r.fields["code"] == "E_INTERNAL" and "boom" in r.fields["message"]
        assert client.request("version").status == "OK"
    finally:
        COMMANDS.pop("explode")


def test_slow_client_does_not_block_others(server) -> None:
    slow = server.client()
    fast = server.client()
    for ch in b"stat":
        slow.sock.sendall(bytes([ch]))
        r = fast.request("version")
        assert r.status == "OK"
    slow.send("us")
    assert slow.reply().module == "EGP-RVS-STATUS"


def test_quit_interrupts_jobs_closes_everyone_and_exits_zero(server) -> None:
    a, b = server.client(), server.client()
    a.send("sleep -seconds 30")
    job = a.reply().fields["job"]
    r = b.request("quit")
    assert r.status == "OK" and r.fields["interrupted"] == job
    lines = []
    try:
        while True:
            lines.append(a.reply(timeout=5))
    except ConnectionError:
        pass
    assert any(x.fields.get("code") == "E_INTERRUPTED" for x in lines)
    server.thread.join(10)
    assert not server.thread.is_alive() and server.exit_code == 0


def test_sigterm_shuts_down_gracefully(tmp_path: Path) -> None:
    proc = subprocess.Popen(
        [sys.executable, "-m", "rvs_server", "--port", "0", "--data", str(tmp_path / "d"),
         "--set", "drivers.ptu.time_scale=0", "--set", "server.web_port=0", "--set", "server.foxglove_port=0"],
        stderr=subprocess.PIPE, text=True, cwd=Path(__file__).resolve().parents[2],
    )
    try:
        first = proc.stderr.readline()
        assert "listening" in first
        port = int(first.split("port=")[1].split()[0])
        c = LineClient(port)
        assert c.request("version").status == "OK"
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(20) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
    assert os.path.exists(tmp_path / "d" / "rvs.log")


def test_half_closed_client_still_gets_its_job_result(server) -> None:
    c = server.client()
    c.send("@last sleep -seconds 0.3")
    c.sock.shutdown(socket.SHUT_WR)  # as `printf 'sleep ...\n' | nc` does
    lines = []
    try:
        while True:
            lines.append(c.reply())
    except ConnectionError:
        pass
    finals = [r for r in lines if r.module == "EGP-RVS-SLEEP" and r.status == "OK"]
    assert len(finals) == 1 and finals[0].tag == "last"


def test_startup_errors_are_reported_once(tmp_path: Path) -> None:
    proc = subprocess.run(
        [sys.executable, "-m", "rvs_server", "--port", "0", "--data", str(tmp_path), "--scene", "nosuch"],
        capture_output=True, text=True, timeout=60, cwd=Path(__file__).resolve().parents[2],
    )
    assert proc.returncode == 2 and "listen" not in proc.stderr  # a usage error, like a bad --set
    head, _, known = proc.stderr.strip().partition("; known scenes: ")
    assert head == "rvs-server: no scene 'nosuch'", proc.stderr
    assert {"dense", "hirise", "marsyard", "office"} <= set(known.split(", ")), proc.stderr
    proc = subprocess.run([sys.executable, "-m", "rvs_server", "--set", "sleep.seconds=-1"],
                          capture_output=True, text=True, timeout=60, cwd=Path(__file__).resolve().parents[2])
    assert proc.returncode == 2 and proc.stderr == "rvs-server: --set sleep.seconds is -1, out of range [0, 86400] s\n"


def test_telnet_cr_cr_lf_line_ends(client: LineClient) -> None:
    client.send(b"version\r\r\n")  # what `telnet` sends for a piped CR LF
    assert client.reply().module == "EGP-RVS-VERSION"
    client.send(b"help\r\x00\r\n")  # and telnet's CR NUL
    assert client.reply().fields["commands"]


def test_kernels_warm_up_in_the_background(server_factory) -> None:
    srv = server_factory(["server.warm_up=true"])
    c = srv.client()
    assert c.request("version").status == "OK"  # served while the kernels load
    assert wait_for(lambda: "kernels_ready" in (srv.data / "rvs.log").read_text(), timeout=120)
