"""The rover device: the sim backend drives the simulated world, the gnc backend waits for the
GNC's pose reports (sent over TCP here, as a GNC sends them), both behind one drive call."""

from __future__ import annotations

import math
import threading
import time
from typing import Any

import pytest

from drivers.base import DeviceError, DeviceInterrupted
from drivers.registry import registry
from drivers.rover import Motion, Rover, Settle, Silent, create
from drivers.sim.world import World


class Pilot:
    """Drives the given motions in order, recording what the rover tells it."""

    def __init__(self, motions: list[Motion], on_next: Any = None) -> None:
        self.motions = list(motions)
        self.asked: list[tuple[float, float, float]] = []
        self.moved_to: list[tuple[tuple[float, float, float], bool]] = []
        self.on_next = on_next

    def next(self, pose: tuple[float, float, float]) -> Motion | None:
        self.asked.append(pose)
        if self.on_next is not None:
            self.on_next(pose)
        return self.motions.pop(0) if self.motions else None

    def moved(self, truth: tuple[float, float, float], end: bool) -> None:
        self.moved_to.append((truth, end))


class Feed:
    """The server's pose, as the App keeps it: a condition, a version and set_pose."""

    def __init__(self) -> None:
        self.pose_changed = threading.Condition()
        self.pose_version = 0
        self.pose: Any = None
        self.sources: list[str] = []

    def set_pose(self, x: float, y: float, heading: float, *, stopped: bool = False, source: str = "gnc",
                 sigma: float = 0.0, sigma_heading: float = 0.0) -> None:
        from rvs_server.app import Pose

        with self.pose_changed:
            self.pose = Pose(x, y, heading, stopped=stopped, source=source)
            self.sources.append(source)
            self.pose_version += 1
            self.pose_changed.notify_all()


def _sim_rover(feed: Feed | None = None) -> tuple[Rover, World]:
    world = World.from_scene("office", clock_scale=0.0)
    rover = create({"backend": "sim"}, world, feed)
    rover.open()
    return rover, world


def test_the_registry_offers_both_backends_and_a_sim_rover_needs_a_world() -> None:
    reg = registry("rover")
    assert reg.names() == ["gnc", "replay", "sim"]  # the default first: a real rover's GNC drives
    assert reg.settings_class()().backend == "gnc"
    with pytest.raises(DeviceError, match="drivers.rover.backend=gnc"):
        create({"backend": "sim"}, None).open()
    with pytest.raises(DeviceError, match="not open"):
        create({"backend": "sim"}, World.from_scene("office", clock_scale=0.0)).drive(Pilot([]))


def test_sim_motions_toward_a_point_steer_by_odometry_and_report_every_step() -> None:
    feed = Feed()
    rover, world = _sim_rover(feed)
    world.set_slip(0.05, 2.0, 5)
    pilot = Pilot([Motion.toward(1.0, 1.0), Motion.toward(2.0, 0.0)])
    end = rover.drive(pilot, settle=Settle(), since=rover.mark())
    assert end == pytest.approx((2.0, 0.0, -45.0), abs=1e-6)  # the odometry: the last waypoint, facing it
    assert pilot.asked[0] == (0.0, 0.0, 0.0) and pilot.asked[1] == pytest.approx((1.0, 1.0, 45.0), abs=1e-6)
    assert len(pilot.asked) == 3  # asked again after each motion, and the third answer ends the drive
    truth = world.rover_pose()
    assert 0.05 < math.hypot(truth[0] - 2.0, truth[1]) < 0.5  # slip: short and beside
    assert pilot.moved_to[-1] == (truth, True) and sum(end for _, end in pilot.moved_to) == 2
    # the turns on the spot are motion too: steps that turned without moving reach the pilot
    standing = [p for p, _ in pilot.moved_to if p[0] == 0.0 and p[1] == 0.0]
    assert len(standing) >= 25 and standing[-1][2] == pytest.approx(45.0, abs=1e-6)
    # every step became the server's pose, from the odometry (as a GNC streaming its pose)
    assert set(feed.sources) == {"odometry"} and feed.pose_version > 250
    assert (feed.pose.x, feed.pose.y, feed.pose.heading) == pytest.approx(end, abs=1e-9)
    assert world.truth()["sim_time"] == pytest.approx(2 * math.sqrt(2) / 0.1 + 135.0 / 15.0, abs=0.2)


def test_sim_arcs_and_turns_on_the_spot() -> None:
    rover, world = _sim_rover()
    assert rover.steers and rover.speeds() == (0.1, 15.0)
    rover.drive(Pilot([Motion.arc(0.1, 10.0, 3.0)]))
    x, y, heading = rover.pose()
    assert heading == pytest.approx(30.0, abs=1e-6)
    r = 0.1 / math.radians(10.0)  # the arc's radius
    assert (x, y) == pytest.approx((r * math.sin(math.radians(30)), r * (1 - math.cos(math.radians(30)))), abs=1e-3)
    rover.drive(Pilot([Motion.face(x, y + 1.0)]))
    assert rover.pose() == pytest.approx((x, y, 90.0), abs=1e-6)  # turned on the spot, did not move


def test_a_cancelled_sim_drive_stops_at_its_next_step_and_leaves_the_pose_there() -> None:
    feed = Feed()
    rover, world = _sim_rover(feed)
    cancel = threading.Event()
    pilot = Pilot([Motion.toward(3.0, 0.0)])

    def moved(truth: tuple[float, float, float], end: bool) -> None:
        if truth[0] >= 0.5:
            cancel.set()

    pilot.moved = moved  # type: ignore[method-assign]
    with pytest.raises(DeviceInterrupted):
        rover.drive(pilot, cancel=cancel)
    x, _, _ = rover.pose()
    assert 0.5 <= x < 0.52  # one 0.1 s step past where the cancel came
    assert (feed.pose.x, feed.pose.y) == pytest.approx(rover.pose()[:2], abs=1e-12)
    assert not rover.status()["driving"]


# ------------------------------------------------------------------ the GNC, through TCP


def _drive_in_thread(rover: Rover, pilot: Pilot, settle: Settle, since: int) -> dict[str, Any]:
    out: dict[str, Any] = {}

    def run() -> None:
        try:
            out["pose"] = rover.drive(pilot, settle=settle, since=since)
        except Exception as exc:  # noqa: BLE001 - the test reads it
            out["error"] = exc

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    out["thread"] = thread
    return out


def test_the_gnc_backend_takes_the_reports_that_moved_as_cycles_and_ends_when_they_hold(server) -> None:
    rover = server.app.devices.get("rover")
    assert rover.backend == "gnc" and not rover.steers
    gnc = server.client()
    since = rover.mark()
    pilot = Pilot([])
    run = _drive_in_thread(rover, pilot, Settle(seconds=0.5, distance=0.01, degrees=1.0), since)
    for i in range(5):  # driving: each report moved 5 cm
        assert gnc.request(f"pose -x {0.05 * i:.2f} -y 0 -heading 0").status == "OK"
        time.sleep(0.05)
    # standing: reports within 1 cm of the first of them do not count as cycles
    for _ in range(3):
        assert gnc.request("pose -x 0.205 -y 0 -heading 0.5").status == "OK"
    run["thread"].join(30)
    assert "error" not in run, run
    assert run["pose"] == pytest.approx((0.205, 0.0, 0.5))  # the latest report, once they held still
    assert [p[0] for p in pilot.asked] == pytest.approx([0.0, 0.05, 0.1, 0.15, 0.2])  # one cycle per move
    assert pilot.moved_to[-1] == ((0.205, 0.0, 0.5), True)
    assert rover.truth() == rover.pose() == pytest.approx((0.205, 0.0, 0.5))
    gnc.close()


def test_the_gnc_backend_ends_at_stopped_at_once_and_a_silent_gnc_times_out(server) -> None:
    rover = server.app.devices.get("rover")
    gnc = server.client()
    run = _drive_in_thread(rover, Pilot([]), Settle(seconds=600.0), rover.mark())
    assert gnc.request("pose -x 0.3 -y -0.1 -heading 10 -stopped true").status == "OK"
    run["thread"].join(30)
    assert run["pose"] == pytest.approx((0.3, -0.1, 10.0))
    with pytest.raises(Silent, match="no pose within 0.2 s"):
        rover.drive(Pilot([]), settle=Settle(timeout=0.2), since=rover.mark())
    # stop ends the wait: the server stops waiting (the GNC is told by navigate's EVENT)
    run = _drive_in_thread(rover, Pilot([]), Settle(), rover.mark())
    rover.stop()
    run["thread"].join(30)
    assert isinstance(run.get("error"), DeviceInterrupted)
    gnc.close()


def test_the_rover_is_a_device_like_the_others(server) -> None:
    c = server.client()
    status = c.request("status")
    assert "rover:ok" in status.fields["devices"].split(",")
    r = c.request("config -module drivers -set rover.backend=sim")
    assert r.status == "OK" and r.fields["pending"] == "rover.backend", r.fields
    assert c.request("reinit -device rover").status == "OK"
    rover = server.app.devices.get("rover")
    assert rover.backend == "sim" and rover.steers
    assert c.request("config -module drivers -set rover.backend=wheels").fields["code"] == "E_ARG"
    c.close()


def test_the_rovers_attitude_is_its_imus_the_sims_from_the_ground_the_gncs_from_its_pose(server) -> None:
    """The sim rover's IMU reads the tilt of the plane its wheels rest on (within its declared
    noise); the GNC's roll and pitch come with its pose reports (both or neither), and a GNC
    that sends none leaves the attitude unknown, but in the simulator, whose IMU stands in."""
    from drivers.sim.rover import IMU_SIGMA_DEG, RoverBody, resting_attitude

    world = World.from_scene("office", clock_scale=0.0)
    rover = create({"backend": "sim"}, world, None)
    rover.open()
    roll, pitch, sigma = rover.attitude()
    true_roll, true_pitch = world.rover_attitude()
    assert sigma == IMU_SIGMA_DEG and abs(roll - true_roll) < 5 * sigma and abs(pitch - true_pitch) < 5 * sigma
    # on a plane rising 10 % along x and falling 5 % along y, heading 90 deg (the nose along +y)
    roll, pitch = resting_attitude(RoverBody(), lambda x, y: 0.1 * x - 0.05 * y, (1.0, 2.0, 90.0))
    assert pitch == pytest.approx(math.degrees(math.atan(-0.05)), abs=1e-6)  # the nose goes downhill
    assert math.tan(math.radians(roll)) / math.cos(math.radians(pitch)) == pytest.approx(-0.1, abs=1e-6)

    gnc_rover = server.app.devices.get("rover")
    real_gnc = create({"backend": "gnc"}, None, server.app)  # the same reports, on a rover with no simulator
    real_gnc.open()
    gnc = server.client()
    assert gnc.request("pose -x 0.3 -y -0.1 -heading 10").status == "OK"
    assert real_gnc.attitude() is None  # this GNC says nothing of its attitude
    # in the simulator the simulated rover's IMU gives what the report left out
    roll, pitch, sigma = gnc_rover.attitude()
    true_roll, true_pitch = server.app.world.rover_attitude()
    assert sigma == IMU_SIGMA_DEG and abs(roll - true_roll) < 5 * sigma and abs(pitch - true_pitch) < 5 * sigma
    r = gnc.request("pose -x 0.3 -y -0.1 -heading 10 -roll 2.5 -pitch -4")
    assert r.status == "OK" and (r.fields["roll"], r.fields["pitch"]) == ("2.50", "-4.00")
    assert gnc_rover.attitude()[:2] == (2.5, -4.0) and real_gnc.attitude()[:2] == (2.5, -4.0)
    bad = gnc.request("pose -x 0.3 -roll 2")
    assert bad.status == "ERROR" and bad.fields["code"] == "E_ARG" and "-roll and -pitch" in bad.fields["message"]
    gnc.close()
