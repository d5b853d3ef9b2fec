"""A product of many files lands whole or not at all (prox_workflows/products.py product_set)."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from prox_workflows import products
from prox_workflows.products import finish_product_sets, product_set, write_text_atomic


def _write_set(folder: Path, text: str, names: tuple[str, ...] = ("a", "b", "c", "d")) -> None:
    with product_set(folder):
        for n in names:
            final = folder / f"{n}.txt"
            before = final.read_text() if final.exists() else None
            write_text_atomic(final, text)
            assert (final.read_text() if final.exists() else None) == before  # not yet: at the set's end


def _contents(folder: Path) -> dict[str, str]:
    return {p.name: p.read_text() for p in sorted(folder.iterdir())}


def test_the_set_lands_at_its_end_and_nothing_else_stays(tmp_path: Path) -> None:
    _write_set(tmp_path, "old")
    _write_set(tmp_path, "new")
    assert _contents(tmp_path) == {f"{n}.txt": "new" for n in "abcd"}


def test_a_set_that_raises_leaves_the_previous_one_whole(tmp_path: Path) -> None:
    _write_set(tmp_path, "old")
    with pytest.raises(RuntimeError), product_set(tmp_path):
        write_text_atomic(tmp_path / "a.txt", "new")
        write_text_atomic(tmp_path / "b.txt", "new")
        raise RuntimeError("disk full")
    assert _contents(tmp_path) == {f"{n}.txt": "old" for n in "abcd"}


def test_a_commit_cut_short_is_finished_at_the_next_start(tmp_path: Path, monkeypatch) -> None:
    _write_set(tmp_path, "old")
    real = os.replace
    calls = {"n": 0}

    def dies_after_two(src, dst):  # the process is killed in the middle of the renames
        if str(dst).endswith(".txt"):
            calls["n"] += 1
            if calls["n"] > 2:
                raise KeyboardInterrupt("killed")
        return real(src, dst)

    monkeypatch.setattr(products.os, "replace", dies_after_two)
    with pytest.raises(KeyboardInterrupt):
        _write_set(tmp_path, "new")
    monkeypatch.setattr(products.os, "replace", real)
    mixed = {k: v for k, v in _contents(tmp_path).items() if not k.startswith(".")}
    assert sorted(mixed.values()) == ["new", "new", "old", "old"]  # what a reader would see until the start
    assert list(tmp_path.glob(".products-*.commit"))
    assert finish_product_sets(tmp_path) == {"rolled_forward": 2, "removed": 0}
    assert _contents(tmp_path) == {f"{n}.txt": "new" for n in "abcd"}


def test_a_set_cut_short_before_its_commit_keeps_the_old_files_and_its_temporaries_are_swept(
        tmp_path: Path) -> None:
    _write_set(tmp_path, "old")
    (tmp_path / "sub").mkdir()
    (tmp_path / ".a.txt.k2j3.tmp.txt").write_text("half")  # a kill before the journal: no commit
    (tmp_path / "sub" / ".x.tif.abcd.tmp.tif").write_text("half")
    (tmp_path / ".products-0123.commit.x1y2.tmp.commit").write_text("- [.a.txt.k2j3")  # a journal half written
    assert finish_product_sets(tmp_path) == {"rolled_forward": 0, "removed": 3}
    assert {p.name: p.read_text() for p in tmp_path.glob("*.txt")} == {f"{n}.txt": "old" for n in "abcd"}
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.txt", "b.txt", "c.txt", "d.txt", "sub"]
    assert not list((tmp_path / "sub").iterdir())


def test_a_file_written_twice_in_one_set_keeps_the_later_and_no_temporary(tmp_path: Path) -> None:
    with product_set(tmp_path):
        write_text_atomic(tmp_path / "a.yaml", "first")
        write_text_atomic(tmp_path / "a.yaml", "second")
    assert _contents(tmp_path) == {"a.yaml": "second"}
