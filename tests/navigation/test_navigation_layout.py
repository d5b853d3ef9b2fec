"""Navigation's layout: thin handlers over the navigation package, and the rover's backends found
by the registry alone (a new backend is its module and the package's import line)."""

from __future__ import annotations

from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def test_the_handlers_stay_thin_and_the_package_holds_the_mission() -> None:
    """No cycle runs through navigation (tests/test_architecture.py checks every package); here,
    the command module hands the mission to the package, and the package never reaches back."""
    handlers = (ROOT / "rvs_server" / "commands" / "navigation.py").read_text()
    assert "from ..navigation.mission import" in handlers
    assert len(handlers.splitlines()) < 150
    for path in (ROOT / "rvs_server" / "navigation").glob("*.py"):
        text = path.read_text()
        assert "commands" not in "".join(line for line in text.splitlines() if "import" in line), path


def test_a_rover_backend_is_its_module_and_one_import_line() -> None:
    """The registry composes the settings and builds the backend by name: nothing else in the
    server names a rover backend."""
    named = [p.relative_to(ROOT) for p in (ROOT / "rvs_server").rglob("*.py")
             if "GncRover" in p.read_text() or "SimRover" in p.read_text()]
    assert not named, named
    init = (ROOT / "drivers" / "rover" / "__init__.py").read_text()
    assert "from . import gnc, replay, sim  # noqa: F401 - registers the backends" in init
