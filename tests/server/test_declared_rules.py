"""Rules a command states in help are the ones it applies, through a socket: move-ptu with no
axis is no move, and hazard-start's stop-within-warning rule is declared, shown and applied."""

from __future__ import annotations

import pytest
from support.server import LineClient


def test_move_ptu_with_no_axis_keeps_both_and_answers_where_it_stands(client: LineClient) -> None:
    r = client.request("move-ptu -pan 20 -tilt -10")
    assert r.status == "OK", r
    where = (r.fields["pan"], r.fields["tilt"])
    r = client.request("move-ptu")
    assert r.status == "OK" and (r.fields["pan"], r.fields["tilt"]) == where, r
    assert client.request("status").fields["ptu"] == ",".join(where)


def test_the_stop_within_warning_rule_shows_in_help_and_is_applied(client: LineClient) -> None:
    h = client.request("help hazard-start").fields
    assert "at most -warn-distance" in h["opt_stop_distance"], h
    assert "at least -stop-distance" in h["opt_warn_distance"], h
    r = client.request("hazard-start -warn-distance 0")
    assert (r.status, r.fields["code"]) == ("ERROR", "E_ARG"), r
    assert r.fields["message"] == ("-stop-distance 0.5 must not exceed -warn-distance 0: give -warn-distance "
                                   "at least 0.5 or -stop-distance at most 0"), r
    r = client.request("hazard-start -warn-distance 0 -stop-distance 0")  # the pair given keeps the rule
    assert r.status == "OK" and (r.fields["stop_distance"], r.fields["warn_distance"]) == ("0.000", "0.000"), r
    assert client.request("hazard-stop").status == "OK"


def test_config_set_is_judged_on_the_pair_it_sets(client: LineClient) -> None:
    r = client.request("config -module hazard-start -set warn_distance=0.2")
    assert r.fields["code"] == "E_ARG" and "must not exceed -warn-distance 0.2" in r.fields["message"], r
    assert r.fields["message"].endswith("nothing was changed"), r
    r = client.request("config -module hazard-start")
    assert (r.fields["stop_distance"], r.fields["warn_distance"]) == ("0.5", "1"), r
    r = client.request("config -module hazard-start -set warn_distance=0.2 -set stop_distance=0.1")
    assert r.status == "OK" and (r.fields["stop_distance"], r.fields["warn_distance"]) == ("0.1", "0.2"), r


def test_a_start_override_that_breaks_the_rule_is_refused(server_factory) -> None:
    with pytest.raises(ValueError, match="^--set hazard_start: stop_distance 0.5 must not exceed warn_distance 0.1"):
        server_factory(["hazard_start.warn_distance=0.1"])
