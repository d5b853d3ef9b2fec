"""Navigation: one navigate mission from the start to the goal (seed 000 sect. 4.4.4).

- :mod:`.config`: navigate's configuration, with its ``plan``, ``see`` and ``localisation``
  sections;
- :mod:`.mission`: the legs (the 360-degree scans, arrival, the products), over a strategy;
- :mod:`.strategy`: what a strategy does; :mod:`.scan` (stop and go) and :mod:`.see_strategy`
  (drive while seeing) are the two;
- the see loop's parts: :mod:`.see` (the seeing driver: frames, their fusion, the check, the
  mast's looks, the stop EVENT), :mod:`.sections` (the chooser: ENav's sections on the bounds
  map), :mod:`.map_legs` (the legs planned on the 5 cm maps and their pilot, ``see_gate
  off``), :mod:`.loop_stats` (what the loop did, for the OK line); where the mast looks is
  planned in :mod:`prox_workflows.algorithms.looks`;
- :mod:`.pursuit`: the see loop's steering geometry; :mod:`.planning`: the planner's parameters,
  the global maps, the goal's stand-in; :mod:`.localiser`: the pose between legs; :mod:`.track`:
  where the rover went.

The rover itself is a device (``drivers/rover``): navigation hands it a pilot per leg and never
knows whether the simulator or the GNC drives. The command handlers are
:mod:`rvs_server.commands.navigation`.
"""
