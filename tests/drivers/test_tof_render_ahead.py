"""The simulated ToF renders the view where the PTU is heading while it travels: a scan's grab
on arrival then costs the camera's frame, not the simulator's render as well (a real SR4000
renders nothing), which is what held the scan at 2-4x the hardware's limit. The frame must be the
one a render at arrival gives."""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from drivers.sim.world import World
from drivers.tof import create


class Counted:
    """The world's renders, counted (the pose of each), with the world's own render kept to
    make the frame a camera that renders at its grab measures."""

    def __init__(self, world: World) -> None:
        self.world, self.render, self.poses = world, world.render, []
        world.render = self  # type: ignore[method-assign]

    def __call__(self, K, w, h, T, cancel=None):  # noqa: ANN001, ANN204 - the world's own signature
        self.poses.append(np.asarray(T).copy())
        return self.render(K, w, h, T, cancel)

    def settle(self, n: int) -> None:
        """Wait for the n-th render (a render ahead runs in its own thread), then a little more."""
        end = time.monotonic() + 30.0
        while len(self.poses) < n and time.monotonic() < end:
            time.sleep(0.01)
        time.sleep(0.2)

    def move_and_grab(self, cam: Any, target: tuple[float, float], stop: tuple[float, float], ahead: int,
                      after: int) -> None:
        """The PTU heads for ``target`` (``ahead`` renders by then) and stops at ``stop``, where
        ``cam`` grabs: ``after`` renders, the last one where the ToF is."""
        self.world.set_ptu_target(*target)
        self.settle(ahead)
        self.world.set_ptu(*stop)
        cam.grab_xyz()
        assert len(self.poses) == after
        np.testing.assert_array_equal(self.poses[-1], self.world.sensor_pose("tof"))

    def fresh_frame(self) -> np.ndarray:
        """What a camera of the same seed that renders at its grab measures here, uncounted."""
        self.world.render = self.render  # type: ignore[method-assign]
        fresh = create({"backend": "sim", "seed": 3}, self.world)
        fresh.open()
        try:
            return fresh.grab_xyz(integrate=2)[0]
        finally:
            fresh.close()
            self.world.render = self  # type: ignore[method-assign]


def test_a_move_starts_the_render_of_where_it_stops_and_the_grab_there_uses_it() -> None:
    world = World.from_scene("office")
    renders = Counted(world)
    cam = create({"backend": "sim", "seed": 3}, world)
    cam.open()
    world.set_ptu_target(30.0, -20.0)  # as the simulated PTU says when its move starts
    world.set_ptu(30.0, -20.0)  # ... and where it stops
    xyz, _ = cam.grab_xyz(integrate=2)
    assert len(renders.poses) == 1  # the one rendered ahead, not a second at the grab
    np.testing.assert_array_equal(renders.poses[0], world.sensor_pose("tof"))
    # the same frame a camera that renders at the grab measures (same seed, same noise)
    np.testing.assert_array_equal(xyz, renders.fresh_frame())
    # a move that stops elsewhere than announced is rendered at the grab, where it stopped
    renders.move_and_grab(cam, (10.0, -20.0), (12.0, -20.0), ahead=2, after=3)
    cam.close()
    world.set_ptu_target(-30.0, -20.0)  # a closed camera renders nothing ahead
    assert len(renders.poses) == 3


def test_a_camera_that_takes_no_frame_stops_rendering_ahead_until_it_takes_one() -> None:
    """While the PTU points other sensors (a stereo scan, orient), the ToF renders the first
    move's view ahead and no further views it never uses; its next frame is the one a render at
    that pose gives, and the renders ahead resume from there."""
    world = World.from_scene("office")
    renders = Counted(world)
    cam = create({"backend": "sim", "seed": 3}, world)
    cam.open()
    for i, pan in enumerate((30.0, 10.0, -10.0, -30.0, 20.0)):  # five moves, no frame: two renders ahead
        world.set_ptu_target(pan, -20.0)
        renders.settle(min(i + 1, 2))
        world.set_ptu(pan, -20.0)
    assert len(renders.poses) == 2
    xyz, _ = cam.grab_xyz(integrate=2)  # where the PTU is: rendered at the grab
    assert len(renders.poses) == 3
    np.testing.assert_array_equal(renders.poses[-1], world.sensor_pose("tof"))
    np.testing.assert_array_equal(xyz, renders.fresh_frame())
    # a frame was taken: the next move is rendered ahead again, and its grab uses that render
    renders.move_and_grab(cam, (0.0, -30.0), (0.0, -30.0), ahead=4, after=4)
    cam.close()


def test_the_simulated_ptu_announces_the_stop_of_every_move() -> None:
    """Through the PTU's own serial protocol: the world hears the target in degrees, as the
    PTU will report its position on arrival."""
    from drivers.ptu import create as create_ptu

    world = World.from_scene("office")
    heard: list[tuple[float, float]] = []
    world.watch_ptu_target(lambda pan, tilt: heard.append((pan, tilt)))
    ptu = create_ptu({"backend": "sim", "time_scale": 0.0}, world)
    ptu.open()
    try:
        ptu.move(25.0, -15.0, True)
        assert heard and heard[-1] == world.ptu()
        assert abs(heard[-1][0] - 25.0) < 0.05 and abs(heard[-1][1] + 15.0) < 0.05
    finally:
        ptu.close()
