"""The simulated ToF renders the view where the PTU is heading while it travels: a scan's grab
on arrival then costs the camera's frame, not the simulator's render as well (a real SR4000
renders nothing), which is what held the scan at 2-4x the hardware's limit. The frame must be the
one a render at arrival gives."""

from __future__ import annotations

import time

import numpy as np

from drivers.sim.world import World
from drivers.tof import create


def test_a_move_starts_the_render_of_where_it_stops_and_the_grab_there_uses_it() -> None:
    world = World.from_scene("office")
    renders: list[np.ndarray] = []
    render = world.render

    def counted(K, w, h, T, cancel=None):  # noqa: ANN001, ANN202 - the world's own signature
        renders.append(np.asarray(T).copy())
        return render(K, w, h, T, cancel)

    world.render = counted  # type: ignore[method-assign]
    cam = create({"backend": "sim", "seed": 3}, world)
    cam.open()
    world.set_ptu_target(30.0, -20.0)  # as the simulated PTU says when its move starts
    world.set_ptu(30.0, -20.0)  # ... and where it stops
    xyz, _ = cam.grab_xyz(integrate=2)
    assert len(renders) == 1  # the one rendered ahead, not a second at the grab
    np.testing.assert_array_equal(renders[0], world.sensor_pose("tof"))
    # the same frame a camera that renders at the grab measures (same seed, same noise)
    world.render = render  # type: ignore[method-assign]
    fresh = create({"backend": "sim", "seed": 3}, world)
    fresh.open()
    again, _ = fresh.grab_xyz(integrate=2)
    fresh.close()
    np.testing.assert_array_equal(xyz, again)
    # a move that stops elsewhere than announced is rendered at the grab, where it stopped
    world.render = counted  # type: ignore[method-assign]
    world.set_ptu_target(10.0, -20.0)
    end = time.monotonic() + 30.0
    while len(renders) < 2 and time.monotonic() < end:  # the render ahead, in its thread
        time.sleep(0.01)
    world.set_ptu(12.0, -20.0)
    cam.grab_xyz()
    assert len(renders) == 3
    np.testing.assert_array_equal(renders[-1], world.sensor_pose("tof"))
    cam.close()
    world.set_ptu_target(-30.0, -20.0)  # a closed camera renders nothing ahead
    assert len(renders) == 3


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


def test_a_camera_that_takes_no_frame_stops_rendering_ahead_until_it_takes_one() -> None:
    """While the PTU points other sensors (a stereo scan, orient), the ToF renders the first
    move's view ahead and no further views it never uses; its next frame is the one a render at
    that pose gives, and the renders ahead resume from there."""
    world = World.from_scene("office")
    renders: list[np.ndarray] = []
    render = world.render

    def counted(K, w, h, T, cancel=None):  # noqa: ANN001, ANN202 - the world's own signature
        renders.append(np.asarray(T).copy())
        return render(K, w, h, T, cancel)

    world.render = counted  # type: ignore[method-assign]
    cam = create({"backend": "sim", "seed": 3}, world)
    cam.open()

    def settled(n: int) -> None:  # the render ahead runs in its own thread
        end = time.monotonic() + 30.0
        while len(renders) < n and time.monotonic() < end:
            time.sleep(0.01)
        time.sleep(0.2)

    for i, pan in enumerate((30.0, 10.0, -10.0, -30.0, 20.0)):  # five moves, no frame: two renders ahead
        world.set_ptu_target(pan, -20.0)
        settled(min(i + 1, 2))
        world.set_ptu(pan, -20.0)
    assert len(renders) == 2
    xyz, _ = cam.grab_xyz(integrate=2)  # where the PTU is: rendered at the grab
    assert len(renders) == 3
    np.testing.assert_array_equal(renders[-1], world.sensor_pose("tof"))
    world.render = render  # type: ignore[method-assign]
    fresh = create({"backend": "sim", "seed": 3}, world)
    fresh.open()
    again, _ = fresh.grab_xyz(integrate=2)
    fresh.close()
    np.testing.assert_array_equal(xyz, again)
    world.render = counted  # type: ignore[method-assign]
    world.set_ptu_target(0.0, -30.0)  # a frame was taken: the next move is rendered ahead again
    settled(4)
    world.set_ptu(0.0, -30.0)
    cam.grab_xyz()
    assert len(renders) == 4
    np.testing.assert_array_equal(renders[-1], world.sensor_pose("tof"))
    cam.close()
