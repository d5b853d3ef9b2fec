"""The simulated world all simulated devices see (terrain, objects, rover, sensor head) and
its renderer. Start from :class:`drivers.sim.world.World`::

    world = World.from_scene("office")      # config/scenes/office.yaml
    world.set_ptu(30.0, -10.0)
    r = world.render_sensor("tof", 176, 144)  # depth, range, albedo, normal, points, ...
"""
