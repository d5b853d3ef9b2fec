"""Numbers on the wire, through a socket: ASCII decimal only (PROTOCOL.md), and inf/nan in any
spelling read as values, so that each option's own check answers them with one message."""

from __future__ import annotations

import pytest
from support.server import LineClient

from rvs_server.protocol import parse_request


def ptu(client: LineClient) -> tuple[str, str]:
    r = client.request("status")
    pan, tilt = r.fields["ptu"].split(",")
    return pan, tilt


@pytest.mark.parametrize("value", ["-inf", "-nan", "-Infinity", "+inf", "inf", "nan", "NaN", "-INF"])
def test_inf_and_nan_are_values_that_the_finite_check_refuses(client: LineClient, value: str) -> None:
    before = ptu(client)
    r = client.request(f"move-ptu -tilt {value}")
    assert (r.status, r.fields["code"]) == ("ERROR", "E_ARG"), r
    assert r.fields["message"].startswith("-tilt must be a finite number"), r
    r = client.request(f"move-ptu -pan {value} -tilt 5")  # the value is taken, -tilt stays an option
    assert r.fields["message"].startswith("-pan must be a finite number"), r
    assert ptu(client) == before


@pytest.mark.parametrize("value", ["1_0", "\uff19", "\u0663", '" 10"', "1e1_0", "0x10"])
def test_numbers_not_in_ascii_decimal_are_refused_saying_the_form(client: LineClient, value: str) -> None:
    before = ptu(client)
    r = client.request(f"move-ptu -pan {value}")
    assert (r.status, r.fields["code"]) == ("ERROR", "E_ARG"), r
    assert r.fields["message"].startswith("-pan takes a number") and "ASCII decimal" in r.fields["message"], r
    assert ptu(client) == before


def test_every_numeric_path_is_ascii_decimal(client: LineClient) -> None:
    cases = {
        "grab-tof -integrate \uff14": "-integrate takes an integer",  # an int option
        "status -job 1_0": "-job takes an integer",  # an optional int
        "navigate -goal 1_0,2": "-goal takes 2 numbers",  # a list
        "dem-full -range -150,150,-50,\uff11": "-range takes 4 numbers",
        "config -module sleep -set seconds=1_0": "-seconds takes a number",  # config -set
        "config -module drivers -set tof.auto_exposure_params.desired=7_0": "is not a int (write it in ASCII",  # a mapping's key
        "config -module drivers -set tof.camera_matrix=[[1_0,0,0],[0,1,0],[0,0,1]]": "'1_0' is not a number",  # YAML
    }
    for line, start in cases.items():
        r = client.request(line)
        assert (r.status, r.fields["code"]) == ("ERROR", "E_ARG"), (line, r)
        assert start in r.fields["message"] and "ASCII" in r.fields["message"], (line, r)
    r = client.request("config -module sleep")
    assert r.fields["seconds"] == "10", r
    r = client.request("navigate -goal -inf,2")
    assert r.fields["code"] == "E_ARG" and "each finite" in r.fields["message"], r
    r = client.request("dem-full -range -Infinity,0,-50,-15")
    assert r.fields["code"] == "E_ARG" and r.fields["message"].startswith("-range takes"), r


def test_ascii_numbers_still_move_the_ptu(client: LineClient) -> None:
    r = client.request("move-ptu -pan -12.5 -tilt -1e1")
    assert r.status == "OK", r
    # the PTU reports the position its steps reach: within a step (0.05 deg) of the request
    assert abs(float(r.fields["pan"]) + 12.5) < 0.05 and abs(float(r.fields["tilt"]) + 10) < 0.05, r


def test_a_number_after_an_option_is_its_value_an_option_is_not() -> None:
    assert parse_request("move-ptu -tilt -inf -pan 3").options == [("tilt", "-inf"), ("pan", "3")]
    assert parse_request("dem-full -range -Infinity,1,2,3").options == [("range", "-Infinity,1,2,3")]
    assert parse_request("navigate -auto -sensor tof").options == [("auto", True), ("sensor", "tof")]
    assert parse_request("x -a -information").options == [("a", True), ("information", True)]
