"""config -module X through a socket: every module's reply has each key once, in the reply
grammar's lower_snake_case, and every setting that can be not set can be put back to not set."""

from __future__ import annotations

import json
import re

import pytest
from support.server import LineClient

from rvs_server.protocol import KEY_RE

# key=value pairs of a text reply line: a bare value, or a quoted one with \" and \\ escapes
PAIR = re.compile(r' ([^ =]+)=(?:"(?:[^"\\]|\\.)*"|[^ ]*)')


def keys_of(line: str) -> list[str]:
    head, _, rest = line.partition(" OK")
    assert head == "EGP-RVS-CONFIG", line
    return PAIR.findall(rest)


def test_every_module_reply_has_each_key_once_in_lower_snake_case(client: LineClient) -> None:
    modules = client.request("config").fields["modules"].split()
    assert {"dem_full", "dem_full_tof", "dem_update", "dem_update_tof", "logbook", "navigate"} <= set(modules)
    for module in modules:
        client.send(f"config -module {module}")
        line = client.line()
        keys = keys_of(line)
        assert keys[0] == "module_name" and f" module_name={module} " in line + " "
        assert len(keys) == len(set(keys)), (module, sorted(k for k in keys if keys.count(k) > 1))
        assert all(KEY_RE.fullmatch(k) for k in keys), (module, [k for k in keys if not KEY_RE.fullmatch(k)])


def test_navigate_global_is_shown_and_set_by_its_wire_name(client: LineClient) -> None:
    client.send("config -module navigate")
    keys = keys_of(client.line())
    assert "global" in keys and "global_" not in keys
    r = client.request("config -module navigate -set global=site.tif")
    assert r.status == "OK" and r.fields["global"] == "site.tif", r
    r = client.request("config -module navigate -set global=none")
    assert r.status == "OK" and r.fields["global"] == "none", r


@pytest.mark.parametrize("spelling", ["none", "NULL", "~"])
@pytest.mark.parametrize("module", ["dem_full", "navigate", "logbook"])
def test_a_name_is_put_back_to_not_set(client: LineClient, module: str, spelling: str) -> None:
    r = client.request(f"config -module {module} -set name=site_7")
    assert r.status == "OK" and r.fields["name"] == "site_7", r
    r = client.request(f"config -module {module} -set name={spelling}")
    assert r.status == "OK" and r.fields["name"] == "none", r


def _sets(settings: dict, prefix: str = "") -> list[str]:
    """-set words that give every setting the value a JSON reply shows (null as the word none)."""
    out: list[str] = []
    for key, value in settings.items():
        if isinstance(value, dict):
            out += _sets(value, f"{prefix}{key}.")
        elif value is None:
            out.append(f"-set {prefix}{key}=none")
        elif isinstance(value, bool):
            out.append(f"-set {prefix}{key}={str(value).lower()}")
        elif isinstance(value, list):
            out.append(f"-set {prefix}{key}=" + ",".join(str(v) for v in value))
        else:
            out.append(f"-set {prefix}{key}={value}")
    return out


@pytest.mark.parametrize("module", ["dem_full", "dem_update_tof", "navigate", "logbook", "move-ptu"])
def test_what_config_shows_is_taken_back_as_it_is_shown(server, module: str) -> None:
    c = server.client()
    c.send(f"config -module {module}")
    text = c.line()
    assert " name=none" in text or " pan=none" in text, text  # not set, shown as the word -set takes
    c.send("format json")
    c.line()  # format's OK
    c.line()  # the JSON greeting
    c.send(f"config -module {module}")
    shown = json.loads(c.line())["settings"]
    sets = _sets(shown)
    c.send(f"config -module {module} " + " ".join(sets))
    back = json.loads(c.line())
    assert back["status"] == "OK" and back["settings"] == shown, (sets, back)


def test_an_empty_name_is_refused_saying_how_to_unset(client: LineClient) -> None:
    r = client.request('config -module dem_full -set name=""')
    assert r.fields["code"] == "E_ARG" and "none for the default" in r.fields["message"], r


def test_a_number_declared_not_set_is_put_back_to_not_set(client: LineClient) -> None:
    r = client.request("config -module move-ptu -set pan=12.5")
    assert r.status == "OK" and r.fields["pan"] == "12.5", r
    r = client.request("config -module move-ptu -set pan=none")
    assert r.status == "OK" and r.fields["pan"] == "none", r
    r = client.request("config -module move-ptu -set pan=nan")  # a value, not the not-set word
    assert r.fields["code"] == "E_ARG" and "finite" in r.fields["message"], r
    r = client.request("help move-ptu")
    assert "or none" in r.fields["opt_pan"], r


def test_an_optional_driver_setting_is_put_back_to_not_set(client: LineClient) -> None:
    r = client.request("config -module drivers -set stereo.sim_hfov_deg=60")
    assert r.status == "OK" and r.fields["stereo_sim_hfov_deg"] == "60", r
    r = client.request("config -module drivers -set stereo.sim_hfov_deg=null")
    assert r.status == "OK" and r.fields["stereo_sim_hfov_deg"] == "none", r


def test_an_option_each_request_must_give_is_neither_shown_nor_set(client: LineClient) -> None:
    client.send("config -module navigate")
    assert "goal" not in keys_of(client.line())
    r = client.request("config -module navigate -set goal=1,2")
    assert r.fields["code"] == "E_ARG" and "given with each request (-goal)" in r.fields["message"], r
